"""Recognise an uploaded file by its content (never by its name alone) and read what the pre-flight check
needs from it: RINEX observation/navigation (plain, gzip, Unix compress, Hatanaka), u-blox UBX logs,
RTCM 3 logs (DJI ``*_PPKRAW.bin``, D-RTK 2 and other base logs), DJI ``*_Timestamp.MRK`` exposure files,
JPEG/TIFF images, camera-event CSV, control/check points CSV, ODM gcp_list.txt, survey.json, zip archives.

The GNSS kinds are told apart by the core's own recognition (``georef_core.gnss.input_files.sniff_bytes``),
so that what the upload accepts is what the pipeline reads; this module only adds the metadata the
pre-flight needs, read cheaply (RTCM 3: a frame scan of the file in bounded pieces, no decoding of the
observations; MRK: the exposure lines).

`recognise(path, name)` returns a `Recognised(kind, meta)` or raises `UnrecognisedFile(message)` whose
message says what the file looks like and what was expected."""

from __future__ import annotations

import csv
import io
import json
import re
import struct
import zlib
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

GPS_EPOCH = datetime(1980, 1, 6)
HEAD_BYTES = 65536
TEXT_TABLE_MAX_BYTES = 50 * 1024**2
# a packed (gzip / Unix-compress) RINEX file's epoch scan unpacks it whole: at most PACKED_MAX_RATIO times
# its packed size (a decompression bomb: LZW and deflate data can be crafted to unpack to thousands of
# times its size) and PACKED_MAX_UNPACKED_BYTES in all, within SCAN_TIME_BUDGET_S; else 422 naming the file
PACKED_MAX_RATIO = 200.0
PACKED_MAX_UNPACKED_BYTES = 8 * 1024**3
SCAN_TIME_BUDGET_S = 120.0
SCAN_MAX_LINE_CHARS = 65536           # longer lines are read in pieces of this size (memory bound)

KINDS = ("rinex-obs", "rinex-nav", "ubx", "rtcm3", "dji-mrk", "image", "events", "points", "gcp-list",
         "survey-metadata", "archive", "site-calibration")
OBSERVATION_KINDS = ("rinex-obs", "ubx", "rtcm3")          # files with a role (rover or base)
# what a DJI flight folder holds that the pipeline reads: photos, the Timestamp.MRK, the aircraft's raw
# GNSS log (RTCM 3 PPKRAW.bin, UBX, its own Rinex.obs) and a navigation file written beside them
FLIGHT_KINDS = ("image", "dji-mrk", "rtcm3", "ubx", "rinex-obs", "rinex-nav")
# upload "kind" hints a client may give -> file kinds they accept
HINTS = {
    "rover": ("rinex-obs", "ubx", "rtcm3"),
    "base": ("rinex-obs", "ubx", "rtcm3"),
    "nav": ("rinex-nav", "ubx", "rtcm3"),
    "flight": FLIGHT_KINDS,
    "images": ("image",),
    "image": ("image",),
    "events": ("events",),
    "points": ("points",),
    "gcp-list": ("gcp-list",),
    "survey-metadata": ("survey-metadata",),
    "archive": ("archive",),
    "site-calibration": ("site-calibration",),
}
# the spellings of earlier API versions, still accepted from clients
HINT_ALIASES = {"gcp_list": "gcp-list", "survey_metadata": "survey-metadata"}
KIND_WORDS = {
    "rinex-obs": "a RINEX observation file", "rinex-nav": "a RINEX navigation file", "ubx": "a u-blox UBX log",
    "rtcm3": "an RTCM 3 log", "dji-mrk": "a DJI Timestamp.MRK (camera exposures)",
    "image": "an image (JPEG/TIFF)", "events": "a camera-event CSV", "points": "a control/check points CSV",
    "gcp-list": "an ODM gcp_list.txt", "survey-metadata": "a survey.json", "archive": "a zip archive",
    "site-calibration": "a site calibration (the JSON of georef datum calibrate, or a CSV of control pairs with "
                        "local_e_m, local_n_m, local_h_m)",
}


def served_kinds() -> dict:
    """The file kinds and upload hints as GET /file-kinds serves them: the one list of names the server and
    the browser's pre-check use (frontend/src/lib/sniff.ts; tests/frontend/test_file_kind_names.py)."""
    return {"kinds": [{"name": k, "description": KIND_WORDS[k]} for k in KINDS],
            "hints": {h: list(v) for h, v in HINTS.items()}, "hint_aliases": dict(HINT_ALIASES),
            "observation_kinds": list(OBSERVATION_KINDS), "flight_kinds": list(FLIGHT_KINDS)}


