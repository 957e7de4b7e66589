"""RINEX navigation (broadcast ephemeris) reader: RINEX 2.x GPS ('N') and GLONASS ('G') files and
RINEX 3.0x single-system or mixed files (GPS, GLONASS, Galileo, QZSS, BeiDou).

Every time is converted to ``gps_time_s`` (see gnss_time.py):

* GPS / QZSS / Galileo: the epoch (toc) is read as GPS time; toe and the transmission time are
  seconds of week resolved to the week closest to toc (the broadcast week number is kept in the record
  but not trusted for the conversion: some writers store it modulo 1024). RINEX aligns the Galileo week
  with the GPS week, and GST is treated as GPST (their offset, tens of ns, is left to the receiver
  clock estimate, as RTKLIB does).
* BeiDou: toc, toe and transmission time are BDT; gps = bdt + 14 s. toe_sow_s and week stay BDT (the
  GEO orbit rotation needs the BDT seconds of week).
* GLONASS: the epoch is UTC(SU) (the reference time tb); gps = utc + leap seconds, taken from the
  header 'LEAP SECONDS' line when present, otherwise from gnss_time.leap_seconds_at. The message
  frame time (RINEX 2: seconds of the UTC day; RINEX 3: seconds of the UTC week) is placed on the
  day nearest to toc.

Records of other systems (SBAS 'S', NavIC 'I', unknown letters) are skipped. Records are sorted by
toe and exact duplicates (same content; only the transmission / frame time may differ) are dropped,
keeping the earliest transmitted. Galileo I/NAV and F/NAV records are both kept, told apart by
``KeplerEphemeris.data_source`` (RINEX 'data sources' bit field); ephemeris.select_ephemeris prefers
I/NAV.

Not read: RINEX 4 files (explicit error), 'TIME SYSTEM CORR' / 'DELTA-UTC' lines, QZSS and NavIC
Klobuchar coefficients (no field in NavigationData), RINEX 3.05 GLONASS extra line content (read for
structure, values unused).
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Iterator, Sequence

import numpy as np

from ..errors import InputFileError
from .compressed_files import read_text
from .ephemeris import MAX_EPHEMERIS_AGE_S
from .gnss_time import (
    BDS_MINUS_GPS_S,
    calendar_to_gps_time_s,
    leap_seconds_at,
    resolve_tow_near,
)
from .navigation import GlonassEphemeris, KeplerEphemeris, NavigationData
from .rinex_nav_kernels import fill_hard_fields, record_epoch_fields, record_fields

PathLike = str | Path

_FIELD_WIDTH = 19
_KEPLER_SYSTEMS = ("G", "E", "J", "C")
# Allowed number of lines (epoch line included) per record, RINEX 3.
_RECORD_LINES_V3 = {"G": (8,), "E": (8,), "J": (8,), "C": (8,), "I": (8,), "R": (4, 5), "S": (4,)}
# RINEX 3 'unknown transmission time' marker (0.9999E+09).
_UNKNOWN_TRANSMIT = 9.0e8
# Free-format fallback: a RINEX navigation number always has a decimal point and an exponent.
_NUMBER_RE = re.compile(r"[+-]?(?:\d+\.\d*|\.\d+)[EeDd][+-]?\d+")
_DAY_S = 86400.0
# records read around the observations' time window: as far from it as ephemeris selection may reach
# (ephemeris.MAX_EPHEMERIS_AGE_S: 2 h GPS/QZSS, 4 h Galileo, 6 h BeiDou, 30 min GLONASS) plus one hour
# (a record's epoch, toc or tb, may differ from its toe; time scale offsets)
EPHEMERIS_WINDOW_SLACK_S = 3600.0


def read_rinex_nav(paths: PathLike | Sequence[PathLike],
                   time_window_gps_s: tuple[float, float] | None = None) -> NavigationData:
    """Read one or several RINEX navigation files (plain, gzip, .Z) into one NavigationData.

    With time_window_gps_s (first, last observation time), only the records that ephemeris selection could
    use for it are read (within MAX_EPHEMERIS_AGE_S of their system plus an hour: a daily multi-GNSS file
    holds thousands of records, a flight needs those of a few hours); the others are counted in
    records_outside_window.

    Several files are merged with NavigationData.merge (duplicates by satellite, toe, IODE and
    Galileo data source dropped; header values of the first file that has them win).
    Raises InputFileError (naming the file and, where it applies, the line) for a missing file, a file
    that is not RINEX navigation (observation, clock, meteo or other text), RINEX 4, a truncated record
    or an unreadable number.
    """
    if isinstance(paths, (str, Path)):
        path_list: list[PathLike] = [paths]
    else:
        path_list = list(paths)
    if not path_list:
        raise ValueError("read_rinex_nav: no navigation file given")
    nav: NavigationData | None = None
    for p in path_list:
        one = _read_one(Path(p), time_window_gps_s)
        nav = one if nav is None else nav.merge(one)
    assert nav is not None
    return nav


# --------------------------------------------------------------------------------------------------
# header


@dataclass
class _Header:
    version: float
    file_type: str            # 'N', 'G', 'H'
    system: str               # file system letter ('G' for RINEX 2 'N', 'R' for 'G', 'M' mixed...)
    leap_seconds: int | None = None
    iono: dict[str, np.ndarray] = field(default_factory=dict)
    body_start: int = 0       # index (0-based) of the first line after END OF HEADER


def _parse_header(lines: list[str], path: Path) -> _Header:
    if not lines or not lines[0].strip():
        raise InputFileError(path, "empty file, expected a RINEX navigation file", line=1)
    first = lines[0]
    if "RINEX VERSION / TYPE" not in first[60:]:
        if "CRINEX" in first[60:] or "COMPACT RINEX" in first:
            raise InputFileError(path, "is a Hatanaka-compressed observation file, expected a RINEX navigation file", line=1)
        raise InputFileError(path, "not a RINEX file (first line lacks 'RINEX VERSION / TYPE'); "
                                   "expected a RINEX navigation file", line=1)
    try:
        version = float(first[0:9])
    except ValueError:
        raise InputFileError(path, f"unreadable RINEX version '{first[0:9].strip()}'", line=1) from None
    file_type = first[20:21].upper()
    system = first[40:41].upper() or " "
    if file_type == "O":
        raise InputFileError(path, "is a RINEX observation file, expected a RINEX navigation file", line=1)
    if file_type == "C":
        raise InputFileError(path, "is a RINEX clock file, expected a RINEX navigation file", line=1)
    if file_type == "M":
        raise InputFileError(path, "is a RINEX meteorological file, expected a RINEX navigation file", line=1)
    if version >= 4.0:
        raise InputFileError(path, f"RINEX {version:.2f} navigation files are not supported "
                                   "(convert to RINEX 3.04, e.g. with gfzrnx or RTKLIB convbin)", line=1)
    if version < 2.0:
        raise InputFileError(path, f"RINEX version {version} is not supported", line=1)
    if version < 3.0:
        if file_type == "N":
            system = "G"
        elif file_type == "G":
            system = "R"
        elif file_type == "H":
            system = "S"
        else:
            raise InputFileError(path, f"unsupported RINEX {version:.2f} file type '{file_type}' "
                                       "(expected N: GPS or G: GLONASS navigation)", line=1)
    elif file_type not in ("N", "G", "H"):
        raise InputFileError(path, f"RINEX file type '{file_type}' is not navigation data", line=1)

    header = _Header(version=version, file_type=file_type, system=system)
    for i in range(1, len(lines)):
        line = lines[i]
        label = line[60:].strip()
        if label == "END OF HEADER":
            header.body_start = i + 1
            return header
        if label == "LEAP SECONDS":
            try:
                leap = int(line[0:6])
            except ValueError:
                raise InputFileError(path, f"unreadable LEAP SECONDS value '{line[0:6].strip()}'", line=i + 1) from None
            if line[24:27] == "BDS":  # RINEX 3.02+: value given as BDT - UTC
                leap += int(-BDS_MINUS_GPS_S)
            header.leap_seconds = leap
        elif label == "ION ALPHA":
            header.iono.setdefault("GPSA", _header_numbers(line, 2, 12, 4, path, i + 1))
        elif label == "ION BETA":
            header.iono.setdefault("GPSB", _header_numbers(line, 2, 12, 4, path, i + 1))
        elif label == "IONOSPHERIC CORR":
            key = line[0:4].strip()
            if key in ("GPSA", "GPSB", "GAL", "BDSA", "BDSB"):
                header.iono.setdefault(key, _header_numbers(line, 5, 12, 4, path, i + 1))
    raise InputFileError(path, "no 'END OF HEADER' line: not a complete RINEX header")


def _header_numbers(line: str, start: int, width: int, count: int, path: Path, lineno: int) -> np.ndarray:
    """Fixed-width header numbers; what follows them (label, RINEX 3.05 time mark) is not checked."""
    return np.array(_numbers(line[:start + count * width], start, width, count, path, lineno))


# --------------------------------------------------------------------------------------------------
# numbers


def _to_float(text: str) -> float | None:
    """A Fortran-style number (D or E exponent), None when unreadable; blank -> 0.0."""
    s = text.strip()
    if not s:
        return 0.0
    try:
        value = float(s.replace("D", "E").replace("d", "e"))
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _numbers(line: str, start: int, width: int, count: int, path: Path, lineno: int,
             continuation: bool = False) -> list[float]:
    """`count` fixed-width numbers from column `start` (blank fields read 0.0).

    Fixed columns separate numbers that run together ('-1.2D-05-2.3D+00'). Writers that do not keep
    the columns are accepted when the line (from `start`, or whole for a continuation line whose indent
    may be off) splits into exponent-form numbers and nothing else.
    """
    end = start + count * width
    if not line[end:].strip():
        seg = line[start:end].replace("D", "E").replace("d", "e")
        try:
            values = [float(f) if f.strip() else 0.0 for f in (seg[k:k + width] for k in range(0, count * width, width))]
        except ValueError:
            values = []
        if values and all(math.isfinite(v) for v in values):
            return values
    # fallback: free-format numbers (must cover every non-blank character)
    rest = line if continuation else line[start:]
    tokens = _NUMBER_RE.findall(rest)
    leftover = _NUMBER_RE.sub(" ", rest).strip()
    if leftover or len(tokens) > count:
        bad = leftover.split()[0] if leftover else rest.strip()
        raise InputFileError(path, f"unreadable number near '{bad[:24]}'", line=lineno)
    values = [_to_float(t) for t in tokens]
    if any(v is None for v in values):
        raise InputFileError(path, f"unreadable number in '{rest.strip()[:40]}'", line=lineno)
    return [float(v) for v in values] + [0.0] * (count - len(values))  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------------
# records


@dataclass
class _Record:
    system: str
    prn: int
    lineno: int               # 1-based line number of the epoch line
    epoch: tuple[int, int, int, int, int, float]
    data: list[float]         # RTKLIB-style data[] : 3 values of the epoch line, then 4 per line


def _line_buffer(lines: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The lines as one byte buffer (one byte per character) with each line's start and length."""
    lens = np.fromiter(map(len, lines), dtype=np.int64, count=len(lines))
    starts = np.zeros(len(lines), dtype=np.int64)
    if len(lines) > 1:
        np.cumsum(lens[:-1] + 1, out=starts[1:])
    buf = np.frombuffer("\n".join(lines).encode("ascii", "replace"), dtype=np.uint8)
    return buf, starts, lens


