"""u-blox UBX binary logs: raw observations, broadcast navigation data and time-mark events.

``read_ubx(path)`` returns a ``UbxLog`` with

* ``observations`` (``RawObservations``) from UBX-RXM-RAWX (0x02 0x15, u-blox 8 / 9 / X20) or, for
  older receivers (LEA-6T), UBX-RXM-RAW (0x02 0x10, GPS L1 only). Values use the RINEX units:
  pseudorange (m), carrier phase (cycles), Doppler (Hz, positive for approaching satellites),
  C/N0 (dB-Hz); signals get RINEX 3 codes (GPS L1 C/A -> C1C/L1C/D1C/S1C, ...). Invalid phase is NaN.
  The loss-of-lock indicator follows RTKLIB demo5 ``convbin`` (so a RINEX file converted from the
  same log carries the same flags), plus a lock-time-versus-gap test (see ``_loss_of_lock``).
* ``navigation`` (``NavigationData``) from UBX-RXM-SFRBX (0x02 0x13), see ubx_nav_decode.py.
* ``event_gps_time_s``: time marks from UBX-TIM-TM2 (0x0D 0x03), e.g. camera triggers. By default the
  FALLING edge of the EXTINT signal marks the event: a camera hot-shoe (X-sync) contact closes to ground
  when the shutter is open, pulling the line low, so the falling edge is the leading edge of the exposure
  pulse; RTKLIB demo5 ``convbin`` writes the same edge as RINEX event epochs (flag 5), so a log and its
  RINEX give identical event times. ``event_edge="rising"`` is for an active-high trigger (e.g. an
  autopilot or opto-coupler output). Times in the UTC time base (TIM-TM2 flags timeBase = 2, as in the
  M8P walk log) get the GPS-UTC leap seconds added, as convbin does; both edges are kept in the ``UbxLog``.
* ``observations.header.approx_position_ecef_m``: the median of the receiver's own 3D fixes (NAV-SOL,
  NAV-POSECEF, NAV-PVT), marked ``approx_position_source = "receiver-fixes"``: metre-level (or, for a base
  in survey-in / fixed mode, the receiver's survey-in mean), never treated as a surveyed position.

Frame synchronisation works on the whole buffer with numpy: every ``B5 62`` candidate gets its
Fletcher checksum from running sums, frames that pass are taken in order, anything else (NMEA,
RTCM 3, truncated or corrupt frames) is skipped and counted.
"""

from __future__ import annotations

import datetime as _dt
import math
import struct
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import InputFileError
from .compressed_files import read_bytes
from .constants import SYSTEMS
from .frames import geodetic_to_ecef_m
from .gnss_time import SECONDS_PER_WEEK, datetime_to_gps_time_s, gps_time_s_to_datetime, leap_seconds_at
from .navigation import NavigationData
from .frame_selection import take_frames_in_order
from .observations import RawObservations, ReceiverHeader, carry_slips_to_valid_phase
from .ubx_nav_decode import SfrbxNavDecoder

__all__ = ["UbxLog", "UbxFrames", "read_ubx", "decode_ubx_bytes", "find_ubx_frames", "ubx_signal_code"]

# message identifiers (class << 8 | id)
ID_NAV_POSECEF = 0x0101
ID_NAV_SOL = 0x0106
ID_NAV_PVT = 0x0107
ID_NAV_TIMEGPS = 0x0120
ID_RXM_RAW = 0x0210
ID_RXM_SFRBX = 0x0213
ID_RXM_RAWX = 0x0215
ID_MON_VER = 0x0A04
ID_TIM_TM2 = 0x0D03

MESSAGE_NAMES = {
    ID_NAV_POSECEF: "NAV-POSECEF", ID_NAV_SOL: "NAV-SOL", ID_NAV_PVT: "NAV-PVT", ID_NAV_TIMEGPS: "NAV-TIMEGPS",
    ID_RXM_RAW: "RXM-RAW", ID_RXM_SFRBX: "RXM-SFRBX", ID_RXM_RAWX: "RXM-RAWX", ID_MON_VER: "MON-VER",
    ID_TIM_TM2: "TIM-TM2", 0x0130: "NAV-SVINFO", 0x013B: "NAV-SVIN", 0x0135: "NAV-SAT", 0x0103: "NAV-STATUS",
    0x0102: "NAV-POSLLH", 0x0104: "NAV-DOP", 0x0112: "NAV-VELNED", 0x0121: "NAV-TIMEUTC", 0x013C: "NAV-RELPOSNED",
    0x0143: "NAV-SIG", 0x0214: "RXM-MEASX", 0x0232: "RXM-RTCM", 0x0501: "ACK-ACK", 0x0500: "ACK-NAK",
}

# UBX classes documented by u-blox (NAV RXM TRK INF ACK CFG UPD MON AID TIM ESF MGA LOG SEC HNR NAV2).
# A checksum-valid frame of another class is treated as a chance match inside foreign data.
_KNOWN_CLASSES = np.zeros(256, dtype=bool)
_KNOWN_CLASSES[[0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x09, 0x0A, 0x0B, 0x0D, 0x10, 0x13, 0x21, 0x27, 0x28, 0x29]] = True
_MAX_PAYLOAD = 16384   # longer "frames" are chance matches (the longest real one, RXM-RAWX, is 8176 bytes)

# u-blox gnssId -> RINEX system letter (SBAS, IMES and NavIC are not kept)
_UBX_SYS = {0: "G", 2: "E", 3: "C", 5: "J", 6: "R"}
_MAX_SVID = {0: 32, 2: 36, 3: 63, 5: 10, 6: 24}