class UnrecognisedFile(Exception):
    """The file is not a survey file, or is one (``kind``) that is damaged."""

    def __init__(self, message: str, kind: str | None = None):
        super().__init__(message)
        self.kind = kind


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
        from georef_core.errors import InputFileError
        from georef_core.gnss.compressed_files import unix_uncompress

        size = path.stat().st_size
        if size > 512 * 1024**2:
            raise UnrecognisedFile("Unix-compress (.Z) file larger than 512 MB; please send it uncompressed or gzip")
        try:   # only the head is unpacked (and only what it needs is read): bounded work whatever the size
            with open(path, "rb") as f:
                return unix_uncompress(f, path, limit=HEAD_BYTES), "compress"
        except InputFileError as exc:
            raise UnrecognisedFile(exc.problem) from None
    return raw, None


def _unpack_cap_bytes(path: Path) -> int:
    return min(PACKED_MAX_UNPACKED_BYTES, max(int(path.stat().st_size * PACKED_MAX_RATIO), HEAD_BYTES))


def _iter_text_lines(path: Path, packing: str | None):
    """The file's lines (pieces of at most SCAN_MAX_LINE_CHARS of a longer one), packed or not. Packed
    data is unpacked within the bounds above (UnrecognisedFile past them: a decompression bomb)."""
    import time

    if packing == "gzip":
        import gzip

        cap = _unpack_cap_bytes(path)
        deadline = time.monotonic() + SCAN_TIME_BUDGET_S
        with gzip.open(path, "rb") as raw:
            text = io.TextIOWrapper(raw, encoding="latin-1", newline="")
            try:
                yield from _bounded_lines(text, lambda: raw.tell(), cap, deadline, "gzip")
            except (OSError, EOFError, zlib.error) as exc:
                raise UnrecognisedFile(f"gzip data is truncated or corrupt ({exc})") from None
    elif packing == "compress":
        import tempfile

        from georef_core.errors import InputFileError
        from georef_core.gnss.compressed_files import unix_uncompress_to_file

        # unpacked into a temporary file (C decoder, ~40 MB/s), read line by line: bounded memory; the
        # unpacking bounded in size and time (the C decoder is stopped as soon as either bound is passed)
        with tempfile.TemporaryFile() as tmp:
            try:
                with open(path, "rb") as src:
                    unix_uncompress_to_file(src, tmp, path, max_bytes=_unpack_cap_bytes(path),
                                            time_budget_s=SCAN_TIME_BUDGET_S)
            except InputFileError as exc:
                raise UnrecognisedFile(exc.problem) from None
            tmp.seek(0)
            yield from _bounded_lines(io.TextIOWrapper(tmp, encoding="latin-1", newline=""), None, None, None, "")
    else:
        with open(path, "rt", encoding="latin-1", newline="") as f:
            yield from _bounded_lines(f, None, None, None, "")


def _bounded_lines(f, unpacked_bytes, cap, deadline, packing: str):
    """Lines of a text file; past ``cap`` unpacked bytes or the monotonic ``deadline``: UnrecognisedFile."""
    import time

    read = 0
    next_check = 1 << 20
    while True:
        line = f.readline(SCAN_MAX_LINE_CHARS)
        if not line:
            return
        read += len(line)
        if cap is not None and read >= next_check:        # every MiB
            next_check = read + (1 << 20)
            if unpacked_bytes() > cap:
                raise UnrecognisedFile(f"{packing} data unpacks to more than {cap} bytes (over {PACKED_MAX_RATIO:g} "
                                       "times its packed size, or the limit for one file): refused as a "
                                       "decompression bomb; send the file unpacked")
            if time.monotonic() > deadline:
                raise UnrecognisedFile(f"{packing} data took more than {SCAN_TIME_BUDGET_S:g} s to unpack and scan: "
                                       "refused; send the file unpacked or split it")
        yield line


