"""`georef demo`: what the README's run command shows a new user.

1. A real GNSS baseline (the committed GEONET sample) processed by the PPK engine.
2. The simulated demo site (generated, not committed: about 100 images, rover/base/nav, targets, truth)
   and its PPK trajectory, with the antenna positions at the camera triggers compared to the truth.
Later steps (georeferencing, DSM, volumes, the web application) extend this as they land.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..gnss.rtk_options import RtkOptions

SAMPLE_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "gnss" / "gsi_0759_3040"
GSI_BASE_ECEF_M = (-3978241.958, 3382840.234, 3649900.853)


def register(sub) -> None:
    p = sub.add_parser("demo", help="process the bundled GNSS sample and a simulated demo site, print the results")
    p.add_argument("--out", default="work_out/demo", help="output folder")
    p.add_argument("--small", action="store_true", help="a 12-image demo site instead of ~100 images")
    p.add_argument("--seed", type=int, default=42, help="seed of the simulated site")
    p.set_defaults(func=cmd_demo)


def _real_baseline(out: Path) -> None:
    from ..steps.gnss_solve import run_gnss_solve

    print("1) Real GNSS baseline: GEONET 0759 (rover) to 3040 (base), 3.3 km, L1+L2, static")
    opts = RtkOptions(mode="static", n_bands=2, systems=("G",), filter_direction="combined",
                      base_position_ecef_m=GSI_BASE_ECEF_M)
    s = run_gnss_solve(SAMPLE_DIR / "07590920.05o", SAMPLE_DIR / "30400920.05o",
                       [SAMPLE_DIR / "07590920.05n", SAMPLE_DIR / "30400920.05n"], out / "gsi_static.pos", opts)
    print(f"   {s['epochs']} epochs, {100 * s['fix_rate']:.1f} % fixed -> {s['outputs']['pos']}")


def _simulated_site(out: Path, small: bool, seed: int) -> None:
    from ..sim.scenario import SimulationOptions, simulate_site
    from ..steps.gnss_solve import run_gnss_solve

    site_dir = out / "site"
    print(f"2) Simulated demo site (seed {seed}) -> {site_dir}")
    options = SimulationOptions.small() if small else SimulationOptions()
    res = simulate_site(site_dir, seed=seed, options=options)
    g = res.gnss
    print(f"   {len(res.image_paths)} images, rover {g.rover_path.name}, base {g.base_path.name}; "
          f"generated in {res.generation_time_s:.0f} s")
    opts = RtkOptions(mode="kinematic", n_bands=2, filter_direction="combined")
    s = run_gnss_solve(g.rover_path, g.base_path, g.nav_paths, site_dir / "ppk" / "trajectory.pos", opts)
    print(f"   PPK: {s['epochs']} epochs, {100 * s['fix_rate']:.1f} % fixed, "
          f"{s['events']['fixed']}/{s['events']['count']} camera events on fixed epochs")
    truth = np.load(g.truth_npz)
    import csv

    with open(s["events"]["csv"]) as f:
        rows = list(csv.DictReader(f))
    est = np.array([[float(r["x_ecef_m"]), float(r["y_ecef_m"]), float(r["z_ecef_m"])] for r in rows])
    err = np.linalg.norm(est - truth["event_position_ecef_m"], axis=1)
    ok = np.isfinite(err)
    print(f"   antenna at the camera triggers vs truth: 3D RMS {1000 * np.sqrt(np.mean(err[ok] ** 2)):.1f} mm, "
          f"max {1000 * np.max(err[ok]):.1f} mm -> {s['events']['csv']}")


def cmd_demo(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _real_baseline(out)
    _simulated_site(out, args.small, args.seed)
    return 0