# (gnssId, sigId) -> RINEX 3 band digit + attribute (u-blox interface descriptions, "Signal identifiers")
_SIGNALS: dict[tuple[int, int], str] = {
    (0, 0): "1C", (0, 3): "2L", (0, 4): "2S", (0, 6): "5I", (0, 7): "5Q",
    (2, 0): "1C", (2, 1): "1B", (2, 3): "5I", (2, 4): "5Q", (2, 5): "7I", (2, 6): "7Q",
    (3, 0): "2I", (3, 1): "2I", (3, 2): "7I", (3, 3): "7I", (3, 5): "1P", (3, 6): "1D", (3, 7): "5P", (3, 8): "5D",
    (5, 0): "1C", (5, 1): "1Z", (5, 4): "2S", (5, 5): "2L", (5, 8): "5I", (5, 9): "5Q",
    (6, 0): "1C", (6, 2): "2C",
}


_SIG_TABLE = sorted(set(_SIGNALS.values()))
_SYS_LUT = np.full(256, -1, dtype=np.int64)      # gnssId -> index into SYSTEMS
_MAX_SV_LUT = np.zeros(256, dtype=np.int64)
_SIG_LUT = np.full((256, 16), -1, dtype=np.int64)  # (gnssId, sigId) -> index into _SIG_TABLE
for _g, _letter in _UBX_SYS.items():
    _SYS_LUT[_g] = SYSTEMS.index(_letter)
    _MAX_SV_LUT[_g] = _MAX_SVID[_g]
for (_g, _s), _code in _SIGNALS.items():
    _SIG_LUT[_g, _s] = _SIG_TABLE.index(_code)


def ubx_signal_code(gnss_id: int, sig_id: int) -> str | None:
    """RINEX 3 band+attribute ('1C', '2L', '7Q', ...) of a u-blox signal, None when not supported."""
    return _SIGNALS.get((gnss_id, sig_id))


_RAWX_HEADER = np.dtype([("rcv_tow", "<f8"), ("week", "<u2"), ("leap_s", "i1"), ("num_meas", "u1"),
                         ("rec_stat", "u1"), ("version", "u1"), ("reserved", "<u2")])
_RAWX_MEAS = np.dtype([("pr", "<f8"), ("cp", "<f8"), ("dop", "<f4"), ("gnss", "u1"), ("sv", "u1"), ("sig", "u1"),
                       ("freq", "u1"), ("lock_ms", "<u2"), ("cno", "u1"), ("pr_std", "u1"), ("cp_std", "u1"),
                       ("do_std", "u1"), ("trk", "u1"), ("reserved", "u1")])
_RAW_HEADER = np.dtype([("itow_ms", "<i4"), ("week", "<i2"), ("num_sv", "u1"), ("reserved", "u1")])
_RAW_MEAS = np.dtype([("cp", "<f8"), ("pr", "<f8"), ("dop", "<f4"), ("sv", "u1"), ("mes_qi", "i1"),
                      ("cno", "i1"), ("lli", "u1")])
assert _RAWX_HEADER.itemsize == 16 and _RAWX_MEAS.itemsize == 32 and _RAW_MEAS.itemsize == 24

LLI_SLIP = 1        # RINEX LLI bit 0: lost lock, cycle slip possible
LLI_HALF_CYCLE = 2  # RINEX LLI bit 1: half-cycle ambiguity not resolved


@dataclass
class UbxFrames:
    """Checksum-valid UBX frames of a buffer, in stream order (arrays of the same length)."""

    start: np.ndarray        # offset of the 0xB5 sync byte
    msg_id: np.ndarray       # class << 8 | id
    length: np.ndarray       # payload length (bytes); the payload is data[start + 6: start + 6 + length]
    n_bytes_total: int
    n_checksum_errors: int   # candidate frames (known class) that failed the checksum
    n_truncated_at_end: int  # a frame cut off by the end of the data

    @property
    def n_bytes_in_frames(self) -> int:
        return int(np.sum(self.length.astype(np.int64) + 8))


@dataclass
class UbxLog:
    """Everything decoded from one UBX log (see module docstring).

    observations: RINEX-like arrays of every raw measurement epoch (event_gps_time_s copied in).
    navigation: ephemerides and ionosphere parameters from RXM-SFRBX (empty when the log has none).
    event_gps_time_s: TIM-TM2 time marks of the chosen edge (gps_time_s, sorted; default the falling edge,
        as convbin); the rising and falling edges are both kept, with the EXTINT channel and the
        receiver's accuracy estimate (s) of the chosen edge.
    warnings: human-readable problems (checksum failures, truncated log, parity errors, ...).
    message_counts, bytes_total, bytes_skipped, checksum_errors, nav_stats: decoding statistics.
    """

    source_path: str
    observations: RawObservations
    navigation: NavigationData
    event_gps_time_s: np.ndarray                 # (N,) time marks of the chosen edge (default falling)
    warnings: list[str] = field(default_factory=list)
    event_rising_gps_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    event_falling_gps_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    event_channel: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.uint8))  # of event_gps_time_s
    event_accuracy_s: np.ndarray = field(default_factory=lambda: np.zeros(0))               # of event_gps_time_s
    message_counts: dict[str, int] = field(default_factory=dict)   # checksum-valid frames by message name
    bytes_total: int = 0
    bytes_skipped: int = 0       # bytes outside valid UBX frames (NMEA, RTCM 3, corrupt or truncated frames)
    checksum_errors: int = 0
    nav_stats: dict[str, int] = field(default_factory=dict)