def _record_spans(lines: list[str], header: _Header, path: Path, buf: np.ndarray, starts: np.ndarray,
                  lens: np.ndarray) -> list[tuple[str, int, int]]:
    """(system, index of the epoch line, number of lines) of every record of a used system, checked for
    completeness (truncated or over-long records raise InputFileError). A record starts at a line with
    a satellite id in its first column(s); the lines up to the next such line belong to it."""
    v3 = header.version >= 3.0
    id_width = 1 if v3 else 2
    n = len(lines)
    b0 = header.body_start
    safe = np.minimum(starts, max(len(buf) - 1, 0))
    is_id = (lens >= 1) & (buf[safe] != 32) if len(buf) else np.zeros(n, bool)
    if id_width == 2 and len(buf):
        is_id |= (lens >= 2) & (buf[np.minimum(starts + 1, len(buf) - 1)] != 32)
    ids = np.flatnonzero(is_id[b0:]) + b0
    first_id = int(ids[0]) if len(ids) else n
    for i in range(b0, first_id):
        if lines[i].strip():
            raise InputFileError(path, "continuation line without a record (satellite/epoch) line", line=i + 1)
    fast = _regular_record_spans(header, buf, starts, ids, n)
    if fast is not None:
        return fast
    bounds = ids.tolist() + [n]
    spans = []
    for k in range(len(bounds) - 1):
        start, j = bounds[k], bounds[k + 1]
        if v3:
            system = lines[start][0].upper()
            allowed = _RECORD_LINES_V3.get(system)
        else:
            system = header.system
            allowed = (8,) if system == "G" else (4,)
        if allowed is None:
            continue  # unknown system letter: skip the record (all its continuation lines)
        nlines = j - start
        while nlines > max(allowed) and not lines[start + nlines - 1].strip():
            nlines -= 1  # trailing blank lines
        if nlines < min(allowed):
            raise InputFileError(path, f"truncated navigation record ({nlines} of {min(allowed)} lines)", line=start + 1)
        if nlines not in allowed:
            raise InputFileError(path, f"navigation record has {nlines} lines, expected "
                                       f"{' or '.join(str(a) for a in allowed)}", line=start + 1)
        if system not in _KEPLER_SYSTEMS and system != "R":
            continue  # SBAS, NavIC: recognised but not used
        spans.append((system, start, nlines))
    return spans


