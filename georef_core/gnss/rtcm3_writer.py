"""RTCM 3 encoder: the inverse of rtcm3.py / rtcm3_nav.py, for the simulator (a DJI-style raw log
``*_PPKRAW.bin``, a base station stream).

``encode_rtcm3_stream(obs, nav, ...)`` returns the bytes of a stream; ``encode_rtcm3(...)`` returns
them with a report (``Rtcm3Encoding``: message counts, phase arcs shifted by whole cycles, values that
could not be represented). The stream holds, per epoch of ``obs``:

* the station messages 1006 (antenna reference point, when ``station_ecef_m`` is given) and 1033
  (descriptors, when given) at the start and every ``nav_interval_s``;
* the ephemeris messages of ``nav`` (1019 GPS, 1020 GLONASS, 1042 BeiDou, 1044 QZSS, 1045 Galileo
  F/NAV, 1046 Galileo I/NAV after the record's ``data_source``): every record is written before the
  first epoch at or after its toe (records older than the first epoch at the start, records newer
  than the last epoch at the end) and repeated every ``nav_interval_s`` while it is its satellite's
  newest record (GLONASS for at most 11 h after tb, the day a reader can resolve);
* one MSM (4, 5, 6 or 7: ``msm``) per system present, in the order GPS 107x, GLONASS 108x, Galileo
  109x, QZSS 111x, BeiDou 112x, the multiple-message bit set on all but the last of the epoch. A
  satellite x signal table larger than the 64 cells of one MSM is split over several messages of the
  same epoch (satellites in PRN order, each message carrying the signals of its own satellites).

MSM contents (RTCM 10403.3 section 3.5.12). Rough range: the mid-point of the satellite's
pseudoranges (of its carrier-phase ranges when it has none) rounded to 1/1024 ms; fine pseudorange
and fine phase range relative to it; rough phase-range rate: the first signal's (lowest signal ID)
phase-range rate (-Doppler x wavelength) rounded to 1 m/s, fine rates relative to it (MSM5/7);
GLONASS extended info: frequency channel + 7 from ``obs.header.glonass_fcn`` (else the GLONASS
records of ``nav``; 15 = unknown). Phase (cycles) -> phase range (m) with the signal's wavelength
(``rtcm3.signal_frequency_hz``); a GLONASS FDMA phase or Doppler without a known channel cannot be
written and is dropped (counted). NaN and values a field cannot hold are written as the field's
invalid value (counted in ``Rtcm3Encoding.dropped``).

Carrier-phase ambiguity. RTCM requires the phase range to lie within 2^-8 ms (+-1171 m) of the
rough range (the fine phase-range field, 22 bits of 2^-29 ms or 24 bits of 2^-31 ms); receivers keep
the integer ambiguity so that phase range - pseudorange stays small. A
continuous arc of a signal (from one loss-of-lock flag, LLI bit 0, to the next) whose phase range
does not fit is shifted by one whole number of cycles for the whole arc (the one that centres it on
the rough ranges), so that decoded phases differ from the input by a constant integer number of
cycles per arc, which changes nothing for a carrier-phase solution (the ambiguity is estimated per
arc). Arcs that fit are written unchanged. ``Rtcm3Encoding.phase_shifts`` lists the shifted arcs
(satellite, phase code, start time, cycles added). An arc whose code-minus-phase drifts by more than
the field's whole width (about 2.3 km: not a real receiver) is cut where it stops fitting, with a
loss of lock written there (``Rtcm3Encoding.forced_slips``).

Lock time. Per signal the encoder keeps the time since the arc began: the epoch of a loss-of-lock
flag (LLI bit 0 on a valid phase), or, for a signal whose first observation carries no flag (the
receiver tracked it before the log began), 1 s before that first observation. A gap in the data
(epochs or cells missing) without a flag after it does not restart the count (the input says the
receiver kept lock). The lock-time indicator (DF402 4 bits for MSM4/5, DF407 10 bits extended for
MSM6/7) is rounded DOWN (it is a minimum lock time). Then the reader's rules (rtcm3._loss_of_lock,
RTKLIB's lossoflock: a slip where the indicator decreases or stays zero; with ``slip_on_lock_gap``
where 2 x lock + 32 ms is shorter than the time since the signal's previous cell) flag exactly the
input's slips, at the same epochs, and no other: an arc's lock time is never shorter than its time
since the previous cell, and the rounded-down indicator is at least half of it. Limits: MSM4/5 write
0 below 32 ms, so at rates above ~30 Hz a slip is also flagged at the epoch after one; a gap longer
than twice the MSM4/5 indicator's ceiling (524 s, i.e. a 17.5 min gap) is flagged by readers that
test gaps. LLI bit 1 is written as the half-cycle ambiguity indicator.

Times: GPS, Galileo, QZSS epoch fields are the GPS time of week in ms, BeiDou the BDT time of week
(GPS - 14 s), GLONASS the day of week and the Moscow time of day in ms (UTC + 3 h, with
gnss_time.leap_seconds_at). Epochs off the millisecond grid are rounded to it.

Round-trip error bounds (round to nearest: half a step; c = 299,792,458 m/s), all reached in
tests/gnss/test_rtcm3_writer.py (measured worst cases within 0.1 % of them):

=====================  ==========================  ==========================
quantity               MSM4 / MSM5                 MSM6 / MSM7
=====================  ==========================  ==========================
pseudorange            2^-25 ms = 8.93 mm          2^-30 ms = 0.279 mm
phase range            2^-30 ms = 0.279 mm         2^-32 ms = 0.0698 mm
phase (cycles)         1.50e-3 (lambda >= 0.1867)  3.74e-4 (lambda >= 0.1867)
Doppler                (MSM5) 5e-5 m/s: 2.7e-4 Hz  (MSM7) the same
C/N0 (1..63 dB-Hz)     0.5 dB-Hz                   1/32 dB-Hz
=====================  ==========================  ==========================

plus about 1e-8 m of float64 rounding, and for the phase the whole cycles of a shifted arc; the
Doppler bound is 2.63e-4 Hz at L1, 1.96e-4 Hz at L5, 2.68e-4 Hz for GLONASS G1 channel +6. Epoch
times are exact on the 1 ms grid, LLI bits 0 and 1 identical (see above).

Ephemerides carry the navigation messages' own fields and scale factors (LSBs), so values that were
broadcast come back as the satellite sent them (a RINEX file's 12-13 significant digits round to
the same LSB: the real records of the tests come back within 3e-5 m in position and 4e-16 s in
clock, the print precision of RINEX); other values are rounded to half an LSB (e.g. GLONASS position
2^-12 km = 0.24 m, velocity 4.8e-4 m/s; Kepler angles 2^-32 pi rad, 2 cm along track; sqrt(A)
2^-20 m^0.5, 1 cm of radius; GPS af0 2^-32 s = 0.07 ns). Week numbers are written modulo 1024
(GPS, QZSS), 4096 (Galileo) and 8192 (BeiDou); the week is that of the broadcast, the stream time
where the message stands (the toe's week except for a record whose toe lies across a week boundary
from that time), as the navigation messages do and as this project's reader and RTKLIB expect (a
toe in the next week, written just before the roll-over, would otherwise be read a week late). URA,
SISA and GLONASS FT indices are the smallest whose value is at least the record's accuracy; GLONASS
health: Bn = any bit but bit 3, ln = bit 3 (the reader's health = ln << 3 | Bn).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from .constants import CLIGHT_M_S
from .gnss_time import SECONDS_PER_WEEK, gps_time_s_to_datetime, leap_seconds_at
from .navigation import GlonassEphemeris, KeplerEphemeris, NavigationData
from .observations import RawObservations
from .rtcm3 import _CRC24Q, _MSM_SIGNALS, RANGE_MS_M, signal_frequency_hz
from .ubx_nav_decode import _GLONASS_FT_M, galileo_sisa_m

__all__ = [
    "PRIOR_LOCK_S",
    "BitWriter",
    "Rtcm3Encoding",
    "encode_ephemeris",
    "encode_rtcm3",
    "encode_rtcm3_stream",
    "encode_station_1006",
    "encode_station_1033",
    "ephemeris_message_type",
    "frame_rtcm3",
    "is_fnav",
    "msm_lock_indicator",
]

GLONASS_UTC_OFFSET_S = 10800.0
BDT_TO_GPST_S = 14.0
GST_WEEK_OFFSET = 1024
BDT_WEEK_OFFSET = 1356
SC2RAD = math.pi
PRIOR_LOCK_S = 1.0              # lock time assumed before a signal's first observation without a slip flag
_GLONASS_REPEAT_MAX_S = 11 * 3600.0

_SIGNAL_IDS: dict[str, dict[str, int]] = {sys: {code: sid for sid, code in table.items()}
                                          for sys, table in _MSM_SIGNALS.items()}
_MSM_BASE = {"G": 1070, "R": 1080, "E": 1090, "J": 1110, "C": 1120}
_SYSTEM_ORDER = "GREJC"
_ROUGH_MAX = 255 * 1024 - 1     # rough range in 1/1024 ms (255 ms is the invalid value)
_CRC_TABLE = [int(x) for x in _CRC24Q]


@dataclass(frozen=True)
class _MsmFormat:
    pr_bits: int
    pr_scale_ms: float
    cp_bits: int
    cp_scale_ms: float
    lock_bits: int
    cnr_bits: int
    cnr_scale: float
    has_rate: bool


_FORMATS = {
    4: _MsmFormat(15, 2.0**-24, 22, 2.0**-29, 4, 6, 1.0, False),
    5: _MsmFormat(15, 2.0**-24, 22, 2.0**-29, 4, 6, 1.0, True),
    6: _MsmFormat(20, 2.0**-29, 24, 2.0**-31, 10, 10, 2.0**-4, False),
    7: _MsmFormat(20, 2.0**-29, 24, 2.0**-31, 10, 10, 2.0**-4, True),
}


# ----------------------------------------------------------------------------------------------- report
@dataclass
class Rtcm3Encoding:
    """An encoded stream and what the encoder had to change or leave out."""

    data: bytes
    message_counts: dict[int, int] = field(default_factory=dict)
    n_epochs: int = 0
    # arcs whose phase was shifted by whole cycles: (satellite, phase code, arc start gps_time_s, cycles added)
    phase_shifts: list[tuple[str, str, float, int]] = field(default_factory=list)
    # loss of lock written where the input had none (an arc too long for the fine phase field)
    forced_slips: list[tuple[str, str, float]] = field(default_factory=list)
    # observations written as invalid: {"pseudorange": n, "phase": n, "doppler": n}
    dropped: dict[str, int] = field(default_factory=dict)
    unsupported: list[str] = field(default_factory=list)       # 'G:C1N', 'S20': no MSM signal / system
    skipped_ephemerides: list[str] = field(default_factory=list)

    @property
    def n_shifted_arcs(self) -> int:
        return len(self.phase_shifts)


# ----------------------------------------------------------------------------------------------- bits
class BitWriter:
    """Big-endian bit fields (the inverse of rtcm3.BitReader); raises ValueError for a value its field
    cannot hold."""

    __slots__ = ("n", "value")

    def __init__(self) -> None:
        self.value = 0
        self.n = 0

    def u(self, v: int, n: int, name: str = "") -> None:
        v = int(v)
        if not 0 <= v < (1 << n):
            raise ValueError(f"{name or 'field'} {v} does not fit {n} unsigned bits")
        self.value = (self.value << n) | v
        self.n += n

    def s(self, v: int, n: int, name: str = "") -> None:
        v = int(v)
        if not -(1 << (n - 1)) <= v < (1 << (n - 1)):
            raise ValueError(f"{name or 'field'} {v} does not fit {n} signed bits")
        self.value = (self.value << n) | (v & ((1 << n) - 1))
        self.n += n

    def sm(self, v: int, n: int, name: str = "") -> None:
        """Sign-magnitude (GLONASS): the first bit is the sign."""
        v = int(v)
        if abs(v) >= (1 << (n - 1)):
            raise ValueError(f"{name or 'field'} {v} does not fit {n} sign-magnitude bits")
        self.value = (self.value << n) | ((1 << (n - 1)) if v < 0 else 0) | abs(v)
        self.n += n

    def text(self, s: str, name: str = "") -> None:
        b = s.encode("latin-1", "replace")[:31]
        self.u(len(b), 8, name)
        for c in b:
            self.u(c, 8, name)

    def to_bytes(self) -> bytes:
        pad = -self.n % 8
        return (self.value << pad).to_bytes((self.n + pad) // 8, "big")


def frame_rtcm3(payload: bytes) -> bytes:
    """``D3 | 6 zero bits | 10-bit length | payload | CRC-24Q``."""
    if len(payload) > 1023:
        raise ValueError(f"RTCM 3 payload of {len(payload)} bytes (at most 1023)")
    head = bytes([0xD3, len(payload) >> 8, len(payload) & 0xFF]) + payload
    crc = 0
    table = _CRC_TABLE
    for b in head:
        crc = ((crc << 8) & 0xFFFFFF) ^ table[(crc >> 16) ^ b]
    return head + crc.to_bytes(3, "big")


def _bits_of(values, n: int) -> np.ndarray:
    """Bits (MSB first, uint8) of each value in n-bit two's complement."""
    v = np.asarray(values, dtype=np.int64).ravel() & ((1 << n) - 1)
    shifts = np.arange(n - 1, -1, -1, dtype=np.int64)
    return ((v[:, None] >> shifts) & 1).astype(np.uint8).ravel()