# ============================================================================ framing
def find_ubx_frames(data: bytes) -> UbxFrames:
    """Locate every checksum-valid UBX frame (``B5 62 class id len16 payload ck_a ck_b``).

    Vectorised: the 8-bit Fletcher sums of all candidates come from two running sums (mod 256) of the
    buffer, so a resync after corrupt data costs nothing. Frames are then taken greedily in stream
    order, skipping candidates that start inside an accepted frame."""
    n = len(data)
    buf = np.frombuffer(data, dtype=np.uint8)
    empty = np.zeros(0, dtype=np.int64)
    if n < 8:
        return UbxFrames(empty, empty, empty, n, 0, int(n >= 2 and data.rfind(b"\xb5\x62") >= 0))
    cand = np.flatnonzero((buf[:-1] == 0xB5) & (buf[1:] == 0x62)).astype(np.int64)
    cand = cand[cand + 6 <= n]          # a sync pair in the last 5 bytes is looked at below
    length = buf[cand + 4].astype(np.int64) | (buf[cand + 5].astype(np.int64) << 8)
    end = cand + 8 + length
    fits = end <= n
    known = _KNOWN_CLASSES[buf[cand + 2]] & (length <= _MAX_PAYLOAD)
    # Fletcher-8 over [s, e): ck_a = sum b_j, ck_b = sum b_j * (e - j)  (all mod 256, uint8 wraps)
    s1 = np.zeros(n + 1, dtype=np.uint8)
    np.cumsum(buf, dtype=np.uint8, out=s1[1:])
    ramp = np.tile(np.arange(256, dtype=np.uint8), n // 256 + 1)[:n]
    s2 = np.zeros(n + 1, dtype=np.uint8)
    np.cumsum(buf * ramp, dtype=np.uint8, out=s2[1:])
    del ramp
    ok = np.zeros(len(cand), dtype=bool)
    e_ck = end[fits] - 2
    s = cand[fits] + 2
    ck_a = s1[e_ck] - s1[s]
    ck_b = (e_ck & 0xFF).astype(np.uint8) * ck_a - (s2[e_ck] - s2[s])
    ok[fits] = (ck_a == buf[e_ck]) & (ck_b == buf[e_ck + 1])
    ok &= known
    good, inside = take_frames_in_order(cand, end, ok)
    starts = cand[good]
    last_end = int(end[good][-1]) if len(good) else 0
    # candidates outside accepted frames that failed: corrupt / interleaved frames (or chance B5 62)
    failed = ~ok & ~inside & known
    n_ck = int(np.count_nonzero(failed & fits))
    # the log ends inside a frame: a plausible frame start after the last good frame runs past the end
    n_trunc = int(np.any(failed & ~fits & (cand >= last_end)) or data.find(b"\xb5\x62", max(n - 5, last_end)) >= 0)
    msg_id = (buf[starts + 2].astype(np.int64) << 8) | buf[starts + 3]
    return UbxFrames(starts, msg_id, length[good], n, n_ck, n_trunc)


# ============================================================================ public API
def read_ubx(path, *, event_edge: Literal["rising", "falling"] = "falling",
             max_cp_stdev_index: int | None = None, slip_on_lock_gap: bool = True) -> UbxLog:
    """Decode a u-blox UBX log (plain, .gz or .Z).

    event_edge: which TIM-TM2 edge gives ``event_gps_time_s`` (both are kept in the log). Default
        "falling": the leading edge of a hot-shoe (active-low, contact to ground) exposure pulse, and the
        edge RTKLIB convbin writes as RINEX event epochs; "rising" for an active-high trigger signal.
    max_cp_stdev_index: carrier phase with a larger cpStdev index (0.004 cycles per step) is
        dropped; None = RTKLIB demo5 defaults (5 for u-blox 8, 14 when u-blox 9 signals are seen).
    slip_on_lock_gap: also flag a slip when the lock time is shorter than the time since the
        previous measurement of the signal (a re-lock the receiver did not report as a decrease).
    Raises InputFileError when the file holds no UBX frame at all.
    """
    p = Path(path)
    data = read_bytes(p)
    return decode_ubx_bytes(data, str(p), event_edge=event_edge, max_cp_stdev_index=max_cp_stdev_index,
                            slip_on_lock_gap=slip_on_lock_gap)


def decode_ubx_bytes(data: bytes, source_path: str = "<bytes>", *,
                     event_edge: Literal["rising", "falling"] = "falling",
                     max_cp_stdev_index: int | None = None, slip_on_lock_gap: bool = True) -> UbxLog:
    """``read_ubx`` on a buffer already in memory (``source_path`` only names it in messages)."""
    if event_edge not in ("rising", "falling"):
        raise ValueError(f"event_edge must be 'rising' or 'falling', not {event_edge!r}")
    frames = find_ubx_frames(data)
    if len(frames.start) == 0:
        what = "the file is empty" if len(data) == 0 else "no UBX frame found (not a u-blox UBX log?)"
        raise InputFileError(source_path, what)
    warnings: list[str] = []
    counts = Counter(frames.msg_id.tolist())
    message_counts = {MESSAGE_NAMES.get(k, f"0x{k >> 8:02X}-0x{k & 0xFF:02X}"): v for k, v in sorted(counts.items())}
    if frames.n_checksum_errors:
        warnings.append(f"{frames.n_checksum_errors} UBX frame(s) failed the checksum (corrupt or interleaved "
                        "data) and were skipped")
    if frames.n_truncated_at_end:
        warnings.append("the log ends with a truncated UBX frame")

    def select(msg: int) -> tuple[np.ndarray, np.ndarray]:
        m = frames.msg_id == msg
        return frames.start[m] + 6, frames.length[m]

    # ---- measurement epochs (also the time reference of the navigation decoding)
    rawx = _decode_rawx(data, *select(ID_RXM_RAWX), max_cp_stdev_index, warnings)
    raw = _decode_raw(data, *select(ID_RXM_RAW), warnings)
    meas = rawx if rawx is not None else raw
    if rawx is not None and raw is not None:
        warnings.append("the log holds both RXM-RAWX and RXM-RAW; RXM-RAW was ignored")
    ref_pos, ref_time = _time_references(data, frames, meas)
    leap = _leap_seconds(rawx, ref_time)

    # ---- navigation messages
    nav_dec = SfrbxNavDecoder(leap)
    sf_pos, sf_len = select(ID_RXM_SFRBX)
    if len(sf_pos):
        refs = _reference_times(sf_pos, ref_pos, ref_time)
        if np.isnan(refs).any():
            now = datetime_to_gps_time_s(_dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None)) + leap
            refs = np.where(np.isnan(refs), now, refs)
            warnings.append("no receiver time in the log: navigation message weeks were resolved with today's date")
        for p0, ln, t in zip(sf_pos.tolist(), sf_len.tolist(), refs.tolist()):
            nav_dec.add(data[p0:p0 + ln], t)
    navigation = nav_dec.result(source_path)
    stats = dict(nav_dec.stats)
    n_sub = stats.get("lnav_subframes", 0)
    if stats.get("lnav_parity_error", 0) > max(2, 0.05 * n_sub):
        warnings.append(f"{stats['lnav_parity_error']} GPS/QZSS subframes failed the parity check")
    if stats.get("glonass_hamming_error", 0) > max(2, 0.05 * stats.get("glonass_strings", 0)):
        warnings.append(f"{stats['glonass_hamming_error']} GLONASS strings failed the Hamming check")
    if stats.get("galileo_crc_error", 0) > max(2, 0.05 * stats.get("galileo_words", 0)):
        warnings.append(f"{stats['galileo_crc_error']} Galileo I/NAV pages failed the CRC")

    # ---- time marks
    ev = _decode_tm2(data, *select(ID_TIM_TM2), leap, warnings)
    chosen = ev["rising"] if event_edge == "rising" else ev["falling"]

    # ---- observations
    header = _receiver_header(data, frames, meas)
    if meas is None:
        warnings.append("no raw measurements (RXM-RAWX or RXM-RAW) in the log: enable them on the receiver "
                        "for PPK")
        observations = RawObservations(source_path, np.zeros(0), [], [], np.zeros((0, 0, 0)),
                                       np.zeros((0, 0, 0), np.uint8), np.zeros((0, 0, 0), np.uint8), header,
                                       chosen[0].copy(), np.zeros(0, np.uint8))
    else:
        observations = _build_observations(meas, source_path, header, slip_on_lock_gap)
        observations.event_gps_time_s = chosen[0].copy()
    for sat, fcn in navigation.glonass_fcn().items():
        observations.header.glonass_fcn.setdefault(sat, fcn)
    return UbxLog(
        source_path=source_path, observations=observations, navigation=navigation,
        event_gps_time_s=chosen[0], warnings=warnings,
        event_rising_gps_time_s=ev["rising"][0], event_falling_gps_time_s=ev["falling"][0],
        event_channel=chosen[1], event_accuracy_s=chosen[2], message_counts=message_counts,
        bytes_total=frames.n_bytes_total, bytes_skipped=frames.n_bytes_total - frames.n_bytes_in_frames,
        checksum_errors=frames.n_checksum_errors, nav_stats=stats)


