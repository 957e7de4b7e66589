"""S3-compatible storage (MinIO in docker-compose, AWS S3, ...) with boto3."""

from __future__ import annotations

from pathlib import Path
from typing import Iterator

from .base import HASH_CHUNK, Storage


class S3Storage(Storage):
    def __init__(self, bucket: str, endpoint_url: str | None = None, region: str = "us-east-1",
                 access_key_id: str | None = None, secret_access_key: str | None = None):
        import boto3
        from botocore.config import Config

        self.bucket = bucket
        self.client = boto3.client("s3", endpoint_url=endpoint_url, region_name=region,
                                   aws_access_key_id=access_key_id, aws_secret_access_key=secret_access_key,
                                   config=Config(retries={"max_attempts": 5, "mode": "standard"},
                                                 s3={"addressing_style": "path"}))
        self._bucket_checked = False

    def _ensure_bucket(self) -> None:
        if self._bucket_checked:
            return
        from botocore.exceptions import ClientError

        try:
            self.client.head_bucket(Bucket=self.bucket)
        except ClientError:
            self.client.create_bucket(Bucket=self.bucket)
        self._bucket_checked = True

    def put_file(self, key: str, path: Path, move: bool = False) -> None:
        self._ensure_bucket()
        with _full_as_enospc(key):
            self.client.upload_file(str(path), self.bucket, key)   # multipart above 8 MB, atomic on completion
        if move:
            Path(path).unlink(missing_ok=True)

    def put_bytes(self, key: str, data: bytes) -> None:
        self._ensure_bucket()
        with _full_as_enospc(key):
            self.client.put_object(Bucket=self.bucket, Key=key, Body=data)

    def _head(self, key: str):
        from botocore.exceptions import ClientError

        self._ensure_bucket()
        try:
            return self.client.head_object(Bucket=self.bucket, Key=key)
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                return None
            raise

    def exists(self, key: str) -> bool:
        return self._head(key) is not None

    def size(self, key: str) -> int | None:
        h = self._head(key)
        return None if h is None else int(h["ContentLength"])

    def iter_bytes(self, key: str, start: int = 0, end: int | None = None, chunk: int = HASH_CHUNK) -> Iterator[bytes]:
        self._ensure_bucket()
        kw = {}
        if start or end is not None:
            kw["Range"] = f"bytes={start}-" + ("" if end is None else str(end - 1))
        body = self.client.get_object(Bucket=self.bucket, Key=key, **kw)["Body"]
        try:
            yield from body.iter_chunks(chunk)
        finally:
            body.close()

    def fetch(self, key: str, dest: Path, link_ok: bool = False) -> None:
        import os

        self._ensure_bucket()
        dest = Path(dest)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = dest.with_name(dest.name + ".part")
        self.client.download_file(self.bucket, key, str(tmp))
        os.replace(tmp, dest)

    def delete(self, key: str) -> None:
        self._ensure_bucket()
        self.client.delete_object(Bucket=self.bucket, Key=key)

    def delete_prefix(self, prefix: str) -> None:
        self._ensure_bucket()
        paginator = self.client.get_paginator("list_objects_v2")
        for page in paginator.paginate(Bucket=self.bucket, Prefix=prefix):
            keys = [{"Key": o["Key"]} for o in page.get("Contents", [])]
            if keys:
                self.client.delete_objects(Bucket=self.bucket, Delete={"Objects": keys})

    def check(self) -> None:
        self._bucket_checked = False
        self._ensure_bucket()


# what S3-compatible stores answer when they have no room left (MinIO; S3 itself has no such state)
_STORAGE_FULL_CODES = ("XMinioStorageFull", "StorageFull", "InsufficientStorage", "507")


class _full_as_enospc:
    """A full object store raised as OSError(ENOSPC), the same as a full local disk (API: 507)."""

    def __init__(self, key: str):
        self.key = key

    def __enter__(self):
        return self

    def __exit__(self, et, exc, tb):
        if exc is None:
            return False
        import errno

        from botocore.exceptions import ClientError

        try:
            from boto3.exceptions import S3UploadFailedError
        except ImportError:      # pragma: no cover
            S3UploadFailedError = ()
        text = str(exc)
        code = exc.response.get("Error", {}).get("Code") if isinstance(exc, ClientError) else ""
        if code in _STORAGE_FULL_CODES or (isinstance(exc, S3UploadFailedError)
                                           and any(c in text for c in _STORAGE_FULL_CODES[:2])):
            raise OSError(errno.ENOSPC, f"object store full, {self.key} not stored") from exc
        return False
