"""RINEX observation files: a fast reader (versions 2.10/2.11, 3.00-3.05, 4.00-4.02; also older 2.0x and the
2.12 draft) and writers (3.04, 2.11).

Reading
-------
``read_rinex_obs(path)`` returns a :class:`~georef_core.gnss.observations.RawObservations`:

* units are those of the file: code/pseudorange in m, phase in cycles, Doppler in Hz, SNR in dB-Hz (the
  'S' observations as written; a 'SYS / SCALE FACTOR' header record is applied), times as ``gps_time_s``;
* every satellite system found is kept (G, R, E, J, C and also S, I); ``sat_ids`` are sorted by system
  (G R E J C S I) then PRN, e.g. 'G05'; ``obs_codes`` is the union, in header order, of the RINEX 3 codes of the
  systems that have at least one satellite record (a 2-character code such as Septentrio's channel number 'X1'
  is kept as 'X1');
* RINEX 2 observation types are renamed to RINEX 3 codes per system, see :data:`RINEX2_TO_RINEX3`. GPS 'C2' is
  read as 'C2X' (the civil L2C code, whose M+L tracking is what RINEX 2.11 receivers record as C2), 'P2'/'L2'
  as 'C2W'/'L2W' (semi-codeless P(Y) tracking). RINEX 2 LLI bit 2 (antispoofing) is kept as is;
* RINEX 3.00-3.02 BeiDou B1I codes 'x1y' become 'x2y' (RINEX 3.03+ convention);
* the RINEX 2 'WAVELENGTH FACT L1/2' record (half-cycle phases of 1990s squaring receivers) is not applied;
* blank fields and fields equal to 0.000 are missing (NaN) as the RINEX standard defines ("missing observations
  are written as 0.0 or blanks"); LLI and SSI are 0 where the value is missing;
* epoch times in GPS, GAL, QZS or IRN time are used as they are; BDT adds 14 s; GLO and UTC add the
  GPS-UTC leap seconds (``gnss_time.leap_seconds_at``). Without a time system, a single-system file uses its
  system's time and a mixed file GPS time;
* epoch flags 0 and 1 are observations (their flag is kept in ``epoch_flags``); flag 5 (external event, e.g.
  a camera shutter) adds the epoch time to ``event_gps_time_s``; flags 2-4 carry header records, which are
  applied (a change of observation types in the middle of the file is supported; other updates such as a new
  'ANTENNA: DELTA H/E/N' overwrite the header, last value wins); flag 6 (cycle-slip records) is skipped;
* errors raise :class:`~georef_core.errors.InputFileError` naming the file and, where it applies, the line. A
  file that ends inside an epoch (fewer lines than announced, or a last line cut inside a value) is *not* an
  error: the complete epochs are kept and a :class:`RinexTruncatedWarning` names the file and line.

Speed (~0.005-0.02 s/MB on a 2-core machine): the only per-epoch Python work is splitting RINEX 3 epochs (RINEX
2 epochs are split by a compiled kernel, which leaves events, header records and damaged lines to the Python
scan). Observation lines are copied from the file's bytes into one fixed-width byte matrix and its 16-character
fields (F14.3 value, LLI, SSI) are decoded by compiled kernels (rinex_obs_kernels.py) that read the integer
value in thousandths and check the layout
(blanks, optional minus, digits, the point in column 11, three decimals, flags blank or a digit). Anything else
takes a slower per-field path: valid numbers in other layouts (other decimals, exponents) are read there, and
letters or a shifted column are reported with their line.

Writing
-------
``write_rinex3_obs`` (RINEX 3.04) and ``write_rinex2_obs`` (RINEX 2.11) write a ``RawObservations``, with event
records (flag 5) interleaved at their times, LLI/SSI digits and the header fields above. Values are written
F14.3 (a value that rounds to 0.000 therefore reads back as missing). Times are written in GPS time.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputFileError
from .compressed_files import read_text
from .gnss_time import calendar_to_gps_time_s, gps_time_s_to_datetime, leap_seconds_at
from .observations import RawObservations, ReceiverHeader
from .rinex_obs_kernels import decode_fields, pad_rows, scan_rinex2_epochs

__all__ = [
    "RINEX2_TO_RINEX3",
    "RinexTruncatedWarning",
    "read_rinex_obs",
    "write_rinex2_obs",
    "write_rinex3_obs",
]


class RinexTruncatedWarning(UserWarning):
    """The file ends inside an epoch record; the complete epochs before it were kept."""


SYSTEM_ORDER = "GREJCSI"
_SYSTEM_TIME = {"G": "GPS", "R": "GLO", "E": "GAL", "J": "QZS", "C": "BDT", "I": "IRN", "S": "GPS"}
_SUPPORTED_TIME_SYSTEMS = ("GPS", "GAL", "QZS", "IRN", "BDT", "GLO", "UTC")
BDT_TO_GPS_S = 14.0

# RINEX 2 observation type -> RINEX 3 code, per system (2.11 for G R E S; 2.12 drafts for J C I).
RINEX2_TO_RINEX3: dict[str, dict[str, str]] = {
    "G": {
        "C1": "C1C", "P1": "C1W", "L1": "L1C", "D1": "D1C", "S1": "S1C",
        "C2": "C2X", "P2": "C2W", "L2": "L2W", "D2": "D2W", "S2": "S2W",
        "C5": "C5X", "L5": "L5X", "D5": "D5X", "S5": "S5X",
    },
    "R": {
        "C1": "C1C", "P1": "C1P", "L1": "L1C", "D1": "D1C", "S1": "S1C",
        "C2": "C2C", "P2": "C2P", "L2": "L2P", "D2": "D2P", "S2": "S2P",
    },
    "E": {f"{t}{d}": f"{t}{d}X" for d in "15678" for t in "CLDS"},
    "S": {**{f"{t}1": f"{t}1C" for t in "CLDS"}, **{f"{t}5": f"{t}5X" for t in "CLDS"}},
    "J": {
        **{f"{t}1": f"{t}1C" for t in "CLDS"},
        **{f"{t}{d}": f"{t}{d}X" for d in "256" for t in "CLDS"},
    },
    "C": {f"{t}{d}": f"{t}{b}I" for d, b in (("1", "2"), ("2", "2"), ("7", "7"), ("6", "6")) for t in "CLDS"},
    "I": {f"{t}{d}": f"{t}{d}A" for d in "59" for t in "CLDS"},
}
_RINEX2_WRITABLE_SYSTEMS = "GRES"   # systems RINEX 2.11 defines


# ----------------------------------------------------------------------------------------------------------
# Decoding of 16-character observation fields (F14.3 value, I1 LLI, I1 SSI): compiled fast path
# (rinex_obs_kernels.decode_fields), slow path for other number layouts
# ----------------------------------------------------------------------------------------------------------

_FIELD = 16
_CHUNK_FIELDS = 1 << 14     # fields per decoding chunk
# right-aligned in its 14 columns: trailing blanks would mean a shifted column
_GENERIC_NUMBER = re.compile(rb"^ *[-+]?(\d+\.?\d*|\.\d+)([eEdD][-+]?\d+)?$")


def _decode_chunk(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(n, 16) uint8 fields -> values (NaN where missing), LLI, SSI, and a mask of fields not in F14.3 layout."""
    return decode_fields(c)