def _int_bits(value: int, n: int) -> np.ndarray:
    return np.unpackbits(np.frombuffer(value.to_bytes((n + 7) // 8, "big"), dtype=np.uint8))[-n:] if n else \
        np.zeros(0, np.uint8)


# ----------------------------------------------------------------------------------------------- lock time
def msm_lock_indicator(lock_ms, extended: bool) -> np.ndarray:
    """Lock-time indicator rounded DOWN (the largest whose minimum lock time is <= lock_ms): DF402
    (4 bits, MSM4/5) or, ``extended``, DF407 (10 bits, MSM6/7); inverse of rtcm3._lock_ms_msm4/6."""
    t = np.maximum(np.asarray(lock_ms, dtype=np.int64), 0)
    _, e = np.frexp(np.maximum(t, 1).astype(float))      # t = f * 2^e, f in [0.5, 1): floor(log2 t) = e - 1
    log2 = e.astype(np.int64) - 1
    if not extended:
        return np.where(t < 32, 0, np.minimum(log2 - 4, 15)).astype(np.int64)
    m = np.maximum(log2 - 5, 0)
    return np.where(t < 64, t, np.minimum((t >> m) + 32 * m, 704)).astype(np.int64)


# ----------------------------------------------------------------------------------------------- MSM
@dataclass
class _SystemMsm:
    """Every field of one system's MSM cells over the whole log, ready to pack."""

    letter: str
    prns: np.ndarray          # (S,)
    sig_ids: np.ndarray       # (G,)
    exists: np.ndarray        # (E, S, G) bool
    rough: np.ndarray         # (E, S) rough range in 1/1024 ms
    ext: np.ndarray           # (S,)
    rough_rate: np.ndarray    # (E, S)
    fine_pr: np.ndarray       # (E, S, G)
    fine_cp: np.ndarray
    lock: np.ndarray
    half: np.ndarray
    cnr: np.ndarray
    fine_rate: np.ndarray
    epoch_field: np.ndarray   # (E,)


def _nan_reduce(fn, a: np.ndarray, axis: int, fill: float) -> np.ndarray:
    out = fn.reduce(np.where(np.isnan(a), fill, a), axis=axis)
    return np.where(np.isinf(out), np.nan, out)


def _epoch_fields(letter: str, times: np.ndarray) -> np.ndarray:
    t_ms = np.round(times * 1000.0).astype(np.int64)
    week_ms = int(SECONDS_PER_WEEK) * 1000
    if letter == "C":
        return (t_ms - int(BDT_TO_GPST_S * 1000)) % week_ms
    if letter != "R":
        return t_ms % week_ms
    leap = np.array([leap_seconds_at(gps_time_s_to_datetime(t)) for t in times], dtype=np.int64) \
        if len(times) else np.zeros(0, np.int64)
    moscow_ms = t_ms - leap * 1000 + int(GLONASS_UTC_OFFSET_S * 1000)
    day = moscow_ms // 86400000
    return ((day % 7) << 27) | (moscow_ms - day * 86400000)


def _prepare_system(obs: RawObservations, letter: str, fmt: _MsmFormat, fcn_of: dict[str, int],
                    report: Rtcm3Encoding, unsupported: set[str]) -> _SystemMsm | None:
    table = _SIGNAL_IDS[letter]
    sats = []
    for k, s in enumerate(obs.sat_ids):
        if s[0] != letter:
            continue
        try:
            prn = int(s[1:])
        except ValueError:
            prn = 0
        if 1 <= prn <= 64:
            sats.append((prn, k, s))
        else:
            unsupported.add(s)
    if not sats:
        return None
    sats.sort()
    sat_idx = np.array([k for _, k, _ in sats])
    sat_names = [s for _, _, s in sats]
    col = {c: k for k, c in enumerate(obs.obs_codes)}
    sub = obs.values[:, sat_idx, :]
    has_data = np.isfinite(sub).any(axis=(0, 1)) if sub.size else np.zeros(len(obs.obs_codes), bool)
    sigs = set()
    for c, k in col.items():
        if len(c) != 3 or c[0] not in "CLDS" or not has_data[k]:
            continue
        if c[1:] in table:
            sigs.add(c[1:])
        else:
            unsupported.add(f"{letter}:{c}")
    if not sigs:
        return None
    sig_list = sorted(sigs, key=table.get)
    n_e, n_s, n_g = obs.n_epochs, len(sats), len(sig_list)

    def take(kind: str) -> np.ndarray:
        out = np.full((n_e, n_s, n_g), np.nan)
        for g, sig in enumerate(sig_list):
            k = col.get(kind + sig)
            if k is not None:
                out[:, :, g] = sub[:, :, k]
        return out

    pr, cp_cyc, dop, cnr_db = take("C"), take("L"), take("D"), take("S")
    lli = np.zeros((n_e, n_s, n_g), dtype=np.uint8)
    for g, sig in enumerate(sig_list):
        k = col.get("L" + sig)
        if k is not None:
            lli[:, :, g] = obs.lli[:, sat_idx, k]
    wl = np.full((n_s, n_g), np.nan)
    for i, name in enumerate(sat_names):
        for g, sig in enumerate(sig_list):
            wl[i, g] = CLIGHT_M_S / signal_frequency_hz(letter, sig, fcn_of.get(name))
    dropped = report.dropped

    # validity of what can be written
    has_wl = np.isfinite(wl)[None, :, :]
    ph_ok = np.isfinite(cp_cyc) & has_wl
    dropped["phase"] += int(np.count_nonzero(np.isfinite(cp_cyc) & ~has_wl))
    rate = -dop * wl[None, :, :]
    dop_ok = np.isfinite(rate) if fmt.has_rate else np.zeros_like(ph_ok)
    if fmt.has_rate:
        dropped["doppler"] += int(np.count_nonzero(np.isfinite(dop) & ~has_wl))
    pr_ok = np.isfinite(pr)
    cnr_ok = np.isfinite(cnr_db) & (cnr_db > 0.0)
    exists = pr_ok | ph_ok | dop_ok | cnr_ok

    # rough range from the pseudoranges
    lo, hi = _nan_reduce(np.fmin, np.where(pr_ok, pr, np.nan), 2, np.inf), \
        _nan_reduce(np.fmax, np.where(pr_ok, pr, np.nan), 2, -np.inf)
    has_pr = np.isfinite(lo)
    rough = np.zeros((n_e, n_s), dtype=np.int64)
    mid = np.where(has_pr, 0.5 * (lo + hi), 0.0)
    rough[has_pr] = np.clip(np.round(mid[has_pr] / RANGE_MS_M * 1024.0), 0, _ROUGH_MAX).astype(np.int64)
    rough_m = (rough * 2.0**-10) * RANGE_MS_M

    # carrier phase: whole-cycle shift per arc, loss-of-lock events
    cp_unit_m = fmt.cp_scale_ms * RANGE_MS_M
    cp_lim_m = (_lim(fmt.cp_bits) - 1) * cp_unit_m
    ph_range = np.full((n_e, n_s, n_g), np.nan)
    events = np.zeros((n_e, n_s, n_g), dtype=bool)
    times = obs.gps_time_s
    for i in range(n_s):
        for g in range(n_g):
            idx = np.flatnonzero(ph_ok[:, i, g])
            if not len(idx):
                continue
            w = wl[i, g]
            flagged = (lli[idx, i, g] & 1) != 0
            events[idx[flagged], i, g] = True
            d = np.where(has_pr[idx, i], cp_cyc[idx, i, g] - rough_m[idx, i] / w, np.nan)
            starts = np.flatnonzero(flagged)
            if not len(starts) or starts[0] != 0:
                starts = np.concatenate([[0], starts])
            k_of = np.zeros(len(idx))
            bounds = list(starts) + [len(idx)]
            for a in range(len(starts)):
                for s0, s1, k, forced in _arc_shifts(d[bounds[a]:bounds[a + 1]], w, cp_lim_m):
                    p0, p1 = bounds[a] + s0, bounds[a] + s1
                    k_of[p0:p1] = k
                    if k:
                        report.phase_shifts.append((sat_names[i], "L" + sig_list[g], float(times[idx[p0]]), int(k)))
                    if forced:
                        events[idx[p0], i, g] = True
                        report.forced_slips.append((sat_names[i], "L" + sig_list[g], float(times[idx[p0]])))
            ph_range[idx, i, g] = (cp_cyc[idx, i, g] + k_of) * w

    # rough range of satellites without a pseudorange: from their phase ranges
    plo, phi = _nan_reduce(np.fmin, ph_range, 2, np.inf), _nan_reduce(np.fmax, ph_range, 2, -np.inf)
    from_phase = ~has_pr & np.isfinite(plo)
    rough[from_phase] = np.clip(np.round(0.5 * (plo + phi)[from_phase] / RANGE_MS_M * 1024.0), 0,
                                _ROUGH_MAX).astype(np.int64)
    rough_m = (rough * 2.0**-10) * RANGE_MS_M

    # fine pseudorange and phase range
    pr_unit_m = fmt.pr_scale_ms * RANGE_MS_M
    with np.errstate(invalid="ignore"):
        fpr = np.round((pr - rough_m[:, :, None]) / pr_unit_m)
        pr_fit = pr_ok & (np.abs(fpr) <= _lim(fmt.pr_bits))
        fcp = np.round((ph_range - rough_m[:, :, None]) / cp_unit_m)
        cp_fit = np.isfinite(ph_range) & (np.abs(fcp) <= _lim(fmt.cp_bits))
    dropped["pseudorange"] += int(np.count_nonzero(pr_ok & ~pr_fit))
    dropped["phase"] += int(np.count_nonzero(np.isfinite(ph_range) & ~cp_fit))
    fine_pr = np.where(pr_fit, fpr, -(1 << (fmt.pr_bits - 1))).astype(np.int64)
    fine_cp = np.where(cp_fit, fcp, -(1 << (fmt.cp_bits - 1))).astype(np.int64)

    # lock time since the arc began (see module docstring)
    lock_ms = np.zeros((n_e, n_s, n_g), dtype=np.int64)
    for i in range(n_s):
        for g in range(n_g):
            ex = np.flatnonzero(exists[:, i, g])
            if not len(ex):
                continue
            t = times[ex]
            ev = events[ex, i, g]
            start = np.where(ev, t, np.nan)
            if not ev[0]:
                start[0] = t[0] - PRIOR_LOCK_S
            last = np.maximum.accumulate(np.where(np.isfinite(start), np.arange(len(ex)), 0))
            lock_ms[ex, i, g] = np.maximum(np.round((t - start[last]) * 1000.0), 0).astype(np.int64)
    lock = msm_lock_indicator(lock_ms, extended=fmt.lock_bits == 10)
    half = ((lli & 2) != 0) & ph_ok

    # C/N0
    cnr_max = (1 << fmt.cnr_bits) - 1
    with np.errstate(invalid="ignore"):
        cnr = np.where(cnr_ok, np.clip(np.round(cnr_db / fmt.cnr_scale), 1, cnr_max), 0).astype(np.int64)

    # phase-range rates (MSM5/7): rough from the first signal with a Doppler
    rough_rate = np.full((n_e, n_s), -8192, dtype=np.int64)
    fine_rate = np.full((n_e, n_s, n_g), -16384, dtype=np.int64)
    if fmt.has_rate:
        first = np.argmax(dop_ok, axis=2)
        r0 = np.take_along_axis(np.where(dop_ok, rate, 0.0), first[:, :, None], axis=2)[:, :, 0]
        rr = np.round(r0)
        rr_ok = dop_ok.any(axis=2) & (np.abs(rr) <= 8191)
        with np.errstate(invalid="ignore"):
            fr = np.round((rate - rr[:, :, None]) / 1e-4)
            fit = dop_ok & rr_ok[:, :, None] & (np.abs(fr) <= 16383)
        dropped["doppler"] += int(np.count_nonzero(dop_ok & ~fit))
        rough_rate = np.where(rr_ok, rr, -8192).astype(np.int64)
        fine_rate = np.where(fit, fr, -16384).astype(np.int64)

    ext = np.zeros(n_s, dtype=np.int64)
    if letter == "R":
        for i, name in enumerate(sat_names):
            f = fcn_of.get(name)
            ext[i] = f + 7 if f is not None and -7 <= f <= 6 else 15
    return _SystemMsm(letter, np.array([p for p, _, _ in sats]), np.array([table[s] for s in sig_list]), exists,
                      rough, ext, rough_rate, fine_pr, fine_cp, lock, half.astype(np.int64), cnr, fine_rate,
                      _epoch_fields(letter, times))


def _lim(bits: int) -> int:
    """Largest magnitude a signed MSM field holds (its most negative value means invalid)."""
    return (1 << (bits - 1)) - 1


def _arc_shifts(d: np.ndarray, wl: float, lim_m: float):
    """Whole-cycle shifts of one arc: [(start, end, cycles, forced_slip_at_start)]. ``d`` is the phase
    minus the rough range in cycles (NaN where the rough range is not known yet)."""
    known = np.isfinite(d)
    if not known.any():
        return [(0, len(d), 0, False)]
    lo, hi = float(np.min(d[known])), float(np.max(d[known]))
    if -lim_m <= lo * wl and hi * wl <= lim_m:
        return [(0, len(d), 0, False)]
    width = 2.0 * lim_m - wl
    if (hi - lo) * wl <= width:
        return [(0, len(d), -round(0.5 * (lo + hi)), False)]
    out, start, lo, hi = [], 0, math.inf, -math.inf
    for p in range(len(d)):
        if not known[p]:
            continue
        nlo, nhi = min(lo, d[p]), max(hi, d[p])
        if (nhi - nlo) * wl > width:
            out.append((start, p, lo, hi))
            start, nlo, nhi = p, d[p], d[p]
        lo, hi = nlo, nhi
    out.append((start, len(d), lo, hi))
    res = []
    for n, (s0, s1, a, b) in enumerate(out):
        k = 0 if (-lim_m <= a * wl and b * wl <= lim_m) else -round(0.5 * (a + b))
        res.append((s0, s1, k, n > 0))
    return res


def _msm_groups(present: np.ndarray, exists_e: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Satellites (indices, PRN order) of one epoch split so that satellites x signals <= 64 cells."""
    union = exists_e[present].any(axis=0)
    if len(present) * int(np.count_nonzero(union)) <= 64:
        return [(present, union)]
    groups, cur, cur_sig = [], [], np.zeros(exists_e.shape[1], dtype=bool)
    for s in present.tolist():
        u = cur_sig | exists_e[s]
        if cur and (len(cur) + 1) * int(np.count_nonzero(u)) > 64:
            groups.append((np.array(cur), cur_sig))
            cur, u = [], exists_e[s].copy()
        cur.append(s)
        cur_sig = u
    groups.append((np.array(cur), cur_sig))
    return groups


def _msm_payload(sysm: _SystemMsm, msm: int, fmt: _MsmFormat, e: int, sats: np.ndarray, sig_sel: np.ndarray,
                 station_id: int, multiple: bool) -> bytes:
    g_idx = np.flatnonzero(sig_sel)
    head = (((msm + _MSM_BASE[sysm.letter]) << 61) | (station_id << 49) | (int(sysm.epoch_field[e]) << 19)
            | (int(multiple) << 18))            # then IODS, reserved, clock steering, ext clock, smoothing: 0
    sat_mask = np.zeros(64, dtype=np.uint8)
    sat_mask[sysm.prns[sats] - 1] = 1
    sig_mask = np.zeros(32, dtype=np.uint8)
    sig_mask[sysm.sig_ids[g_idx] - 1] = 1
    ix = np.ix_([e], sats, g_idx)
    cell = sysm.exists[ix][0]
    cells = cell.ravel()
    rough = sysm.rough[e, sats]
    parts = [_int_bits(head, 73), sat_mask, sig_mask, cells.astype(np.uint8), _bits_of(rough >> 10, 8)]
    if fmt.has_rate:
        parts.append(_bits_of(sysm.ext[sats], 4))
    parts.append(_bits_of(rough & 1023, 10))
    if fmt.has_rate:
        parts.append(_bits_of(sysm.rough_rate[e, sats], 14))

    def cell_values(a: np.ndarray) -> np.ndarray:
        return a[ix][0].ravel()[cells]

    parts += [_bits_of(cell_values(sysm.fine_pr), fmt.pr_bits), _bits_of(cell_values(sysm.fine_cp), fmt.cp_bits),
              _bits_of(cell_values(sysm.lock), fmt.lock_bits), _bits_of(cell_values(sysm.half), 1),
              _bits_of(cell_values(sysm.cnr), fmt.cnr_bits)]
    if fmt.has_rate:
        parts.append(_bits_of(cell_values(sysm.fine_rate), 15))
    return np.packbits(np.concatenate(parts)).tobytes()


# ----------------------------------------------------------------------------------------------- station
def encode_station_1006(station_id: int, arp_ecef_m, antenna_height_m: float = 0.0,
                        systems: str = "GRE") -> bytes:
    """Framed 1006: antenna reference point (ECEF, 0.1 mm) and its height above the marker (0.1 mm)."""
    w = BitWriter()
    w.u(1006, 12)
    w.u(station_id, 12, "station ID")
    w.u(0, 6)                                          # ITRF realisation year
    w.u(int("G" in systems), 1)
    w.u(int("R" in systems), 1)
    w.u(int("E" in systems), 1)
    w.u(0, 1)                                          # reference station (not a virtual one)
    x, y, z = (round(float(v) * 1e4) for v in arp_ecef_m)
    w.s(x, 38, "ARP X")
    w.u(0, 2)                                          # single receiver oscillator, reserved
    w.s(y, 38, "ARP Y")
    w.u(0, 2)                                          # quarter cycle indicator
    w.s(z, 38, "ARP Z")
    w.u(round(min(max(antenna_height_m, 0.0), 6.5535) * 1e4), 16, "antenna height")
    return frame_rtcm3(w.to_bytes())


def encode_station_1033(station_id: int, antenna_descriptor: str = "", receiver_type: str = "", *,
                        antenna_serial: str = "", receiver_firmware: str = "", receiver_serial: str = "") -> bytes:
    """Framed 1033: antenna and receiver descriptors (at most 31 characters each)."""
    w = BitWriter()
    w.u(1033, 12)
    w.u(station_id, 12, "station ID")
    w.text(antenna_descriptor)
    w.u(0, 8)                                          # antenna setup ID
    for s in (antenna_serial, receiver_type, receiver_firmware, receiver_serial):
        w.text(s)
    return frame_rtcm3(w.to_bytes())


# ----------------------------------------------------------------------------------------------- ephemerides
_URA_UPPER_M = (2.4, 3.4, 4.85, 6.85, 9.65, 13.65, 24.0, 48.0, 96.0, 192.0, 384.0, 768.0, 1536.0, 3072.0, 6144.0)
_SISA_M = [galileo_sisa_m(i) for i in range(126)]


def _ura_index(acc_m: float) -> int:
    """GPS/QZSS/BDS URA index: the range (IS-GPS-200 20.3.3.3.1.3) holding the accuracy (15: unknown)."""
    if not math.isfinite(acc_m):
        return 15
    for i, upper in enumerate(_URA_UPPER_M):
        if acc_m <= upper + 1e-9:
            return i
    return 15


def _sisa_index(acc_m: float) -> int:
    if math.isfinite(acc_m) and acc_m >= 0.0:
        for i, v in enumerate(_SISA_M):
            if v >= acc_m - 1e-9:
                return i
    return 255


def _ft_index(acc_m: float) -> int:
    if math.isfinite(acc_m):
        for i, v in enumerate(_GLONASS_FT_M):
            if v >= acc_m - 1e-9:
                return i
    return 15


def _q(value: float, scale: float) -> int:
    if not math.isfinite(value):
        raise ValueError(f"non-finite value {value}")
    return round(value / scale)


def _sc(angle_rad: float, scale: float, wrap: bool = False) -> int:
    """An angle (rad) in semicircles over ``scale`` (wrapped into [-1, 1) semicircle when asked)."""
    sc = angle_rad / SC2RAD
    if wrap:
        sc = (sc + 1.0) % 2.0 - 1.0
    return _q(sc, scale)


def _sow(t: float) -> float:
    return t - math.floor(t / SECONDS_PER_WEEK) * SECONDS_PER_WEEK


def _broadcast_week(t_sys: float, date_sys: float) -> int:
    """The whole week to broadcast with a time of week so that a reader placing it near the stream time
    (the stream's time of week in that week) gets ``t_sys`` back (see rtcm3_nav._in_message_week)."""
    return round((t_sys - _sow(date_sys)) / SECONDS_PER_WEEK)


def _tow_field(t_sys: float, step: float) -> int:
    return round(_sow(t_sys) / step) % round(SECONDS_PER_WEEK / step)


def _kepler_orbit(w: BitWriter, e: KeplerEphemeris, beidou: bool) -> None:
    """crs .. omega_dot, common to 1019/1044/1045/1046/1042 (BeiDou: its own harmonic scales)."""
    r_scale, u_scale, r_bits = (2.0**-6, 2.0**-31, 18) if beidou else (2.0**-5, 2.0**-29, 16)
    w.s(_q(e.crs_m, r_scale), r_bits, "crs")
    w.s(_sc(e.delta_n_rad_s, 2.0**-43), 16, "delta n")
    w.s(_sc(e.m0_rad, 2.0**-31, True), 32, "M0")
    w.s(_q(e.cuc_rad, u_scale), r_bits, "cuc")
    w.u(_q(e.e, 2.0**-33), 32, "e")
    w.s(_q(e.cus_rad, u_scale), r_bits, "cus")
    w.u(_q(e.sqrt_a, 2.0**-19), 32, "sqrt A")


def _kepler_angles(w: BitWriter, e: KeplerEphemeris, beidou: bool) -> None:
    """cic .. omega_dot (after toe)."""
    r_scale, u_scale, r_bits = (2.0**-6, 2.0**-31, 18) if beidou else (2.0**-5, 2.0**-29, 16)
    w.s(_q(e.cic_rad, u_scale), r_bits, "cic")
    w.s(_sc(e.omega0_rad, 2.0**-31, True), 32, "OMEGA0")
    w.s(_q(e.cis_rad, u_scale), r_bits, "cis")
    w.s(_sc(e.i0_rad, 2.0**-31, True), 32, "i0")
    w.s(_q(e.crc_m, r_scale), r_bits, "crc")
    w.s(_sc(e.omega_rad, 2.0**-31, True), 32, "omega")
    w.s(_sc(e.omega_dot_rad_s, 2.0**-43), 24, "OMEGA dot")


def _gps_1019(e: KeplerEphemeris, date_s: float) -> bytes:
    w = BitWriter()
    w.u(1019, 12)
    w.u(int(e.sat_id[1:]), 6, "PRN")
    w.u(_broadcast_week(e.toe_gps_s, date_s) % 1024, 10)
    w.u(_ura_index(e.accuracy_m), 4)
    w.u(0, 2)                                          # code on L2
    w.s(_sc(e.idot_rad_s, 2.0**-43), 14, "IDOT")
    w.u(e.iode & 0xFF, 8)
    w.u(_tow_field(e.toc_gps_s, 16.0), 16, "toc")
    w.s(_q(e.af2_s_s2, 2.0**-55), 8, "af2")
    w.s(_q(e.af1_s_s, 2.0**-43), 16, "af1")
    w.s(_q(e.af0_s, 2.0**-31), 22, "af0")
    w.u(e.iodc & 0x3FF, 10)
    _kepler_orbit(w, e, False)
    w.u(_tow_field(e.toe_gps_s, 16.0), 16, "toe")
    _kepler_angles(w, e, False)
    w.s(_q(e.tgd_s[0], 2.0**-31), 8, "TGD")
    w.u(e.health & 0x3F, 6)
    w.u(0, 1)                                          # L2 P data flag
    w.u(int(e.fit_interval_h > 4.0), 1)
    return w.to_bytes()


def _qzss_1044(e: KeplerEphemeris, date_s: float) -> bytes:
    w = BitWriter()
    w.u(1044, 12)
    w.u(int(e.sat_id[1:]), 4, "QZSS PRN")
    w.u(_tow_field(e.toc_gps_s, 16.0), 16, "toc")
    w.s(_q(e.af2_s_s2, 2.0**-55), 8, "af2")
    w.s(_q(e.af1_s_s, 2.0**-43), 16, "af1")
    w.s(_q(e.af0_s, 2.0**-31), 22, "af0")
    w.u(e.iode & 0xFF, 8)
    _kepler_orbit(w, e, False)
    w.u(_tow_field(e.toe_gps_s, 16.0), 16, "toe")
    _kepler_angles(w, e, False)
    w.s(_sc(e.idot_rad_s, 2.0**-43), 14, "IDOT")
    w.u(0, 2)                                          # codes on L2
    w.u(_broadcast_week(e.toe_gps_s, date_s) % 1024, 10)
    w.u(_ura_index(e.accuracy_m), 4)
    w.u(e.health & 0x3F, 6)
    w.s(_q(e.tgd_s[0], 2.0**-31), 8, "TGD")
    w.u(e.iodc & 0x3FF, 10)
    w.u(int(e.fit_interval_h > 2.0), 1)
    return w.to_bytes()


def is_fnav(data_source: int) -> bool:
    """Galileo F/NAV record (RINEX data source bit 1, or bit 8 without the I/NAV bits 0, 2, 9)."""
    return bool(data_source & 2) or (bool(data_source & 256) and not data_source & (1 | 4 | 512))


def _galileo_1045_1046(e: KeplerEphemeris, date_s: float) -> bytes:
    fnav = is_fnav(e.data_source)
    w = BitWriter()
    w.u(1045 if fnav else 1046, 12)
    w.u(int(e.sat_id[1:]), 6, "Galileo PRN")
    w.u((_broadcast_week(e.toe_gps_s, date_s) - GST_WEEK_OFFSET) % 4096, 12)
    w.u(e.iode & 0x3FF, 10)
    w.u(_sisa_index(e.accuracy_m), 8)
    w.s(_sc(e.idot_rad_s, 2.0**-43), 14, "IDOT")
    w.u(_tow_field(e.toc_gps_s, 60.0), 14, "toc")
    w.s(_q(e.af2_s_s2, 2.0**-59), 6, "af2")
    w.s(_q(e.af1_s_s, 2.0**-46), 21, "af1")
    w.s(_q(e.af0_s, 2.0**-34), 31, "af0")
    _kepler_orbit(w, e, False)
    w.u(_tow_field(e.toe_gps_s, 60.0), 14, "toe")
    _kepler_angles(w, e, False)
    w.s(_q(e.tgd_s[0], 2.0**-32), 10, "BGD E5a/E1")
    h = int(e.health)
    if fnav:
        w.u((h >> 4) & 3, 2)                           # E5a signal health status
        w.u((h >> 3) & 1, 1)                           # E5a data validity status
        w.u(0, 7)
    else:
        w.s(_q(e.tgd_s[1] if len(e.tgd_s) > 1 else 0.0, 2.0**-32), 10, "BGD E5b/E1")
        w.u((h >> 7) & 3, 2)
        w.u((h >> 6) & 1, 1)
        w.u((h >> 1) & 3, 2)
        w.u(h & 1, 1)
        w.u(0, 2)
    return w.to_bytes()


def _beidou_1042(e: KeplerEphemeris, date_s: float) -> bytes:
    toe_bdt, toc_bdt, date_bdt = e.toe_gps_s - BDT_TO_GPST_S, e.toc_gps_s - BDT_TO_GPST_S, date_s - BDT_TO_GPST_S
    w = BitWriter()
    w.u(1042, 12)
    w.u(int(e.sat_id[1:]), 6, "BeiDou PRN")
    w.u((_broadcast_week(toe_bdt, date_bdt) - BDT_WEEK_OFFSET) % 8192, 13)
    w.u(_ura_index(e.accuracy_m), 4)
    w.s(_sc(e.idot_rad_s, 2.0**-43), 14, "IDOT")
    w.u(e.iode & 0x1F, 5)
    w.u(_tow_field(toc_bdt, 8.0), 17, "toc")
    w.s(_q(e.af2_s_s2, 2.0**-66), 11, "a2")
    w.s(_q(e.af1_s_s, 2.0**-50), 22, "a1")
    w.s(_q(e.af0_s, 2.0**-33), 24, "a0")
    w.u(e.iodc & 0x1F, 5)
    _kepler_orbit(w, e, True)
    w.u(_tow_field(toe_bdt, 8.0), 17, "toe")
    _kepler_angles(w, e, True)
    w.s(_q(e.tgd_s[0], 1e-10), 10, "TGD1")
    w.s(_q(e.tgd_s[1] if len(e.tgd_s) > 1 else 0.0, 1e-10), 10, "TGD2")
    w.u(int(e.health != 0), 1)
    return w.to_bytes()


def _moscow_tod_s(t_gps_s: float) -> float:
    leap = leap_seconds_at(gps_time_s_to_datetime(t_gps_s))
    m = t_gps_s - leap + GLONASS_UTC_OFFSET_S
    return m - math.floor(m / 86400.0) * 86400.0


def _glonass_1020(g: GlonassEphemeris) -> bytes:
    tb = round(_moscow_tod_s(g.toe_gps_s) / 900.0) % 96
    tof = g.frame_time_gps_s if math.isfinite(g.frame_time_gps_s) else g.toe_gps_s
    tk = math.floor(_moscow_tod_s(tof) + 1e-6) % 86400
    h = int(g.health)
    w = BitWriter()
    w.u(1020, 12)
    w.u(int(g.sat_id[1:]), 6, "GLONASS slot")
    w.u(g.fcn + 7, 5, "frequency channel")
    w.u(0, 1)                                          # almanac health
    w.u(0, 1)                                          # almanac health availability
    w.u(0, 2)                                          # P1
    w.u(tk // 3600, 5)
    w.u((tk % 3600) // 60, 6)
    w.u(int(tk % 60 >= 30), 1)
    w.u(int((h & ~8) != 0), 1)                         # Bn MSB
    w.u(tb & 1, 1)                                     # P2
    w.u(tb, 7)
    for k in range(3):
        w.sm(_q(g.velocity_ecef_m_s[k] * 1e-3, 2.0**-20), 24, "velocity")
        w.sm(_q(g.position_ecef_m[k] * 1e-3, 2.0**-11), 27, "position")
        w.sm(_q(g.acceleration_ecef_m_s2[k] * 1e-3, 2.0**-30), 5, "acceleration")
    w.u(0, 1)                                          # P3
    w.sm(_q(g.gamma_n, 2.0**-40), 11, "gamma_n")
    w.u(0, 2)                                          # P
    w.u((h >> 3) & 1, 1)                               # ln (third string)
    w.sm(_q(g.tau_n_s, 2.0**-30), 22, "tau_n")
    w.sm(0, 5)                                         # delta tau_n
    w.u(min(max(int(g.age_days), 0), 31), 5)
    w.u(0, 1)                                          # P4
    w.u(_ft_index(g.accuracy_m), 4)
    w.u(0, 11)                                         # NT
    w.u(1, 2)                                          # M: GLONASS-M
    w.u(0, 1)                                          # additional data availability
    w.u(0, 11)                                         # NA
    w.s(0, 32)                                         # tau_c
    w.u(0, 5)                                          # N4
    w.sm(0, 22)                                        # tau_GPS
    w.u(0, 1)                                          # ln (fifth string)
    w.u(0, 7)
    return w.to_bytes()


def ephemeris_message_type(record) -> int | None:
    """The RTCM message a record is written as (None: a system RTCM 3 has no ephemeris message for here)."""
    if isinstance(record, GlonassEphemeris):
        return 1020
    return {"G": 1019, "J": 1044, "C": 1042}.get(record.sat_id[0]) or \
        ((1045 if is_fnav(record.data_source) else 1046) if record.sat_id[0] == "E" else None)


def encode_ephemeris(record: KeplerEphemeris | GlonassEphemeris, stream_gps_s: float | None = None) -> bytes:
    """One framed ephemeris message. ``stream_gps_s``: the stream time where it will stand (the latest
    observation epoch before it, which dates it for a reader); default the record's toe. Raises
    ValueError for a record its message cannot hold."""
    mt = ephemeris_message_type(record)
    if mt is None:
        raise ValueError(f"{record.sat_id}: no RTCM 3 ephemeris message for this system")
    date = record.toe_gps_s if stream_gps_s is None else float(stream_gps_s)
    if mt == 1020:
        payload = _glonass_1020(record)
    elif mt == 1019:
        payload = _gps_1019(record, date)
    elif mt == 1044:
        payload = _qzss_1044(record, date)
    elif mt == 1042:
        payload = _beidou_1042(record, date)
    else:
        payload = _galileo_1045_1046(record, date)
    return frame_rtcm3(payload)


# ----------------------------------------------------------------------------------------------- the stream
def _nav_schedule(nav: NavigationData | None, times: np.ndarray, interval_s: float, report: Rtcm3Encoding):
    """{epoch index (len(times) = after the last): [records]} in emission order."""
    plan: dict[int, list] = {}
    if nav is None:
        return plan
    n_e = len(times)
    streams: dict[tuple, list] = {}
    for recs in list(nav.kepler.values()) + list(nav.glonass.values()):
        for r in recs:
            mt = ephemeris_message_type(r)
            if mt is None:
                report.skipped_ephemerides.append(f"{r.sat_id}: no RTCM 3 ephemeris message")
                continue
            streams.setdefault((r.sat_id, mt), []).append(r)
    for (_, mt), recs in sorted(streams.items()):
        recs = sorted(recs, key=lambda r: r.toe_gps_s)
        first = [int(np.searchsorted(times, r.toe_gps_s - 1e-6)) if n_e else 0 for r in recs]
        first = [0 if r.toe_gps_s <= (times[0] if n_e else math.inf) else f for r, f in zip(recs, first)]
        for j, (r, f) in enumerate(zip(recs, first)):
            plan.setdefault(f, []).append(r)
            end = first[j + 1] if j + 1 < len(recs) else n_e
            if f >= n_e or interval_s is None or interval_s <= 0 or end <= f + 1:
                continue
            last = times[f]
            while True:
                k = int(np.searchsorted(times, last + interval_s - 1e-6))
                if k >= end or (mt == 1020 and times[k] - r.toe_gps_s > _GLONASS_REPEAT_MAX_S):
                    break
                plan.setdefault(k, []).append(r)
                last = times[k]
    return plan


def encode_rtcm3(obs: RawObservations, nav: NavigationData | None = None, *, station_ecef_m=None, station_id: int = 0,
                 msm: int = 7, antenna_descriptor: str = "", receiver_type: str = "", nav_interval_s: float = 60.0,
                 antenna_height_m: float | None = None) -> Rtcm3Encoding:
    """Encode observations (and ephemerides, station data) as an RTCM 3 stream, with a report of what
    had to change (see the module docstring). ``antenna_height_m`` (1006): default the observations'
    antenna height (``obs.header.antenna_delta_hen_m[0]``)."""
    if msm not in _FORMATS:
        raise ValueError(f"msm must be 4, 5, 6 or 7, not {msm}")
    if not 0 <= station_id <= 4095:
        raise ValueError(f"station ID {station_id} outside 0..4095")
    fmt = _FORMATS[msm]
    report = Rtcm3Encoding(b"", dropped={"pseudorange": 0, "phase": 0, "doppler": 0})
    times = np.asarray(obs.gps_time_s, dtype=float)
    n_e = len(times)
    fcn_of: dict[str, int] = dict(nav.glonass_fcn()) if nav is not None else {}
    fcn_of.update(obs.header.glonass_fcn)
    unsupported: set[str] = set()
    systems = []
    for letter in _SYSTEM_ORDER:
        sysm = _prepare_system(obs, letter, fmt, fcn_of, report, unsupported)
        if sysm is not None:
            systems.append(sysm)
    for s in obs.sat_ids:
        if s[0] not in _SYSTEM_ORDER:
            unsupported.add(s)
    report.unsupported = sorted(unsupported)

    has_msm = np.zeros(n_e, dtype=bool)
    for sysm in systems:
        has_msm |= sysm.exists.any(axis=(1, 2))
    msm_epochs = np.flatnonzero(has_msm)
    plan = _nav_schedule(nav, times, nav_interval_s, report)
    station: list[bytes] = []
    if station_ecef_m is not None:
        height = antenna_height_m if antenna_height_m is not None else float(obs.header.antenna_delta_hen_m[0])
        present = "".join(sorted({s.letter for s in systems}))
        station.append(encode_station_1006(station_id, station_ecef_m, height if math.isfinite(height) else 0.0,
                                           present or "GRE"))
    if antenna_descriptor or receiver_type:
        station.append(encode_station_1033(station_id, antenna_descriptor, receiver_type))

    out = bytearray()
    counts: Counter = Counter()
    last_msm_t = float(times[msm_epochs[0]]) if len(msm_epochs) else None
    last_station_t = -math.inf

    def emit_nav(records) -> None:
        for r in records:
            if isinstance(r, GlonassEphemeris) and last_msm_t is not None and \
                    abs(last_msm_t - r.toe_gps_s) > _GLONASS_REPEAT_MAX_S:
                # tb is a time of day: a reader takes it in the day of the stream time
                report.skipped_ephemerides.append(f"{r.sat_id} toe {r.toe_gps_s:.0f}: more than 11 h from the "
                                                  "stream's epochs (tb would be read in another day)")
                continue
            try:
                frame = encode_ephemeris(r, last_msm_t)
            except ValueError as exc:
                report.skipped_ephemerides.append(f"{r.sat_id} toe {r.toe_gps_s:.0f}: {exc}")
                continue
            out.extend(frame)
            counts[ephemeris_message_type(r)] += 1

    repeat = nav_interval_s is not None and nav_interval_s > 0
    for e in range(n_e):
        t = float(times[e])
        if station and (e == 0 or (repeat and t - last_station_t >= nav_interval_s - 1e-6)):
            for frame in station:
                out.extend(frame)
                counts[int.from_bytes(frame[3:5], "big") >> 4] += 1
            last_station_t = t
        emit_nav(plan.get(e, ()))
        messages = []
        for sysm in systems:
            present = np.flatnonzero(sysm.exists[e].any(axis=1))
            if not len(present):
                continue
            for sats, sig_sel in _msm_groups(present, sysm.exists[e]):
                messages.append((sysm, sats, sig_sel))
        for j, (sysm, sats, sig_sel) in enumerate(messages):
            out.extend(frame_rtcm3(_msm_payload(sysm, msm, fmt, e, sats, sig_sel, station_id,
                                                j < len(messages) - 1)))
            counts[_MSM_BASE[sysm.letter] + msm] += 1
        if messages:
            last_msm_t = t
    if n_e == 0:
        for frame in station:
            out.extend(frame)
            counts[int.from_bytes(frame[3:5], "big") >> 4] += 1
    emit_nav(plan.get(n_e, ()))
    report.data = bytes(out)
    report.message_counts = dict(sorted(counts.items()))
    report.n_epochs = len(msm_epochs)
    return report


def encode_rtcm3_stream(obs: RawObservations, nav: NavigationData | None = None, *, station_ecef_m=None,
                        station_id: int = 0, msm: int = 7, antenna_descriptor: str = "", receiver_type: str = "",
                        nav_interval_s: float = 60.0) -> bytes:
    """The RTCM 3 stream of ``encode_rtcm3`` (bytes only; use encode_rtcm3 for the report)."""
    return encode_rtcm3(obs, nav, station_ecef_m=station_ecef_m, station_id=station_id, msm=msm,
                        antenna_descriptor=antenna_descriptor, receiver_type=receiver_type,
                        nav_interval_s=nav_interval_s).data
