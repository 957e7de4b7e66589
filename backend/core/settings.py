"""Typed settings of the web platform, read from the environment (prefix GEOREF_) and an optional .env file.

The embedded default (one laptop: SQLite, files on local disk, a Celery broker in a SQLite file) needs no
variable at all; the production shape (docker-compose.yml) sets the database, broker and S3 variables."""

from __future__ import annotations

import ipaddress
import json
import os

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, IPvAnyNetwork, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="GEOREF_", env_file=".env", extra="ignore")

    # --- where everything lives (embedded shape)
    data_dir: Path = Path("work_out/platform")
    database_url: str = ""            # default: sqlite:///{data_dir}/georef.sqlite
    broker_url: str = ""              # default: sqla+sqlite:///{data_dir}/broker.sqlite
    # --- storage of uploaded files and results
    storage: Literal["local", "s3"] = "local"
    storage_dir: Path | None = None   # local: default {data_dir}/storage
    s3_endpoint_url: str | None = None
    s3_bucket: str = "georef"
    s3_region: str = "us-east-1"
    s3_access_key_id: str | None = None
    s3_secret_access_key: str | None = None
    work_dir: Path | None = None      # worker scratch (materialised surveys, run folders); default {data_dir}/work

    # --- web
    secret_key: str = "change-me-in-production"   # signs nothing secret-critical yet; used as webhook/test pepper
    cookie_secure: bool = True
    session_hours: float = 12.0
    cors_origins: list[str] = Field(default_factory=list)
    frontend_dist: Path | None = None  # default: <repo>/frontend/dist when it exists
    public_url: str = "http://127.0.0.1:8000"
    max_concurrent_requests: int = 32          # per API process; the database pool holds 60 connections
    # GET/HEAD requests inside the application at once per process (0 = two per CPU core, at least 4): reads
    # are CPU-bound, and more of them at once only share the cores and the GIL (docs/deploy.md)
    max_concurrent_reads: int = 0
    # collect and freeze the long-lived heap after start-up and after requests that import modules, so that
    # full garbage collections stay short (core/heap_freeze.py; docs/deploy.md)
    freeze_heap: bool = True
    # --- slow and oversized requests (docs/security.md, core/limits.py RequestBodyGuard): a request's body
    # is received in full before the request is admitted; it must arrive within request_body_timeout_s plus
    # one second per request_body_min_rate bytes received (else 408), and be at most max_request_body_bytes
    # (upload chunks: max_chunk_bytes; else 413). The embedded server also closes a connection whose request
    # headers take longer than request_header_timeout_s (408) or exceed max_request_header_bytes (431)
    request_body_timeout_s: float = Field(default=20.0, gt=0)
    request_body_min_rate: int = Field(default=16384, ge=1)       # bytes per second, past the timeout above
    max_request_body_bytes: int = Field(default=2 * 1024**2, ge=1024)
    request_header_timeout_s: float = Field(default=10.0, gt=0)
    max_request_header_bytes: int = Field(default=64 * 1024, ge=1024)
    # --- storage space: /health reports the storage as full (503) when less than this is free where
    # uploads and results are written (local disk: the storage folder and the work folder)
    min_free_storage_bytes: int = Field(default=256 * 1024**2, ge=0)

    # --- logins (docs/security.md): failed attempts are counted per account and per client address in the
    # database (every API process sees them); past the free attempts each further failure doubles the wait
    # (429 with Retry-After), up to login_backoff_max_s; counts are forgotten after login_failure_memory_s
    # without a failure, and an account's on a successful login
    login_max_failures_per_account: int = Field(default=5, ge=1)
    login_max_failures_per_client: int = Field(default=20, ge=1)
    login_backoff_base_s: float = Field(default=1.0, gt=0)
    login_backoff_max_s: float = Field(default=900.0, gt=0)
    login_failure_memory_s: float = Field(default=3600.0, gt=0)

    def resolved_max_concurrent_reads(self) -> int:
        if self.max_concurrent_reads > 0:
            return self.max_concurrent_reads
        return max(4, 2 * (os.cpu_count() or 1))

    # --- uploads
    max_upload_bytes: int = 20 * 1024**3      # one file (an image archive can be GBs)
    max_chunk_bytes: int = 64 * 1024**2
    max_archive_members: int = 20000
    max_archive_total_bytes: int = 40 * 1024**3
    max_archive_ratio: float = 200.0          # uncompressed / compressed, per member and in total
    upload_expiry_hours: float = 72.0

    # --- jobs
    heavy_queue: str = "heavy"       # georef and dense go there; '' = everything on the default queue
    default_queue: str = "georef"
    step_lease_s: float = 60.0       # a running step whose heartbeat is older than this is taken over
    requeue_queued_after_s: float = 600.0
    visibility_timeout_s: int = 3600      # Redis: an unacknowledged message is redelivered after this
    broker_restore_interval_s: int = 30   # Redis: how often workers look for such messages
    task_max_retries: int = 5
    schedule_tick_s: float = 60.0
    new_data_debounce_s: float = 300.0
    webhook_timeout_s: float = 10.0
    webhook_max_attempts: int = 8
    # webhook targets must be public addresses; networks listed here are allowed too (an on-premise GIS
    # server): "10.20.0.0/16,192.168.5.0/24" or a JSON list. Default: none (docs/security.md)
    webhook_allowed_networks: Annotated[list[IPvAnyNetwork], NoDecode] = Field(default_factory=list)

    @field_validator("webhook_allowed_networks", mode="before")
    @classmethod
    def _split_networks(cls, v):
        if isinstance(v, str):
            text = v.strip()
            if text.startswith("["):
                return json.loads(text)
            return [x for x in text.replace(",", " ").split() if x]
        if isinstance(v, (ipaddress.IPv4Network, ipaddress.IPv6Network)):
            return [v]
        return v

    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'georef.sqlite').resolve()}"

    def resolved_broker_url(self) -> str:
        if self.broker_url:
            return self.broker_url
        return f"sqla+sqlite:///{(self.data_dir / 'broker.sqlite').resolve()}"

    def resolved_storage_dir(self) -> Path:
        return (self.storage_dir or self.data_dir / "storage").resolve()

    def resolved_work_dir(self) -> Path:
        return (self.work_dir or self.data_dir / "work").resolve()

    def resolved_frontend_dist(self) -> Path | None:
        if self.frontend_dist is not None:
            return self.frontend_dist if self.frontend_dist.is_dir() else None
        p = Path(__file__).resolve().parents[2] / "frontend" / "dist"
        return p if (p / "index.html").is_file() else None


@lru_cache
def get_settings() -> Settings:
    return Settings()