def _gps_seconds(y: int, mo: int, d: int, h: int, mi: int, s: float) -> float:
    """GPS seconds of a calendar date; ValueError for an impossible one (month 13, a 30-digit year ...)."""
    if y < 100:
        y += 2000 if y < 80 else 1900
    try:
        return (datetime(y, mo, d, h, mi) - GPS_EPOCH).total_seconds() + s
    except OverflowError:
        raise ValueError(f"date {y}-{mo}-{d} {h}:{mi} out of range") from None


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
    for n_line, line in enumerate(_iter_text_lines(path, packing), 1):
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
        try:
            t = _gps_seconds(*(int(m.group(i)) for i in range(1, 6)), float(m.group(6)))
        except (ValueError, OverflowError):   # month 13, day 32, hour 25, a year of 30 digits: named
            raise UnrecognisedFile(f"RINEX observation file, line {n_line}: impossible epoch date/time "
                                   f"{line[:30].strip()!r}") from None
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


UBX_SCAN_BYTES = 8 * 1024 * 1024      # the file is scanned in pieces of this size (memory bound)
_UBX_MAX_FRAME = 16384 + 8            # the core's longest plausible frame (payload limit + header + checksum)


def _ubx_meta(path: Path) -> dict:
    """Time span of the raw measurements (RXM-RAWX) and number of time marks (TIM-TM2) of a UBX log.

    The frames are found by the core's vectorised framing (``find_ubx_frames``: every candidate's
    Fletcher checksum from two running sums, so a file full of sync bytes costs the same as any other),
    in pieces of UBX_SCAN_BYTES: time and memory grow linearly with the file, whatever it holds."""
    import numpy as np
    from georef_core.gnss.ubx import find_ubx_frames

    size = path.stat().st_size
    if size == 0:
        raise UnrecognisedFile("empty file")
    first = last = None
    rawx = tm2 = frames = bad = 0
    pos = 0
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            data = f.read(UBX_SCAN_BYTES + _UBX_MAX_FRAME)
            if not data:
                break
            at_end = pos + len(data) >= size
            fr = find_ubx_frames(data)
            keep = np.ones(len(fr.start), dtype=bool) if at_end else fr.start < UBX_SCAN_BYTES
            start, length, msg = fr.start[keep], fr.length[keep], fr.msg_id[keep]
            frames += len(start)
            bad += fr.n_checksum_errors
            buf = np.frombuffer(data, dtype=np.uint8)
            sel = start[(msg == 0x0215) & (length >= 16)]
            if len(sel):
                tow = buf[sel[:, None] + 6 + np.arange(8)].copy().view("<f8")[:, 0]
                week = buf[sel[:, None] + 14 + np.arange(2)].copy().view("<u2")[:, 0]
                t = week.astype(np.float64) * 604800.0 + tow
                t = t[np.isfinite(t)]
                if len(t):
                    first = float(t.min()) if first is None else min(first, float(t.min()))
                    last = float(t.max()) if last is None else max(last, float(t.max()))
                rawx += len(sel)
            tm2 += int(np.count_nonzero(msg == 0x0D03))
            if at_end:
                break
            ends = start + length + 8
            pos += max(UBX_SCAN_BYTES, int(ends.max()) if len(ends) else 0)
    if frames == 0:
        raise UnrecognisedFile("u-blox sync bytes found but no valid UBX frame (checksum errors)")
    meta = {"frames": frames, "bad_frames": int(bad), "rawx_epochs": rawx, "event_marks": tm2}
    if first is not None:
        meta.update(first_gps_time_s=first, last_gps_time_s=last)
    return meta


# RTCM 3: message numbers -> what the pre-flight says about a log
RTCM3_EPHEMERIS_SYSTEM = {1019: "G", 1020: "R", 1042: "C", 1044: "J", 1045: "E", 1046: "E"}
RTCM3_MSM_SYSTEM = {107: "G", 108: "R", 109: "E", 111: "J", 112: "C"}    # message number // 10
SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "J": "QZSS", "C": "BeiDou"}
RTCM3_SCAN_BYTES = 8 * 1024 * 1024     # the file is scanned in pieces of this size (memory bound)
_RTCM3_MAX_FRAME = 1023 + 6
_WEEK_S = 604800.0


def _msm_tow_ms(buf, starts):
    """The 30-bit epoch time field (ms of the GNSS week) of MSM frames starting at ``starts``."""
    import numpy as np

    p = starts + 3 + 3           # payload byte 3 holds the field's first bits (after 12 + 12 bits)
    word = ((buf[p].astype(np.int64) << 24) | (buf[p + 1].astype(np.int64) << 16)
            | (buf[p + 2].astype(np.int64) << 8) | buf[p + 3].astype(np.int64))
    return (word >> 2) & 0x3FFFFFFF


