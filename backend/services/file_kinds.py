"""Recognise an uploaded file by its content (never by its name alone) and read what the pre-flight check
needs from it: RINEX observation/navigation (plain, gzip, Unix compress, Hatanaka), u-blox UBX logs,
JPEG/TIFF images, camera-event CSV, control/check points CSV, ODM gcp_list.txt, survey.json, zip archives.

`recognise(path, name)` returns a `Recognised(kind, meta)` or raises `UnrecognisedFile(message)` whose
message says what the file looks like and what was expected."""

from __future__ import annotations

import csv
import io
import json
import mmap
import re
import struct
import zlib
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

GPS_EPOCH = datetime(1980, 1, 6)
HEAD_BYTES = 65536
TEXT_TABLE_MAX_BYTES = 50 * 1024**2

KINDS = ("rinex-obs", "rinex-nav", "ubx", "image", "events", "points", "gcp-list", "survey-metadata", "archive")
# upload "kind" hints a client may give -> file kinds they accept
HINTS = {
    "rover": ("rinex-obs", "ubx"),
    "base": ("rinex-obs", "ubx"),
    "nav": ("rinex-nav", "ubx"),
    "images": ("image",),
    "image": ("image",),
    "events": ("events",),
    "points": ("points",),
    "gcp_list": ("gcp-list",),
    "survey_metadata": ("survey-metadata",),
    "archive": ("archive",),
}
KIND_WORDS = {
    "rinex-obs": "a RINEX observation file", "rinex-nav": "a RINEX navigation file", "ubx": "a u-blox UBX log",
    "image": "an image (JPEG/TIFF)", "events": "a camera-event CSV", "points": "a control/check points CSV",
    "gcp-list": "an ODM gcp_list.txt", "survey-metadata": "a survey.json", "archive": "a zip archive",
}


class UnrecognisedFile(Exception):
    pass


@dataclass
class Recognised:
    kind: str
    meta: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- helpers


def _read_head(path: Path, n: int = HEAD_BYTES) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def _decompressed_head(path: Path, raw: bytes) -> tuple[bytes, str | None]:
    """First bytes after removing gzip / Unix-compress packing; the packing's name."""
    if raw[:2] == b"\x1f\x8b":
        d = zlib.decompressobj(16 + zlib.MAX_WBITS)
        out = b""
        with open(path, "rb") as f:
            while len(out) < HEAD_BYTES:
                block = f.read(65536)
                if not block:
                    break
                try:
                    out += d.decompress(block, HEAD_BYTES - len(out))
                except zlib.error as exc:
                    raise UnrecognisedFile(f"gzip data is corrupt ({exc})") from None
        return out, "gzip"
    if raw[:2] == b"\x1f\x9d":
        import unlzw3

        size = path.stat().st_size
        if size > 512 * 1024**2:
            raise UnrecognisedFile("Unix-compress (.Z) file larger than 512 MB; please send it uncompressed or gzip")
        try:
            return unlzw3.unlzw(path.read_bytes())[:HEAD_BYTES], "compress"
        except Exception as exc:
            raise UnrecognisedFile(f"Unix-compress (.Z) data is truncated or corrupt ({exc})") from None
    return raw, None


def _iter_text_lines(path: Path, packing: str | None):
    if packing == "gzip":
        import gzip

        with gzip.open(path, "rt", encoding="latin-1", newline="") as f:
            yield from f
    elif packing == "compress":
        import unlzw3

        yield from io.StringIO(unlzw3.unlzw(path.read_bytes()).decode("latin-1"))
    else:
        with open(path, "rt", encoding="latin-1", newline="") as f:
            yield from f


def _gps_seconds(y: int, mo: int, d: int, h: int, mi: int, s: float) -> float:
    if y < 100:
        y += 2000 if y < 80 else 1900
    return (datetime(y, mo, d, h, mi) - GPS_EPOCH).total_seconds() + s


def _looks_binary(data: bytes) -> bool:
    return b"\x00" in data[:8192]


# ---------------------------------------------------------------------------------------------- GNSS


_R3_EPOCH = re.compile(r"^> (\d{4}) +(\d+) +(\d+) +(\d+) +(\d+) +(\d+\.\d+) +(\d)")
_R2_EPOCH = re.compile(r"^ (\d\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d\.\d{7})  (\d)")


