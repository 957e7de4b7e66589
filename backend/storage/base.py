"""The storage interface shared by the local-disk and S3 implementations."""

from __future__ import annotations

import hashlib
from abc import ABC, abstractmethod
from pathlib import Path
from typing import BinaryIO, Iterator

HASH_CHUNK = 1024 * 1024


def blob_key(sha256: str) -> str:
    return f"blobs/{sha256[:2]}/{sha256[2:4]}/{sha256}"


def sha256_of_file(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(HASH_CHUNK)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


class Storage(ABC):
    @abstractmethod
    def put_file(self, key: str, path: Path, move: bool = False) -> None:
        """Store a local file under key (atomically: a reader sees the whole file or nothing). ``move``: the
        file is the store's afterwards (a local store renames it into place instead of copying its bytes;
        the file is gone once this returns)."""

    @abstractmethod
    def put_bytes(self, key: str, data: bytes) -> None: ...

    @abstractmethod
    def exists(self, key: str) -> bool: ...

    @abstractmethod
    def size(self, key: str) -> int | None: ...

    @abstractmethod
    def iter_bytes(self, key: str, start: int = 0, end: int | None = None,
                   chunk: int = HASH_CHUNK) -> Iterator[bytes]:
        """The bytes [start, end) of the object, in chunks."""

    @abstractmethod
    def fetch(self, key: str, dest: Path, link_ok: bool = False) -> None:
        """Write the object to a local path (a hard link is fine when link_ok and the store is local)."""

    @abstractmethod
    def delete(self, key: str) -> None: ...

    @abstractmethod
    def delete_prefix(self, prefix: str) -> None: ...

    def local_path(self, key: str) -> Path | None:
        """A local path of the object when the store is a local disk (served with sendfile), else None."""
        return None

    def read_bytes(self, key: str) -> bytes:
        return b"".join(self.iter_bytes(key))

    def open_read(self, key: str) -> BinaryIO:
        import io

        return io.BytesIO(self.read_bytes(key))

    def put_blob(self, path: Path, sha256: str | None = None) -> tuple[str, int]:
        """Store a file content-addressed; returns (sha256, size). Stored once whatever the number of copies."""
        sha = sha256 or sha256_of_file(path)
        key = blob_key(sha)
        if not self.exists(key):
            self.put_file(key, path)
        return sha, Path(path).stat().st_size

    def put_blob_bytes(self, data: bytes) -> tuple[str, int]:
        sha = hashlib.sha256(data).hexdigest()
        key = blob_key(sha)
        if not self.exists(key):
            self.put_bytes(key, data)
        return sha, len(data)

    def check(self, min_free_bytes: int = 0) -> None:
        """Raise when the store cannot be reached or, where it can tell, has less than ``min_free_bytes``
        free (health check: StorageFull)."""

    def free_bytes(self) -> int | None:
        """Bytes a new object may still take, where the store can tell (local disk), else None."""
        return None


class StorageFull(OSError):
    """Less room in the store than the operator's minimum (GEOREF_MIN_FREE_STORAGE_BYTES)."""
