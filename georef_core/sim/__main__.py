"""``python -m georef_core.sim OUT_DIR [--seed N] [--small] ...``: simulate a survey into OUT_DIR."""

from __future__ import annotations

import argparse
from dataclasses import replace

from .scenario import SimulationOptions, simulate_site


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m georef_core.sim", description=__doc__)
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--small", action="store_true", help="12 images of 640x480 over a 36 x 16 m site")
    ap.add_argument("--height", type=float, help="flight height above take-off (m)")
    ap.add_argument("--speed", type=float, help="ground speed on the lines (m/s)")
    ap.add_argument("--size", type=float, nargs=2, metavar=("EAST_M", "NORTH_M"), help="work area size")
    ap.add_argument("--image-size", type=int, nargs=2, metavar=("W", "H"), help="image size in pixels")
    ap.add_argument("--workers", type=int, help="images rendered concurrently")
    ap.add_argument("--no-images", action="store_true", help="site, flight and truth only")
    a = ap.parse_args(argv)
    o = SimulationOptions.small() if a.small else SimulationOptions()
    if a.height is not None:
        o.flight = replace(o.flight, height_m=a.height)
    if a.speed is not None:
        o.flight = replace(o.flight, speed_m_s=a.speed)
    if a.size is not None:
        o.site = replace(o.site, size_m=tuple(a.size))
    if a.image_size is not None:
        o.camera = o.camera.scaled(*a.image_size)
    if a.workers is not None:
        o.workers = a.workers
    if a.no_images:
        o.write_images = False
    simulate_site(a.out_dir, seed=a.seed, options=o)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
