"""Open GNSS files whatever their packing: plain, gzip (.gz), Unix compress (.Z) and Hatanaka (.crx, .##d),
alone or combined (.crx.gz, .21d.Z). The packing is recognised by content (magic bytes), not only by name."""

from __future__ import annotations

import gzip
import zlib
from pathlib import Path

from ..errors import InputFileError

_GZIP_MAGIC = b"\x1f\x8b"
_COMPRESS_MAGIC = b"\x1f\x9d"


def read_bytes(path) -> bytes:
    """File content with gzip / Unix-compress layers removed (Hatanaka is left as is)."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "file not found")
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a file")
    data = p.read_bytes()
    for _ in range(3):  # nested packings, e.g. a gzip inside a .Z (rare but seen)
        if data[:2] == _GZIP_MAGIC:
            try:
                data = gzip.decompress(data)
            except (OSError, EOFError, zlib.error) as exc:
                raise InputFileError(p, f"gzip data is truncated or corrupt ({exc})") from None
        elif data[:2] == _COMPRESS_MAGIC:
            data = unix_uncompress(data, p)
        else:
            break
    return data


class _Enough(Exception):
    pass


class _CappedSink:
    """A file-like sink that keeps the first ``limit`` bytes written and then stops the writer."""

    def __init__(self, limit: int | None):
        self.data = bytearray()
        self.limit = limit

    def write(self, chunk) -> int:
        self.data += chunk
        if self.limit is not None and len(self.data) >= self.limit:
            raise _Enough
        return len(chunk)


def unix_uncompress(data: bytes, path, limit: int | None = None) -> bytes:
    """Unpack Unix compress (.Z, LZW) data with ncompress (C, ~40 MB/s; the pure-Python decoder used before
    took 3 s per 1.5 MB). ``limit``: stop once that many bytes are unpacked (a head for recognising a file
    costs what the head costs, whatever the file's size). Corrupt data raises InputFileError naming ``path``."""
    import io

    import ncompress

    sink = _CappedSink(limit)
    try:
        ncompress.decompress(io.BytesIO(data), sink)
    except _Enough:
        pass
    except (ValueError, OSError, EOFError) as exc:
        raise InputFileError(path, f"Unix-compress (.Z) data is truncated or corrupt ({exc})") from None
    return bytes(sink.data if limit is None else sink.data[:limit])


def read_head_bytes(path, n: int = 65536) -> bytes:
    """The first ``n`` bytes of the unpacked content: only those are read and unpacked of a plain, gzip or
    Unix-compress file (a large log is recognised without unpacking it whole)."""
    p = Path(path)
    if not p.is_file():
        return read_bytes(p)[:n]          # raises the "not found" / "is a folder" error
    with open(p, "rb") as f:
        magic = f.read(2)
    if magic == _GZIP_MAGIC:
        try:
            with gzip.open(p, "rb") as g:
                data = g.read(n)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputFileError(p, f"gzip data is truncated or corrupt ({exc})") from None
        return read_bytes(p)[:n] if data[:2] in (_GZIP_MAGIC, _COMPRESS_MAGIC) else data
    if magic == _COMPRESS_MAGIC:
        data = unix_uncompress(p.read_bytes(), p, limit=n)
        return read_bytes(p)[:n] if data[:2] in (_GZIP_MAGIC, _COMPRESS_MAGIC) else data
    with open(p, "rb") as f:
        return f.read(n)


def is_hatanaka(data: bytes) -> bool:
    head = data[:200]
    return b"CRINEX VERS" in head or b"COMPACT RINEX FORMAT" in head


def read_text(path) -> str:
    """Text of a RINEX-like file, decompressing gzip/.Z and Hatanaka as needed."""
    p = Path(path)
    data = read_bytes(p)
    if is_hatanaka(data):
        try:
            import hatanaka

            data = hatanaka.decompress(data)
        except Exception as exc:
            raise InputFileError(p, f"Hatanaka (CRINEX) data could not be decompressed ({exc})") from None
    if isinstance(data, bytes):
        if b"\x00" in data[:4096]:
            raise InputFileError(p, "binary data where a text (RINEX) file was expected")
        return data.decode("latin-1")
    return data
