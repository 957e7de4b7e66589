"""SQLAlchemy 2 typed ORM models: one module per area, every table registered on Base.metadata."""

from .accounts import ApiToken, LoginThrottle, Organisation, User, UserSession
from .base import Base
from .runs import Run, RunLog, RunOutput, RunStep, RunStepPart, VolumeMeasurement
from .sites import ROLES, DesignChangeJob, Schedule, Site, SiteCalibration, SiteDesign, SiteRole, Stockpile
from .surveys import Survey, SurveyFile, Upload, UploadChunk
from .webhooks import Webhook, WebhookDelivery

__all__ = ["ApiToken", "Base", "DesignChangeJob", "LoginThrottle", "Organisation", "ROLES", "Run", "RunLog", "RunOutput", "RunStep", "RunStepPart", "Schedule", "Site", "SiteCalibration", "SiteDesign",
           "SiteRole", "Stockpile", "Survey", "SurveyFile", "Upload", "UploadChunk", "User", "UserSession", "VolumeMeasurement", "Webhook",
           "WebhookDelivery"]
