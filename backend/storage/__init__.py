"""Object storage behind one interface: local disk (embedded) or S3-compatible (MinIO, AWS) via boto3.

Files of surveys and outputs of runs are stored content-addressed by SHA-256 (`blobs/ab/cd/abcd...`):
identical files are stored once, a key never changes content, and a step's outputs can be checked
against their checksums. Upload chunks live under `uploads/<upload_id>/` until the upload completes."""

from __future__ import annotations

from functools import lru_cache

from ..core.settings import Settings
from .base import Storage, blob_key
from .local import LocalStorage


def make_storage(settings: Settings) -> Storage:
    if settings.storage == "s3":
        from .s3 import S3Storage

        return S3Storage(bucket=settings.s3_bucket, endpoint_url=settings.s3_endpoint_url,
                         region=settings.s3_region, access_key_id=settings.s3_access_key_id,
                         secret_access_key=settings.s3_secret_access_key)
    return LocalStorage(settings.resolved_storage_dir())


@lru_cache(maxsize=16)
def _cached(kind: str, a: str, b: str | None, c: str | None, d: str | None, e: str | None) -> Storage:
    if kind == "s3":
        from .s3 import S3Storage

        return S3Storage(bucket=a, endpoint_url=b, region=c or "us-east-1", access_key_id=d, secret_access_key=e)
    from pathlib import Path

    return LocalStorage(Path(a))


def storage_for(settings: Settings) -> Storage:
    if settings.storage == "s3":
        return _cached("s3", settings.s3_bucket, settings.s3_endpoint_url, settings.s3_region,
                       settings.s3_access_key_id, settings.s3_secret_access_key)
    return _cached("local", str(settings.resolved_storage_dir()), None, None, None, None)


__all__ = ["Storage", "LocalStorage", "blob_key", "make_storage", "storage_for"]