def _rtcm3_meta(path: Path) -> dict:
    """What an RTCM 3 log holds, from a scan of its frames (CRC-24Q checked, payloads not decoded except
    a few bits: the satellite of each ephemeris, the epoch time of MSM messages, the week of a few
    ephemerides): message counts, observed systems, ephemerides per system, station position, time span
    (of week; as GPS time when an ephemeris gives the week)."""
    from collections import Counter

    import numpy as np
    from georef_core.gnss.rtcm3 import find_rtcm3_frames

    size = path.stat().st_size
    counts: Counter = Counter()
    eph_sats: dict[str, set] = {}
    week_payloads: dict[int, list[bytes]] = {}
    crc_errors = bytes_in_frames = 0
    first_tow = last_tow = None
    weeks_run = 0            # week roll-overs seen between the first and the last epoch
    epochs = 0
    interval = None
    prev_tail_ms = None
    pos = 0
    with open(path, "rb") as f:
        while pos < size:
            f.seek(pos)
            data = f.read(RTCM3_SCAN_BYTES + _RTCM3_MAX_FRAME)
            at_end = pos + len(data) >= size
            fr = find_rtcm3_frames(data)
            keep = np.ones(len(fr.start), dtype=bool) if at_end else fr.start < RTCM3_SCAN_BYTES
            start, length, msg = fr.start[keep], fr.length[keep], fr.msg_type[keep]
            crc_errors += fr.n_crc_errors
            bytes_in_frames += int(np.sum(length + 6))
            types, n = np.unique(msg, return_counts=True)
            counts.update(dict(zip(types.tolist(), n.tolist())))
            buf = np.frombuffer(data, dtype=np.uint8)
            for k in np.flatnonzero(np.isin(msg, list(RTCM3_EPHEMERIS_SYSTEM))).tolist():
                mt, s0 = int(msg[k]), int(start[k]) + 3
                b1, b2 = data[s0 + 1], data[s0 + 2]
                sat = (b1 & 0x0F) if mt == 1044 else ((b1 & 0x0F) << 2) | (b2 >> 6)
                eph_sats.setdefault(RTCM3_EPHEMERIS_SYSTEM[mt], set()).add(sat)
                got = week_payloads.setdefault(mt, [])
                if len(got) < 9:
                    got.append(data[s0:s0 + int(length[k])])
            # epochs: the time field of the GPS-time MSM messages (GPS, Galileo, QZSS; BeiDou + 14 s)
            group = msg // 10
            sel = np.isin(group, (107, 109, 111, 112)) & np.isin(msg % 10, (4, 5, 6, 7)) & (length >= 8)
            if np.any(sel):
                tow = _msm_tow_ms(buf, start[sel]) + np.where(group[sel] == 112, 14000, 0)
                tow = tow[tow < 604800000 + 14000]
                if len(tow):
                    uniq = np.unique(tow)
                    # an epoch whose messages are split by the piece boundary counts once
                    epochs += len(uniq) - int(prev_tail_ms is not None and prev_tail_ms in uniq)
                    if interval is None and len(uniq) > 2:
                        d = np.diff(uniq)
                        d = d[d > 0]
                        if len(d):
                            interval = float(np.median(d)) / 1000.0
                    if first_tow is None:
                        first_tow = int(tow[0])
                    if prev_tail_ms is not None and int(tow[0]) < prev_tail_ms - 302400000:
                        weeks_run += 1
                    weeks_run += int(np.count_nonzero(np.diff(tow) < -302400000))
                    prev_tail_ms = last_tow = int(tow[-1])
            if at_end:
                break
            ends = start + length + 6
            pos += max(RTCM3_SCAN_BYTES, int(ends.max()) if len(ends) else 0)
    if not counts:
        raise UnrecognisedFile("no valid RTCM 3 frame (CRC errors)", kind="rtcm3")
    msm = {mt: c for mt, c in counts.items() if mt // 10 in RTCM3_MSM_SYSTEM and mt % 10 in range(1, 8)}
    systems = sorted({RTCM3_MSM_SYSTEM[mt // 10] for mt in msm}, key="GREJC".find)
    eph = {mt: c for mt, c in counts.items() if mt in RTCM3_EPHEMERIS_SYSTEM}
    meta: dict = {
        "frames": int(sum(counts.values())), "crc_errors": int(crc_errors),
        "bytes_outside_frames": int(size - bytes_in_frames),
        "message_counts": {str(k): int(v) for k, v in sorted(counts.items())},
        "msm_messages": int(sum(msm.values())), "systems": systems,
        "ephemeris_messages": int(sum(eph.values())),
        "ephemeris_satellites": {s: len(v) for s, v in sorted(eph_sats.items(), key=lambda kv: "GREJC".find(kv[0]))},
        "station_position": bool(counts.get(1005) or counts.get(1006)),
    }
    if first_tow is not None:
        meta["epochs"] = int(epochs)
        meta["first_tow_s"] = first_tow / 1000.0
        meta["last_tow_s"] = last_tow / 1000.0 + weeks_run * _WEEK_S
        if interval:
            meta["interval_s"] = round(interval, 3)
        ref, label = _rtcm3_week_reference(week_payloads)
        if ref is not None:
            from georef_core.gnss.gnss_time import resolve_tow_near

            t0 = resolve_tow_near(meta["first_tow_s"], ref)
            meta.update(first_gps_time_s=t0, last_gps_time_s=t0 + meta["last_tow_s"] - meta["first_tow_s"],
                        time_reference=label)
    return meta


def _rtcm3_week_reference(payloads: dict[int, list[bytes]]) -> tuple[float | None, str]:
    """A GPS time within days of the log from the week of its ephemerides (as read_rtcm3 dates a log:
    Galileo, then BeiDou, then GPS/QZSS in the 1024-week cycle nearest today); the median of a few."""
    import datetime as dt
    import statistics

    from georef_core.gnss.gnss_time import datetime_to_gps_time_s
    from georef_core.gnss.rtcm3_nav import ephemeris_week_time

    now = datetime_to_gps_time_s(dt.datetime.now(dt.timezone.utc).replace(tzinfo=None))
    for types, label in (((1045, 1046), "Galileo ephemeris week"), ((1042,), "BeiDou ephemeris week"),
                         ((1019, 1044), "GPS ephemeris week")):
        times = []
        for mt in types:
            for p in payloads.get(mt, []):
                try:
                    t = ephemeris_week_time(mt, p, now)
                except ValueError:
                    continue
                if t is not None:
                    times.append(t)
        if times:
            return float(statistics.median(times)), label
    return None, ""


def _mrk_meta(path: Path) -> dict:
    """Exposures of a DJI Timestamp.MRK: count, first/last GPS time, quality counts. A damaged file is
    refused naming the line."""
    from georef_core.errors import InputFileError
    from georef_core.gnss.dji_mrk import quality_name, read_mrk

    if path.stat().st_size > TEXT_TABLE_MAX_BYTES:
        raise UnrecognisedFile(f"DJI Timestamp.MRK larger than {TEXT_TABLE_MAX_BYTES // 1024**2} MB", kind="dji-mrk")
    try:
        mrk = read_mrk(path)
    except InputFileError as exc:
        where = f", line {exc.line}" if exc.line is not None else ""
        raise UnrecognisedFile(f"damaged DJI Timestamp.MRK{where}: {exc.problem}", kind="dji-mrk") from None
    q, n = (mrk.quality.tolist(), len(mrk))
    counts: dict[str, int] = {}
    for code in q:
        counts[str(code)] = counts.get(str(code), 0) + 1
    return {"exposures": n, "first_gps_time_s": float(mrk.gps_time_s[0]), "last_gps_time_s": float(mrk.gps_time_s[-1]),
            "gps_week": int(mrk.gps_week[0]), "first_index": int(mrk.index[0]), "last_index": int(mrk.index[-1]),
            "quality_counts": counts,
            "quality": {quality_name(int(c)): k for c, k in counts.items()},
            "warnings": mrk.warnings[:5]}


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
    """Rows of a points.csv as the georef step reads them (the core's parse_points_table: the same column
    names and checks), {name, easting_m, northing_m, ellipsoidal_height_m, role}; raises ValueError with the
    line number of the first problem."""
    from georef_core.adjustment.control_points import parse_points_table
    from georef_core.errors import InputFileError

    try:
        return parse_points_table(text)
    except InputFileError as exc:
        raise ValueError(f"line {exc.line}: {exc.problem}" if exc.line else exc.problem) from None


def format_points_csv(points: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*POINT_COLUMNS, "role"])
    for p in points:
        w.writerow([p["name"], f"{p['easting_m']:.4f}", f"{p['northing_m']:.4f}", f"{p['ellipsoidal_height_m']:.4f}",
                    p["role"]])
    return buf.getvalue()


def parse_events_csv(text: str) -> list[dict]:
    """The core's reading of events.csv (camera_events.parse_event_table); ValueError with its message."""
    from georef_core.errors import InputFileError
    from georef_core.gnss.camera_events import parse_event_table

    try:
        rows = parse_event_table(text, "events.csv")
    except InputFileError as exc:
        raise ValueError(f"line {exc.line}: {exc.problem}" if exc.line else exc.problem) from None
    return [{"gps_time_s": t, "image": image} for t, image in rows]


_CRS_LINE = re.compile(r"^(EPSG:\d+|WGS84 UTM \d+[NS]|\+proj=.*)$", re.IGNORECASE)


def parse_gcp_list(text: str) -> dict:
    """The core's reading of gcp_list.txt (control_points.parse_gcp_list), summarised for the upload check."""
    from georef_core.adjustment.control_points import parse_gcp_list as core_parse_gcp_list
    from georef_core.errors import InputFileError

    try:
        crs, points, measurements = core_parse_gcp_list(text, "gcp_list.txt")
    except InputFileError as exc:
        raise ValueError(f"line {exc.line}: {exc.problem}" if exc.line else exc.problem) from None
    return {"crs": crs, "measurements": len(measurements), "images": sorted({m.image for m in measurements}),
            "points": sorted(points)}


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
        if len(head) < 8:   # the byte order and magic number, and no offset of a first directory
            raise UnrecognisedFile(f"TIFF file of {len(head)} bytes: cut off inside its 8-byte header", kind="image")
        off = struct.unpack_from("<I" if le else ">I", head, 4)[0]
        if off < 8 or off >= size:
            raise UnrecognisedFile("TIFF header points outside the file (truncated?)")
    meta = {"format": fmt}
    try:
        from PIL import Image

        with Image.open(path) as im:
            meta["width"], meta["height"] = im.size
            exif = _exif_summary(im)
    except Exception as exc:   # Pillow raises many types on corrupt data
        raise UnrecognisedFile(f"image header cannot be read ({type(exc).__name__}: {exc})") from None
    meta.update(exif)
    return meta


def _exif_text(v) -> str | None:
    if isinstance(v, bytes):
        v = v.decode("ascii", errors="replace")
    if v is None:
        return None
    v = str(v).strip("\x00 ").strip()
    return v or None


def _exif_summary(im) -> dict:
    """Camera make and model, and the capture time (EXIF DateTimeOriginal + SubSecTimeOriginal, the
    camera's clock, as written: ISO text without zone) of an open image; {} when it has no EXIF. Only
    the EXIF directory is read (no pixels): the pre-flight compares photos of one flight with it."""
    out: dict = {}
    try:
        ex = im.getexif()
        make, model = _exif_text(ex.get(271)), _exif_text(ex.get(272))
        sub = ex.get_ifd(0x8769) if ex else {}
        dto, subsec = _exif_text(sub.get(36867)), _exif_text(sub.get(37521))
    except Exception:   # a damaged EXIF block: the pixels are still usable
        return out
    if make:
        out["make"] = make[:100]
    if model:
        out["model"] = model[:100]
    if dto:
        try:
            t = datetime.strptime(dto, "%Y:%m:%d %H:%M:%S")
        except ValueError:
            t = None
        if t is not None:
            text = t.isoformat()
            if subsec and subsec.isdigit():
                text += "." + subsec[:6]
            out["time_original"] = text
    return out


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


_PAIRS_HEADER = re.compile(r"(^|[,;\s])local_(e|e_m|x|easting_m)\s*([,;\s]|$)")


def _calibration_meta(path: Path, doc: dict | None) -> dict:
    """A site calibration as the datum step reads it (georef_core.datums.site_calibration): the JSON's
    parameters, or the control pairs of a CSV (solved in the step)."""
    from georef_core.datums.site_calibration import calibration_from_dict, read_control_pairs
    from georef_core.errors import InputFileError

    try:
        if doc is not None:
            cal = calibration_from_dict(doc, path.name)
            return {"format": "json", "points": len(cal.pairs), "height_datum": cal.height_datum, "crs": cal.crs}
        pairs = read_control_pairs(path)
    except InputFileError as exc:
        raise UnrecognisedFile(f"site calibration: {exc.problem}" + (f" (line {exc.line})" if exc.line else "")) from None
    return {"format": "csv", "points": len(pairs)}


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
    from georef_core.gnss.compressed_files import is_hatanaka
    from georef_core.gnss.input_files import sniff_bytes

    kind = sniff_bytes(head)           # the core's recognition: what is accepted is what the pipeline reads
    text = head.decode("latin-1", errors="replace") if kind in ("rinex-obs", "rinex-nav") else ""
    if kind == "rinex-obs" and is_hatanaka(head):
        inner = "\n".join(text.splitlines()[2:])          # the RINEX header follows the two CRINEX lines
        return Recognised("rinex-obs", _rinex_obs_meta(path, packing, True, inner))
    if kind == "rinex-obs":
        return Recognised("rinex-obs", _rinex_obs_meta(path, packing, False, text))
    if kind == "rinex-nav":
        meta = _rinex_header(text)
        if not meta.get("header_complete"):
            raise UnrecognisedFile("RINEX navigation header has no END OF HEADER line (truncated file?)")
        if packing:
            meta["compressed"] = packing
        return Recognised("rinex-nav", meta)
    first_line = head[:200].split(b"\n", 1)[0].decode("latin-1", errors="replace")
    if "RINEX VERSION" in first_line:
        raise UnrecognisedFile(f"a RINEX file of type {first_line[20:21].upper()!r} (meteorological, clock and "
                               "other RINEX files are not used: observation or navigation files are)")
    if kind in ("ubx", "rtcm3") and packing is not None:
        raise UnrecognisedFile(f"{KIND_WORDS[kind]} packed with {packing}: send it unpacked (or in a zip archive)")
    if kind == "ubx":
        return Recognised("ubx", _ubx_meta(path))
    if kind == "rtcm3":
        return Recognised("rtcm3", _rtcm3_meta(path))
    if kind == "dji-mrk":
        return Recognised("dji-mrk", _mrk_meta(path))
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
        except RecursionError:
            raise UnrecognisedFile("JSON nested too deeply to be a survey.json") from None
        if not isinstance(obj, dict):
            raise UnrecognisedFile("JSON that is not an object")
        if obj.get("format") == "georef-site-calibration":
            return Recognised("site-calibration", _calibration_meta(path, obj))
        return Recognised("survey-metadata", {"keys": sorted(obj)[:50]})
    text = _read_table_text(path)
    first = next((ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")), "")
    low = first.lower()
    if _CRS_LINE.match(first.strip()):
        try:
            return Recognised("gcp-list", parse_gcp_list(text))
        except ValueError as exc:
            raise UnrecognisedFile(f"ODM gcp_list.txt: {exc}") from None
    if _PAIRS_HEADER.search(low):   # control pairs: a points-like table with the local grid's columns
        return Recognised("site-calibration", _calibration_meta(path, None))
    # a points table is what the georef step reads as one (the core's column names: name/id, easting/x, ...)
    try:
        pts = parse_points_csv(text)
    except ValueError as exc:
        pts = None
        if "needs columns" not in str(exc) and "the point file is empty" not in str(exc):
            raise UnrecognisedFile(f"points CSV: {exc}") from None
    if pts is not None:
        return Recognised("points", {"points": len(pts), "control": sum(p["role"] == "control" for p in pts),
                                     "check": sum(p["role"] == "check" for p in pts)})
    from georef_core.gnss.camera_events import EVENT_TIME_COLUMNS

    if any(c in low.replace(" ", "").split(",") for c in EVENT_TIME_COLUMNS):
        try:
            ev = parse_events_csv(text)
        except ValueError as exc:
            raise UnrecognisedFile(f"camera-event CSV: {exc}") from None
        times = [e["gps_time_s"] for e in ev]
        return Recognised("events", {"events": len(ev), "first_gps_time_s": min(times), "last_gps_time_s": max(times),
                                     "images": [e["image"] for e in ev if e["image"]][:100000]})
    raise UnrecognisedFile(_describe_unknown(raw))
