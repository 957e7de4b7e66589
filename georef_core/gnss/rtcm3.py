"""RTCM 3 binary streams (raw logs of DJI RTK aircraft ``*_PPKRAW.bin``, M4's ``.rtk``, D-RTK 2 logs,
plain ``.rtcm3`` captures): observations, broadcast ephemerides and station data.

``read_rtcm3(path)`` returns an ``Rtcm3Log`` with

* ``observations`` (``RawObservations``) from the Multiple Signal Messages MSM4, MSM5, MSM6 and MSM7
  of GPS (1074-1077), GLONASS (1084-1087), Galileo (1094-1097), QZSS (1114-1117) and BeiDou
  (1124-1127), in RINEX units: pseudorange (m), carrier phase (cycles), Doppler (Hz, positive for an
  approaching satellite, MSM5/7 only), C/N0 (dB-Hz); signals get RINEX 3 codes (RTCM 10403.3 tables
  3.5-91, -96, -99, -105, -108). The messages of one epoch (several systems, the "multiple message"
  bit) become one epoch.
* ``navigation`` (``NavigationData``) from the ephemeris messages 1019 (GPS), 1020 (GLONASS), 1042
  (BeiDou), 1044 (QZSS), 1045 (Galileo F/NAV) and 1046 (Galileo I/NAV), see rtcm3_nav.py: a raw log
  plus a base needs no navigation file when the stream carries them.
* ``station``: the antenna reference point (1005/1006, ECEF, with the antenna height of 1006) and the
  antenna and receiver descriptors (1007/1008/1033).

Times. MSM epochs carry only a time of week (GLONASS: a day of week and a time of day in Moscow
time), so the week comes from elsewhere, in this order: ``approx_gps_time_s`` when the caller knows it
(e.g. from a DJI ``Timestamp.MRK``, which writes the full GPS week), else the median toe of the
Galileo (12-bit GST week) or BeiDou (13-bit BDT week) ephemerides of the stream, which are
unambiguous, else of the GPS 10-bit weeks of 1019 messages taken in the 1024-week cycle closest to
today (the median, because streams repeat stale records of earlier weeks). A stream with none of
these raises ``InputFileError`` asking for the date. Each later epoch is resolved near the previous
one, so a log may run across a week boundary.

Loss of lock (RINEX LLI bit 0) follows RTKLIB demo5 (rtcm3.c): a slip where the lock-time indicator
decreased or stayed at zero; with ``slip_on_lock_gap`` also where the lock time is shorter than the
time since the previous observation of the signal (a re-lock during a gap of the log that an
increasing lock time would hide: the indicator is a lower bound, so the test is against twice it).
LLI bit 1 carries the MSM half-cycle ambiguity indicator.

Framing works on the whole buffer with numpy: every ``D3`` byte followed by six zero bits is a
candidate, CRC-24Q is computed for all candidates at once, valid frames are taken in stream order and
everything else (UBX, NMEA, DJI's own records, corrupt frames) is skipped and counted.
"""

from __future__ import annotations

import datetime as _dt
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .compressed_files import read_bytes
from .constants import CLIGHT_M_S, SYSTEMS
from .gnss_time import SECONDS_PER_WEEK, datetime_to_gps_time_s, gps_time_s_to_datetime, leap_seconds_at
from .navigation import NavigationData
from .frame_selection import take_frames_in_order
from .observations import RawObservations, ReceiverHeader, carry_slips_to_valid_phase
from .ubx_nav_decode import _CRC24Q_TABLE

__all__ = ["Rtcm3Log", "Rtcm3Frames", "StationInfo", "find_rtcm3_frames", "read_rtcm3", "decode_rtcm3_bytes",
           "looks_like_rtcm3", "msm_signal_code", "BitReader"]

RANGE_MS_M = CLIGHT_M_S * 1e-3          # metres of range per millisecond of signal travel
GLONASS_UTC_OFFSET_S = 10800.0          # GLONASS time = UTC(SU) + 3 h
BDT_TO_GPST_S = 14.0