def _regular_record_spans(header: _Header, buf: np.ndarray, starts: np.ndarray, ids: np.ndarray,
                          n: int) -> list[tuple[str, int, int]] | None:
    """_record_spans for the usual file, all at once: every record has a line count its system allows
    (no trailing blank lines to trim, nothing to report). None when any record needs the line-by-line
    checks."""
    n_lines = np.diff(np.append(ids, n))
    if header.version >= 3.0:
        letters = buf[starts[ids]] if len(ids) else np.zeros(0, np.uint8)
        letters = np.where((letters >= 97) & (letters <= 122), letters - 32, letters)
        keep = np.zeros(len(ids), bool)
        for code in np.unique(letters).tolist():
            allowed = _RECORD_LINES_V3.get(chr(code))
            if allowed is None:
                continue  # unknown system letter: skipped, as the line-by-line path does
            mine = letters == code
            if not np.isin(n_lines[mine], allowed).all():
                return None
            if chr(code) in _KEPLER_SYSTEMS or chr(code) == "R":
                keep |= mine
        rows = np.flatnonzero(keep)
        return [(chr(c), i, k) for c, i, k in zip(letters[rows].tolist(), ids[rows].tolist(), n_lines[rows].tolist())]
    system = header.system
    allowed = 8 if system == "G" else 4
    if not (n_lines == allowed).all():
        return None
    if system not in _KEPLER_SYSTEMS and system != "R":
        return []
    return [(system, i, allowed) for i in ids.tolist()]


