"""Open GNSS files whatever their packing: plain, gzip (.gz), Unix compress (.Z) and Hatanaka (.crx, .##d),
alone or combined (.crx.gz, .21d.Z). The packing is recognised by content (magic bytes), not only by name."""

from __future__ import annotations

import gzip
import io
import time
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
            data = gunzip_bounded(data, p, max_bytes=unpack_cap_bytes(len(data)))
        elif data[:2] == _COMPRESS_MAGIC:
            data = unix_uncompress(data, p, max_bytes=unpack_cap_bytes(len(data)))
        else:
            break
    return data


# A packed GNSS file unpacks to a few times its size (RINEX with gzip or compress: 3-10 times). A crafted one
# can unpack to thousands of times its size (LZW: a 16-bit code may stand for 65 kB; deflate: 1032 times), a
# "decompression bomb" that would fill the memory or the disk of whoever unpacks it. Unpacking stops, with
# the file's error, past MAX_UNPACK_RATIO times the packed size (and never before MIN_UNPACK_CAP_BYTES).
MAX_UNPACK_RATIO = 200.0
MIN_UNPACK_CAP_BYTES = 64 * 1024 * 1024


def unpack_cap_bytes(packed_bytes: int, ratio: float | None = None, floor: int | None = None) -> int:
    """The most bytes a packed file of ``packed_bytes`` may unpack to."""
    ratio = MAX_UNPACK_RATIO if ratio is None else ratio
    floor = MIN_UNPACK_CAP_BYTES if floor is None else floor
    return max(int(packed_bytes * ratio), floor)


def _too_large(path, packing: str, max_bytes: int) -> InputFileError:
    return InputFileError(path, f"{packing} data unpacks to more than {max_bytes} bytes (over "
                                f"{MAX_UNPACK_RATIO:g} times its packed size, or the limit for one file): refused "
                                "as a decompression bomb; send the file unpacked")


def _too_slow(path, packing: str, budget_s: float) -> InputFileError:
    return InputFileError(path, f"{packing} data took more than {budget_s:g} s to unpack: refused; send the file "
                                "unpacked or split it")


def gunzip_bounded(data: bytes, path, max_bytes: int) -> bytes:
    """gzip data unpacked (members one after another, as gzip does), at most ``max_bytes`` of it."""
    out = bytearray()
    rest = data
    try:
        while rest[:2] == _GZIP_MAGIC:
            d = zlib.decompressobj(16 + zlib.MAX_WBITS)
            piece = d.decompress(rest, max_bytes + 1 - len(out))
            out += piece
            if len(out) > max_bytes:
                raise _too_large(path, "gzip", max_bytes)
            if not d.eof:
                if d.unconsumed_tail:      # stopped by max_length only: the bound was reached
                    raise _too_large(path, "gzip", max_bytes)
                raise InputFileError(path, "gzip data is truncated or corrupt (ends inside a member)")
            rest = d.unused_data
    except zlib.error as exc:
        raise InputFileError(path, f"gzip data is truncated or corrupt ({exc})") from None
    return bytes(out)


class _Enough(Exception):
    pass


class _TooLarge(Exception):
    pass


class _TooSlow(Exception):
    pass


class _CappedSink:
    """A file-like sink for the decoder: keeps the first ``limit`` bytes written and then stops the writer
    (a head); stops it with _TooLarge past ``max_bytes`` and with _TooSlow past ``deadline`` (monotonic
    seconds). ``out``: a binary file the bytes go to instead of memory."""

    def __init__(self, limit: int | None, max_bytes: int | None = None, deadline: float | None = None, out=None):
        self.data = bytearray()
        self.limit = limit
        self.max_bytes = max_bytes
        self.deadline = deadline
        self.out = out
        self.size = 0

    def write(self, chunk) -> int:
        n = len(chunk)
        self.size += n
        if self.max_bytes is not None and self.size > self.max_bytes:
            raise _TooLarge
        if self.deadline is not None and time.monotonic() > self.deadline:
            raise _TooSlow
        if self.out is not None:
            self.out.write(chunk)
        else:
            self.data += chunk
        if self.limit is not None and self.size >= self.limit:
            raise _Enough
        return n


def _run_uncompress(src, sink: _CappedSink, path, budget_s: float | None) -> None:
    import ncompress

    try:
        ncompress.decompress(src, sink)
    except _Enough:
        pass
    except _TooLarge:
        raise _too_large(path, "Unix-compress (.Z)", sink.max_bytes) from None
    except _TooSlow:
        raise _too_slow(path, "Unix-compress (.Z)", budget_s) from None
    except (ValueError, OSError, EOFError) as exc:
        raise InputFileError(path, f"Unix-compress (.Z) data is truncated or corrupt ({exc})") from None


def unix_uncompress(data, path, limit: int | None = None, max_bytes: int | None = None,
                    time_budget_s: float | None = None) -> bytes:
    """Unpack Unix compress (.Z, LZW) data (bytes or a binary file) with ncompress (C, ~40 MB/s; the
    pure-Python decoder used before took 3 s per 1.5 MB). ``limit``: stop once that many bytes are unpacked
    (a head for recognising a file costs what the head costs, whatever the file's size). ``max_bytes`` and
    ``time_budget_s``: InputFileError naming ``path`` past that many unpacked bytes or seconds (a bomb).
    Corrupt data raises InputFileError naming ``path``."""
    deadline = None if time_budget_s is None else time.monotonic() + time_budget_s
    sink = _CappedSink(limit, max_bytes, deadline)
    _run_uncompress(io.BytesIO(data) if isinstance(data, (bytes, bytearray, memoryview)) else data, sink, path,
                    time_budget_s)
    return bytes(sink.data if limit is None else sink.data[:limit])


def unix_uncompress_to_file(src, out, path, max_bytes: int, time_budget_s: float | None = None) -> int:
    """Unpack Unix compress data from the binary file ``src`` into the binary file ``out``, at most
    ``max_bytes`` of it and within ``time_budget_s`` (else InputFileError naming ``path``); the size."""
    deadline = None if time_budget_s is None else time.monotonic() + time_budget_s
    sink = _CappedSink(None, max_bytes, deadline, out=out)
    _run_uncompress(src, sink, path, time_budget_s)
    return sink.size


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
        with open(p, "rb") as f:       # only the head is unpacked: the packed file is not read whole
            data = unix_uncompress(f, p, limit=n)
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
