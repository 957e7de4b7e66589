"""Observation containers shared by every reader (RINEX 2/3, UBX) and the processing engine.

``RawObservations`` keeps every signal as read (RINEX 3 codes, e.g. 'C1C', 'L2W', 'D1C', 'S1C';
RINEX 2 codes are mapped to RINEX 3 on reading). ``select_bands`` turns it into an
``ObservationSet`` with one signal per satellite and band (see constants.py for the band convention),
choosing the tracking code by priority.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .constants import CODE_PRIORITY, N_BANDS, RINEX_DIGIT_TO_BAND


@dataclass
class ReceiverHeader:
    marker_name: str = ""
    receiver_type: str = ""
    antenna_type: str = ""
    approx_position_ecef_m: np.ndarray | None = None   # (3,) or None when absent / zero
    antenna_delta_hen_m: np.ndarray = field(default_factory=lambda: np.zeros(3))  # height, east, north
    interval_s: float | None = None
    glonass_fcn: dict[str, int] = field(default_factory=dict)   # 'R05' -> -4
    rinex_version: float | None = None


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