def _iter_records(lines: list[str], header: _Header, path: Path,
                  time_window_gps_s: tuple[float, float] | None = None,
                  stats: dict | None = None) -> Iterator[_Record]:
    """The records of the file, their numbers read by the compiled fixed-column reader where it reads
    every field (rinex_nav_kernels.py), else line by line here. With a time window, the records whose
    epoch lies outside it are skipped before any of their numbers is read; `stats` then receives how
    many were skipped and the span of all record epochs (for the caller's error message)."""
    v3 = header.version >= 3.0
    buf, starts, lens = _line_buffer(lines)
    spans = _record_spans(lines, header, path, buf, starts, lens)
    if not spans:
        return
    rec_line = np.array([sp[1] for sp in spans], dtype=np.int64)
    rec_n = np.array([sp[2] for sp in spans], dtype=np.int64)
    if time_window_gps_s is not None:
        epoch_s, readable = _record_epochs_s(buf, starts, lens, rec_line, v3)
        t0, t1 = time_window_gps_s
        longest = max(MAX_EPHEMERIS_AGE_S.values())
        margin = np.array([MAX_EPHEMERIS_AGE_S.get(sp[0], longest) for sp in spans])
        margin += EPHEMERIS_WINDOW_SLACK_S
        # unreadable epochs are kept: their record is then parsed and the error reported with its line
        keep = ~readable | ((epoch_s >= t0 - margin) & (epoch_s <= t1 + margin))
        if stats is not None and readable.any():
            stats["skipped"] = int((~keep).sum())
            stats["span_gps_s"] = (float(epoch_s[readable].min()), float(epoch_s[readable].max()))
        if not keep.all():
            idx = np.flatnonzero(keep)
            spans = [spans[k] for k in idx]
            rec_line, rec_n = rec_line[idx], rec_n[idx]
            if not spans:
                return
    n_values = 3 + 4 * (int(rec_n.max()) - 1)
    values, ok, hard = record_fields(buf, starts, lens, rec_line, rec_n, 23 if v3 else 22, 4 if v3 else 3, n_values)
    fill_hard_fields(values, buf, hard)
    for k, (system, start, nlines) in enumerate(spans):
        data = values[k, :3 + 4 * (nlines - 1)].tolist() if ok[k] else None
        yield _parse_record(lines[start], lines[start + 1:start + nlines], start + 1, system, v3, path, data)


