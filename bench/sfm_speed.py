"""Benchmark: the SfM step (georef_core.photo.sfm.run_sfm, automatic matcher) against a plain exhaustive
pycolmap run with pycolmap's defaults, on the same images in this same process. Prints, per stage, the
time per image of both and the ratio (plain / ours, > 1 means ours is faster), and both registration
counts and mean reprojection errors.

    python bench/sfm_speed.py                       # caliterra_subset30 from the shared data folder
    python bench/sfm_speed.py --images DIR --threads 2 --matcher spatial
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.photo.sfm import SfmOptions, run_sfm


def default_images() -> Path:
    shared = Path(os.environ.get("GEOREF_SHARED_DATA", REPO.parent / "shared"))
    return shared / "data" / "images" / "caliterra_subset30"


def plain_pycolmap(image_dir: Path, work: Path) -> dict:
    """The reference: what a user would write with pycolmap directly (defaults everywhere)."""
    import pycolmap  # the benchmark's baseline talks to pycolmap itself, on purpose

    pycolmap.logging.minloglevel = 1
    work.mkdir(parents=True, exist_ok=True)
    db = work / "database.db"
    t = {}
    t0 = time.perf_counter()
    pycolmap.extract_features(str(db), str(image_dir))
    t["extraction"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    pycolmap.match_exhaustive(str(db))
    t["matching"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    models = pycolmap.incremental_mapping(str(db), str(image_dir), str(work / "sparse"))
    t["mapping"] = time.perf_counter() - t0
    best = max(models.values(), key=lambda r: r.num_reg_images()) if models else None
    n_images = len([p for p in image_dir.iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png", ".tif", ".tiff")])
    return {"timings_s": t, "n_images": n_images, "registered": best.num_reg_images() if best else 0,
            "error_px": best.compute_mean_reprojection_error() if best else float("nan")}


def ours(image_dir: Path, work: Path, args) -> dict:
    opts = SfmOptions(num_threads=args.threads, matcher=args.matcher, camera_model=args.camera_model)
    r = run_sfm(image_dir, work, opts)
    return {"timings_s": r.timings_s, "n_images": r.n_images, "registered": r.n_registered,
            "error_px": r.mean_reprojection_error_px, "matcher": r.matcher}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=Path, default=default_images())
    ap.add_argument("--threads", type=int, default=2, help="our pipeline's threads (the plain run uses all cores)")
    ap.add_argument("--matcher", default="auto", choices=("auto", "exhaustive", "spatial", "sequential"))
    ap.add_argument("--camera-model", default="SIMPLE_RADIAL")
    args = ap.parse_args(argv)
    if not args.images.is_dir():
        print(f"image folder not found: {args.images}", file=sys.stderr)
        return 2
    print(f"images: {args.images}  (cores: {os.cpu_count()})")
    with tempfile.TemporaryDirectory(prefix="georef_sfm_bench_") as tmp:
        a = ours(args.images, Path(tmp) / "ours", args)
        b = plain_pycolmap(args.images, Path(tmp) / "plain")
    n = a["n_images"]
    print(f"\n{'stage':<12}{'ours s/img':>12}{'plain s/img':>13}{'ratio':>8}")
    for stage in ("extraction", "matching", "mapping"):
        ta, tb = a["timings_s"][stage] / n, b["timings_s"][stage] / n
        print(f"{stage:<12}{ta:>12.3f}{tb:>13.3f}{tb / ta:>8.2f}")
    sa = sum(a["timings_s"][k] for k in ("extraction", "matching", "mapping"))
    sb = sum(b["timings_s"].values())
    print(f"{'total':<12}{sa / n:>12.3f}{sb / n:>13.3f}{sb / sa:>8.2f}   (ratio = plain / ours, > 1: ours faster)")
    print(f"\nours  ({a['matcher']}): registered {a['registered']}/{n}, mean reprojection error {a['error_px']:.3f} px")
    print(f"plain (exhaustive): registered {b['registered']}/{b['n_images']}, "
          f"mean reprojection error {b['error_px']:.3f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
