"""Local-disk storage: a folder tree; writes go to a temporary file renamed into place."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .base import HASH_CHUNK, Storage, StorageFull


class LocalStorage(Storage):
    def __init__(self, root: Path):
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def _path(self, key: str) -> Path:
        p = (self.root / key).resolve()
        if self.root not in p.parents:
            raise ValueError(f"storage key outside the store: {key!r}")
        return p

    def _write_atomic(self, key: str, writer) -> None:
        dest = self._path(key)
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=dest.parent, prefix=".tmp-")
        try:
            with os.fdopen(fd, "wb") as f:
                writer(f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, dest)
        except BaseException:
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            raise

    def put_file(self, key: str, path: Path, move: bool = False) -> None:
        if move and self._move_in(key, Path(path)):
            return

        def w(f):
            with open(path, "rb") as src:
                shutil.copyfileobj(src, f, HASH_CHUNK)
        self._write_atomic(key, w)
        if move:
            Path(path).unlink(missing_ok=True)

    def _move_in(self, key: str, path: Path) -> bool:
        """Rename a local file into place (its bytes are written once, where they were received): synced
        first, so that the stored object survives a crash as a copied one does. False where a rename cannot
        do it (another file system): the caller copies."""
        dest = self._path(key)
        dest.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "rb+") as f:
            os.fsync(f.fileno())
        try:
            os.replace(path, dest)
        except OSError as exc:
            if exc.errno in (errno.EXDEV, errno.EPERM, errno.EACCES):
                return False
            raise
        try:
            fd = os.open(dest.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        except OSError:
            pass
        return True

    def put_bytes(self, key: str, data: bytes) -> None:
        self._write_atomic(key, lambda f: f.write(data))

    def exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def size(self, key: str) -> int | None:
        try:
            return self._path(key).stat().st_size
        except FileNotFoundError:
            return None

    def iter_bytes(self, key: str, start: int = 0, end: int | None = None, chunk: int = HASH_CHUNK) -> Iterator[bytes]:
        with open(self._path(key), "rb") as f:
            f.seek(start)
            remaining = None if end is None else max(0, end - start)
            while remaining is None or remaining > 0:
                b = f.read(chunk if remaining is None else min(chunk, remaining))
                if not b:
                    break
                if remaining is not None:
                    remaining -= len(b)
                yield b

    def read_bytes(self, key: str) -> bytes:
        return self._path(key).read_bytes()

    def fetch(self, key: str, dest: Path, link_ok: bool = False) -> None:
        src = self._path(key)
        dest = Path(dest)
        dest.parent.mkdir(parents=True, exist_ok=True)
        if dest.exists() or dest.is_symlink():
            dest.unlink()
        if link_ok:
            try:
                os.link(src, dest)
                return
            except OSError:
                pass
        tmp = dest.with_name(dest.name + ".part")
        shutil.copyfile(src, tmp)
        os.replace(tmp, dest)

    def delete(self, key: str) -> None:
        try:
            self._path(key).unlink()
        except FileNotFoundError:
            pass

    def delete_prefix(self, prefix: str) -> None:
        p = self._path(prefix.rstrip("/"))
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        elif p.is_file():
            p.unlink()

    def local_path(self, key: str) -> Path | None:
        p = self._path(key)
        return p if p.is_file() else None

    def free_bytes(self) -> int | None:
        """Space an unprivileged writer may still use (statvfs f_bavail: the blocks reserved for root are
        not counted, so that a server running as root does not report room it should not take)."""
        st = os.statvfs(self.root)
        return st.f_bavail * st.f_frsize

    def check(self, min_free_bytes: int = 0) -> None:
        if not os.access(self.root, os.W_OK):
            raise OSError(f"storage folder {self.root} is not writable")
        free = self.free_bytes()
        if free is not None and free < max(min_free_bytes, 1):
            raise StorageFull(errno.ENOSPC, f"storage full: {free} bytes free, at least {min_free_bytes} wanted")