_EPOCH_COLS_V3 = np.array(((4, 4), (9, 2), (12, 2), (15, 2), (18, 2), (21, 2)), dtype=np.int64)
_EPOCH_COLS_V2 = np.array(((3, 2), (6, 2), (9, 2), (12, 2), (15, 2), (17, 3)), dtype=np.int64)


def _record_epochs_s(buf: np.ndarray, starts: np.ndarray, lens: np.ndarray, rec_line: np.ndarray,
                     v3: bool) -> tuple[np.ndarray, np.ndarray]:
    """Epoch of each record's first line (seconds since 1980-01-06 in its own time scale, whole seconds),
    read from the fixed columns of the byte buffer for all records at once (compiled:
    rinex_nav_kernels.record_epoch_fields); and whether it was readable."""
    fields, readable = record_epoch_fields(buf, starts, lens, np.ascontiguousarray(rec_line, dtype=np.int64),
                                           _EPOCH_COLS_V3 if v3 else _EPOCH_COLS_V2)
    year, month, day, hour, minute, second = fields.T
    if not v3:
        year = np.where(year < 80, year + 2000, year + 1900)
    readable &= (month >= 1) & (month <= 12) & (day >= 1) & (day <= 31)
    return np.asarray(calendar_to_gps_time_s(year, month, day, hour, minute, second), dtype=float), readable


def _parse_record(first: str, body: list[str], lineno: int, system: str, v3: bool, path: Path,
                  data: list[float] | None = None) -> _Record:
    if v3:
        prn_text, epoch_text, data_col = first[1:3], first[4:23], 23
    else:
        prn_text, epoch_text, data_col = first[0:2], first[3:22], 22
    try:
        prn = int(prn_text)
    except ValueError:
        raise InputFileError(path, f"unreadable satellite number '{first[:3].strip()}'", line=lineno) from None
    if prn <= 0:
        raise InputFileError(path, f"invalid satellite number '{first[:3].strip()}'", line=lineno)
    epoch = _parse_epoch(epoch_text, v3, path, lineno)
    cont_col = 4 if v3 else 3
    if data is None:
        data = _record_numbers(first, body, data_col, cont_col)
    if data is None:  # line by line, with the free-format fallback and error reporting
        data = _numbers(first, data_col, _FIELD_WIDTH, 3, path, lineno)
        for k, line in enumerate(body):
            data.extend(_numbers(line, cont_col, _FIELD_WIDTH, 4, path, lineno + 1 + k, continuation=True))
    return _Record(system, prn, lineno, epoch, data)


def _record_numbers(first: str, body: list[str], data_col: int, cont_col: int) -> list[float] | None:
    """Fast path of _numbers for a whole record whose lines all keep the fixed columns (3 numbers on the
    epoch line, 4 per continuation line, blank fields 0.0); None when any line needs the careful path."""
    w = _FIELD_WIDTH
    end = data_col + 3 * w
    if first[end:].strip():
        return None
    parts = [first[data_col:end].ljust(3 * w)]
    end = cont_col + 4 * w
    for line in body:
        if line[end:].strip():
            return None
        parts.append(line[cont_col:end].ljust(4 * w))
    text = "".join(parts).replace("D", "E").replace("d", "e")
    n_fields = len(text) // w
    text = text.rstrip()   # blank spare fields at the end read 0.0
    fields = [text[k:k + w] for k in range(0, len(text), w)]
    try:
        values = list(map(float, fields)) + [0.0] * (n_fields - len(fields))
    except ValueError:
        try:
            values = [float(f) if f.strip() else 0.0 for f in fields] + [0.0] * (n_fields - len(fields))
        except ValueError:
            return None
    total = sum(values)
    return values if math.isfinite(total) else None