# ============================================================================ measurements
@dataclass
class _Measurements:
    """Flat table of raw measurements of one message type, epochs sorted and unique."""

    kind: str                 # 'rawx' or 'raw'
    epoch_time: np.ndarray    # (E,) gps_time_s
    epoch_pos: np.ndarray     # (E,) stream offset of the message (time reference for SFRBX)
    epoch: np.ndarray         # (M,) epoch index
    sys: np.ndarray           # (M,) index into SYSTEMS
    prn: np.ndarray           # (M,)
    signal: np.ndarray        # (M,) index into ``signals``
    signals: list[str]        # '1C', '2L', ...
    pr: np.ndarray            # (M,) m, NaN when invalid
    cp: np.ndarray            # (M,) cycles, NaN when invalid
    dop: np.ndarray           # (M,) Hz, NaN when absent
    cno: np.ndarray           # (M,) dB-Hz, NaN when absent
    lock_ms: np.ndarray       # (M,) carrier lock time (ms); -1 when the message has none (RXM-RAW)
    half_valid: np.ndarray    # (M,) bool
    half_sub: np.ndarray      # (M,) bool, half cycle subtracted from phase
    slip_flag: np.ndarray     # (M,) bool, slip reported by the receiver (RAW lli bit / cpStdev saturated)
    glonass_fcn: dict[str, int]
    leap_s: int | None        # GPS-UTC from RAWX when the receiver flags it as determined


def _gather(data: bytes, offsets: np.ndarray, sizes: np.ndarray) -> bytes:
    return b"".join(data[o:o + s] for o, s in zip(offsets.tolist(), sizes.tolist()))