def _rinex_header(text: str) -> dict:
    meta: dict = {}
    for line in text.splitlines():
        label = line[60:].strip()
        if label == "RINEX VERSION / TYPE":
            try:
                meta["rinex_version"] = float(line[:9])
            except ValueError:
                pass
        elif label == "MARKER NAME":
            meta["marker"] = line[:60].strip()
        elif label == "INTERVAL":
            try:
                meta["interval_s"] = float(line[:10])
            except ValueError:
                pass
        elif label == "APPROX POSITION XYZ":
            try:
                meta["approx_position_ecef_m"] = [float(line[i:i + 14]) for i in (0, 14, 28)]
            except ValueError:
                pass
        elif label in ("TIME OF FIRST OBS", "TIME OF LAST OBS"):
            try:
                f = line[:43].split()
                t = _gps_seconds(int(f[0]), int(f[1]), int(f[2]), int(f[3]), int(f[4]), float(f[5]))
                meta["first_gps_time_s" if "FIRST" in label else "header_last_gps_time_s"] = t
            except (ValueError, IndexError):
                pass
        elif label == "END OF HEADER":
            meta["header_complete"] = True
            break
    return meta


def _rinex_obs_meta(path: Path, packing: str | None, hatanaka: bool, head_text: str) -> dict:
    meta = _rinex_header(head_text)
    if hatanaka:   # epoch lines are differenced: trust the header
        if "header_last_gps_time_s" in meta:
            meta["last_gps_time_s"] = meta["header_last_gps_time_s"]
        meta["compressed"] = "hatanaka"
        return meta
    first = last = None
    epochs = events = 0
    in_header = True
    v3 = meta.get("rinex_version", 3.0) >= 3
    rx = _R3_EPOCH if v3 else _R2_EPOCH
    for line in _iter_text_lines(path, packing):
        if in_header:
            if "END OF HEADER" in line[60:]:
                in_header = False
            continue
        if (v3 and not line.startswith(">")) or (not v3 and not line.startswith(" ")):
            continue
        m = rx.match(line)
        if not m:
            continue
        flag = int(m.group(7))
        t = _gps_seconds(*(int(m.group(i)) for i in range(1, 6)), float(m.group(6)))
        if flag == 5:
            events += 1
        elif flag in (0, 1):
            epochs += 1
            first = t if first is None else min(first, t)
            last = t if last is None else max(last, t)
    if in_header:
        raise UnrecognisedFile("RINEX observation header has no END OF HEADER line (truncated file?)")
    if not epochs:
        raise UnrecognisedFile("RINEX observation file without any observation epoch")
    meta.update(first_gps_time_s=first, last_gps_time_s=last, epochs=epochs, event_marks=events)
    if packing:
        meta["compressed"] = packing
    return meta


def _ubx_meta(path: Path) -> dict:
    """Time span of the raw measurements (RXM-RAWX) and number of time marks (TIM-TM2) of a UBX log."""
    first = last = None
    rawx = tm2 = frames = bad = 0
    size = path.stat().st_size
    if size == 0:
        raise UnrecognisedFile("empty file")
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        i = mm.find(b"\xb5\x62")
        while 0 <= i < size - 8:
            cls, mid, length = mm[i + 2], mm[i + 3], struct.unpack_from("<H", mm, i + 4)[0]
            end = i + 6 + length + 2
            if end > size:
                break
            ck_a = ck_b = 0
            for b in mm[i + 2:i + 6 + length]:
                ck_a = (ck_a + b) & 0xFF
                ck_b = (ck_b + ck_a) & 0xFF
            if ck_a == mm[end - 2] and ck_b == mm[end - 1]:
                frames += 1
                if cls == 0x02 and mid == 0x15 and length >= 16:
                    tow, week = struct.unpack_from("<dH", mm, i + 6)
                    t = week * 604800.0 + tow
                    first = t if first is None else min(first, t)
                    last = t if last is None else max(last, t)
                    rawx += 1
                elif cls == 0x0D and mid == 0x03:
                    tm2 += 1
                i = mm.find(b"\xb5\x62", end)
            else:
                bad += 1
                i = mm.find(b"\xb5\x62", i + 2)
    if frames == 0:
        raise UnrecognisedFile("u-blox sync bytes found but no valid UBX frame (checksum errors)")
    meta = {"frames": frames, "bad_frames": bad, "rawx_epochs": rawx, "event_marks": tm2}
    if first is not None:
        meta.update(first_gps_time_s=first, last_gps_time_s=last)
    return meta


# ---------------------------------------------------------------------------------------------- tables


def _read_table_text(path: Path) -> str:
    if path.stat().st_size > TEXT_TABLE_MAX_BYTES:
        raise UnrecognisedFile(f"text table larger than {TEXT_TABLE_MAX_BYTES // 1024**2} MB")
    data = path.read_bytes()
    if _looks_binary(data):
        raise UnrecognisedFile("binary data")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


POINT_COLUMNS = ("name", "easting_m", "northing_m", "ellipsoidal_height_m")


