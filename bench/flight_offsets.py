"""Honest camera-centre covariances in a survey of several flights (docs/georeferencing.md, "Several
flights: a common GNSS offset per flight").

Synthetic GNSS-aided blocks with known truth (tests/adjustment/test_bundle_adjustment.make_block: 4 lines
of 10 photos, two heights, tie points as exact projections plus 0.3 px noise, GNSS camera positions with
4 mm of independent noise per photo), split into two flights (lines 1-2, lines 3-4), each flight's GNSS
positions shifted by a common offset. Prints the ANEES (mean over cameras or points of e^T P^-1 e / 3,
1 = honest) of the camera centres and of check points (tie points away from the control point, with their
posterior covariance) with and without the per-flight offsets modelled, and the offsets recovered with
one control point.

    python bench/flight_offsets.py [--surveys 20]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the repository root: tests/ holds the blocks
from tests.adjustment.test_flight_offsets import FIXED_OFFSETS_M, run_case


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surveys", type=int, default=20, help="Monte-Carlo surveys (offsets drawn from the prior)")
    ap.add_argument("--flight-sigma", type=float, default=0.035, help="per-flight offset sigma, each axis (m)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    sf = args.flight_sigma
    print(f"fixed offsets: flight 1 {FIXED_OFFSETS_M[0]} m, flight 2 {FIXED_OFFSETS_M[1]} m; prior: per flight "
          f"{sf} m each axis, no common part (surveyed base)")
    for n_control in (0, 1):
        for model in (False, True):
            r = run_case(0, FIXED_OFFSETS_M, n_control, model, 0.0, sf)
            line = (f"  {n_control} GCP, offsets {'modelled' if model else 'not modelled'}: ANEES cameras "
                    f"{r['anees_cameras']:.2f}, check points {r['anees_checks']:.2f}; sigma0 gnss "
                    f"{r['sigma0_gnss']:.2f}; mean camera error {np.round(1000 * r['mean_camera_error_m'], 1)} mm, "
                    f"median sigma {np.round(1000 * r['median_camera_sigma_m'], 1)} mm")
            if model:
                line += (f"; offsets {np.round(100 * r['offsets_m'], 2).tolist()} cm +- "
                         f"{np.round(100 * r['offsets_sigma_m'], 2).tolist()} cm")
            print(line)
    # Monte Carlo: offsets drawn from the prior (common 2 cm, e.g. an unsurveyed base, + per flight sf)
    common = 0.02
    rng = np.random.default_rng(7)
    for n_control in (0, 1):
        stats = {False: [], True: []}
        z = []
        for s in range(args.surveys):
            off = rng.normal(0, common, 3)[None] + rng.normal(0, sf, (2, 3))
            for model in (False, True):
                r = run_case(100 + s, off, n_control, model, common, sf)
                stats[model].append((r["anees_cameras"], r["anees_checks"]))
                if model:
                    z.append(((r["offsets_m"] - off) / r["offsets_sigma_m"]).reshape(-1))
        for model in (False, True):
            a = np.array(stats[model])
            print(f"Monte Carlo {args.surveys} surveys, {n_control} GCP, offsets {'modelled' if model else 'not modelled'}"
                  f": ANEES cameras {a[:, 0].mean():.2f} (median {np.median(a[:, 0]):.2f}), check points "
                  f"{a[:, 1].mean():.2f} (median {np.median(a[:, 1]):.2f})")
        z = np.array(z)
        print(f"  offset errors / their sigma: RMS {np.sqrt(np.mean(z ** 2)):.2f}, within 2 sigma "
              f"{np.mean(np.abs(z) < 2):.0%}")
    print(f"{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
