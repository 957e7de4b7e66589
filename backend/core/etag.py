"""ETags: rows with a version counter get '"<id>.v<version>"'; other representations the hash of their bytes."""

from __future__ import annotations

import hashlib


def version_etag(obj) -> str:
    return f'"{obj.id[:8]}.v{obj.version}"'


def bytes_etag(data: bytes) -> str:
    return '"' + hashlib.blake2b(data, digest_size=12).hexdigest() + '"'


def if_none_match_hits(header: str | None, etag: str) -> bool:
    if not header:
        return False
    tags = [t.strip().removeprefix("W/") for t in header.split(",")]
    return "*" in tags or etag in tags