# ----------------------------------------------------------------------------------------------- signals
# MSM signal ID (1..32) -> RINEX 3 band+attribute, per system (RTCM 10403.3 section 3.5.12.3)
_MSM_SIGNALS: dict[str, dict[int, str]] = {
    "G": {2: "1C", 3: "1P", 4: "1W", 8: "2C", 9: "2P", 10: "2W", 15: "2S", 16: "2L", 17: "2X",
          22: "5I", 23: "5Q", 24: "5X", 30: "1S", 31: "1L", 32: "1X"},
    "R": {2: "1C", 3: "1P", 8: "2C", 9: "2P"},
    "E": {2: "1C", 3: "1A", 4: "1B", 5: "1X", 6: "1Z", 8: "6C", 9: "6A", 10: "6B", 11: "6X", 12: "6Z",
          14: "7I", 15: "7Q", 16: "7X", 18: "8I", 19: "8Q", 20: "8X", 22: "5I", 23: "5Q", 24: "5X"},
    "J": {2: "1C", 9: "6S", 10: "6L", 11: "6X", 15: "2S", 16: "2L", 17: "2X", 22: "5I", 23: "5Q", 24: "5X",
          30: "1S", 31: "1L", 32: "1X"},
    "C": {2: "2I", 3: "2Q", 4: "2X", 8: "6I", 9: "6Q", 10: "6X", 14: "7I", 15: "7Q", 16: "7X",
          22: "5D", 23: "5P", 24: "5X", 25: "7D", 30: "1D", 31: "1P", 32: "1X"},
}
# MSM message group (message number // 10) -> system letter; SBAS (110) and NavIC (113) are not kept
_MSM_GROUPS = {107: "G", 108: "R", 109: "E", 111: "J", 112: "C"}

# carrier frequency (Hz) per system and RINEX frequency digit; GLONASS 1/2 are FDMA (base + k * step)
_FREQ_HZ = {
    "G": {"1": 1575.42e6, "2": 1227.60e6, "5": 1176.45e6},
    "J": {"1": 1575.42e6, "2": 1227.60e6, "5": 1176.45e6, "6": 1278.75e6},
    "E": {"1": 1575.42e6, "5": 1176.45e6, "6": 1278.75e6, "7": 1207.14e6, "8": 1191.795e6},
    "C": {"1": 1575.42e6, "2": 1561.098e6, "5": 1176.45e6, "6": 1268.52e6, "7": 1207.14e6, "8": 1191.795e6},
    "R": {"3": 1202.025e6, "4": 1600.995e6, "6": 1248.06e6},
}
_GLO_FDMA = {"1": (1602.0e6, 0.5625e6), "2": (1246.0e6, 0.4375e6)}


def msm_signal_code(system: str, signal_id: int) -> str | None:
    """RINEX 3 band+attribute ('1C', '2W', '7Q', ...) of an MSM signal ID, None when not defined."""
    return _MSM_SIGNALS.get(system, {}).get(signal_id)


def signal_frequency_hz(system: str, code: str, glonass_fcn: int | None = None) -> float:
    """Carrier frequency of a signal (RINEX band+attribute); NaN for GLONASS FDMA without its channel."""
    digit = code[0]
    if system == "R" and digit in _GLO_FDMA:
        if glonass_fcn is None:
            return float("nan")
        base, step = _GLO_FDMA[digit]
        return base + glonass_fcn * step
    return _FREQ_HZ.get(system, {}).get(digit, float("nan"))


# ----------------------------------------------------------------------------------------------- framing
_CRC24Q = np.array(_CRC24Q_TABLE, dtype=np.uint32)


@dataclass
class Rtcm3Frames:
    """CRC-valid RTCM 3 frames of a buffer, in stream order (arrays of the same length)."""

    start: np.ndarray        # offset of the 0xD3 preamble
    length: np.ndarray       # payload length (bytes); the payload is data[start + 3: start + 3 + length]
    msg_type: np.ndarray     # message number (DF002)
    n_bytes_total: int
    n_crc_errors: int        # plausible frames (known message number) that failed the CRC
    n_truncated_at_end: int  # a frame cut off by the end of the data

    @property
    def n_bytes_in_frames(self) -> int:
        return int(np.sum(self.length.astype(np.int64) + 6))


def _known_message(msg: np.ndarray) -> np.ndarray:
    return (((msg >= 1001) & (msg <= 1039)) | ((msg >= 1041) & (msg <= 1046)) | ((msg >= 1057) & (msg <= 1068))
            | ((msg >= 1071) & (msg <= 1137)) | ((msg >= 1230) & (msg <= 1230)) | ((msg >= 4001) & (msg <= 4095)))