def _unique_epochs(t: np.ndarray, kind: str, warnings: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Index of the epoch of every message and the kept messages (first of duplicates, time-sorted)."""
    if np.any(np.diff(t) < 0):
        warnings.append(f"{kind} epochs are not in time order (concatenated logs?); they were sorted")
    key = np.round(t * 1e6).astype(np.int64)
    uniq, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    keep = np.zeros(len(t), dtype=bool)
    keep[first] = True
    if np.count_nonzero(~keep):
        warnings.append(f"{np.count_nonzero(~keep)} duplicate {kind} epoch(s) dropped")
    return inverse.reshape(-1), keep


def _decode_rawx(data: bytes, pos: np.ndarray, length: np.ndarray, max_cp_std: int | None,
                 warnings: list[str]) -> _Measurements | None:
    if len(pos) == 0:
        return None
    ok_len = length >= 16
    pos, length = pos[ok_len], length[ok_len]
    hdr = np.frombuffer(_gather(data, pos, np.full(len(pos), 16)), dtype=_RAWX_HEADER)
    n_meas = hdr["num_meas"].astype(np.int64)
    tow_ok = np.isfinite(hdr["rcv_tow"]) & (hdr["rcv_tow"] >= 0.0) & (hdr["rcv_tow"] < SECONDS_PER_WEEK + 1.0)
    good = (length >= 16 + 32 * n_meas) & (hdr["week"] > 0) & tow_ok
    n_bad_len = int(np.count_nonzero(length < 16 + 32 * n_meas)) + int(np.count_nonzero(~ok_len))
    if n_bad_len:
        warnings.append(f"{n_bad_len} RXM-RAWX message(s) with an inconsistent length were skipped")
    pos, hdr, n_meas = pos[good], hdr[good], n_meas[good]
    if len(pos) == 0:
        return None
    t_msg = hdr["week"].astype(np.float64) * SECONDS_PER_WEEK + hdr["rcv_tow"]
    epoch_of_msg, keep = _unique_epochs(t_msg, "RXM-RAWX", warnings)
    meas = np.frombuffer(_gather(data, pos + 16, 32 * n_meas), dtype=_RAWX_MEAS)
    msg_of_meas = np.repeat(np.arange(len(pos)), n_meas)
    version = hdr["version"][msg_of_meas]
    gnss = meas["gnss"].astype(np.int64)
    sv = meas["sv"].astype(np.int64)
    sig = np.where(version >= 1, meas["sig"], 0).astype(np.int64)   # sigId is reserved (0) in version 0

    sys_idx = _SYS_LUT[gnss]
    max_sv = _MAX_SV_LUT[gnss]
    signal = _SIG_LUT[gnss, np.minimum(sig, 15)]
    use = keep[msg_of_meas] & (sys_idx >= 0) & (sv >= 1) & (sv <= max_sv) & (signal >= 0)
    dropped_sys = np.count_nonzero(keep[msg_of_meas] & ((sys_idx < 0) | (signal < 0)) & (gnss != 1) & (gnss != 4))
    if dropped_sys:
        warnings.append(f"{dropped_sys} RXM-RAWX measurement(s) of unsupported signals were skipped")
    meas, msg_of_meas, sys_idx, sv, signal = (a[use] for a in (meas, msg_of_meas, sys_idx, sv, signal))
    sig_used = sig[use]

    trk = meas["trk"]
    cp_std = meas["cp_std"] & 0x0F
    if max_cp_std is None:
        max_cp_std = 14 if np.any(sig_used > 1) else 5     # RTKLIB demo5: u-blox 9 (F9P) vs u-blox 8
    pr = np.where(((trk & 1) != 0) & (meas["pr"] != 0.0) & np.isfinite(meas["pr"]), meas["pr"], np.nan)
    cp_raw = meas["cp"]
    cp_ok = ((trk & 2) != 0) & (cp_raw != -0.5) & (cp_raw != 0.0) & (cp_std <= max_cp_std) & np.isfinite(cp_raw)
    cp = np.where(cp_ok, cp_raw, np.nan)
    # BeiDou GEO phases are offset by half a cycle on u-blox receivers (RTKLIB demo5 correction)
    bds_geo = (sys_idx == SYSTEMS.index("C")) & ((sv <= 5) | (sv >= 59))
    cp = np.where(bds_geo, cp + 0.5, cp)
    dop = meas["dop"].astype(np.float64)
    dop = np.where((dop != 0.0) & np.isfinite(dop), dop, np.nan)
    cno = meas["cno"].astype(np.float64)
    cno = np.where(cno > 0, cno, np.nan)

    glo = sys_idx == SYSTEMS.index("R")
    fcn: dict[str, int] = {}
    if np.any(glo):
        pairs = np.unique(np.stack([sv[glo], meas["freq"][glo].astype(np.int64)], axis=1), axis=0)
        for s_, f_ in pairs.tolist():
            if f_ <= 13:
                fcn.setdefault(f"R{s_:02d}", f_ - 7)
    leap_valid = (hdr["rec_stat"] & 1) != 0
    leap_s = int(np.median(hdr["leap_s"][leap_valid])) if np.any(leap_valid) else None
    kept_msgs = np.flatnonzero(keep)
    order = np.argsort(t_msg[kept_msgs], kind="stable")
    return _Measurements(
        kind="rawx", epoch_time=t_msg[kept_msgs][order], epoch_pos=pos[kept_msgs][order],
        epoch=epoch_of_msg[msg_of_meas], sys=sys_idx, prn=sv, signal=signal, signals=_SIG_TABLE,
        pr=pr, cp=cp, dop=dop, cno=cno, lock_ms=meas["lock_ms"].astype(np.int64),
        half_valid=(trk & 4) != 0, half_sub=(trk & 8) != 0, slip_flag=cp_std >= 15,
        glonass_fcn=fcn, leap_s=leap_s)


def _decode_raw(data: bytes, pos: np.ndarray, length: np.ndarray, warnings: list[str]) -> _Measurements | None:
    """UBX-RXM-RAW (u-blox 6 / LEA-6T): GPS L1 C/A only; mesQI >= 4 code+Doppler, >= 5 phase valid."""
    if len(pos) == 0:
        return None
    ok_len = length >= 8
    pos, length = pos[ok_len], length[ok_len]
    hdr = np.frombuffer(_gather(data, pos, np.full(len(pos), 8)), dtype=_RAW_HEADER)
    n_sv = hdr["num_sv"].astype(np.int64)
    good = (length >= 8 + 24 * n_sv) & (hdr["week"] > 0) & (hdr["itow_ms"] >= 0) & (hdr["itow_ms"] < 604_801_000)
    n_bad = int(np.count_nonzero(length < 8 + 24 * n_sv)) + int(np.count_nonzero(~ok_len))
    if n_bad:
        warnings.append(f"{n_bad} RXM-RAW message(s) with an inconsistent length were skipped")
    pos, hdr, n_sv = pos[good], hdr[good], n_sv[good]
    if len(pos) == 0:
        return None
    t_msg = hdr["week"].astype(np.float64) * SECONDS_PER_WEEK + hdr["itow_ms"] * 1e-3
    epoch_of_msg, keep = _unique_epochs(t_msg, "RXM-RAW", warnings)
    meas = np.frombuffer(_gather(data, pos + 8, 24 * n_sv), dtype=_RAW_MEAS)
    msg_of_meas = np.repeat(np.arange(len(pos)), n_sv)
    sv = meas["sv"].astype(np.int64)
    use = keep[msg_of_meas] & (sv >= 1) & (sv <= 32)   # SBAS (120-158) not kept
    meas, msg_of_meas, sv = meas[use], msg_of_meas[use], sv[use]
    qi = meas["mes_qi"].astype(np.int64)
    pr = np.where((qi >= 4) & (meas["pr"] != 0.0) & np.isfinite(meas["pr"]), meas["pr"], np.nan)
    cp = np.where((qi >= 5) & (meas["cp"] != 0.0) & np.isfinite(meas["cp"]), meas["cp"], np.nan)
    dop = np.where((qi >= 4) & (meas["dop"] != 0.0) & np.isfinite(meas["dop"]), meas["dop"].astype(np.float64),
                   np.nan)
    cno = meas["cno"].astype(np.float64)
    cno = np.where(cno > 0, cno, np.nan)
    n = len(meas)
    kept_msgs = np.flatnonzero(keep)
    order = np.argsort(t_msg[kept_msgs], kind="stable")
    return _Measurements(
        kind="raw", epoch_time=t_msg[kept_msgs][order], epoch_pos=pos[kept_msgs][order],
        epoch=epoch_of_msg[msg_of_meas], sys=np.zeros(n, dtype=np.int64), prn=sv,
        signal=np.zeros(n, dtype=np.int64), signals=["1C"], pr=pr, cp=cp, dop=dop, cno=cno,
        lock_ms=np.full(n, -1, dtype=np.int64), half_valid=np.ones(n, dtype=bool), half_sub=np.zeros(n, dtype=bool),
        # lli bit 0: loss of lock; mesQI < 6: "likely loss of carrier lock in previous interval"
        slip_flag=((meas["lli"] & 1) != 0) | (qi < 6), glonass_fcn={}, leap_s=None)


def _loss_of_lock(m: _Measurements, slip_on_lock_gap: bool) -> np.ndarray:
    """RINEX LLI of every measurement's phase (0 where the phase is NaN).

    As RTKLIB demo5 (ublox.c): a slip is detected when the lock time is 0 or decreased, when the
    half-cycle-subtracted flag changed (its initial state being 'not subtracted'), or cpStdev is
    saturated; it is carried to the next valid phase of the signal. Bit 1 is set when the
    half-cycle ambiguity is not resolved. With ``slip_on_lock_gap`` a lock time shorter than the time
    since the previous measurement of the signal (less 10 ms) is a slip too (a re-lock during a gap
    in the log, e.g. a lossy base-station log, that an increasing lock time would hide).
    """
    n = len(m.epoch)
    lli = np.zeros(n, dtype=np.uint8)
    if n == 0:
        return lli
    n_sig = max(len(m.signals), 1)
    key = (m.sys * 100 + m.prn) * n_sig + m.signal
    # measurement order by signal, then epoch (radix sort of a 16-bit key when epochs are already in order)
    if np.all(np.diff(m.epoch) >= 0):
        order = np.argsort(key.astype(np.int16) if key.max() < 32768 else key, kind="stable")
    else:
        order = np.lexsort((m.epoch, key))
    k_s, e_s = key[order], m.epoch[order]
    t_s = m.epoch_time[e_s]
    lock = m.lock_ms[order]
    half_sub = m.half_sub[order]
    valid = ~np.isnan(m.cp[order])
    idx = np.arange(n)
    same = np.zeros(n, dtype=bool)
    same[1:] = k_s[1:] == k_s[:-1]
    prev = np.maximum(idx - 1, 0)
    if m.kind == "rawx":
        prev_half = np.where(same, half_sub[prev], False)
        slip = (lock == 0) | (same & (lock < lock[prev])) | (half_sub != prev_half) | m.slip_flag[order]
        if slip_on_lock_gap:
            gap_ms = np.where(same, (t_s - t_s[prev]) * 1000.0, 0.0)
            slip |= same & (lock + 10 < gap_ms)
    else:
        slip = m.slip_flag[order].copy()
    # carry a slip to the next valid phase: any slip since the previous valid phase of the signal
    carried = carry_slips_to_valid_phase(slip, valid, same)
    out = np.where(carried, LLI_SLIP, 0) | np.where(valid & ~m.half_valid[order], LLI_HALF_CYCLE, 0)
    lli[order] = out.astype(np.uint8)
    return lli


def _ssi_from_cno(cno: np.ndarray) -> np.ndarray:
    """RINEX 3 signal strength indicator (1: < 12 dB-Hz ... 9: >= 54 dB-Hz); 0 where unknown."""
    ssi = np.clip(np.floor(cno / 6.0), 1, 9)
    return np.where(np.isnan(cno), 0, ssi).astype(np.uint8)


def _build_observations(m: _Measurements, source_path: str, header: ReceiverHeader,
                        slip_on_lock_gap: bool) -> RawObservations:
    lli = _loss_of_lock(m, slip_on_lock_gap)
    sat_key = m.sys * 100 + m.prn
    present = np.zeros(len(SYSTEMS) * 100, dtype=bool)
    present[sat_key] = True
    sat_keys = np.flatnonzero(present)
    sat_index = (np.cumsum(present) - 1)[sat_key]
    sat_ids = [f"{SYSTEMS[k // 100]}{k % 100:02d}" for k in sat_keys.tolist()]
    used = np.flatnonzero(np.bincount(m.signal, minlength=len(m.signals)))
    sig_names = sorted((m.signals[i] for i in used.tolist()), key=lambda c: (c[0], "CBLSXIQPDZW".find(c[1]), c))
    sig_col = np.full(len(m.signals), -1, dtype=np.int64)
    for j, name in enumerate(sig_names):
        sig_col[m.signals.index(name)] = j
    obs_codes = [f"{t}{name}" for name in sig_names for t in "CLDS"]
    n_e, n_s, n_k = len(m.epoch_time), len(sat_ids), len(obs_codes)
    values = np.full((n_e, n_s, n_k), np.nan)
    lli_arr = np.zeros((n_e, n_s, n_k), dtype=np.uint8)
    ssi_arr = np.zeros((n_e, n_s, n_k), dtype=np.uint8)
    e, s, base = m.epoch, sat_index.reshape(-1), 4 * sig_col[m.signal]
    ssi = _ssi_from_cno(m.cno)
    for off, vals in enumerate((m.pr, m.cp, m.dop, m.cno)):
        values[e, s, base + off] = vals
        ssi_arr[e, s, base + off] = np.where(np.isnan(vals), 0, ssi)
    lli_arr[e, s, base + 1] = lli
    fcn = dict(sorted(m.glonass_fcn.items()))
    header.glonass_fcn.update(fcn)
    if n_e > 1:   # the regular spacing, also when epochs are missing (lossy logs)
        d = np.diff(m.epoch_time)
        d = d[d > 5e-4]
        if len(d):
            header.interval_s = float(np.round(np.median(d[d < 1.5 * d.min()]), 3))
    return RawObservations(source_path, m.epoch_time.copy(), sat_ids, obs_codes, values, lli_arr, ssi_arr, header,
                           np.zeros(0), np.zeros(n_e, dtype=np.uint8))


# ============================================================================ times, header, events
def _time_references(data: bytes, frames: UbxFrames, meas: _Measurements | None) -> tuple[np.ndarray, np.ndarray]:
    """Stream offsets and gps_time_s of messages that tell the receiver time (measurement epochs,
    else NAV-SOL / NAV-TIMEGPS with valid week and time of week)."""
    if meas is not None and len(meas.epoch_time):
        order = np.argsort(meas.epoch_pos)
        return meas.epoch_pos[order], meas.epoch_time[order]
    pos_list, t_list = [], []
    for start, mid, ln in zip(frames.start.tolist(), frames.msg_id.tolist(), frames.length.tolist()):
        p0 = start + 6
        if mid == ID_NAV_SOL and ln >= 52:
            itow, ftow, week, _fix, flags = (int.from_bytes(data[p0:p0 + 4], "little"),
                                             int.from_bytes(data[p0 + 4:p0 + 8], "little", signed=True),
                                             int.from_bytes(data[p0 + 8:p0 + 10], "little", signed=True),
                                             data[p0 + 10], data[p0 + 11])
            if flags & 0x0C == 0x0C and week > 0 and itow < 604_800_000:
                pos_list.append(start)
                t_list.append(week * SECONDS_PER_WEEK + itow * 1e-3 + ftow * 1e-9)
        elif mid == ID_NAV_TIMEGPS and ln >= 16:
            itow = int.from_bytes(data[p0:p0 + 4], "little")
            ftow = int.from_bytes(data[p0 + 4:p0 + 8], "little", signed=True)
            week = int.from_bytes(data[p0 + 8:p0 + 10], "little", signed=True)
            if data[p0 + 11] & 0x03 == 0x03 and week > 0 and itow < 604_800_000:
                pos_list.append(start)
                t_list.append(week * SECONDS_PER_WEEK + itow * 1e-3 + ftow * 1e-9)
    return np.array(pos_list, dtype=np.int64), np.array(t_list, dtype=float)


def _reference_times(pos: np.ndarray, ref_pos: np.ndarray, ref_time: np.ndarray) -> np.ndarray:
    """For every message offset, the time of the latest reference message before it (else the first one)."""
    if len(ref_pos) == 0:
        return np.full(len(pos), np.nan)
    k = np.searchsorted(ref_pos, pos, side="right") - 1
    return ref_time[np.maximum(k, 0)]


def _leap_seconds(rawx: _Measurements | None, ref_time: np.ndarray) -> int:
    if rawx is not None and rawx.leap_s is not None:
        return rawx.leap_s
    if len(ref_time):
        return leap_seconds_at(gps_time_s_to_datetime(float(ref_time[0])))
    return leap_seconds_at(_dt.datetime.now(_dt.timezone.utc).replace(tzinfo=None))


def _decode_tm2(data: bytes, pos: np.ndarray, length: np.ndarray, leap: int,
                warnings: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """TIM-TM2 time marks: per edge, (gps_time_s, channel, accuracy_s), each edge reported once.

    An edge's time is wn * 604800 + towMs * 1e-3 + towSubMs * 1e-9 (towSubMs is in ns); a message reports
    the latest rising and falling edge and flags which of them is new. With timeBase = 2 (UTC) the
    GPS-UTC leap seconds are added (RTKLIB demo5 convbin: utc2gpst); timeBase 1 (GNSS) is taken as GPS
    time. Marks without a valid time (flags bit 6) are dropped with a warning."""
    out: dict[str, list[tuple[float, int, float]]] = {"rising": [], "falling": []}
    n_invalid = 0
    for p0, ln in zip(pos.tolist(), length.tolist()):
        if ln < 28:
            continue
        ch, flags = data[p0], data[p0 + 1]
        wn_r = int.from_bytes(data[p0 + 4:p0 + 6], "little")
        wn_f = int.from_bytes(data[p0 + 6:p0 + 8], "little")
        tow_r, sub_r, tow_f, sub_f, acc = struct.unpack_from("<5I", data, p0 + 8)
        time_base = (flags >> 3) & 0x03
        valid = bool(flags & 0x40)
        for edge, new, wn, tow, sub in (("rising", flags & 0x80, wn_r, tow_r, sub_r),
                                        ("falling", flags & 0x04, wn_f, tow_f, sub_f)):
            if not new:
                continue
            if not valid or wn == 0 or tow >= 604_800_000 or sub >= 1_000_000:
                n_invalid += 1
                continue
            t = wn * SECONDS_PER_WEEK + tow * 1e-3 + sub * 1e-9
            if time_base == 2:        # UTC -> GPS time
                t += leap
            out[edge].append((t, ch, acc * 1e-9))
    if n_invalid:
        warnings.append(f"{n_invalid} TIM-TM2 time mark edge(s) without a valid time were dropped")
    result = {}
    for edge, rows in out.items():
        arr = np.array(rows, dtype=float).reshape(-1, 3)
        order = np.argsort(arr[:, 0], kind="stable")
        arr = arr[order]
        result[edge] = (arr[:, 0].copy(), arr[:, 1].astype(np.uint8), arr[:, 2].copy())
    return result


def _receiver_header(data: bytes, frames: UbxFrames, meas: _Measurements | None) -> ReceiverHeader:
    """Receiver type (MON-VER) and an approximate position: the median of the receiver's own 3D fixes
    (source "receiver-fixes": its navigation solution, or for a base in survey-in / fixed mode the position
    it reports, which is the survey-in mean; metre-level, not a surveyed header position)."""
    header = ReceiverHeader(rinex_version=None)
    ver = frames.start[frames.msg_id == ID_MON_VER]
    if len(ver):
        p0 = int(ver[0]) + 6
        ln = int(frames.length[frames.msg_id == ID_MON_VER][0])
        text = [data[p0 + k:p0 + k + 30].split(b"\0")[0].decode("ascii", "replace") for k in range(40, ln, 30)]
        hw = data[p0 + 30:p0 + 40].split(b"\0")[0].decode("ascii", "replace")
        model = next((t[4:] for t in text if t.startswith("MOD=")), "")
        header.receiver_type = f"u-blox {model or hw}".strip()
        sw = data[p0:p0 + 30].split(b"\0")[0].decode("ascii", "replace").strip()
        header.receiver_version = next((t[6:] for t in text if t.startswith("FWVER=")), sw)
    else:
        header.receiver_type = "u-blox"
    pts = []
    for start, mid, ln in zip(frames.start.tolist(), frames.msg_id.tolist(), frames.length.tolist()):
        if len(pts) >= 600:
            break
        p0 = start + 6
        if mid == ID_NAV_SOL and ln >= 52 and data[p0 + 10] >= 3 and data[p0 + 11] & 1:
            x, y, z = (int.from_bytes(data[p0 + k:p0 + k + 4], "little", signed=True) * 0.01 for k in (12, 16, 20))
            pts.append((x, y, z))
        elif mid == ID_NAV_POSECEF and ln >= 20:
            x, y, z = (int.from_bytes(data[p0 + k:p0 + k + 4], "little", signed=True) * 0.01 for k in (4, 8, 12))
            if x or y or z:
                pts.append((x, y, z))
        elif mid == ID_NAV_PVT and ln >= 92 and data[p0 + 20] >= 3 and data[p0 + 21] & 1:
            lon, lat = (int.from_bytes(data[p0 + k:p0 + k + 4], "little", signed=True) * 1e-7 for k in (24, 28))
            h = int.from_bytes(data[p0 + 32:p0 + 36], "little", signed=True) * 1e-3
            pts.append(tuple(geodetic_to_ecef_m(math.radians(lat), math.radians(lon), h).tolist()))
    if pts:
        header.approx_position_ecef_m = np.median(np.array(pts), axis=0)
        header.approx_position_source = "receiver-fixes"
    return header
