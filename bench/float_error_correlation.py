"""How long does a float (or single-point) PPK solution's error stay correlated? Measured on real data,
for the float-stretch gap of the per-flight offsets (FLOAT_STRETCH_GAP_S in georef_core/steps/georef.py,
docs/georeferencing.md "One offset per float stretch").

Our engine processes real recordings single frequency (L1) with ambiguity resolution OFF (pos2-armode=off:
every epoch float, the longest float stretch the data allow) and in single-point mode, and compares each epoch
with a truth that does not come from that run (docs/gnss.md "Real corpus", bench/gnss_corpus.py):

* CHOOSE: the shared car (cssrlib 2021-265, mosaic-X5, 5.3 km to GEONET 3034, 360 s at 1 Hz) against its L1+L2
  quasi-truth (epochs where our and demo5's L1+L2 fix-and-hold solutions are both fixed and agree within 1 cm);
* CHECK (not looked at while choosing): the shared GEONET static baseline 0759-3040 (3.3 km, GPS, 30 s, one
  hour) against its L1+L2 static quasi-truth (both engines' static L1+L2 solutions agreeing within 1 cm), and
  the shared MatRTKLIB 1 m static baseline (two mosaic-X5, 301 s at 1 Hz) against its published coordinate.

For each run and axis (east, north, up; metres, ENU at the truth) it prints the error's correlation against the
time lag, two ways, over the pairs of epochs (t, t + lag) that both have a truth:

* r0 ("about zero"): sum e(t) e(t+lag) / sqrt(sum e(t)^2 sum e(t+lag)^2). This is what the per-flight offset
  assumes: a bias shared by the exposures of a stretch, drawn about zero (a constant bias gives r0 = 1 at every
  lag, however noisy the epochs are otherwise);
* r (the usual autocorrelation, mean of the whole series removed): how fast the error's variation about its own
  mean forgets itself. A single realisation's mean is part of the bias, so r understates how long the error
  stays alike; it is printed beside r0 as the lower bound.

and the first lag at which each falls below 0.5 and below 0.2 (">" the longest lag with enough pairs when it
never does). Usage: python bench/float_error_correlation.py [--max-lag-s 300] [--min-pairs 20]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

from georef_core.gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic  # noqa: E402
from georef_core.gnss.ppk import solve_files  # noqa: E402
from georef_core.gnss.rtk_options import read_rtklib_conf  # noqa: E402
from gnss_corpus import Truth, _match, cases, make_conf, quasi_truth  # noqa: E402

CHOOSE = "shared_cssrlib_2021_265_car"
CHECKS = ("shared_rtklib_gsi_0759_3040_static", "shared_matrtklib_static_1m")
PRINT_LAGS_S = (0, 5, 10, 20, 30, 60, 90, 120, 180, 240, 300)
THRESHOLDS = (0.5, 0.2)
AXES = ("E", "N", "U")

# (label, RTKLIB keys): L1, kinematic, no ambiguity resolution (float every epoch), filter direction as named;
# then single-point positioning
RUNS = (
    ("float, combined", {"pos1-posmode": "kinematic", "pos1-frequency": "l1", "pos1-soltype": "combined",
                         "pos2-armode": "off"}),
    ("float, forward", {"pos1-posmode": "kinematic", "pos1-frequency": "l1", "pos1-soltype": "forward",
                        "pos2-armode": "off"}),
    ("single point", {"pos1-posmode": "single", "pos1-frequency": "l1", "pos1-soltype": "forward"}),
)


def errors_enu_m(time_s: np.ndarray, ecef_m: np.ndarray, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """(times, errors (N, 3) east/north/up in metres) of the epochs that have a truth."""
    if truth.point is not None:
        ref_t, ref = time_s, np.repeat(truth.point[None, :], len(time_s), axis=0)
        ia = np.arange(len(time_s))
    else:
        ia, ib = _match(time_s, truth.time_s)
        ref_t, ref = time_s[ia], truth.ecef[ib]
    lat, lon, _ = ecef_to_geodetic(ref.mean(axis=0))
    return ref_t, (ecef_m[ia] - ref) @ ecef_to_enu_rotation(lat, lon).T


def correlation_vs_lag(t_s: np.ndarray, e: np.ndarray, step_s: float, max_lag_s: float, min_pairs: int):
    """For lags 0, step, 2 step ... max: (lags_s, r0 (L, 3), r (L, 3), pairs (L,)); NaN where fewer than
    min_pairs pairs. Epochs are placed on the step grid (rounded), so missing epochs only remove pairs."""
    k = np.round((t_s - t_s[0]) / step_s).astype(int)
    n = k.max() + 1
    grid = np.full((n, 3), np.nan)
    grid[k] = e
    centred = grid - np.nanmean(grid, axis=0)
    var = np.nanmean(centred ** 2, axis=0)
    n_lags = int(max_lag_s // step_s) + 1
    lags, r0, r, pairs = [], [], [], []
    for lag in range(min(n_lags, n)):
        a, b = grid[: n - lag], grid[lag:]
        ok = ~np.isnan(a[:, 0]) & ~np.isnan(b[:, 0])
        lags.append(lag * step_s)
        pairs.append(int(ok.sum()))
        if ok.sum() < min_pairs:
            r0.append([np.nan] * 3)
            r.append([np.nan] * 3)
            continue
        a, b = a[ok], b[ok]
        r0.append(np.sum(a * b, axis=0) / np.sqrt(np.sum(a * a, axis=0) * np.sum(b * b, axis=0)))
        ca, cb = centred[: n - lag][ok], centred[lag:][ok]
        r.append(np.mean(ca * cb, axis=0) / var)
    return np.array(lags), np.array(r0), np.array(r), np.array(pairs)


def first_below(lags: np.ndarray, rho: np.ndarray, level: float) -> str:
    valid = ~np.isnan(rho)
    below = np.nonzero(valid & (rho < level))[0]
    if len(below):
        return f"{lags[below[0]]:.0f} s"
    return f"> {lags[valid][-1]:.0f} s" if valid.any() else "-"


def report(case, truth: Truth, tmp: Path, max_lag_s: float, min_pairs: int) -> None:
    for label, keys in RUNS:
        conf = make_conf(case, tmp, "corr_" + label.replace(",", "").replace(" ", "_"), **keys)
        t0 = time.perf_counter()
        sol = solve_files(case.rover, case.base, case.navs, read_rtklib_conf(conf).options)
        secs = time.perf_counter() - t0
        keep = sol.status != 0
        t_s, e = errors_enu_m(sol.time_s[keep], sol.position_ecef_m[keep], truth)
        step = float(np.median(np.diff(t_s)))
        lags, r0, r, pairs = correlation_vs_lag(t_s, e, step, max_lag_s, min_pairs)
        statuses = {int(s): int(c) for s, c in zip(*np.unique(sol.status[keep], return_counts=True))}
        print(f"\n  {label}: {len(t_s)} epochs with a truth (statuses {statuses}), step {step:.0f} s, "
              f"solved in {secs:.1f} s; error RMS E/N/U {np.sqrt(np.mean(e ** 2, axis=0)).round(3).tolist()} m, "
              f"mean {e.mean(axis=0).round(3).tolist()} m, std {e.std(axis=0).round(3).tolist()} m")
        shown = [i for i, lag in enumerate(lags) if any(abs(lag - p) < step / 2 for p in PRINT_LAGS_S)]
        print("    lag s   pairs | r0 E   r0 N   r0 U  | r E    r N    r U")
        for i in shown:
            print(f"    {lags[i]:5.0f} {pairs[i]:6d} | " + " ".join(f"{v:6.2f}" for v in r0[i]) + " | "
                  + " ".join(f"{v:6.2f}" for v in r[i]))
        for name, rho in (("r0", r0), ("r ", r)):
            print(f"    {name} first below " + "; ".join(
                f"{lvl}: " + ", ".join(f"{AXES[a]} {first_below(lags, rho[:, a], lvl)}" for a in range(3))
                for lvl in THRESHOLDS))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-lag-s", type=float, default=300.0)
    ap.add_argument("--min-pairs", type=int, default=20, help="fewest epoch pairs for a lag's estimate")
    a = ap.parse_args()
    by_name = {c.name: c for c in cases()}
    if any(n not in by_name for n in (CHOOSE, *CHECKS)):
        print("the shared GNSS data (shared/data/gnss) are not here")
        return 1
    tmp = Path(tempfile.mkdtemp(prefix="float_corr_"))
    for role, name in (("CHOOSE", CHOOSE), *(("CHECK", n) for n in CHECKS)):
        case = by_name[name]
        t0 = time.perf_counter()
        truth = quasi_truth(case, tmp)
        n_truth = len(truth.time_s) if truth.time_s is not None else "static point"
        print(f"\n{role}: {name} ({case.note}); truth: {truth.kind} ({n_truth}) in {time.perf_counter() - t0:.1f} s")
        if not truth.kind:
            print("  no truth: skipped")
            continue
        report(case, truth, tmp, a.max_lag_s, a.min_pairs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