def find_rtcm3_frames(data: bytes) -> Rtcm3Frames:
    """Locate every CRC-valid RTCM 3 frame (``D3 000000ll llllllll payload crc24``).

    The CRC-24Q of every candidate is computed at once with numpy, candidates sorted by length so
    that each step works on the ones still inside their frame. Frames are then taken greedily in
    stream order, skipping candidates that start inside an accepted frame."""
    n = len(data)
    buf = np.frombuffer(data, dtype=np.uint8)
    empty = np.zeros(0, dtype=np.int64)
    if n < 6:
        return Rtcm3Frames(empty, empty, empty, n, 0, int(n > 0 and data.rfind(b"\xd3") >= 0))
    cand = np.flatnonzero(buf[:-2] == 0xD3).astype(np.int64)
    cand = cand[(buf[cand + 1] & 0xFC) == 0]
    length = ((buf[cand + 1].astype(np.int64) & 0x03) << 8) | buf[cand + 2]
    cand, length = cand[length >= 2], length[length >= 2]
    end = cand + 6 + length
    fits = end <= n
    msg = np.zeros(len(cand), dtype=np.int64)
    has_type = cand + 5 <= n
    msg[has_type] = (buf[cand[has_type] + 3].astype(np.int64) << 4) | (buf[cand[has_type] + 4] >> 4)
    known = _known_message(msg)
    # CRC over the 3 header bytes and the payload, for every fitting candidate at once
    idx = np.flatnonzero(fits)
    covered = length[idx] + 3
    order = idx[np.argsort(-covered, kind="stable")]
    lens = length[order] + 3
    crc = np.zeros(len(order), dtype=np.uint32)
    starts = cand[order]
    n_active = len(order)
    for k in range(int(lens.max()) if len(lens) else 0):
        while n_active and lens[n_active - 1] <= k:
            n_active -= 1
        b = buf[starts[:n_active] + k].astype(np.uint32)
        c = crc[:n_active]
        crc[:n_active] = ((c << 8) & 0xFFFFFF) ^ _CRC24Q[((c >> 16) ^ b) & 0xFF]
    stored = ((buf[starts + lens].astype(np.uint32) << 16) | (buf[starts + lens + 1].astype(np.uint32) << 8)
              | buf[starts + lens + 2])
    ok = np.zeros(len(cand), dtype=bool)
    ok[order] = crc == stored
    good, inside = take_frames_in_order(cand, end, ok)
    starts_ok = cand[good]
    last_end = int(end[good][-1]) if len(good) else 0
    failed = ~ok & ~inside & known
    n_crc = int(np.count_nonzero(failed & fits))
    n_trunc = int(np.any(failed & ~fits & (cand >= last_end)))
    return Rtcm3Frames(starts_ok, length[good], msg[good], n, n_crc, n_trunc)


