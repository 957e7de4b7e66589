"""Safe extraction of zip archives of survey files.

Refused, with the member named: absolute paths, drive letters, `..` components (path traversal), symbolic
links and other special files, encrypted members, nested archives, duplicate names, more members than
allowed, and any member or total whose uncompressed size exceeds the limits or whose compression ratio
exceeds the limit (zip bombs). Sizes are counted while decompressing, so a lying header cannot get more
bytes through than it declared."""

from __future__ import annotations

import errno
import posixpath
import shutil
import stat
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

IGNORED_NAMES = {".DS_Store", "Thumbs.db", "desktop.ini"}
IGNORED_PREFIXES = ("__MACOSX/",)
SMALL_MEMBER_BYTES = 1024 * 1024   # the ratio limit is not applied below this size (tiny text compresses well)
MAX_NAME_BYTES = 255               # one file or folder name (NAME_MAX of Linux and most file systems)
MAX_PATH_BYTES = 1024              # a member's whole relative path (PATH_MAX is 4096 with the folder above)
MAX_DEPTH = 32


class UnsafeArchive(Exception):
    pass


@dataclass
class ExtractedMember:
    name: str        # normalised relative POSIX path inside the archive
    path: Path       # where it was written
    size: int


@dataclass
class ArchiveLimits:
    max_members: int
    max_total_bytes: int
    max_member_bytes: int
    max_ratio: float


def normalise_member_name(raw: str) -> str:
    """The member's relative POSIX path, or UnsafeArchive when it would escape the extraction folder."""
    name = raw.replace("\\", "/")
    if name.startswith("/") or (len(name) > 1 and name[1] == ":"):
        raise UnsafeArchive(f"member {raw!r} has an absolute path")
    parts = [p for p in name.split("/") if p not in ("", ".")]
    if any(p == ".." for p in parts):
        raise UnsafeArchive(f"member {raw!r} points outside the archive folder ('..')")
    if any("\x00" in p for p in parts):
        raise UnsafeArchive(f"member {_short(raw)!r} has a NUL character in its name")
    for p in parts:
        if len(p.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
            raise UnsafeArchive(f"member {_short(raw)!r} has a file or folder name longer than {MAX_NAME_BYTES} "
                                "bytes (file systems refuse it): rename it")
    if len(parts) > MAX_DEPTH or len(name.encode("utf-8", "surrogatepass")) > MAX_PATH_BYTES:
        raise UnsafeArchive(f"member {_short(raw)!r} is nested too deeply or its path is longer than "
                            f"{MAX_PATH_BYTES} bytes")
    return posixpath.join(*parts) if parts else ""


def _short(name: str, n: int = 120) -> str:
    return name if len(name) <= n else name[:n] + "..."


def extract_zip(archive: Path, dest: Path, limits: ArchiveLimits) -> list[ExtractedMember]:
    archive, dest = Path(archive), Path(dest)
    try:
        zf = zipfile.ZipFile(archive)
    except zipfile.BadZipFile as exc:
        raise UnsafeArchive(f"not a readable zip archive ({exc}; truncated upload?)") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > limits.max_members:
            raise UnsafeArchive(f"{len(infos)} members, more than the limit of {limits.max_members}")
        declared_total = 0
        plan: list[tuple[zipfile.ZipInfo, str]] = []
        seen: set[str] = set()
        for info in infos:
            name = normalise_member_name(info.filename)
            mode = info.external_attr >> 16
            if info.is_dir() or not name:
                continue
            if stat.S_ISLNK(mode):
                raise UnsafeArchive(f"member {info.filename!r} is a symbolic link")
            if mode and not stat.S_ISREG(mode) and stat.S_IFMT(mode) != 0:
                raise UnsafeArchive(f"member {info.filename!r} is not a regular file")
            if info.flag_bits & 0x1:
                raise UnsafeArchive(f"member {info.filename!r} is encrypted")
            if posixpath.basename(name) in IGNORED_NAMES or name.startswith(IGNORED_PREFIXES):
                continue
            key = name.lower()
            if key in seen:
                raise UnsafeArchive(f"member {info.filename!r} appears twice")
            seen.add(key)
            if info.file_size > limits.max_member_bytes:
                raise UnsafeArchive(f"member {info.filename!r} is {info.file_size} bytes uncompressed, "
                                    f"more than the limit of {limits.max_member_bytes}")
            if info.file_size > SMALL_MEMBER_BYTES and info.file_size > limits.max_ratio * max(info.compress_size, 1):
                raise UnsafeArchive(f"member {info.filename!r} expands {info.file_size / max(info.compress_size, 1):.0f}"
                                    f" times (limit {limits.max_ratio:.0f}): refused as a possible zip bomb")
            declared_total += info.file_size
            plan.append((info, name))
        if declared_total > limits.max_total_bytes:
            raise UnsafeArchive(f"archive expands to {declared_total} bytes, more than the limit of "
                                f"{limits.max_total_bytes}")
        archive_size = max(archive.stat().st_size, 1)
        if declared_total > SMALL_MEMBER_BYTES and declared_total > limits.max_ratio * archive_size:
            raise UnsafeArchive(f"archive expands {declared_total / archive_size:.0f} times (limit "
                                f"{limits.max_ratio:.0f}): refused as a possible zip bomb")
        out: list[ExtractedMember] = []
        total = 0
        dest_root = dest.resolve()
        for info, name in plan:
            target = (dest_root / name).resolve()
            if dest_root not in target.parents:
                raise UnsafeArchive(f"member {info.filename!r} points outside the archive folder")
            written = 0
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                with zf.open(info) as src, open(target, "wb") as dst:
                    while True:
                        block = src.read(1024 * 1024)
                        if not block:
                            break
                        written += len(block)
                        total += len(block)
                        if written > info.file_size:
                            raise UnsafeArchive(f"member {info.filename!r} expands beyond its declared size")
                        if total > limits.max_total_bytes:
                            raise UnsafeArchive("archive expands beyond the size limit")
                        dst.write(block)
            except (zipfile.BadZipFile, EOFError, zlib.error) as exc:
                raise UnsafeArchive(f"member {info.filename!r} is corrupt ({exc})") from None
            except NotImplementedError as exc:
                raise UnsafeArchive(f"member {info.filename!r} uses an unsupported compression ({exc})") from None
            except OSError as exc:
                if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                    raise                # a full disk is the server's problem (507), not the archive's
                raise UnsafeArchive(f"member {_short(info.filename)!r} cannot be written as a file "
                                    f"({exc.strerror or exc})") from None
            out.append(ExtractedMember(name, target, written))
        return out


def remove_tree(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)
