"""The real datasets of shared/data/gnss and their RTKLIB reference cases (conf + .pos)."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def shared_gnss_dir() -> Path | None:
    """The shared GNSS data folder: $GEOREF_SHARED_DATA (the 'shared' folder, its 'data' or 'data/gnss')
    or <repo>/../shared; None when absent (tests that need it skip)."""
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else REPO.parent / "shared"
    for cand in (root / "data" / "gnss", root / "gnss", root):
        if (cand / "matrtklib_static_1m").is_dir():
            return cand
    return None


DATASETS = {
    "rtklib_gsi_0759_3040_static": ("07590920.05o", "30400920.05o", ["07590920.05n", "30400920.05n"]),
    "cssrlib_2021_265_car_kinematic": ("SEPT265G.21O", "3034265G.21O", ["SEPT2650.21P"]),
    "matrtklib_static_1m": ("rover.obs", "base.obs", ["base.nav"]),
    "ublox_m8p_20181004_walk": ("rover-20181004-1532.obs", "base-20181004-1452.obs", ["base-20181004-1452.nav"]),
}


def reference_cases(build: str = "demo5_ex251"):
    """(dataset, case, rover, base, navs, conf, ref_pos) for every reference solution present."""
    root = shared_gnss_dir()
    if root is None:
        return []
    out = []
    for ds, (rover, base, navs) in DATASETS.items():
        ref_dir = root / "reference" / build / ds
        if not ref_dir.is_dir():
            continue
        for conf in sorted(ref_dir.glob("*.conf")):
            out.append((ds, conf.stem, root / ds / rover, root / ds / base, [root / ds / n for n in navs], conf,
                        conf.with_suffix(".pos")))
    return out