def _parse_epoch(text: str, v3: bool, path: Path, lineno: int) -> tuple[int, int, int, int, int, float]:
    parts = text.split()
    try:
        if len(parts) != 6:
            raise ValueError
        year, month, day, hour, minute = (int(p) for p in parts[:5])
        second = float(parts[5])
    except ValueError:
        raise InputFileError(path, f"unreadable epoch '{text.strip()}'", line=lineno) from None
    if not v3 and year < 100:
        year += 2000 if year < 80 else 1900
    try:
        _dt.date(year, month, day)
        valid = 1980 <= year <= 2100 and 0 <= hour <= 24 and 0 <= minute <= 59 and 0.0 <= second < 61.0
    except ValueError:
        valid = False
    if not valid:
        raise InputFileError(path, f"invalid epoch '{text.strip()}'", line=lineno)
    return year, month, day, hour, minute, second


# --------------------------------------------------------------------------------------------------
# records to ephemerides


_GPS_EPOCH_ORDINAL = _dt.date(1980, 1, 6).toordinal()


def _epoch_seconds(epoch: tuple[int, int, int, int, int, float]) -> float:
    """Calendar epoch to seconds since 1980-01-06 in the epoch's own time scale (no leap seconds)."""
    y, mo, d, h, mi, sec = epoch
    days = _dt.date(y, mo, d).toordinal() - _GPS_EPOCH_ORDINAL
    return days * 86400.0 + h * 3600.0 + mi * 60.0 + sec


def _kepler(rec: _Record) -> KeplerEphemeris:
    d = rec.data
    sys = rec.system
    t_epoch = _epoch_seconds(rec.epoch)  # GPST for G/J/E, BDT for C
    offset = -BDS_MINUS_GPS_S if sys == "C" else 0.0   # system time -> GPST
    toe = resolve_tow_near(d[11], t_epoch) + offset
    transmit = float("nan") if abs(d[27]) >= _UNKNOWN_TRANSMIT else resolve_tow_near(d[27], t_epoch) + offset
    eph = KeplerEphemeris(
        sat_id=f"{sys}{rec.prn:02d}",
        toe_gps_s=toe,
        toc_gps_s=t_epoch + offset,
        af0_s=d[0], af1_s_s=d[1], af2_s_s2=d[2],
        sqrt_a=d[10], e=d[8], i0_rad=d[15], omega0_rad=d[13], omega_rad=d[17], m0_rad=d[6],
        delta_n_rad_s=d[5], idot_rad_s=d[19], omega_dot_rad_s=d[18],
        cuc_rad=d[7], cus_rad=d[9], crc_m=d[16], crs_m=d[4], cic_rad=d[12], cis_rad=d[14],
        toe_sow_s=d[11], week=int(d[21]),
        iode=int(d[3]),
        accuracy_m=d[23], health=int(d[24]),
        transmit_gps_s=transmit,
    )
    if sys in ("G", "J"):
        eph.iodc = int(d[26])
        eph.tgd_s = (d[25], 0.0)
        if sys == "G":
            fit = d[28]
            eph.fit_interval_h = fit if fit > 1.0 else (6.0 if fit == 1.0 else 4.0)
        else:
            eph.fit_interval_h = 2.0 if d[28] == 0.0 else 4.0
    elif sys == "E":
        eph.data_source = int(d[20])
        eph.tgd_s = (d[25], d[26])   # BGD E1-E5a, BGD E1-E5b
    else:  # BeiDou
        eph.iodc = int(d[28])        # AODC
        eph.tgd_s = (d[25], d[26])   # TGD1 (B1I), TGD2 (B2I)
    return eph