def _decode_generic(path: Path, c: np.ndarray, line_of_field: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slow path for fields that are not in F14.3 layout: a right-aligned plain or exponent number, else an error."""
    values = np.full(len(c), np.nan)
    for i, raw in enumerate(c):
        text = raw[:14].tobytes()
        flags = raw[14:16]
        if not (((flags >= 48) & (flags <= 57)) | (flags == 32)).all():
            raise InputFileError(path, f"invalid LLI/SSI flag in observation field {raw.tobytes()!r}",
                                 int(line_of_field[i]))
        if text.strip() == b"":
            continue
        if _GENERIC_NUMBER.match(text) is None:
            raise InputFileError(path, f"not a number in observation field {text.decode('latin-1')!r}",
                                 int(line_of_field[i]))
        values[i] = float(text.replace(b"D", b"E").replace(b"d", b"e"))
    values[values == 0.0] = np.nan
    digits = np.where(c[:, 14:16] == 32, 0, c[:, 14:16].astype(np.int16) - 48).astype(np.uint8)
    return values, digits[:, 0], digits[:, 1]


def _decode_fields(path: Path, fields: np.ndarray, field_line: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decode (n, K, 16) uint8 fields. ``field_line`` (n, K) gives each field's file line number for errors.

    Returns values (n, K) float64 (NaN where missing), lli (n, K) uint8, ssi (n, K) uint8 (0 where missing)."""
    n, k = fields.shape[:2]
    values = np.empty((n, k))
    lli = np.empty((n, k), np.uint8)
    ssi = np.empty((n, k), np.uint8)
    if n == 0 or k == 0:
        return values, lli, ssi
    rows = max(1, _CHUNK_FIELDS // k)
    for a in range(0, n, rows):
        chunk = np.ascontiguousarray(fields[a:a + rows]).reshape(-1, _FIELD)
        v, ll, ss, odd = _decode_chunk(chunk)
        if odd.any():
            idx = np.flatnonzero(odd)
            lines = field_line[a:a + rows].reshape(-1)[idx]
            v[idx], ll[idx], ss[idx] = _decode_generic(path, chunk[idx], lines)
        m = len(chunk) // k
        values[a:a + m] = v.reshape(m, k)
        lli[a:a + m] = ll.reshape(m, k)
        ssi[a:a + m] = ss.reshape(m, k)
    missing = np.isnan(values)
    lli[missing] = 0
    ssi[missing] = 0
    return values, lli, ssi


# ----------------------------------------------------------------------------------------------------------
# Header
# ----------------------------------------------------------------------------------------------------------

def _float_or_none(text: str) -> float | None:
    text = text.strip()
    return float(text.replace("D", "E")) if text else None


@dataclass
class _Header:
    """Parse state of the header (and of header records inside the data section)."""

    path: Path
    version: float = 0.0
    file_system: str = "G"
    time_system: str = ""
    info: ReceiverHeader = field(default_factory=ReceiverHeader)
    obs_types: dict[str, list[str]] = field(default_factory=dict)   # RINEX 2: key '*' -> 2-char types
    declared: dict[str, tuple[int, int]] = field(default_factory=dict)  # sys -> (count, line)
    scale: dict[str, dict[str, float]] = field(default_factory=dict)  # sys -> code ('' = all) -> factor
    types_changed: bool = False
    _last_sys: str = ""
    _last_scale: tuple[str, float] = ("", 1.0)

    def apply(self, line: str, line_no: int) -> None:
        """Apply one header record (label in columns 61-80)."""
        label = line[60:80].strip()
        try:
            self._apply(label, line)
        except (ValueError, IndexError) as exc:
            raise InputFileError(self.path, f"malformed '{label}' header record ({exc})", line_no) from None
        if label in ("SYS / # / OBS TYPES", "# / TYPES OF OBSERV"):
            self.types_changed = True
            key = self._last_sys
            if key and key in self.declared:
                self.declared[key] = (self.declared[key][0], line_no)

    def _apply(self, label: str, line: str) -> None:
        info = self.info
        if label == "MARKER NAME":
            info.marker_name = line[:60].strip()
        elif label == "REC # / TYPE / VERS":
            info.receiver_type = line[20:40].strip()
            info.receiver_version = line[40:60].strip()
        elif label == "ANT # / TYPE":
            info.antenna_type = line[20:40].strip()
        elif label == "APPROX POSITION XYZ":
            xyz = np.array([float(line[i:i + 14]) for i in (0, 14, 28)])
            info.approx_position_ecef_m = None if not xyz.any() else xyz
        elif label == "ANTENNA: DELTA H/E/N":
            info.antenna_delta_hen_m = np.array([float(line[i:i + 14]) for i in (0, 14, 28)])
        elif label == "INTERVAL":
            interval = _float_or_none(line[:10])
            info.interval_s = interval if interval else None
        elif label == "TIME OF FIRST OBS":
            self.time_system = line[48:51].strip().upper()
        elif label == "GLONASS SLOT / FRQ #":
            for i in range(8):
                entry = line[4 + 7 * i: 11 + 7 * i]
                if entry[:3].strip():
                    info.glonass_fcn[_sat_id(entry[:3])] = int(entry[4:6])
        elif label == "SYS / # / OBS TYPES":
            sys = line[0]
            if sys != " ":
                self._last_sys = sys
                self.obs_types[sys] = []
                self.declared[sys] = (int(line[3:6]), 0)
            elif not self._last_sys:
                raise ValueError("continuation line before any system")
            self.obs_types[self._last_sys] += [c for c in (line[7 + 4 * i: 10 + 4 * i].strip() for i in range(13)) if c]
        elif label == "# / TYPES OF OBSERV":
            if line[:6].strip():
                self._last_sys = "*"
                self.obs_types["*"] = []
                self.declared["*"] = (int(line[:6]), 0)
            self.obs_types.setdefault("*", []).extend(
                c for c in (line[10 + 6 * i: 12 + 6 * i].strip() for i in range(9)) if c)
        elif label == "SYS / SCALE FACTOR":
            if line[0] != " ":
                self._last_scale = (line[0], float(line[2:6]))
                if not line[8:10].strip() or int(line[8:10]) == 0:
                    self.scale.setdefault(line[0], {})[""] = self._last_scale[1]
            sys, factor = self._last_scale
            for i in range(12):
                code = line[11 + 4 * i: 14 + 4 * i].strip()
                if code and sys:
                    self.scale.setdefault(sys, {})[code] = factor

    def check_types(self) -> None:
        """Raise if an obs-type record announces more or fewer types than it lists."""
        for key, (count, line_no) in self.declared.items():
            found = len(self.obs_types.get(key, []))
            if found != count:
                what = "SYS / # / OBS TYPES" if key != "*" else "# / TYPES OF OBSERV"
                raise InputFileError(self.path, f"'{what}' announces {count} observation types but lists {found}",
                                     line_no or None)

    def layout(self) -> dict[str, list[str | None]]:
        """Per system, the RINEX 3 code of each field position (None: a type this reader drops)."""
        if self.version < 3:
            types = self.obs_types.get("*", [])
            return {sys: [table.get(t) for t in types] for sys, table in RINEX2_TO_RINEX3.items()}
        out: dict[str, list[str | None]] = {}
        for sys, codes in self.obs_types.items():
            if sys == "C" and self.version < 3.03:
                codes = [c[0] + "2" + c[2:] if len(c) == 3 and c[1] == "1" else c for c in codes]
            out[sys] = list(codes)
        return out


def _sat_id(text: str) -> str:
    """'G 5', 'G05', ' 5' (RINEX 2 GPS) -> 'G05'."""
    sys = text[0] if text[0] != " " else "G"
    return f"{sys}{int(text[1:3]):02d}"


_SUPPORTED_VERSIONS = ((2.0, 2.12), (3.0, 3.05), (4.0, 4.02))


def _read_header(path: Path, lines: list[bytes]) -> tuple[_Header, int]:
    """Parse the header; returns the state and the index of the first data line."""
    first = lines[0].decode("latin-1")
    if first[60:80].strip() != "RINEX VERSION / TYPE":
        if "CRINEX" in first:
            raise InputFileError(path, "Hatanaka-compressed data could not be recognised")
        raise InputFileError(path, "not a RINEX file (the first line is not a 'RINEX VERSION / TYPE' record)", 1)
    try:
        version = float(first[:9])
    except ValueError:
        raise InputFileError(path, f"unreadable RINEX version {first[:9].strip()!r}", 1) from None
    file_type = first[20:21].upper()
    if file_type != "O":
        kind = {"N": "a navigation", "G": "a GLONASS navigation", "H": "a SBAS navigation", "M": "a meteorological",
                "C": "a clock", "L": "a Galileo navigation"}.get(file_type, f"a type '{file_type}'")
        raise InputFileError(path, f"{kind} file, not an observation file", 1)
    if not any(lo <= round(version, 2) <= hi for lo, hi in _SUPPORTED_VERSIONS):
        raise InputFileError(path, f"unsupported RINEX version {version:.2f} (supported: 2.00-2.12, 3.00-3.05, "
                                   "4.00-4.02)", 1)
    state = _Header(path=path, version=version)
    state.file_system = (first[40:41].strip() or "G").upper()
    state.info.rinex_version = version
    for i in range(1, len(lines)):
        line = lines[i].decode("latin-1")
        if line[60:80].strip() == "END OF HEADER":
            state.check_types()
            if not state.declared:
                raise InputFileError(path, "the header has no observation types record")
            state.types_changed = False
            return state, i + 1
        state.apply(line, i + 1)
    raise InputFileError(path, "no 'END OF HEADER' record (truncated or not an observation file)")


# ----------------------------------------------------------------------------------------------------------
# Data section: splitting into epochs (the only per-line Python work)
# ----------------------------------------------------------------------------------------------------------

@dataclass
class _Block:
    """Observation records that share one observation-type layout."""

    layout: dict[str, list[str | None]]
    epoch: list[int] = field(default_factory=list)        # per epoch in the block: epoch index
    start: list[int] = field(default_factory=list)        # index (in the file's line list) of the first record line
    count: list[int] = field(default_factory=list)        # records in that epoch (each lines_per_record lines)
    sat_text: list[bytes] = field(default_factory=list)   # RINEX 2: 3 characters per record
    lines_per_record: int = 1


_Calendar = tuple[int, int, int, int, int, float]    # year, month, day, hour, minute, second


@dataclass
class _Scan:
    """Result of splitting the data section: epoch and event times (with their line numbers), record blocks."""

    epoch_fields: list[_Calendar] = field(default_factory=list)
    epoch_lines: list[int] = field(default_factory=list)
    epoch_flags: list[int] = field(default_factory=list)
    event_fields: list[_Calendar] = field(default_factory=list)
    event_lines: list[int] = field(default_factory=list)
    blocks: list[_Block] = field(default_factory=list)


def _truncated(path: Path, line_no: int, n_epochs: int) -> None:
    warnings.warn(f"{path}, line {line_no}: the file ends inside this epoch record (truncated file?); "
                  f"kept the {n_epochs} complete epochs before it", RinexTruncatedWarning, stacklevel=3)


def _cut_inside_value(lines: list[bytes], end: int, prefix: int) -> bool:
    """True if the file stops, without a final newline, inside an F14.3 value of line ``end - 1`` (values are
    right-aligned in 14 columns, so a complete line never ends inside one)."""
    if end != len(lines):
        return False          # a newline follows: the line is complete (a garbled one is reported as such)
    n = len(lines[end - 1].rstrip())
    return n > prefix and (n - prefix) % _FIELD not in (0, 14, 15)


def _misplaced_epoch(path: Path, lines: list[bytes], epoch_at: int, end: int) -> None:
    """Raise at an epoch record that was taken as a satellite record of the previous epoch (RINEX 3)."""
    for j in range(epoch_at + 1, end):
        if lines[j][:1] == b">":
            raise InputFileError(path, f"epoch record where a satellite record was expected: the epoch at line "
                                       f"{epoch_at + 1} announces more satellites than it has", j + 1)


def _header_records(state: _Header, lines: list[bytes], a: int, b: int) -> None:
    for j in range(a, b):
        state.apply(lines[j].decode("latin-1"), j + 1)


def _scan_rinex3(path: Path, lines: list[bytes], i: int, state: _Header) -> _Scan:
    scan = _Scan()
    n_lines = len(lines)
    while n_lines > i and not lines[n_lines - 1].strip():
        n_lines -= 1
    block = _Block(layout=state.layout())
    scan.blocks.append(block)
    last_epoch = -1
    while i < n_lines:
        line = lines[i]
        if line[:1] != b">":
            if not line.strip():
                i += 1
                continue
            _misplaced_epoch(path, lines, last_epoch, i)
            raise InputFileError(path, "expected an epoch record starting with '>' (the previous epoch may announce "
                                       "more satellites than it has)", i + 1)
        last_epoch = i
        try:
            flag = int(line[31:32].strip() or b"0")
            n = int(line[32:35])
        except ValueError:
            if i == n_lines - 1:
                _truncated(path, i + 1, len(scan.epoch_flags))
                break
            raise InputFileError(path, f"malformed epoch record {line.decode('latin-1').rstrip()!r}", i + 1) from None
        end = i + 1 + n
        if end > n_lines or (flag <= 1 and n > 0 and _cut_inside_value(lines, end, 3)):
            _truncated(path, i + 1, len(scan.epoch_flags))
            break
        if flag <= 1 or flag == 5:
            try:
                t = (int(line[2:6]), int(line[7:9]), int(line[10:12]), int(line[13:15]), int(line[16:18]),
                     float(line[18:29]))
            except ValueError:
                raise InputFileError(path, f"malformed epoch time {line[:29].decode('latin-1')!r}", i + 1) from None
            if flag <= 1:
                block.epoch.append(len(scan.epoch_flags))
                block.start.append(i + 1)
                block.count.append(n)
                scan.epoch_fields.append(t)
                scan.epoch_lines.append(i + 1)
                scan.epoch_flags.append(flag)
            else:
                scan.event_fields.append(t)
                scan.event_lines.append(i + 1)
        elif flag in (2, 3, 4):
            _header_records(state, lines, i + 1, end)
            if state.types_changed:
                state.check_types()
                state.types_changed = False
                block = _Block(layout=state.layout())
                scan.blocks.append(block)
        elif flag != 6:
            raise InputFileError(path, f"unknown epoch flag {flag}", i + 1)
        i = end
    return scan


def _add_regular_epochs(scan: _Scan, block: _Block, found: tuple) -> None:
    """Append the regular epochs found by the compiled scan (rinex_obs_kernels.scan_rinex2_epochs)."""
    _, at, flags, counts, first, fields, sats = found
    e0 = len(scan.epoch_flags)
    block.epoch.extend(range(e0, e0 + len(at)))
    block.start.extend(first.tolist())
    block.count.extend(counts.tolist())
    block.sat_text.append(sats.tobytes())
    calendar = fields[:, :5].astype(np.int64).tolist()
    scan.epoch_fields.extend((*c, sec) for c, sec in zip(calendar, fields[:, 5].tolist()))
    scan.epoch_lines.extend((at + 1).tolist())
    scan.epoch_flags.extend(flags.tolist())


def _scan_rinex2(path: Path, lines: list[bytes], i: int, state: _Header,
                 line_spans: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> _Scan:
    """Split the data section into epochs. With `line_spans` (the file's bytes, each line's start and end),
    runs of regular epochs are walked by a compiled kernel and only the other records (events, header
    records, anything malformed, the last epoch) by the Python code below, which reports the errors."""
    scan = _Scan()
    n_lines = len(lines)
    while n_lines > i and not lines[n_lines - 1].strip():
        n_lines -= 1

    def new_block() -> _Block:
        per_record = max(1, math.ceil(len(state.obs_types.get("*", [])) / 5))
        return _Block(layout=state.layout(), lines_per_record=per_record)

    block = new_block()
    scan.blocks.append(block)
    while i < n_lines:
        if line_spans is not None:
            found = scan_rinex2_epochs(*line_spans, i, n_lines, block.lines_per_record)
            if len(found[1]):
                _add_regular_epochs(scan, block, found)
            i = found[0]
            if i >= n_lines:
                break
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        try:
            flag = int(line[26:29].strip() or b"0")
            n = int(line[29:32])
            if line[0:1] != b" " or not 0 <= flag <= 6:
                raise ValueError
        except ValueError:
            if i == n_lines - 1:
                _truncated(path, i + 1, len(scan.epoch_flags))
                break
            raise InputFileError(path, "expected an epoch record (the previous epoch may announce more or fewer "
                                       "satellites or observation types than it has)", i + 1) from None
        if flag in (0, 1, 6):
            n_cont = (n - 1) // 12 if n > 0 else 0
            first_obs = i + 1 + n_cont
            end = first_obs + n * block.lines_per_record
            if end > n_lines or (flag <= 1 and n > 0 and _cut_inside_value(lines, end, 0)):
                _truncated(path, i + 1, len(scan.epoch_flags))
                break
            if flag <= 1:
                try:
                    yy = int(line[1:3])
                    t = (yy + (1900 if yy >= 80 else 2000), int(line[4:6]), int(line[7:9]), int(line[10:12]),
                         int(line[13:15]), float(line[15:26]))
                except ValueError:
                    raise InputFileError(path, f"malformed epoch time {line[:26].decode('latin-1')!r}",
                                         i + 1) from None
                sats = b"".join([lines[j][32:68].ljust(36) for j in range(i, first_obs)])[:3 * n]
                block.sat_text.append(sats)
                block.epoch.append(len(scan.epoch_flags))
                block.start.append(first_obs)
                block.count.append(n)
                scan.epoch_fields.append(t)
                scan.epoch_lines.append(i + 1)
                scan.epoch_flags.append(flag)
        else:
            end = i + 1 + n
            if end > n_lines:
                _truncated(path, i + 1, len(scan.epoch_flags))
                break
            if flag == 5 and line[1:26].strip():
                try:
                    yy = int(line[1:3])
                    scan.event_fields.append((yy + (1900 if yy >= 80 else 2000), int(line[4:6]), int(line[7:9]),
                                              int(line[10:12]), int(line[13:15]), float(line[15:26])))
                    scan.event_lines.append(i + 1)
                except ValueError:
                    raise InputFileError(path, "malformed event epoch time", i + 1) from None
            elif flag in (2, 3, 4):
                _header_records(state, lines, i + 1, end)
                if state.types_changed:
                    state.check_types()
                    state.types_changed = False
                    block = new_block()
                    scan.blocks.append(block)
        i = end
    return scan


# ----------------------------------------------------------------------------------------------------------
# Assembly into RawObservations
# ----------------------------------------------------------------------------------------------------------

def _ranges(starts: np.ndarray, counts: np.ndarray, step: int) -> np.ndarray:
    """Concatenation of start + step * arange(count) for every (start, count)."""
    total = int(counts.sum())
    offset = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    return np.repeat(starts, counts) + step * offset


@dataclass
class _Records:
    """Observation records of one block, as matrices."""

    block: _Block
    epoch: np.ndarray        # (n,) epoch index
    sat_key: np.ndarray      # (n,) int: system order * 100 + PRN
    sys_char: np.ndarray     # (n,) uint8
    line_no: np.ndarray      # (n,) file line number of the record's first line
    fields: np.ndarray       # (n, K, 16) uint8


def _records(path: Path, block: _Block, version: float, line_spans: tuple) -> _Records:
    """The block's records as matrices; `line_spans`: the file's bytes and each line's start and end, from
    which the record lines are copied into fixed-width rows (compiled: rinex_obs_kernels.pad_rows)."""
    counts = np.asarray(block.count, dtype=np.int64)
    epoch = np.repeat(np.asarray(block.epoch, dtype=np.int64), counts)
    per = block.lines_per_record
    starts = np.asarray(block.start, dtype=np.int64)
    first_line = _ranges(starts, counts, per) + 1
    record_lines = _ranges(starts, counts * per, 1)
    k_max = max((len(v) for v in block.layout.values()), default=0)
    if version >= 3:
        mat = pad_rows(*line_spans, record_lines, 3 + _FIELD * k_max)
        ids = mat[:, :3]
        fields = mat[:, 3:].reshape(len(mat), k_max, _FIELD)
    else:
        mat = pad_rows(*line_spans, record_lines, 80)
        fields = mat.reshape(len(mat) // per, per * 5, _FIELD)[:, :k_max]
        ids = np.frombuffer(b"".join(block.sat_text), np.uint8).reshape(-1, 3).copy()
        ids[ids[:, 0] == 32, 0] = ord("G")      # RINEX 2: blank system means GPS
    prn = ids[:, 1:3].astype(np.int64) - 48
    prn[ids[:, 1:3] == 32] = 0
    bad = ((prn < 0) | (prn > 9)).any(axis=1) | (ids[:, 0] == ord(">"))
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        what = ids[r].tobytes().decode("latin-1")
        line = int(first_line[r]) if version >= 3 else _epoch_line_of(block, r)
        raise InputFileError(path, f"invalid satellite identifier {what!r}", line)
    order = np.full(256, 99, dtype=np.int64)
    for j, s in enumerate(SYSTEM_ORDER):
        order[ord(s)] = j
    sys_char = ids[:, 0].copy()
    key = order[sys_char] * 100 + prn[:, 0] * 10 + prn[:, 1]
    return _Records(block, epoch, key, sys_char, first_line, fields)


def _epoch_line_of(block: _Block, record: int) -> int | None:
    """File line number of the (RINEX 2) epoch record that lists a given satellite record."""
    cum = np.cumsum(block.count)
    e = int(np.searchsorted(cum, record, side="right"))
    return block.start[e] if e < len(block.start) else None


def _gps_time(path: Path, fields: list[_Calendar], line_nos: list[int], time_system: str) -> np.ndarray:
    """Epoch calendar fields in the file's time system -> gps_time_s (s)."""
    if not fields:
        return np.zeros(0)
    arr = np.asarray(fields, dtype=np.float64)
    ymd = arr[:, :5].astype(np.int64)
    bad = (ymd[:, 1] < 1) | (ymd[:, 1] > 12) | (ymd[:, 2] < 1) | (ymd[:, 2] > 31) | (ymd[:, 3] > 23) | \
        (ymd[:, 4] > 59) | (arr[:, 5] < 0) | (arr[:, 5] >= 61)
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise InputFileError(path, f"impossible epoch date/time {fields[j]}", line_nos[j])
    t = np.asarray(calendar_to_gps_time_s(ymd[:, 0], ymd[:, 1], ymd[:, 2], ymd[:, 3], ymd[:, 4], arr[:, 5]),
                   dtype=np.float64).reshape(-1)
    if time_system == "BDT":
        t = t + BDT_TO_GPS_S
    elif time_system in ("GLO", "UTC"):
        leaps = {leap_seconds_at(gps_time_s_to_datetime(x)) for x in (t[0], t[-1])}
        if len(leaps) == 1:
            t = t + leaps.pop()
        else:
            t = t + np.array([leap_seconds_at(gps_time_s_to_datetime(x)) for x in t])
    return t


def _time_system(state: _Header, systems_present: set[str]) -> str:
    ts = state.time_system
    if not ts:
        if state.file_system in _SYSTEM_TIME:
            ts = _SYSTEM_TIME[state.file_system]
        elif len(systems_present) == 1:
            ts = _SYSTEM_TIME.get(next(iter(systems_present)), "GPS")
        else:
            ts = "GPS"
    if ts not in _SUPPORTED_TIME_SYSTEMS:
        raise InputFileError(state.path, f"unsupported time system {ts!r} in 'TIME OF FIRST OBS'")
    return ts


def read_rinex_obs(path: str | Path) -> RawObservations:
    """Read a RINEX 2.10/2.11, 3.00-3.05 or 4.0x observation file (plain, gzip, .Z or Hatanaka).

    Returns every signal of every satellite: values in m (code), cycles (phase), Hz (Doppler), dB-Hz (SNR),
    epoch times and event (flag 5) times in gps_time_s. See the module docstring for the conventions.

    Raises InputFileError for a missing, empty, wrong-type, unsupported or corrupt file. A truncated last
    epoch is dropped with a RinexTruncatedWarning."""
    p = Path(path)
    text = read_text(p)
    if not text or text.isspace():
        raise InputFileError(p, "file is empty")
    data = text.encode("latin-1")
    del text
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    lines = data.split(b"\n")
    buf = np.frombuffer(data, np.uint8)
    newlines = np.flatnonzero(buf == 10)
    spans = (buf, np.concatenate(([0], newlines + 1)), np.concatenate((newlines, [len(buf)])))
    del newlines
    state, first_data = _read_header(p, lines)
    if state.version >= 3:
        scan = _scan_rinex3(p, lines, first_data, state)
    else:
        scan = _scan_rinex2(p, lines, first_data, state, spans)
    del lines
    if not scan.epoch_flags:
        raise InputFileError(p, "contains no (complete) observation epoch")
    records = [_records(p, b, state.version, spans) for b in scan.blocks if b.count]
    del data, buf, spans    # the padded matrices hold the data now: free the file before the outputs

    # satellites and observation codes
    all_keys = np.unique(np.concatenate([r.sat_key for r in records]))
    keep_keys = all_keys[all_keys < 99 * 100]
    sat_ids = [f"{SYSTEM_ORDER[k // 100]}{k % 100:02d}" for k in keep_keys]
    systems = {s[0] for s in sat_ids}
    codes: list[str] = []
    for r in records:
        for sys in sorted(r.block.layout, key=lambda s: SYSTEM_ORDER.index(s) if s in SYSTEM_ORDER else 99):
            if sys in systems and np.any(r.sys_char == ord(sys)):
                codes += [c for c in r.block.layout[sys] if c is not None and c not in codes]
    col = {c: k for k, c in enumerate(codes)}

    n_e, n_s, n_k = len(scan.epoch_flags), len(sat_ids), len(codes)
    values = np.full((n_e, n_s, n_k), np.nan)
    lli = np.zeros((n_e, n_s, n_k), np.uint8)
    ssi = np.zeros((n_e, n_s, n_k), np.uint8)
    for r in records:
        if state.version >= 3:
            declared = np.frombuffer("".join(r.block.layout).encode("latin-1"), np.uint8)
            unknown = ~np.isin(r.sys_char, declared)
            if unknown.any():
                row = int(np.flatnonzero(unknown)[0])
                raise InputFileError(p, f"satellite system {chr(r.sys_char[row])!r} has no 'SYS / # / OBS TYPES' "
                                        "record", int(r.line_no[row]))
        for sys, layout in r.block.layout.items():
            rows = np.flatnonzero(r.sys_char == ord(sys))
            if len(rows) == 0 or sys not in systems:
                continue
            k_src = [k for k, c in enumerate(layout) if c is not None]
            k_dst = np.array([col[layout[k]] for k in k_src], dtype=np.int64)
            fields = r.fields[rows][:, k_src]
            field_line = r.line_no[rows][:, None] + (np.asarray(k_src)[None, :] // 5 if state.version < 3 else 0)
            v, ll, ss = _decode_fields(p, fields, np.broadcast_to(field_line, fields.shape[:2]))
            factors = state.scale.get(sys)
            if factors:
                f = np.array([factors.get(layout[k] or "", factors.get("", 1.0)) for k in k_src])
                v = v / f
            s_idx = np.searchsorted(keep_keys, r.sat_key[rows])
            flat = ((r.epoch[rows] * n_s + s_idx) * n_k)[:, None] + k_dst[None, :]
            values.reshape(-1)[flat] = v
            lli.reshape(-1)[flat] = ll
            ssi.reshape(-1)[flat] = ss

    ts = _time_system(state, systems)
    return RawObservations(
        source_path=str(p),
        gps_time_s=_gps_time(p, scan.epoch_fields, scan.epoch_lines, ts),
        sat_ids=sat_ids,
        obs_codes=codes,
        values=values,
        lli=lli,
        ssi=ssi,
        header=state.info,
        event_gps_time_s=_gps_time(p, scan.event_fields, scan.event_lines, ts),
        epoch_flags=np.asarray(scan.epoch_flags, dtype=np.uint8),
    )


# ----------------------------------------------------------------------------------------------------------
# Writers
# ----------------------------------------------------------------------------------------------------------

_POW10 = 10 ** np.arange(13, dtype=np.int64)


def _format_f14_3(values: np.ndarray, lli: np.ndarray, ssi: np.ndarray) -> np.ndarray:
    """(n,) values, LLI, SSI -> (n, 16) uint8 RINEX fields: F14.3 value, LLI digit, SSI digit (blank if 0/NaN)."""
    n = len(values)
    out = np.empty((n, _FIELD), np.uint8)
    step = 1 << 15
    for a in range(0, n, step):
        v = values[a:a + step]
        present = np.isfinite(v)
        scaled = np.rint(np.where(present, v, 0.0) * 1000.0)
        if np.any(scaled > 9_999_999_999_999) or np.any(scaled < -999_999_999_999):
            raise ValueError("an observation does not fit the RINEX F14.3 format (|value| >= 1e9..1e10)")
        m = scaled.astype(np.int64)
        q = np.abs(m)
        digits = (q[:, None] // _POW10[None, ::-1]) % 10           # (n, 13): 10 integer + 3 decimal digits
        n_int = np.maximum(1, 10 - np.sum(np.cumsum(digits[:, :10], axis=1) == 0, axis=1))
        shown = np.arange(10)[None, :] >= (10 - n_int)[:, None]
        chunk = out[a:a + step]
        chunk[:, :10] = np.where(shown, 48 + digits[:, :10], 32)
        chunk[:, 10] = ord(".")
        chunk[:, 11:14] = 48 + digits[:, 10:]
        rows = np.flatnonzero(m < 0)
        chunk[rows, 9 - n_int[rows]] = ord("-")
        chunk[:, 14] = np.where(lli[a:a + step] > 0, 48 + np.minimum(lli[a:a + step], 9), 32)
        chunk[:, 15] = np.where(ssi[a:a + step] > 0, 48 + np.minimum(ssi[a:a + step], 9), 32)
        chunk[~present] = 32
    return out


def _validate(raw: RawObservations) -> None:
    shape = (len(raw.gps_time_s), len(raw.sat_ids), len(raw.obs_codes))
    for name in ("values", "lli", "ssi"):
        if np.shape(getattr(raw, name)) != shape:
            raise ValueError(f"raw.{name} has shape {np.shape(getattr(raw, name))}, expected {shape}")
    for s in raw.sat_ids:
        if len(s) != 3 or not s[1:].isdigit():
            raise ValueError(f"invalid satellite id {s!r} (expected e.g. 'G05')")
    if len(raw.gps_time_s) == 0:
        raise ValueError("no epochs to write")
    if np.any(np.diff(raw.gps_time_s) < 0):
        raise ValueError("epochs are not in time order")
    if raw.epoch_flags is not None:
        flags = np.asarray(raw.epoch_flags)
        if flags.shape != (len(raw.gps_time_s),) or np.any(flags > 1):
            raise ValueError("epoch_flags must hold one flag per epoch, 0 (ok) or 1 (power failure before it)")


def _split_time(t: float) -> tuple[_dt.datetime, float]:
    """gps_time_s -> (calendar time to the second, seconds of minute with 1e-7 s resolution)."""
    whole = math.floor(t)
    frac = round((t - whole) * 1e7)
    if frac >= 10_000_000:
        whole += 1
        frac -= 10_000_000
    d = gps_time_s_to_datetime(whole)
    return d, d.second + frac * 1e-7


def _hline(content: str, label: str) -> str:
    return f"{content:<60.60}{label:<20}"


def _common_header(raw: RawObservations, program: str) -> list[str]:
    h = raw.header
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d %H%M%S UTC")
    xyz = h.approx_position_ecef_m if h.approx_position_ecef_m is not None else np.zeros(3)
    hen = np.asarray(h.antenna_delta_hen_m if h.antenna_delta_hen_m is not None else np.zeros(3), dtype=float)
    out = [
        _hline(f"{program:<20.20}{'':<20}{now:<20}", "PGM / RUN BY / DATE"),
        _hline(h.marker_name, "MARKER NAME"),
        _hline("", "OBSERVER / AGENCY"),
        _hline(f"{'':<20}{h.receiver_type:<20.20}{'':<20}", "REC # / TYPE / VERS"),
        _hline(f"{'':<20}{h.antenna_type:<20.20}", "ANT # / TYPE"),
        _hline("".join(f"{x:14.4f}" for x in xyz), "APPROX POSITION XYZ"),
        _hline("".join(f"{x:14.4f}" for x in hen), "ANTENNA: DELTA H/E/N"),
    ]
    return out


def _time_records(raw: RawObservations) -> list[str]:
    out = []
    if raw.header.interval_s:
        out.append(_hline(f"{raw.header.interval_s:10.3f}", "INTERVAL"))
    for label, t in (("TIME OF FIRST OBS", raw.gps_time_s[0]), ("TIME OF LAST OBS", raw.gps_time_s[-1])):
        d, sec = _split_time(float(t))
        out.append(_hline(f"{d.year:6d}{d.month:6d}{d.day:6d}{d.hour:6d}{d.minute:6d}{sec:13.7f}     GPS", label))
    return out


def _records_to_write(raw: RawObservations, sat_cols: dict[str, list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """(epoch, sat) index pairs, epoch-major, of satellites with at least one value to write."""
    has = np.zeros((len(raw.gps_time_s), len(raw.sat_ids)), dtype=bool)
    for s, sat in enumerate(raw.sat_ids):
        cols = sat_cols.get(sat[0], [])
        if cols:
            has[:, s] = ~np.isnan(raw.values[:, s, cols]).all(axis=1)
    return np.nonzero(has)


def _format_records(raw: RawObservations, rec_e: np.ndarray, rec_s: np.ndarray, sat_cols: dict[str, list[int]],
                    width_fields: int) -> np.ndarray:
    """(n, width_fields, 16) uint8 fields of each record, in its system's column order; blank beyond."""
    out = np.full((len(rec_e), width_fields, _FIELD), 32, np.uint8)
    sys_of = np.array([s[0] for s in raw.sat_ids]) if raw.sat_ids else np.zeros(0, dtype="<U1")
    rec_sys = sys_of[rec_s]
    for sys, cols in sat_cols.items():
        rows = np.flatnonzero(rec_sys == sys)
        if len(rows) == 0 or not cols:
            continue
        e, s = rec_e[rows][:, None], rec_s[rows][:, None]
        c = np.asarray(cols)[None, :]
        f = _format_f14_3(raw.values[e, s, c].reshape(-1), raw.lli[e, s, c].reshape(-1), raw.ssi[e, s, c].reshape(-1))
        out[rows, :len(cols)] = f.reshape(len(rows), len(cols), _FIELD)
    return out


def _event_positions(raw: RawObservations) -> tuple[np.ndarray, np.ndarray]:
    """Sorted event times and, for each, the index of the first observation epoch written after it."""
    events = np.sort(np.asarray(raw.event_gps_time_s, dtype=float))
    return events, np.searchsorted(raw.gps_time_s, events, side="right")


def _system_codes(raw: RawObservations) -> dict[str, list[int]]:
    """Per system present, the columns of ``raw.obs_codes`` that hold at least one value for it."""
    out: dict[str, list[int]] = {}
    sys_of = np.array([s[0] for s in raw.sat_ids])
    for sys in sorted(set(sys_of), key=lambda s: SYSTEM_ORDER.index(s) if s in SYSTEM_ORDER else 99):
        sel = np.flatnonzero(sys_of == sys)
        present = ~np.isnan(raw.values[:, sel, :]).all(axis=(0, 1))
        out[sys] = [int(k) for k in np.flatnonzero(present)]
    return out


def write_rinex3_obs(path: str | Path, raw: RawObservations, program: str = "georef") -> None:
    """Write ``raw`` as a RINEX 3.04 observation file (GPS time; values F14.3 in the units of RawObservations).

    Each system lists the codes that hold at least one value for its satellites; event times become flag-5
    epochs placed in time order (after an observation epoch of the same time)."""
    _validate(raw)
    for c in raw.obs_codes:
        if not 2 <= len(c) <= 3:
            raise ValueError(f"invalid RINEX 3 observation code {c!r}")
    sys_cols = _system_codes(raw)
    systems = [s for s, cols in sys_cols.items() if cols]
    if not systems:
        raise ValueError("no observation to write (every value is NaN)")
    file_sys = systems[0] if len(systems) == 1 else "M"
    head = [_hline(f"{3.04:9.2f}{'':11}{'OBSERVATION DATA':<20}{file_sys:<20}", "RINEX VERSION / TYPE")]
    head += _common_header(raw, program)
    for sys in systems:
        codes = [raw.obs_codes[k] for k in sys_cols[sys]]
        for i in range(0, len(codes), 13):
            lead = f"{sys}  {len(codes):3d}" if i == 0 else " " * 6
            head.append(_hline(lead + "".join(f" {c:<3}" for c in codes[i:i + 13]), "SYS / # / OBS TYPES"))
    head.append(_hline("DBHZ", "SIGNAL STRENGTH UNIT"))
    head += _time_records(raw)
    for sys in systems:
        for k in sys_cols[sys]:
            if raw.obs_codes[k][0] == "L":
                head.append(_hline(f"{sys} {raw.obs_codes[k]:<3}", "SYS / PHASE SHIFT"))
    if "R" in systems:
        fcn = sorted((s, k) for s, k in raw.header.glonass_fcn.items())
        entries = [f"{s} {k:2d} " for s, k in fcn]
        for i in range(0, max(len(entries), 1), 8):
            lead = f"{len(entries):3d} " if i == 0 else " " * 4
            head.append(_hline(lead + "".join(entries[i:i + 8]), "GLONASS SLOT / FRQ #"))
        head.append(_hline("", "GLONASS COD/PHS/BIS"))
    head.append(_hline("", "END OF HEADER"))

    k_max = max((len(c) for c in sys_cols.values()), default=0)
    rec_e, rec_s = _records_to_write(raw, sys_cols)
    fields = _format_records(raw, rec_e, rec_s, sys_cols, k_max)
    ids = np.frombuffer("".join(raw.sat_ids).encode("ascii"), np.uint8).reshape(-1, 3)
    mat = np.concatenate([ids[rec_s], fields.reshape(len(rec_e), -1)], axis=1)
    rec_lines = _lines_of(mat)
    counts = np.bincount(rec_e, minlength=len(raw.gps_time_s))
    flags = raw.epoch_flags if raw.epoch_flags is not None else np.zeros(len(raw.gps_time_s), np.uint8)

    def epoch_line(t: float, flag: int, n: int) -> bytes:
        d, sec = _split_time(t)
        return (f"> {d.year:4d} {d.month:02d} {d.day:02d} {d.hour:02d} {d.minute:02d}{sec:11.7f}"
                f"  {flag:1d}{n:3d}").encode("ascii")

    body = _interleave(raw, counts, flags, rec_lines, epoch_line)
    Path(path).write_bytes(("\n".join(head) + "\n").encode("ascii") + body)


def _lines_of(mat: np.ndarray) -> list[bytes]:
    """Rows of a uint8 character matrix as right-stripped byte strings."""
    if len(mat) == 0:
        return []
    width = mat.shape[1]
    data = np.ascontiguousarray(mat).tobytes()
    return [data[i:i + width].rstrip() for i in range(0, len(data), width)]


def _interleave(raw: RawObservations, counts: np.ndarray, flags: np.ndarray, rec_lines: list[bytes],
                epoch_line: Callable[[float, int, int], bytes], per_record: int = 1,
                sat_list: Callable[[bytes, int, int], list[bytes]] | None = None) -> bytes:
    """Data section: epoch lines with their record lines, flag-5 event epochs interleaved in time order.

    ``epoch_line(t, flag, n)`` formats an epoch record; ``sat_list(line, first_record, n)`` (RINEX 2) appends the
    satellite list to it; each record has ``per_record`` lines in ``rec_lines``."""
    events, ev_pos = _event_positions(raw)
    parts: list[bytes] = []
    a = 0
    j = 0
    for e, t in enumerate(raw.gps_time_s):
        while j < len(events) and ev_pos[j] <= e:
            parts.append(epoch_line(float(events[j]), 5, 0))
            j += 1
        n = int(counts[e])
        head = epoch_line(float(t), int(flags[e]), n)
        if sat_list is not None:
            parts += sat_list(head, a, n)
        else:
            parts.append(head)
        parts += rec_lines[a * per_record:(a + n) * per_record]
        a += n
    while j < len(events):
        parts.append(epoch_line(float(events[j]), 5, 0))
        j += 1
    return b"\n".join(parts) + b"\n"


def _rinex2_type(sys: str, code: str) -> str | None:
    """The RINEX 2.11 observation type that carries a RINEX 3 code, or None."""
    if len(code) != 3 or code[0] not in "CLDS":
        return None
    t, d, a = code
    if sys == "G" and d in "125":
        if t == "C" and d in "12":
            return ("P" if a in "WPYMD" else "C") + d
        return t + d
    if sys == "R" and d in "12":
        if t == "C":
            return ("P" if a == "P" else "C") + d
        return t + d
    if sys == "E" and d in "15678":
        return t + d
    if sys == "S" and d in "15":
        return t + d
    return None


def write_rinex2_obs(path: str | Path, raw: RawObservations, program: str = "georef") -> None:
    """Write ``raw`` as a RINEX 2.11 observation file (GPS time; values F14.3 in the units of RawObservations).

    RINEX 3 codes become RINEX 2 types (the inverse of :data:`RINEX2_TO_RINEX3`); where several codes of one
    system map to the same type, the canonical one (e.g. L2W for GPS L2) wins and the others are not written.
    RINEX 2.11 has no QZSS, BeiDou or NavIC, nor GLONASS frequency numbers: those are dropped (with a warning
    for the satellites)."""
    _validate(raw)
    dropped = sorted({s[0] for s in raw.sat_ids} - set(_RINEX2_WRITABLE_SYSTEMS))
    if dropped:
        warnings.warn(f"RINEX 2.11 cannot hold systems {dropped}; their satellites are not written to {path}",
                      stacklevel=2)
    sys_cols3 = {s: c for s, c in _system_codes(raw).items() if s in _RINEX2_WRITABLE_SYSTEMS}
    types: list[str] = []
    sys_map: dict[str, dict[str, int]] = {}
    for sys, cols in sys_cols3.items():
        chosen: dict[str, int] = {}
        canonical = RINEX2_TO_RINEX3.get(sys, {})
        for k in cols:
            t2 = _rinex2_type(sys, raw.obs_codes[k])
            if t2 is None:
                continue
            if t2 not in chosen or canonical.get(t2) == raw.obs_codes[k]:
                chosen[t2] = k
        sys_map[sys] = chosen
        types += [t for t in chosen if t not in types]
    if not types:
        raise ValueError("no observation code can be written in RINEX 2.11")
    # per system, the raw column of each RINEX 2 type (-1: not available)
    sys_cols: dict[str, list[int]] = {s: [m.get(t, -1) for t in types] for s, m in sys_map.items()}
    systems = [s for s in sys_cols3 if sys_map.get(s)]
    file_sys = {"G": "G (GPS)", "R": "R (GLONASS)", "E": "E (GALILEO)", "S": "S (GEO)"}.get(systems[0]) \
        if len(systems) == 1 else "M (MIXED)"

    head = [_hline(f"{2.11:9.2f}{'':11}{'OBSERVATION DATA':<20}{file_sys:<20}", "RINEX VERSION / TYPE")]
    head += _common_header(raw, program)
    head.append(_hline(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2"))
    for i in range(0, len(types), 9):
        lead = f"{len(types):6d}" if i == 0 else " " * 6
        head.append(_hline(lead + "".join(f"    {t:<2}" for t in types[i:i + 9]), "# / TYPES OF OBSERV"))
    head += _time_records(raw)
    head.append(_hline("", "END OF HEADER"))

    # records: a column of -1 means "no such type for this system": point it at an all-NaN column
    values = np.concatenate([raw.values, np.full(raw.values.shape[:2] + (1,), np.nan)], axis=2)
    lli = np.concatenate([raw.lli, np.zeros(raw.lli.shape[:2] + (1,), np.uint8)], axis=2)
    ssi = np.concatenate([raw.ssi, np.zeros(raw.ssi.shape[:2] + (1,), np.uint8)], axis=2)
    nan_col = values.shape[2] - 1
    padded = RawObservations(raw.source_path, raw.gps_time_s, raw.sat_ids, list(raw.obs_codes) + [""],
                             values, lli, ssi, raw.header, raw.event_gps_time_s, raw.epoch_flags)
    cols = {s: [k if k >= 0 else nan_col for k in c] for s, c in sys_cols.items()}
    present = {s: [k for k in c if k >= 0] for s, c in sys_cols.items()}
    rec_e, rec_s = _records_to_write(padded, present)
    per = math.ceil(len(types) / 5)
    fields = _format_records(padded, rec_e, rec_s, cols, per * 5)
    rec_lines = _lines_of(fields.reshape(len(rec_e) * per, 5 * _FIELD))
    counts = np.bincount(rec_e, minlength=len(raw.gps_time_s))
    flags = raw.epoch_flags if raw.epoch_flags is not None else np.zeros(len(raw.gps_time_s), np.uint8)
    rec_sat = [raw.sat_ids[s] for s in rec_s]

    def epoch_line(t: float, flag: int, n: int) -> bytes:
        d, sec = _split_time(t)
        return f" {d.year % 100:02d} {d.month:2d} {d.day:2d} {d.hour:2d} {d.minute:2d}{sec:11.7f}  {flag:1d}{n:3d}" \
            .encode("ascii")

    def sat_list(head_line: bytes, a: int, n: int) -> list[bytes]:
        sats = rec_sat[a:a + n]
        out = [head_line + "".join(sats[:12]).encode("ascii")]
        for i in range(12, n, 12):
            out.append(b" " * 32 + "".join(sats[i:i + 12]).encode("ascii"))
        return out

    body = _interleave(raw, counts, flags, rec_lines, epoch_line, per_record=per, sat_list=sat_list)
    Path(path).write_bytes(("\n".join(head) + "\n").encode("ascii") + body)
