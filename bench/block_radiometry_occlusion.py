"""The block radiometry's occlusion test in each view's own depth map (dense/block_radiometry.py): the
radiometry part solved from the same depth parts' observations without it (before: the depth parts' own
z-buffers only) and with it (after), on a simulated block with injected per-image gains and vignetting and,
optionally, machines (2.5-4 m boxes) on the site - the simulator's tall objects besides its stockpiles.

Simulates the survey (per-image exposure gains 1 +- 15 %, cos^4 vignetting 30 % darker at the corners), runs
the tiled dense step's plan and its depth parts only (phase 1, in this process), then the radiometry part
both ways, each in a fresh process (its peak RSS and wall time measured alone). Prints per way: observations,
hidden ones, the gains against the simulator's truth (log, the block's mean removed: RMS / max %), seconds, peak
RSS, and the per-map cost of the test (seconds per map read, the map's size).

    .venv/bin/python bench/block_radiometry_occlusion.py [--images 40] [--seed 3] [--machines 12] [--tiles 4]
        [--max-image-size 800] [--work DIR]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _simulate(out: Path, args) -> Path:
    from georef_core.cli.simulate_command import fit_site_content, scale_for_image_count
    from georef_core.sim import SimulationOptions, simulate_site

    if (out / "truth" / "radiometry.json").is_file():
        return out
    o = SimulationOptions()
    o.gnss = None
    o, _ = scale_for_image_count(o, args.images)
    o.site = replace(o.site, machines=int(args.machines))
    o, dropped = fit_site_content(o, args.seed)
    o.render = replace(o.render, exposure_spread=0.15, vignetting_cos4=0.30)
    t0 = time.perf_counter()
    simulate_site(out, seed=args.seed, options=o, verbose=False)
    print(f"simulated {out.name} in {time.perf_counter() - t0:.1f} s (dropped: {dropped or 'nothing'})")
    return out


def _options(args) -> dict:
    return {"tiles": args.tiles, "tile_margin": 0.25, "workers": 2, "max_image_size": args.max_image_size}


def _depth_phase(survey: Path, run: Path, args) -> list[dict]:
    """The plan and the depth parts (phase 1); the parts' descriptors are kept in ``run/parts.json``."""
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps import dense_tiles
    from georef_core.steps.contract import Workspace

    f = run / "parts.json"
    if f.is_file():
        return json.loads(f.read_text())
    run.mkdir(parents=True, exist_ok=True)
    oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")
    ws = Workspace(run, run)
    t0 = time.perf_counter()
    parts = [dict(p, index=k) for k, p in enumerate(dense_tiles.plan(ws, _options(args), {}))]
    for p in parts:
        if p.get("phase") == "depth":
            ws.part_dir("dense", p["index"]).mkdir(parents=True, exist_ok=True)
            dense_tiles.part(ws, _options(args), p, None, {})
    print(f"plan and {sum(p.get('phase') == 'depth' for p in parts)} depth parts: {time.perf_counter() - t0:.1f} s")
    f.write_text(json.dumps(parts))
    return parts


def _solve(run: Path, way: str, args) -> dict:
    """The radiometry part's work, one way (in this process: run as a child for its peak RSS)."""
    from georef_core.dense.block_radiometry import OBS_FILE, solve_block
    from georef_core.steps import dense_tiles
    from georef_core.steps.contract import Workspace

    parts = json.loads((run / "parts.json").read_text())
    rad = next(p for p in parts if p.get("phase") == "radiometry")
    ws = Workspace(run, run)
    opts = dense_tiles._options(_options(args))
    t0 = time.perf_counter()
    files = [ws.part_dir("dense", int(j)) / OBS_FILE for j in rad["after"]]
    reader = dense_tiles._depth_map_reader(ws, opts, rad) if way == "after" else None
    result = solve_block(files, vignetting=opts.ortho_options.compensate_vignetting, depth_map_of=reader)
    result["wall_s"] = time.perf_counter() - t0
    result["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if reader is not None:   # one map's size (the test holds one at a time)
        name = next(iter(rad["depth"]))
        got = reader(name)
        result["map_mb"] = got[1].nbytes / 1e6 if got else None
    return result


def _machines(survey: Path):
    f = survey / "truth" / "machines.geojson"
    return len(json.loads(f.read_text()).get("features", [])) if f.is_file() else 0


def _gain_errors(result: dict, truth: dict) -> tuple[float, float]:
    names = sorted(n for n in result["images"] if n in truth["gains"])
    d = np.array([np.mean(result["images"][n][:3]) - np.log(truth["gains"][n]) for n in names])
    d -= d.mean()
    return 100 * float(np.sqrt(np.mean(d ** 2))), 100 * float(np.abs(d).max())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--machines", type=int, default=12)
    ap.add_argument("--tiles", type=int, default=4)
    ap.add_argument("--max-image-size", type=int, default=800)
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_block_occlusion"))
    ap.add_argument("--solve-only", choices=("before", "after"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    tag = f"{args.images}_seed{args.seed}_m{args.machines}"
    run = args.work / f"run_{tag}"
    if args.solve_only:
        print(json.dumps(_solve(run, args.solve_only, args)))
        return 0
    survey = _simulate(args.work / f"survey_{tag}", args)
    parts = _depth_phase(survey, run, args)
    truth = json.loads((survey / "truth" / "radiometry.json").read_text())
    n_img = parts[0]["grid"]["n_images"]
    print(f"{n_img} images, {sum(p.get('phase') == 'depth' for p in parts)} depth parts, "
          f"{sum(p.get('phase') == 'fuse' for p in parts)} tiles, {_machines(survey)} machines placed "
          f"({args.machines} asked)")
    rows = {}
    for way in ("before", "after"):
        cmd = [sys.executable, __file__, "--solve-only", way, "--images", str(args.images), "--seed", str(args.seed),
               "--machines", str(args.machines), "--tiles", str(args.tiles), "--max-image-size",
               str(args.max_image_size), "--work", str(args.work)]
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        rows[way] = json.loads(out.strip().splitlines()[-1])
    for way, r in rows.items():
        rms, mx = _gain_errors(r, truth)
        occ = r.get("occlusion") or {}
        per_map = occ["seconds"] / max(1, occ["views_with_map"]) if occ else None
        print(f"{way:>6}: {r['observations']} observations, hidden {occ.get('hidden', '-')} of tested "
              f"{occ.get('tested', '-')}; gains - truth RMS {rms:.4f} % max {mx:.4f} %; solve {r['seconds']:.2f} s "
              f"(occlusion test {occ.get('seconds', 0):.2f} s, {per_map if per_map is None else round(per_map, 4)} "
              f"s per map of {r.get('map_mb') or 0:.2f} MB); the part's wall {r['wall_s']:.2f} s; peak RSS "
              f"{r['peak_rss_mb']:.0f} MB")
    b, a = rows["before"], rows["after"]
    diff = max(abs(np.mean(a["images"][n][:3]) - np.mean(b["images"][n][:3])) for n in a["images"])
    print(f"largest change of an image's log gain after - before: {100 * diff:.4f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