def _glonass(rec: _Record, leap_header: int | None) -> GlonassEphemeris:
    d = rec.data
    y, mo, dd, h, mi, s = rec.epoch
    toc_utc = _epoch_seconds(rec.epoch)
    if leap_header is not None:
        leap = leap_header
    else:
        leap = leap_seconds_at(_dt.datetime(y, mo, dd) + _dt.timedelta(hours=h, minutes=mi, seconds=s))
    day_start = math.floor(toc_utc / _DAY_S) * _DAY_S
    tof_utc = day_start + math.fmod(d[2], _DAY_S) % _DAY_S   # RINEX 2: tod, RINEX 3: tow (UTC)
    if tof_utc - toc_utc > _DAY_S / 2:
        tof_utc -= _DAY_S
    elif tof_utc - toc_utc < -_DAY_S / 2:
        tof_utc += _DAY_S
    fcn = int(d[10])
    if fcn > 128:  # some receivers write the channel as an unsigned byte
        fcn -= 256
    return GlonassEphemeris(
        sat_id=f"R{rec.prn:02d}",
        toe_gps_s=toc_utc + leap,
        frame_time_gps_s=tof_utc + leap,
        position_ecef_m=np.array([d[3], d[7], d[11]]) * 1e3,
        velocity_ecef_m_s=np.array([d[4], d[8], d[12]]) * 1e3,
        acceleration_ecef_m_s2=np.array([d[5], d[9], d[13]]) * 1e3,
        tau_n_s=-d[0],
        gamma_n=d[1],
        fcn=fcn,
        health=int(d[6]),
        age_days=int(d[14]),
    )


def _kepler_key(e: KeplerEphemeris) -> tuple:
    fields = dict(e.__dict__)
    del fields["transmit_gps_s"]
    return tuple(fields.values())


def _glonass_key(g: GlonassEphemeris) -> tuple:
    return (g.sat_id, g.toe_gps_s, tuple(g.position_ecef_m), tuple(g.velocity_ecef_m_s),
            tuple(g.acceleration_ecef_m_s2), g.tau_n_s, g.gamma_n, g.fcn, g.health, g.age_days, g.accuracy_m)


def _sorted_unique(records: Iterable, key_fn, time_attr: str) -> list:
    def order(r) -> tuple:
        tt = getattr(r, time_attr)
        return (r.toe_gps_s, getattr(r, "data_source", 0), math.inf if math.isnan(tt) else tt)

    seen: set = set()
    out = []
    for r in sorted(records, key=order):
        k = key_fn(r)
        if k not in seen:
            seen.add(k)
            out.append(r)
    return out


def _read_one(path: Path, time_window_gps_s: tuple[float, float] | None = None) -> NavigationData:
    text = read_text(path)
    lines = text.splitlines()
    header = _parse_header(lines, path)
    kepler: dict[str, list[KeplerEphemeris]] = {}
    glonass: dict[str, list[GlonassEphemeris]] = {}
    stats: dict = {}
    for rec in _iter_records(lines, header, path, time_window_gps_s, stats):
        if rec.system == "R":
            g = _glonass(rec, header.leap_seconds)
            glonass.setdefault(g.sat_id, []).append(g)
        else:
            k = _kepler(rec)
            kepler.setdefault(k.sat_id, []).append(k)
    nav = NavigationData(source_paths=[str(path)], records_outside_window=stats.get("skipped", 0),
                         record_span_gps_s=stats.get("span_gps_s"))
    nav.kepler = {s: _sorted_unique(r, _kepler_key, "transmit_gps_s") for s, r in sorted(kepler.items())}
    nav.glonass = {s: _sorted_unique(r, _glonass_key, "frame_time_gps_s") for s, r in sorted(glonass.items())}
    iono = header.iono
    nav.iono_gps_alpha = iono.get("GPSA")
    nav.iono_gps_beta = iono.get("GPSB")
    nav.iono_gal = iono["GAL"][:3].copy() if "GAL" in iono else None
    nav.iono_bds_alpha = iono.get("BDSA")
    nav.iono_bds_beta = iono.get("BDSB")
    nav.leap_seconds = header.leap_seconds
    return nav


__all__ = ["read_rinex_nav"]