def looks_like_rtcm3(data: bytes, min_frames: int = 3) -> bool:
    """Whether a buffer (the first tens of kB of a file) holds at least ``min_frames`` CRC-valid RTCM 3
    frames covering most of its frames' span: content-based recognition, whatever the file name."""
    frames = find_rtcm3_frames(data)
    return len(frames.start) >= min(min_frames, max(1, len(data) // 64))


# ----------------------------------------------------------------------------------------------- bits
class BitReader:
    """Big-endian bit fields of one message payload (RTCM 3 numbers bits from the first byte's MSB)."""

    __slots__ = ("value", "total", "pos")

    def __init__(self, payload: bytes):
        self.value = int.from_bytes(payload, "big")
        self.total = 8 * len(payload)
        self.pos = 0

    def u(self, n: int) -> int:
        """Next ``n`` bits as an unsigned integer."""
        if self.pos + n > self.total:
            raise ValueError("message shorter than its fields")
        v = (self.value >> (self.total - self.pos - n)) & ((1 << n) - 1)
        self.pos += n
        return v

    def s(self, n: int) -> int:
        """Next ``n`` bits, two's complement."""
        v = self.u(n)
        return v - (1 << n) if v >> (n - 1) else v

    def sm(self, n: int) -> int:
        """Next ``n`` bits, sign-magnitude (GLONASS fields: the first bit is the sign)."""
        v = self.u(n)
        mag = v & ((1 << (n - 1)) - 1)
        return -mag if v >> (n - 1) else mag

    def skip(self, n: int) -> None:
        self.pos += n

    def many_u(self, count: int, n: int) -> list[int]:
        return [self.u(n) for _ in range(count)]

    def many_s(self, count: int, n: int) -> list[int]:
        return [self.s(n) for _ in range(count)]


# ----------------------------------------------------------------------------------------------- MSM
@dataclass
class _MsmCells:
    """Flat table of one stream's MSM cells (one row per satellite, signal and message)."""

    msg_index: list[int] = field(default_factory=list)
    sys: list[int] = field(default_factory=list)
    prn: list[int] = field(default_factory=list)
    code: list[str] = field(default_factory=list)
    pr_m: list[float] = field(default_factory=list)
    phase_m: list[float] = field(default_factory=list)
    rate_m_s: list[float] = field(default_factory=list)
    cnr: list[float] = field(default_factory=list)
    lock_ms: list[int] = field(default_factory=list)
    half: list[int] = field(default_factory=list)


_NAN = float("nan")


def _lock_ms_msm4(indicator: int) -> int:
    """DF402 (4 bits): lock time of at least 2^(i+4) ms for i >= 1, 0 for a signal just locked."""
    return 0 if indicator == 0 else 1 << (indicator + 4)


def _lock_ms_msm6(indicator: int) -> int:
    """DF407 (10 bits, extended resolution): minimum lock time in ms (RTCM 10403.3 table 3.5-75)."""
    if indicator < 64:
        return indicator
    if indicator > 704:
        return 67108864
    m = indicator // 32 - 1
    return (indicator << m) - (m << (m + 5))


def _decode_msm(payload: bytes, msg_type: int, msg_index: int, cells: _MsmCells,
                glonass_fcn: dict[str, int]) -> tuple[str, int, bool] | None:
    """One MSM4-7 message into ``cells``; returns (system letter, epoch time field, multiple-message bit)."""
    system = _MSM_GROUPS.get(msg_type // 10)
    kind = msg_type % 10
    if system is None or kind not in (4, 5, 6, 7):
        return None
    r = BitReader(payload)
    r.skip(12)                          # message number
    r.skip(12)                          # reference station ID
    epoch_field = r.u(30)
    multiple = bool(r.u(1))
    r.skip(3 + 7 + 2 + 2 + 1 + 3)       # IODS, reserved, clock steering, external clock, smoothing
    sat_mask = r.u(64)
    sig_mask = r.u(32)
    sats = [i + 1 for i in range(64) if sat_mask >> (63 - i) & 1]
    sigs = [i + 1 for i in range(32) if sig_mask >> (31 - i) & 1]
    n_sat, n_sig = len(sats), len(sigs)
    if n_sat * n_sig > 64:
        raise ValueError(f"{n_sat} satellites x {n_sig} signals exceed the 64 cells of an MSM")
    cell_mask = r.u(n_sat * n_sig)
    cell_list = [(i, j) for i in range(n_sat) for j in range(n_sig) if cell_mask >> (n_sat * n_sig - 1 - (i * n_sig + j)) & 1]
    n_cell = len(cell_list)
    # satellite data
    rough_ms = r.many_u(n_sat, 8)
    if kind in (5, 7):
        ext_info = r.many_u(n_sat, 4)
    rough_mod = r.many_u(n_sat, 10)
    if kind in (5, 7):
        rough_rate = r.many_s(n_sat, 14)
    # signal data
    hi = kind in (6, 7)
    fine_pr = r.many_s(n_cell, 20 if hi else 15)
    fine_cp = r.many_s(n_cell, 24 if hi else 22)
    lock = r.many_u(n_cell, 10 if hi else 4)
    half = r.many_u(n_cell, 1)
    cnr_raw = r.many_u(n_cell, 10 if hi else 6)
    fine_rate = r.many_s(n_cell, 15) if kind in (5, 7) else None
    pr_scale, cp_scale = (2.0**-29, 2.0**-31) if hi else (2.0**-24, 2.0**-29)
    pr_invalid, cp_invalid = (-524288, -8388608) if hi else (-16384, -2097152)
    cnr_scale = 2.0**-4 if hi else 1.0
    lock_ms = _lock_ms_msm6 if hi else _lock_ms_msm4
    sys_index = SYSTEMS.index(system)
    codes = [msm_signal_code(system, s) for s in sigs]
    if system == "R" and kind in (5, 7):
        for i, info in enumerate(ext_info):
            if info <= 13 and 1 <= sats[i] <= 24:
                glonass_fcn[f"R{sats[i]:02d}"] = info - 7
    for k, (i, j) in enumerate(cell_list):
        code = codes[j]
        if code is None:
            continue
        if rough_ms[i] == 255:
            continue
        prn = sats[i]
        rough_m = (rough_ms[i] + rough_mod[i] * 2.0**-10) * RANGE_MS_M
        pr = rough_m + fine_pr[k] * pr_scale * RANGE_MS_M if fine_pr[k] != pr_invalid else _NAN
        cp = rough_m + fine_cp[k] * cp_scale * RANGE_MS_M if fine_cp[k] != cp_invalid else _NAN
        if fine_rate is not None and rough_rate[i] != -8192 and fine_rate[k] != -16384:
            rate = rough_rate[i] + fine_rate[k] * 1e-4
        else:
            rate = _NAN
        cells.msg_index.append(msg_index)
        cells.sys.append(sys_index)
        cells.prn.append(prn)
        cells.code.append(code)
        cells.pr_m.append(pr)
        cells.phase_m.append(cp)
        cells.rate_m_s.append(rate)
        cells.cnr.append(cnr_raw[k] * cnr_scale if cnr_raw[k] else _NAN)
        cells.lock_ms.append(lock_ms(lock[k]))
        cells.half.append(half[k])
    return system, epoch_field, multiple


# ----------------------------------------------------------------------------------------------- station
@dataclass
class StationInfo:
    """Station messages of a stream (the last one of each kind wins)."""

    station_id: int | None = None
    arp_ecef_m: np.ndarray | None = None          # antenna reference point (1005/1006)
    antenna_height_m: float = 0.0                 # 1006: ARP height above the marker
    antenna_descriptor: str = ""                  # 1007/1008/1033
    antenna_serial: str = ""
    receiver_type: str = ""                       # 1033
    receiver_firmware: str = ""
    receiver_serial: str = ""


def _text(r: BitReader) -> str:
    n = r.u(8)
    return bytes(r.u(8) for _ in range(n)).decode("latin-1").strip()


def _decode_station(payload: bytes, msg_type: int, st: StationInfo) -> None:
    r = BitReader(payload)
    r.skip(12)
    st.station_id = r.u(12)
    if msg_type in (1005, 1006):
        r.skip(6 + 1 + 1 + 1 + 1)       # ITRF year, GPS/GLONASS/Galileo indicators, reference station
        x = r.s(38)
        r.skip(2)                       # single receiver oscillator, reserved
        y = r.s(38)
        r.skip(2)                       # quarter cycle indicator
        z = r.s(38)
        xyz = np.array([x, y, z], dtype=float) * 1e-4
        if np.any(xyz != 0.0):
            st.arp_ecef_m = xyz
        if msg_type == 1006:
            st.antenna_height_m = r.u(16) * 1e-4
    elif msg_type in (1007, 1008, 1033):
        st.antenna_descriptor = _text(r) or st.antenna_descriptor
        r.skip(8)                       # antenna setup ID
        if msg_type in (1008, 1033):
            st.antenna_serial = _text(r) or st.antenna_serial
        if msg_type == 1033:
            st.receiver_type = _text(r) or st.receiver_type
            st.receiver_firmware = _text(r) or st.receiver_firmware
            st.receiver_serial = _text(r) or st.receiver_serial


# ----------------------------------------------------------------------------------------------- the log
@dataclass
class Rtcm3Log:
    """Everything decoded from one RTCM 3 stream (see module docstring)."""

    source_path: str
    observations: RawObservations
    navigation: NavigationData
    station: StationInfo
    warnings: list[str] = field(default_factory=list)
    message_counts: dict[int, int] = field(default_factory=dict)   # CRC-valid frames by message number
    bytes_total: int = 0
    bytes_skipped: int = 0        # bytes outside valid RTCM 3 frames
    crc_errors: int = 0
    time_reference: str = ""      # where the week number came from


_EPH_TYPES = (1019, 1020, 1042, 1044, 1045, 1046)
_STATION_TYPES = (1005, 1006, 1007, 1008, 1033)


def read_rtcm3(path, *, approx_gps_time_s: float | None = None, slip_on_lock_gap: bool = True) -> Rtcm3Log:
    """Decode an RTCM 3 log (plain, .gz or .Z). ``approx_gps_time_s``: any time within a few days of
    the log (resolves the week of the epochs; see the module docstring for the fallbacks).
    Raises InputFileError when the file holds no RTCM 3 frame or no way to date it."""
    p = Path(path)
    return decode_rtcm3_bytes(read_bytes(p), str(p), approx_gps_time_s=approx_gps_time_s,
                              slip_on_lock_gap=slip_on_lock_gap)


def decode_rtcm3_bytes(data: bytes, source_path: str = "<bytes>", *, approx_gps_time_s: float | None = None,
                       slip_on_lock_gap: bool = True) -> Rtcm3Log:
    """``read_rtcm3`` on a buffer already in memory (``source_path`` only names it in messages)."""
    from . import rtcm3_nav

    frames = find_rtcm3_frames(data)
    if len(frames.start) == 0:
        what = "the file is empty" if len(data) == 0 else "no RTCM 3 frame found (not an RTCM 3 log?)"
        raise InputFileError(source_path, what)
    warnings: list[str] = []
    counts = Counter(frames.msg_type.tolist())
    if frames.n_crc_errors:
        warnings.append(f"{frames.n_crc_errors} RTCM 3 frame(s) failed the CRC (corrupt data) and were skipped")
    if frames.n_truncated_at_end:
        warnings.append("the log ends with a truncated RTCM 3 frame")

    def payload(k: int) -> bytes:
        s = int(frames.start[k]) + 3
        return data[s:s + int(frames.length[k])]

    # ---- the week: caller, Galileo/BeiDou ephemerides, GPS ephemerides near today
    ref_time, time_reference = _reference_time(frames, payload, approx_gps_time_s)
    if ref_time is None:
        raise InputFileError(source_path, "the RTCM 3 log carries no week number (no ephemeris messages): give "
                                          "the date of the flight (e.g. with the drone's Timestamp.MRK)")
    leap = leap_seconds_at(gps_time_s_to_datetime(ref_time))

    # ---- MSM observations, epochs resolved one after the other
    cells = _MsmCells()
    glonass_fcn: dict[str, int] = {}
    msg_time: list[float] = []          # gps_time_s of each decoded MSM message
    msg_pos: list[int] = []
    n_bad = 0
    last_t = ref_time
    for k in np.flatnonzero((frames.msg_type >= 1071) & (frames.msg_type <= 1137)).tolist():
        mt = int(frames.msg_type[k])
        if mt % 10 not in (4, 5, 6, 7) or mt // 10 not in _MSM_GROUPS:
            continue
        try:
            got = _decode_msm(payload(k), mt, len(msg_time), cells, glonass_fcn)
        except ValueError:
            n_bad += 1
            continue
        if got is None:
            continue
        system, epoch_field, _multiple = got
        t = _msm_epoch_gps_s(system, epoch_field, last_t, leap)
        if t is None:
            n_bad += 1
            _drop_last_message(cells, len(msg_time))
            continue
        last_t = t
        msg_time.append(t)
        msg_pos.append(int(frames.start[k]))
    if n_bad:
        warnings.append(f"{n_bad} MSM message(s) with inconsistent contents were skipped")

    # ---- navigation and station messages, each dated by the stream time where it appears
    pos_arr, t_arr = np.array(msg_pos, dtype=np.int64), np.array(msg_time, dtype=float)
    nav_decoder = rtcm3_nav.Rtcm3NavDecoder(leap)
    station = StationInfo()
    n_bad_nav = 0
    for k in np.flatnonzero(np.isin(frames.msg_type, _EPH_TYPES + _STATION_TYPES)).tolist():
        mt = int(frames.msg_type[k])
        try:
            if mt in _STATION_TYPES:
                _decode_station(payload(k), mt, station)
            else:
                nav_decoder.add(mt, payload(k), _stream_time_at(int(frames.start[k]), pos_arr, t_arr, ref_time))
        except ValueError:
            n_bad_nav += 1
    if n_bad_nav:
        warnings.append(f"{n_bad_nav} ephemeris or station message(s) shorter than their fields were skipped")
    navigation = nav_decoder.result(source_path)
    if nav_decoder.rejected:
        shown = ", ".join(nav_decoder.rejected[:5]) + (" ..." if len(nav_decoder.rejected) > 5 else "")
        warnings.append(f"{len(nav_decoder.rejected)} ephemeris record(s) with an impossible orbit were ignored: "
                        f"{shown}")
    for sat, fcn in navigation.glonass_fcn().items():
        glonass_fcn.setdefault(sat, fcn)

    header = ReceiverHeader(rinex_version=None)
    header.receiver_type = station.receiver_type or "RTCM 3 stream"
    header.receiver_version = station.receiver_firmware
    header.antenna_type = station.antenna_descriptor
    header.marker_name = f"{station.station_id:04d}" if station.station_id is not None else ""
    if station.arp_ecef_m is not None:
        # 1005/1006 give the antenna reference point itself (1006's height is the ARP above the marker,
        # for information): the ARP is the base position, with no delta to add
        header.approx_position_ecef_m = station.arp_ecef_m.copy()
        header.approx_position_source = "rtcm-station"
    observations = _build_observations(cells, t_arr, glonass_fcn, source_path, header, slip_on_lock_gap, warnings)
    if observations.n_epochs == 0:
        warnings.append("no MSM observation messages in the stream (navigation or station data only)")
    return Rtcm3Log(source_path=source_path, observations=observations, navigation=navigation, station=station,
                    warnings=warnings, message_counts=dict(sorted(counts.items())), bytes_total=frames.n_bytes_total,
                    bytes_skipped=frames.n_bytes_total - frames.n_bytes_in_frames, crc_errors=frames.n_crc_errors,
                    time_reference=time_reference)


def _drop_last_message(cells: _MsmCells, msg_index: int) -> None:
    while cells.msg_index and cells.msg_index[-1] == msg_index:
        for name in _MsmCells.__dataclass_fields__:
            getattr(cells, name).pop()


def _reference_time(frames: Rtcm3Frames, payload, approx_gps_time_s: float | None) -> tuple[float | None, str]:
    """A gps_time_s within days of the log and where it came from."""
    from .rtcm3_nav import ephemeris_week_time

    if approx_gps_time_s is not None and math.isfinite(approx_gps_time_s):
        return float(approx_gps_time_s), "given"
    now = datetime_to_gps_time_s(_dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None))
    for types, label in (((1045, 1046), "Galileo ephemeris week"), ((1042,), "BeiDou ephemeris week"),
                         ((1019, 1044), "GPS/QZSS ephemeris week (nearest 1024-week cycle to today)")):
        times = []
        for k in np.flatnonzero(np.isin(frames.msg_type, types)).tolist():
            try:
                t = ephemeris_week_time(int(frames.msg_type[k]), payload(k), now)
            except ValueError:
                continue
            if t is not None:
                times.append(t)
        if times:   # the median: a stream may repeat stale records of earlier weeks
            return float(np.median(times)), label
    return None, ""


def _msm_epoch_gps_s(system: str, epoch_field: int, near_gps_s: float, leap_s: int) -> float | None:
    """The MSM epoch time field as gps_time_s, in the week (day for GLONASS) closest to ``near_gps_s``."""
    if system == "R":
        tod_ms = epoch_field & 0x7FFFFFF
        if tod_ms >= 86400000 + 1000:
            return None
        # Moscow time of day -> GPS time of day
        tod_gps = tod_ms * 1e-3 - GLONASS_UTC_OFFSET_S + leap_s
        day0 = math.floor(near_gps_s / 86400.0) * 86400.0
        t = day0 + tod_gps
        while t - near_gps_s > 43200.0:
            t -= 86400.0
        while t - near_gps_s < -43200.0:
            t += 86400.0
        return t
    if epoch_field >= 604800000 + 1000:
        return None
    tow = epoch_field * 1e-3 + (BDT_TO_GPST_S if system == "C" else 0.0)
    t = math.floor(near_gps_s / SECONDS_PER_WEEK) * SECONDS_PER_WEEK + tow
    if t - near_gps_s > SECONDS_PER_WEEK / 2:
        t -= SECONDS_PER_WEEK
    elif t - near_gps_s < -SECONDS_PER_WEEK / 2:
        t += SECONDS_PER_WEEK
    return t


def _stream_time_at(pos: int, msg_pos: np.ndarray, msg_time: np.ndarray, fallback: float) -> float:
    """The time of the latest observation message before a stream offset (else the first one after)."""
    if len(msg_pos) == 0:
        return fallback
    k = int(np.searchsorted(msg_pos, pos, side="right")) - 1
    return float(msg_time[max(k, 0)])


def _build_observations(cells: _MsmCells, msg_time: np.ndarray, glonass_fcn: dict[str, int], source_path: str,
                        header: ReceiverHeader, slip_on_lock_gap: bool, warnings: list[str]) -> RawObservations:
    if not cells.msg_index:
        return RawObservations(source_path, np.zeros(0), [], [], np.zeros((0, 0, 0)), np.zeros((0, 0, 0), np.uint8),
                               np.zeros((0, 0, 0), np.uint8), header, np.zeros(0), np.zeros(0, np.uint8))
    msg = np.array(cells.msg_index, dtype=np.int64)
    t_cell = msg_time[msg]
    key_t = np.round(t_cell * 1e6).astype(np.int64)
    epoch_keys, epoch = np.unique(key_t, return_inverse=True)
    epoch_time = epoch_keys * 1e-6
    sys_i = np.array(cells.sys, dtype=np.int64)
    prn = np.array(cells.prn, dtype=np.int64)
    codes = np.array(cells.code)
    sat_key = sys_i * 100 + prn
    uniq_sat, sat_index = np.unique(sat_key, return_inverse=True)
    sat_ids = [f"{SYSTEMS[k // 100]}{k % 100:02d}" for k in uniq_sat.tolist()]
    sig_names = sorted(set(cells.code), key=lambda c: (c[0], "CBLSXIQPDZWA".find(c[1]), c))
    sig_col = {c: j for j, c in enumerate(sig_names)}
    col = np.array([sig_col[c] for c in cells.code], dtype=np.int64)
    # duplicates (the same signal twice in one epoch): the first one wins
    flat = (epoch * len(sat_ids) + sat_index) * len(sig_names) + col
    _, first = np.unique(flat, return_index=True)
    if len(first) < len(flat):
        warnings.append(f"{len(flat) - len(first)} repeated MSM observation(s) of an epoch were dropped")
    keep = np.zeros(len(flat), dtype=bool)
    keep[first] = True
    # wavelengths
    wl = np.full(len(msg), np.nan)
    for code in sig_names:
        for s_i in np.unique(sys_i[codes == code]).tolist():
            letter = SYSTEMS[s_i]
            sel = (codes == code) & (sys_i == s_i)
            if letter == "R" and code[0] in _GLO_FDMA:
                for p in np.unique(prn[sel]).tolist():
                    f = signal_frequency_hz("R", code, glonass_fcn.get(f"R{p:02d}"))
                    wl[sel & (prn == p)] = CLIGHT_M_S / f
            else:
                wl[sel] = CLIGHT_M_S / signal_frequency_hz(letter, code)
    pr = np.array(cells.pr_m)
    cp = np.array(cells.phase_m) / wl
    dop = -np.array(cells.rate_m_s) / wl
    cnr = np.array(cells.cnr)
    no_fcn = (sys_i == SYSTEMS.index("R")) & np.isnan(wl)
    if np.any(no_fcn & keep):
        missing = sorted({f"R{p:02d}" for p in prn[no_fcn].tolist()})
        warnings.append(f"no frequency channel for GLONASS {', '.join(missing)} (no MSM5/7 or 1020 message): "
                        "their phase and Doppler were dropped")
    lli = _loss_of_lock(epoch, epoch_time, sat_key * 64 + col,
                        np.array(cells.lock_ms, dtype=np.int64), ~np.isnan(cp), slip_on_lock_gap)
    lli |= np.where(np.array(cells.half, dtype=bool) & ~np.isnan(cp), 2, 0).astype(np.uint8)

    obs_codes = [f"{t}{name}" for name in sig_names for t in "CLDS"]
    n_e, n_s, n_k = len(epoch_time), len(sat_ids), len(obs_codes)
    values = np.full((n_e, n_s, n_k), np.nan)
    lli_arr = np.zeros((n_e, n_s, n_k), dtype=np.uint8)
    ssi_arr = np.zeros((n_e, n_s, n_k), dtype=np.uint8)
    e, s, base = epoch[keep], sat_index[keep], 4 * col[keep]
    ssi = np.where(np.isnan(cnr), 0, np.clip(np.floor(cnr / 6.0), 1, 9)).astype(np.uint8)[keep]
    for off, vals in enumerate((pr, cp, dop, cnr)):
        v = vals[keep]
        values[e, s, base + off] = v
        ssi_arr[e, s, base + off] = np.where(np.isnan(v), 0, ssi)
    lli_arr[e, s, base + 1] = lli[keep]
    header.glonass_fcn.update(dict(sorted(glonass_fcn.items())))
    if n_e > 1:
        d = np.diff(epoch_time)
        d = d[d > 5e-4]
        if len(d):
            header.interval_s = float(np.round(np.median(d[d < 1.5 * d.min()]), 3))
    return RawObservations(source_path, epoch_time, sat_ids, obs_codes, values, lli_arr, ssi_arr, header,
                           np.zeros(0), np.zeros(n_e, dtype=np.uint8))


def _loss_of_lock(epoch: np.ndarray, epoch_time: np.ndarray, signal_key: np.ndarray, lock_ms: np.ndarray,
                  phase_valid: np.ndarray, slip_on_lock_gap: bool) -> np.ndarray:
    """RINEX LLI bit 0 of every cell (see module docstring), carried to the next valid phase."""
    n = len(epoch)
    order = np.lexsort((epoch, signal_key))
    k_s, e_s = signal_key[order], epoch[order]
    lock = lock_ms[order]
    valid = phase_valid[order]
    idx = np.arange(n)
    same = np.zeros(n, dtype=bool)
    same[1:] = k_s[1:] == k_s[:-1]
    prev = np.maximum(idx - 1, 0)
    prev_lock = np.where(same, lock[prev], 0)
    slip = ((lock == 0) & (prev_lock == 0)) | (lock < prev_lock)
    if slip_on_lock_gap:
        t = epoch_time[e_s]
        gap_ms = np.where(same, (t - t[prev]) * 1000.0, 0.0)
        # the indicator is a minimum: at most twice it (plus one 32 ms step) can have passed
        slip |= same & (2 * lock + 32 < gap_ms)
    out = np.zeros(n, dtype=np.uint8)
    out[order] = carry_slips_to_valid_phase(slip, valid, same).astype(np.uint8)
    return out
