"""A site's calibration (services/calibrations.py)."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field


class SiteCalibrationIn(BaseModel):
    document: dict | None = Field(default=None, description="the calibration JSON document `georef datum calibrate` "
                                  "writes (format georef-site-calibration, version 1), in the site CRS and datum")
    pairs_csv: str | None = Field(default=None, max_length=1_000_000, description="or a CSV of control pairs (name, "
                                  "easting_m, northing_m, height_m, local_e_m, local_n_m, local_h_m[, use]) solved "
                                  "here in the site CRS and the site's height datum")
    name: str | None = Field(default=None, max_length=200, description="a name for it (default: the document's, or "
                             "the file's)")
    source_name: str | None = Field(default=None, max_length=255, description="the file it came from (shown)")


class SiteCalibrationOut(BaseModel):
    site_id: str
    name: str
    source_name: str
    crs: str
    height_datum: str
    summary: dict = Field(description="parameters (scale, ppm, rotation, origins, vertical model, constant and "
                          "slopes), sigmas, residuals per point (given local minus calibrated, m) and their statistics")
    document: dict = Field(description="the calibration JSON document the datum step applies")
    set_by: str | None = None
    created_at: datetime
    updated_at: datetime
    version: int
