"""DJI ``*_Timestamp.MRK`` files: one line per camera exposure, written by DJI RTK aircraft
(Phantom 4 RTK, Matrice 300/350 RTK with P1/L1, Mavic 3 Enterprise, Matrice 4E, ...).

A line is tab-separated (the reader accepts any whitespace)::

    1  275295.301059  [2024]  -26,N  19,E  191,V  -36.41144502,Lat  174.63075195,Lon  170.415,Ellh
       1.492559, 1.368525, 3.180128  16,Q

=====================  ==========================================================================
column                 meaning
=====================  ==========================================================================
``1``                  exposure index (photo number in the folder, from 1)
``275295.301059``      GPS seconds of week of the exposure (mid-exposure time mark, GPS scale)
``[2024]``             GPS week (full week number, no 1024 roll-over)
``-26,N 19,E 191,V``   offset from the GNSS antenna phase centre to the camera centre (CMOS), in
                       millimetres, north / east / vertical, already rotated by the aircraft and
                       gimbal attitude. DJI's manuals: north and east positive, **vertical positive
                       downward**. A Phantom 4 RTK logs V of about +190 mm: the camera is 19 cm
                       below the antenna.
``...,Lat ...,Lon``    latitude, longitude (degrees, WGS84 / the RTK service's frame). DJI's manuals
                       call them the position "after compensation", i.e. moved to the camera; they
                       come from the aircraft's real-time solution (single point when RTK is off)
``...,Ellh``           ellipsoidal height (m)
``a, b, c``            standard deviations north / east / vertical (m) of that real-time position
                       (absent in some firmware: NaN)
``16,Q``               solution quality, see ``QUALITY_NAMES`` (absent in some firmware: -1)
=====================  ==========================================================================

Columns after the GPS week are recognised by their label (``,N``, ``,Lat``, ...), not by their place.

Sign convention implemented: ``camera_offset_ned_m = (N, E, V) / 1000`` (metres, north /
east / down; V is copied as is since DJI's V is already positive down), and

    camera centre = antenna phase centre + camera_offset_ned_m   (in the local NED frame at the exposure)

which ``MrkFile.camera_ecef_from_antenna_m`` applies to a PPK antenna trajectory.

Damaged lines (wrong fields, non-numeric values, time not increasing, a GPS week jump) raise
``InputFileError`` with the 1-based line number; an unterminated last line that does not parse (a file
cut off while the aircraft was writing it) is dropped with a warning.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .compressed_files import read_bytes
from .frames import geodetic_to_ecef_m
from .gnss_time import SECONDS_PER_WEEK

__all__ = ["MrkFile", "FlightGap", "QUALITY_NAMES", "QUALITY_FIXED", "quality_name", "read_mrk",
           "parse_mrk_text", "looks_like_mrk", "join_mrk"]

QUALITY_NONE = 0
QUALITY_SINGLE = 16
QUALITY_FLOAT = 34
QUALITY_FIXED = 50
QUALITY_MISSING = -1     # the file has no quality column

# Values of the ``Q`` column (the same codes as the XMP tag ``drone-dji:RtkFlag``). DJI's manuals list
# 0, 16, 34 and 50; some (Mavic 3E/M) describe float as the range 32-49, see ``quality_name``.
QUALITY_NAMES: dict[int, str] = {
    QUALITY_MISSING: "not recorded",
    QUALITY_NONE: "no position",
    QUALITY_SINGLE: "single (metre level)",
    QUALITY_FLOAT: "RTK float (decimetre level)",
    QUALITY_FIXED: "RTK fixed (centimetre level)",
}

_MAX_WEEK_STEP = 1
_LABELS = ("n", "e", "v", "lat", "lon", "ellh", "q")   # column labels, compared in lower case
_REQUIRED = ("n", "e", "v", "lat", "lon", "ellh")
_COLUMN_NAMES = {"n": "north offset (,N)", "e": "east offset (,E)", "v": "vertical offset (,V)",
                 "lat": "latitude (,Lat)", "lon": "longitude (,Lon)", "ellh": "ellipsoidal height (,Ellh)",
                 "q": "quality (,Q)", "sigma": "sigma N, E, V"}
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_MRK_LINE = re.compile(rf"^\s*\d+\s+\d+(?:\.\d*)?\s+\[\s*\d+\s*\]\s+{_NUM}\s*,\s*N\s+{_NUM}\s*,\s*E\s+{_NUM}\s*,\s*V\b")


def quality_name(q: int) -> str:
    """Readable name of a quality code (32-49 read as float, as in the Mavic 3 Enterprise manual)."""
    if q in QUALITY_NAMES:
        return QUALITY_NAMES[q]
    if 32 <= q <= 49:
        return QUALITY_NAMES[QUALITY_FLOAT]
    return f"unknown ({q})"


@dataclass
class FlightGap:
    """Time between two flights of a joined MRK set (flights numbered as in ``MrkFile.flight``)."""

    before_flight: int
    after_flight: int
    start_gps_time_s: float   # last exposure of ``before_flight``
    end_gps_time_s: float     # first exposure of ``after_flight``

    @property
    def duration_s(self) -> float:
        return self.end_gps_time_s - self.start_gps_time_s


@dataclass
class MrkFile:
    """The exposures of one DJI MRK file (or of several joined by ``join_mrk``), arrays of length N
    in time order.

    index: exposure index as written (photo number; not renumbered by ``join_mrk``).
    gps_time_s: continuous GPS time (s since 1980-01-06) = gps_week * 604800 + seconds of week.
    camera_offset_ned_m: (N, 3) antenna phase centre -> camera centre, north/east/down (m), see module doc.
    lat_deg, lon_deg, ellipsoidal_height_m: the aircraft's real-time position (camera, per DJI's manuals).
    sigma_ned_m: (N, 3) standard deviations north/east/vertical (m) of that position; NaN when absent.
    quality: solution quality code (``QUALITY_NAMES``); -1 when the file has no quality column.
    flight: (N,) which flight each exposure came from, an index into ``flight_source_paths``
        (all 0 for a single file).
    flight_gaps: the gaps between consecutive non-overlapping flights of a joined set.
    warnings: human-readable problems that did not stop the reading (dropped partial last line, ...).
    """

    source_path: str
    index: np.ndarray                  # (N,) int64
    gps_time_s: np.ndarray             # (N,) float64
    gps_week: np.ndarray               # (N,) int64
    camera_offset_ned_m: np.ndarray    # (N, 3)
    lat_deg: np.ndarray                # (N,)
    lon_deg: np.ndarray                # (N,)
    ellipsoidal_height_m: np.ndarray   # (N,)
    sigma_ned_m: np.ndarray            # (N, 3), NaN when not recorded
    quality: np.ndarray                # (N,) int64, -1 when not recorded
    warnings: list[str] = field(default_factory=list)
    flight: np.ndarray | None = None   # (N,) int64; None -> all 0
    flight_source_paths: list[str] = field(default_factory=list)
    flight_gaps: list[FlightGap] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.flight is None:
            self.flight = np.zeros(len(self.gps_time_s), dtype=np.int64)
        if not self.flight_source_paths:
            self.flight_source_paths = [self.source_path]

    def __len__(self) -> int:
        return len(self.gps_time_s)

    @property
    def n_exposures(self) -> int:
        return len(self.gps_time_s)

    @property
    def seconds_of_week(self) -> np.ndarray:
        return self.gps_time_s - self.gps_week * SECONDS_PER_WEEK

    @property
    def rtk_fixed(self) -> np.ndarray:
        """(N,) bool: exposures whose real-time solution was RTK fixed (quality 50)."""
        return self.quality == QUALITY_FIXED

    def position_ecef_m(self) -> np.ndarray:
        """(N, 3) WGS84 ECEF (m) of the logged latitude / longitude / ellipsoidal height."""
        return geodetic_to_ecef_m(np.radians(self.lat_deg), np.radians(self.lon_deg), self.ellipsoidal_height_m)

    def offset_ecef_m(self) -> np.ndarray:
        """(N, 3) the antenna -> camera offsets rotated from local NED (at each logged position) to ECEF."""
        lat, lon = np.radians(self.lat_deg), np.radians(self.lon_deg)
        sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
        north = np.stack([-sl * co, -sl * so, cl], axis=-1)
        east = np.stack([-so, co, np.zeros_like(lat)], axis=-1)
        down = -np.stack([cl * co, cl * so, sl], axis=-1)
        d = self.camera_offset_ned_m
        return d[:, 0:1] * north + d[:, 1:2] * east + d[:, 2:3] * down

    def camera_ecef_from_antenna_m(self, antenna_ecef_m) -> np.ndarray:
        """Camera centres (N, 3, ECEF m) from antenna phase centre positions at the exposures (N, 3, ECEF m),
        e.g. a PPK trajectory interpolated at ``gps_time_s``: antenna + ``camera_offset_ned_m`` in NED."""
        a = np.asarray(antenna_ecef_m, dtype=float)
        if a.shape != (self.n_exposures, 3):
            raise ValueError(f"antenna_ecef_m has shape {a.shape}, expected ({self.n_exposures}, 3)")
        return a + self.offset_ecef_m()


# ============================================================================ reading
def read_mrk(path) -> MrkFile:
    """Read a DJI ``*_Timestamp.MRK`` file (plain or gzip). Raises InputFileError on a damaged file."""
    p = Path(path)
    data = read_bytes(p)
    if b"\x00" in data[:4096]:
        raise InputFileError(p, "binary data where a DJI MRK text file was expected")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise InputFileError(p, f"byte 0x{data[exc.start]:02X} is not text (not a DJI MRK file?)", line=line) from None
    return parse_mrk_text(text, str(p))


def parse_mrk_text(text: str, source_path: str = "<text>") -> MrkFile:
    """Parse the text of an MRK file (``source_path`` names it in messages and warnings)."""
    text = text.removeprefix("\ufeff")
    lines = text.split("\n")
    complete_end = text.endswith("\n")
    if lines and lines[-1] == "":
        lines.pop()
    last_data = max((k for k, s in enumerate(lines) if s.strip()), default=-1)
    warnings: list[str] = []
    rows: list[tuple] = []
    columns: tuple[bool, bool] | None = None     # (has sigma, has quality) of the first data line
    first_line = 0
    prev_line = 0
    for k, raw in enumerate(lines):
        s = raw.strip()
        if not s:
            continue
        line_no = k + 1
        partial = k == last_data and not complete_end
        try:
            row = _parse_line(s)
            has = (not np.isnan(row[6][0]), row[7] != QUALITY_MISSING)
            if columns is not None and has != columns:
                raise ValueError(_column_mismatch(has, columns, first_line))
        except ValueError as exc:
            if partial and rows:
                warnings.append(f"line {line_no}: the last line is incomplete ({exc}); it was dropped "
                                "(file cut off while being written?)")
                break
            raise InputFileError(source_path, str(exc), line=line_no) from None
        if rows:
            try:
                _check_order(row, rows[-1], prev_line)
            except ValueError as exc:
                raise InputFileError(source_path, str(exc), line=line_no) from None
        if columns is None:
            columns, first_line = has, line_no
        if rows and row[0] <= rows[-1][0]:
            warnings.append(f"line {line_no}: exposure index {row[0]} does not increase "
                            f"(line {prev_line} has {rows[-1][0]})")
        rows.append(row)
        prev_line = line_no
    if not rows:
        raise InputFileError(source_path, "the file is empty (no exposure line)" if last_data < 0
                             else "no exposure line found")
    index = np.array([r[0] for r in rows], dtype=np.int64)
    week = np.array([r[2] for r in rows], dtype=np.int64)
    sow = np.array([r[1] for r in rows], dtype=float)
    return MrkFile(
        source_path=source_path,
        index=index,
        gps_time_s=week * SECONDS_PER_WEEK + sow,
        gps_week=week,
        camera_offset_ned_m=np.array([r[3] for r in rows], dtype=float).reshape(-1, 3) / 1000.0,
        lat_deg=np.array([r[4][0] for r in rows], dtype=float),
        lon_deg=np.array([r[4][1] for r in rows], dtype=float),
        ellipsoidal_height_m=np.array([r[5] for r in rows], dtype=float),
        sigma_ned_m=np.array([r[6] for r in rows], dtype=float).reshape(-1, 3),
        quality=np.array([r[7] for r in rows], dtype=np.int64),
        warnings=warnings,
    )


def looks_like_mrk(first_bytes: bytes) -> bool:
    """Content-based recognition: the first non-empty line reads ``index sow [week] n,N e,E v,V ...``.
    Give it the first few hundred bytes of the file (at least the first line up to ``,V``)."""
    text = first_bytes[:4096].decode("latin-1").removeprefix("\xef\xbb\xbf")
    for raw in text.split("\n"):
        if raw.strip():
            return bool(_MRK_LINE.match(raw))
    return False


def _parse_line(s: str) -> tuple:
    """(index, sow, week, (n, e, v) mm, (lat, lon), h, (sn, se, sv), quality); ValueError says what is wrong."""
    s = re.sub(r"\s*,\s*", ",", s)
    s = re.sub(r"\[\s*(\S*?)\s*\]", r"[\1]", s)
    tok = s.split()
    if len(tok) < 3:
        raise ValueError(f"{len(tok)} field(s), expected at least 9 (index, seconds of week, [week], N, E, V, "
                         "Lat, Lon, Ellh)")
    if not re.fullmatch(r"[-+]?\d{1,9}", tok[0]):      # bounded: an int64 array holds it
        raise ValueError(f"exposure index {tok[0][:40]!r} is not an integer of at most 9 digits")
    index = int(tok[0])
    sow = _number(tok[1], "GPS seconds of week")
    if not 0.0 <= sow < SECONDS_PER_WEEK:
        raise ValueError(f"GPS seconds of week {tok[1]} is outside [0, 604800)")
    m = re.fullmatch(r"\[(\d{1,5})\]", tok[2])
    if not m:
        raise ValueError(f"GPS week field {tok[2][:40]!r} is not of the form [week] (at most 5 digits)")
    week = int(m.group(1))
    values: dict[str, float] = {}
    sigma = (np.nan, np.nan, np.nan)
    has_sigma = False
    for t in tok[3:]:
        parts = t.split(",")
        if len(parts) == 2 and parts[1].lower() in _LABELS:
            key = parts[1].lower()
            if key in values:
                raise ValueError(f"the {_COLUMN_NAMES[key]} column appears twice")
            values[key] = _number(parts[0], _COLUMN_NAMES[key])
        elif len(parts) == 3 and not has_sigma and all(re.fullmatch(_NUM, p) for p in parts):
            sigma = tuple(float(p) for p in parts)
            has_sigma = True
        elif len(parts) == 2 and re.fullmatch(r"[A-Za-z]+", parts[1]):
            raise ValueError(f"unknown column label {parts[1]!r} in field {t!r}")
        else:
            raise ValueError(f"unexpected field {t!r} (a value without its label, or a cut-off field)")
    missing = [_COLUMN_NAMES[k] for k in _REQUIRED if k not in values]
    if missing:
        raise ValueError(f"missing field(s): {', '.join(missing)}")
    if not -90.0 <= values["lat"] <= 90.0 or not -180.0 <= values["lon"] <= 180.0:
        raise ValueError(f"latitude {values['lat']} / longitude {values['lon']} out of range")
    if has_sigma and min(sigma) < 0:
        raise ValueError(f"negative standard deviation in {sigma}")
    if "q" in values:
        q = values["q"]
        if not abs(q) < 1e6 or q != int(q):
            raise ValueError(f"quality {q} is not an integer")
        quality = int(q)
    else:
        quality = QUALITY_MISSING
    return (index, sow, week, (values["n"], values["e"], values["v"]), (values["lat"], values["lon"]),
            values["ellh"], sigma, quality)


def _number(t: str, what: str) -> float:
    if not re.fullmatch(_NUM, t):
        raise ValueError(f"{what} {t!r} is not a number")
    return float(t)


def _check_order(row: tuple, prev: tuple, prev_line: int) -> None:
    week, prev_week = row[2], prev[2]
    if abs(week - prev_week) > _MAX_WEEK_STEP:
        raise ValueError(f"GPS week jumps from {prev_week} (line {prev_line}) to {week}")
    t = week * SECONDS_PER_WEEK + row[1]
    t_prev = prev_week * SECONDS_PER_WEEK + prev[1]
    if t <= t_prev:
        raise ValueError(f"time {row[1]} s of week {week} is not after the previous exposure's "
                         f"({prev[1]} s of week {prev_week}, line {prev_line})")


def _column_mismatch(has: tuple[bool, bool], first: tuple[bool, bool], first_line: int) -> str:
    what = []
    for name, a, b in (("sigma N, E, V", has[0], first[0]), ("quality (,Q)", has[1], first[1])):
        if a and not b:
            what.append(f"has a {name} column that line {first_line} lacks")
        elif b and not a:
            what.append(f"the {name} column is missing (line {first_line} has it)")
    return "; ".join(what)


# ============================================================================ joining flights
def join_mrk(files: list[MrkFile]) -> MrkFile:
    """Join the MRK files of several flights into one, in time order.

    Exposure indices are kept as written; ``flight`` tells which input each exposure came from (an index
    into ``flight_source_paths``: the inputs' flights in the order given, so for single files the
    position in ``files``). ``flight_gaps`` lists the time between consecutive flights; flights that
    overlap in time get a warning naming both files and the overlap instead (their exposures are
    interleaved by time). The inputs' own warnings are kept, prefixed with their file name.
    """
    if not files:
        raise ValueError("join_mrk needs at least one MRK file")
    paths: list[str] = []
    flights, warnings = [], []
    for f in files:
        flights.append(np.asarray(f.flight, dtype=np.int64) + len(paths))
        paths.extend(f.flight_source_paths)
        warnings.extend(w if w.startswith(f.source_path) else f"{f.source_path}: {w}" for w in f.warnings)
    flight = np.concatenate(flights)
    t = np.concatenate([f.gps_time_s for f in files])
    order = np.argsort(t, kind="stable")

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(f, name) for f in files])[order]

    # per-flight spans in start order -> gaps and overlaps
    spans = sorted((float(t[flight == k].min()), float(t[flight == k].max()), k)
                   for k in range(len(paths)) if np.any(flight == k))
    gaps: list[FlightGap] = []
    end_max, end_flight = spans[0][1], spans[0][2]
    for start, end, k in spans[1:]:
        if start <= end_max:
            warnings.append(f"flights {end_flight} ({paths[end_flight]}) and {k} ({paths[k]}) overlap in time: "
                            f"GPS {start:.3f} to {min(end, end_max):.3f} s ({min(end, end_max) - start:.1f} s); "
                            "their exposures are interleaved")
        else:
            gaps.append(FlightGap(end_flight, k, end_max, start))
        if end > end_max:
            end_max, end_flight = end, k
    return MrkFile(
        source_path=" + ".join(f.source_path for f in files),
        index=cat("index"),
        gps_time_s=t[order],
        gps_week=cat("gps_week"),
        camera_offset_ned_m=cat("camera_offset_ned_m"),
        lat_deg=cat("lat_deg"),
        lon_deg=cat("lon_deg"),
        ellipsoidal_height_m=cat("ellipsoidal_height_m"),
        sigma_ned_m=cat("sigma_ned_m"),
        quality=cat("quality"),
        warnings=warnings,
        flight=flight[order],
        flight_source_paths=paths,
        flight_gaps=gaps,
    )
