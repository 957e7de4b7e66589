"""Plausibility check of a RINEX observation file taken over by hand (bench/data/gnss_corpus): every
observation is compared with its neighbours in time, so that a mistyped digit, a lost or doubled line or a
shifted column shows up as a single-epoch outlier.

* carrier phase: between consecutive epochs the phase of every satellite changes by the range change
  (satellite motion, computed from the navigation data at the single-point position) plus the receiver's
  own displacement and clock change, which are fitted to all satellites of the epoch pair (the fit of
  tdcp_slips.py, undifferenced); a signal whose residual exceeds --phase-m (default 5 cm) is printed, and a
  mistyped phase shows as two such residuals of opposite sign at consecutive epoch pairs (a real cycle slip
  shows as one);
* code: code minus carrier (m) changes by centimetres to decimetres per epoch (ionosphere, multipath, code
  noise): a jump beyond --code-m (default 15 m) that is undone at the next epoch is printed;
* Doppler: against the phase rate, beyond --doppler-hz (default 15 Hz); SNR outside 10-60 dB-Hz.

    python bench/gnss_corpus_check.py ROVER.obs NAV [NAV ...]
Exit status 1 when anything is printed."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.gnss.constants import CLIGHT_M_S, wavelength_table_m
from georef_core.gnss.input_files import load_navigation, load_observations
from georef_core.gnss.observations import select_bands
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.gnss.satellite_geometry import (
    compute_observed_satellites,
    geometric_range_m,
)
from georef_core.gnss.spp import solve_spp


def _fit_residuals(dy: np.ndarray, los: np.ndarray, sys_code: np.ndarray, threshold: float, min_n: int = 5):
    """Least-squares fit of displacement (3) + one clock per system to dy (n,), removing the worst signal
    beyond the threshold until all are within it; returns the residuals of all signals (NaN where
    dy is NaN) and the mask of those removed."""
    ok = np.isfinite(dy)
    removed = np.zeros(len(dy), dtype=bool)
    res = np.full(len(dy), np.nan)
    systems = np.unique(sys_code)
    while ok.sum() >= min_n:
        a = np.zeros((len(dy), 3 + len(systems)))
        a[:, :3] = -los
        for k, s in enumerate(systems):
            a[sys_code == s, 3 + k] = 1.0
        x, *_ = np.linalg.lstsq(a[ok], dy[ok], rcond=None)
        res = np.where(np.isfinite(dy), dy - a @ x, np.nan)
        worst = np.nanargmax(np.where(ok, np.abs(res), -1.0))
        if abs(res[worst]) <= threshold:
            break
        ok[worst] = False
        removed[worst] = True
    return res, removed


def check(path: str, navs: list[str], phase_m: float, code_m: float, doppler_hz: float, quiet: bool = False) -> int:
    raw = load_observations(path).observations
    nav = load_navigation(navs)
    obs = select_bands(raw)
    t = obs.gps_time_s
    n_e, n_s, n_b = obs.phase_cyc.shape
    print(f"{path}: {n_e} epochs {t[0]:.1f}-{t[-1]:.1f} (GPS s), {n_s} satellites, codes {raw.obs_codes}")
    lam = wavelength_table_m(obs.sat_ids, {**obs.header.glonass_fcn, **nav.glonass_fcn()})
    sats = compute_observed_satellites(obs, nav)
    opts = RtkOptions()
    spp = solve_spp(obs, sats, nav, opts, obs.header.approx_position_ecef_m)
    pos = spp.position_ecef_m.copy()
    fill = np.nanmedian(pos, axis=0)
    pos[~spp.valid] = fill
    rng, los = geometric_range_m(np.nan_to_num(sats.position_ecef_m), pos[:, None, :])
    model = rng - CLIGHT_M_S * np.nan_to_num(sats.clock_bias_s)
    model[~sats.valid] = np.nan
    systems = sorted({s[0] for s in obs.sat_ids})
    sys_code = np.array([systems.index(s[0]) for s in obs.sat_ids])
    problems = 0

    def name(e, s, b):
        return f"epoch {e} (t={t[e]:.1f}, {_hms(t[e])}) {obs.sat_ids[s]} band {b}"

    for b in range(n_b):
        ph_m = obs.phase_cyc[..., b] * lam[None, :, b]
        if not np.isfinite(ph_m).any():
            continue
        # phase: time-differenced fit per epoch pair
        y = ph_m - model
        flagged = {}
        all_res = np.full((n_e, n_s), np.nan)
        for e in range(1, n_e):
            if t[e] - t[e - 1] > 30:
                continue
            dy = y[e] - y[e - 1]
            lli = (obs.lli[e, :, b] & 1).astype(bool)
            dy[lli] = np.nan
            if np.isfinite(dy).sum() < 5:
                continue
            res, removed = _fit_residuals(dy, los[e], sys_code, phase_m)
            all_res[e] = res
            for s in np.nonzero(removed)[0]:
                flagged[(e, s)] = res[s]
        for (e, s), r in sorted(flagged.items()):
            back = all_res[e + 1, s] if e + 1 < n_e else np.nan
            spike = np.isfinite(back) and abs(back) > 0.5 * phase_m and back * r < 0
            kind = "SPIKE (mistyped?)" if spike else "jump (slip?)"
            if kind.startswith("SPIKE") or not quiet:
                print(f"  phase {kind}: {name(e, s, b)}: {r:+.3f} m")
            if kind.startswith("SPIKE"):
                problems += 1
        # code minus carrier
        cmc = obs.code_m[..., b] - ph_m
        d = np.diff(cmc, axis=0)
        for e in range(1, n_e - 1):
            for s in range(n_s):
                if np.isfinite(d[e - 1, s]) and np.isfinite(d[e, s]) and abs(d[e - 1, s]) > code_m \
                        and abs(d[e - 1, s] + d[e, s]) < 0.5 * abs(d[e - 1, s]):
                    print(f"  code SPIKE: {name(e, s, b)}: {d[e - 1, s]:+.2f} m")
                    problems += 1
        # Doppler against the phase rate (RINEX: phase rate = -Doppler)
        dt = np.diff(t)[:, None]
        rate = -np.diff(obs.phase_cyc[..., b], axis=0) / dt
        dop = obs.doppler_hz[..., b]
        mid = 0.5 * (dop[1:] + dop[:-1])
        bad = np.abs(rate - mid) > doppler_hz
        bad &= np.isfinite(rate) & np.isfinite(mid) & (dt < 2.5)
        bad &= ~(obs.lli[1:, :, b] & 1).astype(bool)
        for e, s in zip(*np.nonzero(bad)):
            # a mistyped Doppler disagrees with both neighbouring phase rates
            if 0 < e + 1 < n_e - 1 and bad[min(e + 1, len(bad) - 1), s] or e == 0:
                print(f"  Doppler: {name(e + 1, s, b)}: phase rate {rate[e, s]:.2f} Hz, Doppler "
                      f"{dop[e, s]:.3f}/{dop[e + 1, s]:.3f} Hz")
                problems += 1
        snr = obs.snr_dbhz[..., b]
        for e, s in zip(*np.nonzero((snr < 10) | (snr > 60))):
            print(f"  SNR {snr[e, s]}: {name(e, s, b)}")
            problems += 1
    print(f"  {problems} problem(s)")
    return problems


def _hms(t_gps: float) -> str:
    sod = t_gps % 86400
    return f"{int(sod // 3600):02d}:{int(sod % 3600 // 60):02d}:{sod % 60:04.1f}"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("obs")
    ap.add_argument("nav", nargs="+")
    ap.add_argument("--phase-m", type=float, default=0.05)
    ap.add_argument("--code-m", type=float, default=15.0)
    ap.add_argument("--doppler-hz", type=float, default=15.0)
    ap.add_argument("--quiet", action="store_true", help="print only the spikes, not the single jumps")
    args = ap.parse_args()
    return 1 if check(args.obs, args.nav, args.phase_m, args.code_m, args.doppler_hz, args.quiet) else 0


if __name__ == "__main__":
    sys.exit(main())
