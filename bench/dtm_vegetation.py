"""Benchmark: the DTM's ground classification under vegetation and machines, on seeded synthetic clouds with a
known bare earth (georef_core/sim/bare_earth_scene.py: undulating sloped terrain, a ridge stockpile, a cut
batter, trees and bushes with foliage gaps, an excavator, a truck and a box, grass patches; the DSM gridded
from the cloud as the dense step does). For each seed the DTM step's classifier runs twice: as it is, and as
the reference without its two vegetation rules (the stepped-cell and rough-cell rules of
georef_core/dtm/ground_filter.py, i.e. the filter before them); prints per seed and over all seeds the DTM error
against the true terrain (RMSE, p95, max) on open ground, the pile, the batter, under trees, bushes and
machines, the type I rates (ground cells removed: all, pile crest, batter edges) and type II rates (object cells
kept as ground: trees, bushes, machines), and the ratios reference / current.

    python bench/dtm_vegetation.py                       # seeds 101-108 (not the tuning seeds 1-4)
    python bench/dtm_vegetation.py --seeds 1 2 3 4 --noise 0.01 --canopy-noise 0.08
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.dtm import ground_filter as gf  # noqa: E402
from georef_core.sim.bare_earth_scene import (BareEarthSceneOptions, build_bare_earth_scene,  # noqa: E402
                                              evaluate_ground_filter)


def reference_classify(dsm, resolution_m, options):
    """The classifier without the stepped-cell and rough-cell rules."""
    saved = gf.stepped_blocks, gf.rough_blocks
    gf.stepped_blocks = lambda dsm, zmin, f, limit: np.zeros(zmin.shape, bool)
    gf.rough_blocks = lambda dsm, f: np.zeros((-(-dsm.shape[0] // f), -(-dsm.shape[1] // f)), bool)
    try:
        return gf.classify_dsm(dsm, resolution_m, options)
    finally:
        gf.stepped_blocks, gf.rough_blocks = saved


ERR = ("open", "pile", "batter", "under_trees", "under_bushes", "under_machines")
T1 = ("all", "pile", "batter", "pile_crest", "batter_edges", "under_trees")
T2 = ("trees", "bushes_0.9m_up", "bushes_under_0.9m", "machines")


def pooled_err(runs, k):
    """RMSE pooled over seeds (cell-weighted), worst p95 and max."""
    items = [r["dtm_error"][k] for r in runs if r["dtm_error"][k]]
    n = sum(i["cells"] for i in items)
    rmse = float(np.sqrt(sum(i["rmse_m"] ** 2 * i["cells"] for i in items) / n))
    return rmse, max(i["p95_abs_m"] for i in items), max(i["max_abs_m"] for i in items)


def pooled_rate(runs, group, k):
    items = [r[group][k] for r in runs if r[group][k]["cells"]]
    n = sum(i["cells"] for i in items)
    return sum(i["rate"] * i["cells"] for i in items) / n if n else float("nan"), n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(101, 109)))
    ap.add_argument("--noise", type=float, default=0.03, help="ground and machine point noise, m (1 sigma)")
    ap.add_argument("--canopy-noise", type=float, default=0.15, help="foliage point noise, m (1 sigma)")
    a = ap.parse_args()
    so = dataclasses.replace(BareEarthSceneOptions(), noise_m=a.noise, canopy_noise_m=a.canopy_noise)
    cur, ref = [], []
    t_cur = t_ref = 0.0
    for seed in a.seeds:
        sc = build_bare_earth_scene(seed, so)
        t = time.perf_counter()
        cur.append(evaluate_ground_filter(sc))
        t_cur += time.perf_counter() - t
        t = time.perf_counter()
        ref.append(evaluate_ground_filter(sc, classify=reference_classify))
        t_ref += time.perf_counter() - t
        c = cur[-1]
        print(f"seed {seed}: {c['objects']}; DTM RMSE open {c['dtm_error']['open']['rmse_m'] * 100:.1f} cm "
              f"(DSM {c['dsm_error_open']['rmse_m'] * 100:.1f}), trees "
              f"{c['dtm_error']['under_trees']['rmse_m'] * 100:.1f} cm, bushes "
              f"{c['dtm_error']['under_bushes']['rmse_m'] * 100:.1f} cm, machines "
              f"{c['dtm_error']['under_machines']['rmse_m'] * 100:.1f} cm; type I "
              f"{c['type_i']['all']['rate']:.4f}, type II {c['type_ii']['all']['rate']:.4f}", flush=True)
    print(f"\n{len(a.seeds)} seeds {a.seeds}, point noise {a.noise} m, foliage noise {a.canopy_noise} m")
    print(f"{'DTM - truth terrain':24s} {'current RMSE / p95 / max (m)':>32s} {'reference':>26s} {'RMSE ratio ref/cur':>20s}")
    for k in ERR:
        c, r = pooled_err(cur, k), pooled_err(ref, k)
        print(f"{k:24s} {c[0]:10.3f} {c[1]:10.3f} {c[2]:10.3f} {r[0]:8.3f} {r[1]:8.3f} {r[2]:8.3f} {r[0] / c[0]:12.2f}")
    print(f"{'type I (ground removed)':24s} {'current':>10s} {'reference':>10s} {'cells':>10s}")
    for k in T1:
        (c, n), (r, _) = pooled_rate(cur, "type_i", k), pooled_rate(ref, "type_i", k)
        print(f"{k:24s} {c:10.4f} {r:10.4f} {n:10d}")
    print(f"{'type II (object kept)':24s}")
    for k in T2:
        (c, n), (r, _) = pooled_rate(cur, "type_ii", k), pooled_rate(ref, "type_ii", k)
        print(f"{k:24s} {c:10.4f} {r:10.4f} {n:10d}")
    for k in ("ground_not_2", "ground_under_canopy_not_2", "objects_as_2"):
        (c, n), (r, _) = pooled_rate(cur, "points", k), pooled_rate(ref, "points", k)
        print(f"points {k:17s} {c:10.4f} {r:10.4f} {n:10d}")
    print(f"time (scene DSM + classification + DTM + points, per seed): current {t_cur / len(a.seeds):.1f} s, "
          f"reference {t_ref / len(a.seeds):.1f} s (ratio {t_cur / t_ref:.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