def parse_points_csv(text: str) -> list[dict]:
    """Rows of a points.csv (name,easting_m,northing_m,ellipsoidal_height_m[,role]); raises ValueError
    with the line number of the first problem."""
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#")))
    if not rows:
        raise ValueError("no rows")
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in POINT_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"header lacks column(s) {', '.join(missing)} (expected {','.join(POINT_COLUMNS)},role)")
    idx = {c: header.index(c) for c in header}
    out, seen = [], set()
    for n, r in enumerate(rows[1:], 2):
        if len(r) < len(header):
            raise ValueError(f"line {n}: {len(r)} fields, {len(header)} expected")
        name = r[idx["name"]].strip()
        if not name:
            raise ValueError(f"line {n}: empty point name")
        if name in seen:
            raise ValueError(f"line {n}: point {name!r} appears twice")
        seen.add(name)
        vals = {}
        for c in POINT_COLUMNS[1:]:
            try:
                vals[c] = float(r[idx[c]])
            except ValueError:
                raise ValueError(f"line {n}: {c} {r[idx[c]]!r} is not a number") from None
            if vals[c] != vals[c] or abs(vals[c]) == float("inf"):
                raise ValueError(f"line {n}: {c} is not finite")
        role = r[idx["role"]].strip().lower() if "role" in idx else "check"
        if role not in ("control", "check"):
            raise ValueError(f"line {n}: role {role!r} is neither control nor check")
        out.append({"name": name, **vals, "role": role})
    if not out:
        raise ValueError("header only, no point")
    return out


def format_points_csv(points: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*POINT_COLUMNS, "role"])
    for p in points:
        w.writerow([p["name"], f"{p['easting_m']:.4f}", f"{p['northing_m']:.4f}", f"{p['ellipsoidal_height_m']:.4f}",
                    p["role"]])
    return buf.getvalue()


EVENT_TIME_COLUMNS = ("gps_time_s", "trigger_gps_time_s")


def parse_events_csv(text: str) -> list[dict]:
    rows = list(csv.reader(line for line in text.splitlines() if line.strip() and not line.startswith("#")))
    if not rows:
        raise ValueError("no rows")
    header = [h.strip().lower() for h in rows[0]]
    col = next((header.index(c) for c in EVENT_TIME_COLUMNS if c in header), None)
    if col is None:
        raise ValueError("header has no gps_time_s (or trigger_gps_time_s) column")
    img = header.index("image") if "image" in header else None
    out = []
    for n, r in enumerate(rows[1:], 2):
        try:
            t = float(r[col])
        except (ValueError, IndexError):
            raise ValueError(f"line {n}: event time {r[col] if col < len(r) else ''!r} is not a number") from None
        out.append({"gps_time_s": t, "image": r[img].strip() if img is not None and img < len(r) else None})
    if not out:
        raise ValueError("header only, no event")
    return out


_CRS_LINE = re.compile(r"^(EPSG:\d+|WGS84 UTM \d+[NS]|\+proj=.*)$", re.IGNORECASE)


def parse_gcp_list(text: str) -> dict:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ValueError("empty")
    if not _CRS_LINE.match(lines[0]):
        raise ValueError(f"line 1: {lines[0][:60]!r} is not a CRS (EPSG:nnnn, WGS84 UTM nnX or +proj=...)")
    images, points = set(), set()
    for n, ln in enumerate(lines[1:], 2):
        f = ln.split()
        if len(f) < 6:
            raise ValueError(f"line {n}: {len(f)} fields, at least 6 expected (x y z px py image [name])")
        try:
            [float(v) for v in f[:5]]
        except ValueError:
            raise ValueError(f"line {n}: coordinates are not numbers") from None
        images.add(f[5])
        if len(f) > 6:
            points.add(f[6])
    if len(lines) < 2:
        raise ValueError("a CRS line and no measurement")
    return {"crs": lines[0], "measurements": len(lines) - 1, "images": sorted(images), "points": sorted(points)}


# ---------------------------------------------------------------------------------------------- images


def _image_meta(path: Path, head: bytes) -> dict:
    size = path.stat().st_size
    if head[:3] == b"\xff\xd8\xff":
        with open(path, "rb") as f:
            f.seek(max(0, size - 1024 * 1024))
            tail = f.read()
        if b"\xff\xd9" not in tail:
            raise UnrecognisedFile("truncated JPEG (no end-of-image marker)")
        fmt = "jpeg"
    else:
        fmt = "tiff"
        le = head[:2] == b"II"
        off = struct.unpack_from("<I" if le else ">I", head, 4)[0]
        if off < 8 or off >= size:
            raise UnrecognisedFile("TIFF header points outside the file (truncated?)")
    meta = {"format": fmt}
    try:
        from PIL import Image

        with Image.open(path) as im:
            meta["width"], meta["height"] = im.size
    except Exception as exc:   # Pillow raises many types on corrupt data
        raise UnrecognisedFile(f"image header cannot be read ({type(exc).__name__}: {exc})") from None
    return meta


# ---------------------------------------------------------------------------------------------- main


