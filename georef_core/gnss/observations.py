"""Observation containers shared by every reader (RINEX 2/3, UBX) and the processing engine.

``RawObservations`` keeps every signal as read (RINEX 3 codes, e.g. 'C1C', 'L2W', 'D1C', 'S1C';
RINEX 2 codes are mapped to RINEX 3 on reading). ``select_bands`` turns it into an
``ObservationSet`` with one signal per satellite and band (see constants.py for the band convention),
choosing the tracking code by priority.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .constants import CODE_PRIORITY, N_BANDS, RINEX_DIGIT_TO_BAND


@dataclass
class ReceiverHeader:
    marker_name: str = ""
    receiver_type: str = ""
    receiver_version: str = ""      # firmware: RINEX REC # / TYPE / VERS, RTCM 1033, UBX MON-VER
    antenna_type: str = ""
    approx_position_ecef_m: np.ndarray | None = None   # (3,) or None when absent / zero
    antenna_delta_hen_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # height, east, north
    interval_s: float | None = None
    glonass_fcn: dict[str, int] = field(default_factory=dict)   # 'R05' -> -4
    rinex_version: float | None = None
    # where approx_position_ecef_m came from: "rinex-header" (APPROX POSITION XYZ), "rtcm-station" (RTCM 3
    # 1005/1006 reference point), "receiver-fixes" (the median of a UBX log's own navigation fixes:
    # metre-level, only a starting point, never taken as the base position before an averaged single-point
    # solution; see ppk._base_position), or "" = not stated: a header position as before the field existed
    # (the RINEX header's when rinex_version is set)
    approx_position_source: str = ""


@dataclass
class RawObservations:
    """Every signal of one receiver's file, as read.

    values[e, s, k] is observation code ``obs_codes[k]`` of satellite ``sat_ids[s]`` at epoch e
    (code/pseudorange in m, phase in cycles, Doppler in Hz, SNR in dB-Hz); NaN where absent.
    lli[e, s, k] is the loss-of-lock indicator (0 where absent), ssi the signal strength digit.
    """

    source_path: str
    gps_time_s: np.ndarray          # (E,) float64
    sat_ids: list[str]              # (S,) 'G05', 'R12', 'E11', 'J02', 'C20'
    obs_codes: list[str]            # (K,) RINEX 3 codes
    values: np.ndarray              # (E, S, K) float64
    lli: np.ndarray                 # (E, S, K) uint8
    ssi: np.ndarray                 # (E, S, K) uint8
    header: ReceiverHeader = field(default_factory=ReceiverHeader)
    event_gps_time_s: np.ndarray = field(default_factory=lambda: np.zeros(0))  # camera/marker events
    epoch_flags: np.ndarray | None = None   # (E,) uint8 epoch flag (0 ok, 1 power failure, ...)

    @property
    def n_epochs(self) -> int:
        return len(self.gps_time_s)


@dataclass
class ObservationSet:
    """One signal per satellite and band, ready for processing. Arrays are (E, S, N_BANDS)."""

    source_path: str
    gps_time_s: np.ndarray
    sat_ids: list[str]
    code_m: np.ndarray
    phase_cyc: np.ndarray
    doppler_hz: np.ndarray
    snr_dbhz: np.ndarray
    lli: np.ndarray
    signal_codes: np.ndarray        # (E, S, N_BANDS) uint8 index into ``signal_names`` (0 = none)
    signal_names: list[str]         # ['', 'C1C', ...] names of the chosen code observations
    header: ReceiverHeader
    event_gps_time_s: np.ndarray

    @property
    def n_epochs(self) -> int:
        return len(self.gps_time_s)


def select_bands(raw: RawObservations, priority: dict[str, tuple[str, ...]] = CODE_PRIORITY) -> ObservationSet:
    """Pick, per satellite, epoch and band, the highest-priority tracking code that has a phase or code value.

    Code and phase come from the same tracking code where the phase exists (so a DD never mixes a
    W-code phase with an L2C phase on one receiver)."""
    n_e, n_s = len(raw.gps_time_s), len(raw.sat_ids)
    shape = (n_e, n_s, N_BANDS)
    code = np.full(shape, np.nan)
    phase = np.full(shape, np.nan)
    dopp = np.full(shape, np.nan)
    snr = np.full(shape, np.nan)
    lli = np.zeros(shape, dtype=np.uint8)
    chosen = np.zeros(shape, dtype=np.uint8)
    names = [""]
    col = {c: k for k, c in enumerate(raw.obs_codes)}
    sys_of = np.array([s[0] for s in raw.sat_ids])
    for sys in np.unique(sys_of):
        sat_idx = np.nonzero(sys_of == sys)[0]
        digit_map = RINEX_DIGIT_TO_BAND.get(sys)
        prio = priority.get(sys)
        if digit_map is None or prio is None:
            continue
        for digit, band in digit_map.items():
            taken = np.zeros((n_e, len(sat_idx)), dtype=bool)
            for attr in prio[band]:
                kc, kl = col.get(f"C{digit}{attr}"), col.get(f"L{digit}{attr}")
                if kc is None and kl is None:
                    continue
                c_val = raw.values[:, sat_idx, kc] if kc is not None else np.full((n_e, len(sat_idx)), np.nan)
                l_val = raw.values[:, sat_idx, kl] if kl is not None else np.full((n_e, len(sat_idx)), np.nan)
                avail = (~np.isnan(c_val) | ~np.isnan(l_val)) & ~taken
                if not avail.any():
                    continue
                name = f"C{digit}{attr}"
                if name not in names:
                    names.append(name)
                e_i, s_i = np.nonzero(avail)
                s_full = sat_idx[s_i]
                code[e_i, s_full, band] = c_val[e_i, s_i]
                phase[e_i, s_full, band] = l_val[e_i, s_i]
                if kl is not None:
                    lli[e_i, s_full, band] = raw.lli[e_i, s_full, kl]
                kd, ks = col.get(f"D{digit}{attr}"), col.get(f"S{digit}{attr}")
                if kd is not None:
                    dopp[e_i, s_full, band] = raw.values[e_i, s_full, kd]
                if ks is not None:
                    snr[e_i, s_full, band] = raw.values[e_i, s_full, ks]
                chosen[e_i, s_full, band] = names.index(name)
                taken |= avail
    return ObservationSet(raw.source_path, raw.gps_time_s, list(raw.sat_ids), code, phase, dopp, snr, lli,
                          chosen, names, raw.header, raw.event_gps_time_s)


def join_observations(parts: list[RawObservations], gap_factor: float = 5.0) -> tuple[RawObservations, list[str]]:
    """Several files of one receiver (a drone's flights, a base's hourly files or a log split by restarts)
    as one record in time order, and notes naming the gaps between them and any repeated epochs.

    Satellites and observation codes are the union; an epoch present in two files (overlapping hourly
    files) is kept once, from the earlier file. The header is the first file's; when two files' header
    positions differ by more than 1 m they are not the same station (InputFileError-worthy for a base:
    the caller decides), which is reported in the notes."""
    parts = sorted((p for p in parts if p.n_epochs), key=lambda p: float(p.gps_time_s[0]))
    if not parts:
        raise ValueError("join_observations needs at least one file with epochs")
    if len(parts) == 1:
        return parts[0], []
    notes: list[str] = []
    sat_ids = sorted({s for p in parts for s in p.sat_ids}, key=lambda s: ("GREJC".find(s[0]), s))
    codes: list[str] = []
    for p in parts:
        codes += [c for c in p.obs_codes if c not in codes]
    n_e = sum(p.n_epochs for p in parts)
    values = np.full((n_e, len(sat_ids), len(codes)), np.nan)
    lli = np.zeros((n_e, len(sat_ids), len(codes)), dtype=np.uint8)
    ssi = np.zeros_like(lli)
    times = np.empty(n_e)
    flags = np.zeros(n_e, dtype=np.uint8)
    s_col = {s: i for i, s in enumerate(sat_ids)}
    c_col = {c: i for i, c in enumerate(codes)}
    e0 = 0
    starts = []
    for p in parts:
        starts.append(e0)
        e1 = e0 + p.n_epochs
        si = np.array([s_col[s] for s in p.sat_ids], dtype=np.int64)
        ci = np.array([c_col[c] for c in p.obs_codes], dtype=np.int64)
        values[e0:e1, si[:, None], ci[None, :]] = p.values
        lli[e0:e1, si[:, None], ci[None, :]] = p.lli
        ssi[e0:e1, si[:, None], ci[None, :]] = p.ssi
        times[e0:e1] = p.gps_time_s
        if p.epoch_flags is not None:
            flags[e0:e1] = p.epoch_flags
        e0 = e1
    phase_cols = np.array([c_col[c] for c in codes if c.startswith("L")], dtype=np.int64)
    for k, (a, b) in enumerate(zip(parts, parts[1:]), start=1):
        gap = float(b.gps_time_s[0] - a.gps_time_s[-1])
        step = (a.header.interval_s or float(np.median(np.diff(a.gps_time_s)))) if a.n_epochs > 1 else 1.0
        if gap > gap_factor * max(step, 1e-3):
            notes.append(f"gap of {gap:.0f} s between {Path(a.source_path).name} and {Path(b.source_path).name}")
            # tracking across a gap between files is not known to be continuous: a slip on every phase
            first_phase = values[starts[k]][:, phase_cols]
            lli[starts[k]][:, phase_cols] |= np.where(np.isnan(first_phase), 0, 1).astype(np.uint8)
        elif gap < 0:
            notes.append(f"{Path(a.source_path).name} and {Path(b.source_path).name} overlap by {-gap:.0f} s")
    order = np.argsort(times, kind="stable")
    key = np.round(times[order] * 1e6).astype(np.int64)
    first = np.ones(len(key), dtype=bool)
    first[1:] = key[1:] != key[:-1]
    if not first.all():
        notes.append(f"{int((~first).sum())} epoch(s) present in two of the files were kept once")
    keep = order[first]
    positions = [p.header.approx_position_ecef_m for p in parts if p.header.approx_position_ecef_m is not None
                 and getattr(p.header, "approx_position_source", "") != "receiver-fixes"]   # fixes differ by metres
    if len(positions) > 1:
        spread = float(max(np.linalg.norm(q - positions[0]) for q in positions))
        if spread > 1.0:
            notes.append(f"the files' header positions differ by up to {spread:.1f} m (not one station?)")
    header = parts[0].header
    for p in parts[1:]:
        for sat, fcn in p.header.glonass_fcn.items():
            header.glonass_fcn.setdefault(sat, fcn)
    events = np.unique(np.concatenate([p.event_gps_time_s for p in parts]))
    joined = RawObservations(" + ".join(p.source_path for p in parts), times[keep], sat_ids, codes, values[keep],
                             lli[keep], ssi[keep], header, events, flags[keep])
    return joined, notes


def carry_slips_to_valid_phase(slip: np.ndarray, valid: np.ndarray, same_signal: np.ndarray) -> np.ndarray:
    """Measurements sorted by signal then epoch: True where the phase is valid and a slip happened since
    the signal's previous valid phase (a slip while the phase was missing is carried to the next one).
    ``same_signal[i]``: measurement i has the same signal as i - 1. Used by the UBX and RTCM 3 readers."""
    n = len(slip)
    idx = np.arange(n)
    group_start = np.maximum.accumulate(np.where(same_signal, 0, idx))
    cs = np.cumsum(slip)
    last_valid = np.maximum.accumulate(np.where(valid, idx, -1))
    prev_valid = np.empty(n, dtype=np.int64)
    if n:
        prev_valid[0] = -1
        prev_valid[1:] = last_valid[:-1]
    prev_valid = np.maximum(prev_valid, group_start - 1)
    cs_before = np.where(prev_valid >= 0, cs[np.maximum(prev_valid, 0)], 0)
    return valid & ((cs - cs_before) > 0)
