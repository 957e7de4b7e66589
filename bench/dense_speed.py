"""Speed and accuracy of the dense step on the simulator's full-size images (1600 x 1200).

Simulates a survey (``georef simulate --images N``, default 20, seed 3; or uses ``--survey DIR``), runs
``run_dense`` on its true orientations with 2 workers at 1600 px and prints the time per stage and per
image (wall clock and CPU), the machine load, the DSM against truth/dsm.tif over the work area (RMSE,
median, NMAD, completeness), the step's own precision estimate, and the target offsets in the orthophoto.
Target: <= 5 s per image on 2 cores.

    .venv/bin/python bench/dense_speed.py [--images 20] [--survey DIR] [--work DIR] [--workers 2]
        [--max-image-size 1600] [--seed 3]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=20)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--survey", type=Path, help="an existing simulated survey (else one is simulated)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_dense_speed"))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-image-size", type=int, default=1600)
    args = ap.parse_args(argv)

    from simulated_surveys import simulated_survey
    from georef_core.dense.dsm_compare import compare_dsm
    from georef_core.dense.ortho_check import read_targets, target_offsets
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps.dense import DenseOptions, run_dense

    survey = args.survey
    if survey is None:
        survey, dt = simulated_survey(args.work, args.images, args.seed)
        if survey is None:
            return 2
        if dt is not None:
            print(f"simulated in {dt:.1f} s")
    run = args.work / "run"
    oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")

    load0 = os.getloadavg()
    cpu0 = time.process_time()
    s = run_dense(run, DenseOptions(workers=args.workers, max_image_size=args.max_image_size))
    cpu = time.process_time() - cpu0
    load1 = os.getloadavg()
    n = s["n_images"]
    t = s["timings_s"]
    print(f"\n{n} images matched at {s['matching_image_size_px'][0]} x {s['matching_image_size_px'][1]} px, "
          f"{args.workers} workers; load average before {load0[0]:.2f}, after {load1[0]:.2f} (1 min)")
    print(f"{'stage':<16}{'s':>8}{'s/image':>9}")
    for k, v in t.items():
        print(f"{k:<16}{v:8.2f}{v / n:9.3f}")
    print(f"wall {t['total']:.1f} s = {t['total'] / n:.2f} s per image (target <= 5); CPU {cpu:.1f} s = "
          f"{cpu / n:.2f} s per image")
    print(f"pairs {s['pairs']['count']}, points {s['points']['written']} (mean {s['points']['mean_views_per_point']} "
          f"views), GSD {100 * s['gsd_m']:.2f} cm, DSM {s['dsm_resolution_m']} m, ortho "
          f"{s['ortho']['resolution_m']} m, filled {100 * s['dsm']['hole_fraction']:.2f} %")

    site = json.loads((survey / "truth" / "site.json").read_text())
    f, wa = site["frame"], site["work_area_site_xy_m"]
    bounds = (f["origin_E_m"] + wa[0][0], f["origin_N_m"] + wa[0][1], f["origin_E_m"] + wa[1][0],
              f["origin_N_m"] + wa[1][1])
    d = run / "dense"
    c = compare_dsm(d / "dsm.tif", survey / "truth" / "dsm.tif", d / "dsm_filled_mask.tif", bounds=bounds)
    m = c["measured"]
    print(f"DSM - truth over the work area, measured cells ({m['n']}): RMSE {100 * m['rmse_m']:.2f} cm, median "
          f"{100 * m['median_m']:.2f} cm, NMAD {100 * m['nmad_m']:.2f} cm, p95 |dz| {100 * m['p95_abs_m']:.2f} cm, "
          f"max {100 * m['max_abs_m']:.1f} cm; with filled cells RMSE {100 * c['all']['rmse_m']:.2f} cm; "
          f"completeness {100 * c['completeness']:.2f} %")
    print(f"step's precision estimate {100 * s['dsm_vertical_rmse_m']:.2f} cm "
          f"(ratio to the true RMSE {s['dsm_vertical_rmse_m'] / m['rmse_m']:.2f})")
    offs = target_offsets(d / "ortho.tif", read_targets(survey / "truth" / "targets.csv"))
    ok = [o for o in offs if o.pattern_ok]
    if ok:
        e = np.array([o.offset_m for o in ok])
        print(f"orthophoto targets: {len(ok)}/{len(offs)} found, offset mean {100 * e.mean():.2f} cm, max "
              f"{100 * e.max():.2f} cm ({e.max() / s['ortho']['resolution_m']:.2f} ortho cells)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
