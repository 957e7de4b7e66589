"""Benchmark: our PPK engine against RTKLIB demo5 (pyrtklib5, EX 2.5.0, in this same process) on the same
files and configurations. Prints, per case: epochs per second for both and the ratio (ours / demo5, > 1
means we are faster), fix rates, agreement on epochs both fix (as they are, and judged: with the fixes the
carrier phase refutes where the two part by more than 5 cm counted as failures, judged_comparison.py), and
where our time goes. Both engines read
the files, solve and write a .pos file; the two run alternately and each engine's best time of the repeats
is used (the least disturbed by other processes on a shared machine). For forward (or backward) runs both
engines also run the other way once, untimed: the judge's witnesses where the carrier phase is not decisive.

    python bench/gnss_vs_rtklib.py            # the seven cases of shared/data/README.md
    python bench/gnss_vs_rtklib.py --all      # every reference case
    python bench/gnss_vs_rtklib.py --repeat 5 car
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.gnss.input_files import load_navigation, load_observations  # noqa: E402
from georef_core.gnss.judged_comparison import judge_fixes  # noqa: E402
from georef_core.gnss.ppk import prepare, solve_files  # noqa: E402
from georef_core.gnss.rtk_options import read_rtklib_conf  # noqa: E402
from georef_core.gnss.solution_io import read_pos, write_pos  # noqa: E402
from tests.gnss.rtklib_cases import reference_cases, reverse_passes, run_demo5  # noqa: E402

DEFAULT = [("cssrlib_2021_265_car_kinematic", "kinematic_l1l2_fwd_fah"),
           ("cssrlib_2021_265_car_kinematic", "kinematic_l1_fwd_fah"),
           ("matrtklib_static_1m", "kinematic_l1l2_fwd_fah"),
           ("matrtklib_static_1m", "kinematic_l1l2_comb_fah"),
           ("ublox_m8p_20181004_walk", "kinematic_l1_fwd_fah"),
           ("ublox_m8p_20181004_walk", "kinematic_l1_comb_fah"),
           ("rtklib_gsi_0759_3040_static", "static_l1l2_fwd_fah")]


def run_ours(conf, rover, base, navs, out):
    opts = read_rtklib_conf(conf).options
    t0 = time.perf_counter()
    sol = solve_files(rover, base, navs, opts)
    write_pos(out, sol)
    return time.perf_counter() - t0, sol


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("select", nargs="*", help="substrings of dataset/case to run")
    ap.add_argument("--all", action="store_true")
    ap.add_argument("--repeat", type=int, default=5, help="runs per engine; the best time is reported")
    args = ap.parse_args()
    cases = reference_cases()
    if not cases:
        print("shared/data/gnss not found (set GEOREF_SHARED_DATA)")
        return 1
    if args.select:
        cases = [c for c in cases if any(s in f"{c[0]}/{c[1]}" for s in args.select)]
    elif not args.all:
        cases = [c for c in cases if (c[0], c[1]) in DEFAULT]
    # warm-up: numba kernels are compiled (or loaded from cache) on first use
    tmp = Path(tempfile.mkdtemp())
    run_ours(cases[0][5], cases[0][2], cases[0][3], cases[0][4], tmp / "warm.pos")
    print(f"{'dataset/case':52s} {'epochs':>6s} {'demo5 ep/s':>10s} {'ours ep/s':>10s} {'ratio':>6s} "
          f"{'fix demo5':>9s} {'fix ours':>8s} {'medH mm':>7s} {'medV mm':>7s} {'>5cm':>5s} | judged: {'fix demo5':>9s} "
          f"{'medH mm':>7s} {'medV mm':>7s} {'>5cm':>5s} {'refuted demo5/ours':>18s} {'by reverse':>10s} "
          "| our time split (s)")
    ratios = []
    for ds, name, rover, base, navs, conf, ref in cases:
        d_times, o_times = [], []
        for _ in range(args.repeat):
            d_times.append(run_demo5(conf, [rover, base, *navs], tmp / "demo5.pos"))
            t, sol = run_ours(conf, rover, base, navs, tmp / "ours.pos")
            o_times.append(t)
        n = len(sol.time_s)
        td, to = min(d_times), min(o_times)
        opts = read_rtklib_conf(conf).options
        data = prepare(load_observations(rover).observations, load_observations(base).observations,
                       load_navigation(navs), opts)[0]
        # forward or backward runs: both engines' passes the other way are the judge's witnesses (untimed)
        reverse = reverse_passes(conf, rover, base, navs, tmp)
        j = judge_fixes(data, opts, read_pos(tmp / "ours.pos"), read_pos(tmp / "demo5.pos"), **reverse)
        c, g = j.raw, j.judged
        split = ", ".join(f"{k} {v:.2f}" for k, v in sol.timings_s.items() if v >= 0.01)
        ratios.append(td / to)
        print(f"{ds + '/' + name:52s} {n:6d} {n / td:10.0f} {n / to:10.0f} {td / to:6.2f} "
              f"{100 * c.fix_rate_ref:8.1f}% {100 * c.fix_rate:7.1f}% {1000 * c.median_horizontal_m:7.1f} "
              f"{1000 * c.median_vertical_m:7.1f} {c.n_beyond_5cm:5d} |         {100 * g.fix_rate_ref:8.1f}% "
              f"{1000 * g.median_horizontal_m:7.1f} {1000 * g.median_vertical_m:7.1f} {g.n_beyond_5cm:5d} "
              f"{j.n_refuted_ref:12d}/{j.n_refuted_ours:<5d} {j.n_refuted_by_reverse:10d} | {split}")
    print(f"\nspeed ratio ours/demo5 (epochs per second, >1 = faster): median {statistics.median(ratios):.2f}, "
          f"min {min(ratios):.2f}, max {max(ratios):.2f} over {len(ratios)} cases")
    return 0


if __name__ == "__main__":
    sys.exit(main())