def _describe_unknown(head: bytes) -> str:
    if head[:4] == b"%PDF":
        return "a PDF document"
    if head[:4] == b"\x7fELF" or head[:2] == b"MZ":
        return "an executable program"
    if head[:8] == b"\x89PNG\r\n\x1a\n":
        return "a PNG image (drone photos must be JPEG or TIFF)"
    if head[:6] in (b"Rar!\x1a\x07",) or head[:6] == b"7z\xbc\xaf\x27\x1c":
        return "a RAR/7z archive (only zip archives are accepted)"
    if head[:3] == b"BZh" or head[:6] == b"\xfd7zXZ\x00":
        return "a bzip2/xz compressed file (use gzip or zip)"
    if not head:
        return "an empty file"
    if _looks_binary(head):
        return "binary data of an unknown format"
    first = head.split(b"\n", 1)[0][:60].decode("latin-1", errors="replace").strip()
    if first.lower().startswith(("<!doctype html", "<html")):
        return "an HTML page"
    return f"text starting with {first!r}"


def recognise(path, name: str = "") -> Recognised:
    path = Path(path)
    raw = _read_head(path)
    if not raw:
        raise UnrecognisedFile("empty file")
    if raw[:4] in (b"PK\x03\x04", b"PK\x05\x06"):
        return Recognised("archive", {})
    if raw[:3] == b"\xff\xd8\xff" or raw[:4] in (b"II*\x00", b"MM\x00*"):
        return Recognised("image", _image_meta(path, raw))
    head, packing = _decompressed_head(path, raw)
    if b"CRINEX VERS" in head[:200] or b"COMPACT RINEX FORMAT" in head[:200]:
        text = head.decode("latin-1", errors="replace")
        # the RINEX header follows the two CRINEX lines
        inner = "\n".join(text.splitlines()[2:])
        meta = _rinex_obs_meta(path, packing, True, inner)
        return Recognised("rinex-obs", meta)
    first_line = head[:200].split(b"\n", 1)[0].decode("latin-1", errors="replace")
    if "RINEX VERSION" in first_line:
        text = head.decode("latin-1", errors="replace")
        t = first_line[20:21].upper()
        if t == "O" or "OBSERVATION" in first_line.upper():
            return Recognised("rinex-obs", _rinex_obs_meta(path, packing, False, text))
        if t in ("N", "G", "H", "L", "C", "E", "J", "I") or "NAV" in first_line.upper():
            meta = _rinex_header(text)
            if not meta.get("header_complete"):
                raise UnrecognisedFile("RINEX navigation header has no END OF HEADER line (truncated file?)")
            if packing:
                meta["compressed"] = packing
            return Recognised("rinex-nav", meta)
        raise UnrecognisedFile(f"a RINEX file of type {t!r} (meteorological/clock files are not used)")
    if packing is None and b"\xb5\x62" in raw[:4096]:
        return Recognised("ubx", _ubx_meta(path))
    if packing is not None:
        raise UnrecognisedFile(f"{packing}-compressed data that is not RINEX")
    # text tables
    if _looks_binary(raw):
        raise UnrecognisedFile(_describe_unknown(raw))
    stripped = raw.lstrip()
    if stripped[:1] == b"{":
        try:
            obj = json.loads(_read_table_text(path))
        except ValueError as exc:
            raise UnrecognisedFile(f"JSON that cannot be parsed ({exc})") from None
        if not isinstance(obj, dict):
            raise UnrecognisedFile("JSON that is not an object")
        return Recognised("survey-metadata", {"keys": sorted(obj)[:50]})
    text = _read_table_text(path)
    first = next((ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")), "")
    low = first.lower()
    if _CRS_LINE.match(first.strip()):
        try:
            return Recognised("gcp-list", parse_gcp_list(text))
        except ValueError as exc:
            raise UnrecognisedFile(f"ODM gcp_list.txt: {exc}") from None
    if all(c in low for c in POINT_COLUMNS):
        try:
            pts = parse_points_csv(text)
        except ValueError as exc:
            raise UnrecognisedFile(f"points CSV: {exc}") from None
        return Recognised("points", {"points": len(pts), "control": sum(p["role"] == "control" for p in pts),
                                     "check": sum(p["role"] == "check" for p in pts)})
    if any(c in low.replace(" ", "").split(",") for c in EVENT_TIME_COLUMNS):
        try:
            ev = parse_events_csv(text)
        except ValueError as exc:
            raise UnrecognisedFile(f"camera-event CSV: {exc}") from None
        times = [e["gps_time_s"] for e in ev]
        return Recognised("events", {"events": len(ev), "first_gps_time_s": min(times), "last_gps_time_s": max(times),
                                     "images": [e["image"] for e in ev if e["image"]][:100000]})
    raise UnrecognisedFile(_describe_unknown(raw))
