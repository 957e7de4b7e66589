"""The dense step on a large simulated survey, in tiles (steps/dense_tiles.py): time per image of each stage,
peak memory, and the speed-up of 2 (or more) worker processes over 1 running the same tiles.

Simulates a survey (``georef simulate --images N``: 1600 x 1200 images, default 200, seed 5; or ``--survey``),
makes its true orientations (as bench/dense_speed.py), then for each process count P in ``--processes``
(default 1,2): the plan in this process, the parts in a pool of P fresh processes (multiprocessing, one part
per child: the same ``dense_tiles.part`` a Celery worker runs through worker/pipeline.run_part) - first the
depth parts (each image's depth maps once), then the tiles (fusion, DSM, orthophoto from those maps) - the
merge in this process. CPU time: the children's user + system time (ru_utime + ru_stime, imports included)
plus this process's during plan and merge; ``--one-run`` gives the same for the one-run step, and the ratio. Prints per P: wall seconds of plan / parts / merge, the
speed-up against P = 1 in the same script, the parallel fraction (Amdahl) from it and the projected 4-worker
speed-up; the stage times per image (summed over the tiles: the tiles' margins make some images work twice);
the peak RSS of the largest part of each phase (VmHWM of the children, from /proc/self/status: their
ru_maxrss would start at this process's RSS at the fork) and of this process during the plan and during the
merge (VmHWM reset before each, /proc/self/clear_refs); the plan's stages (grid["plan_s"]).
With ``--threads`` (default 1) each part uses that many threads, so P processes use P cores.

    .venv/bin/python bench/scale_dense.py [--images 200] [--tiles 0] [--processes 1,2] [--threads 1] [--tile-margin 0.25]
        [--max-image-size 1600] [--one-run] [--survey DIR] [--work DIR] [--seed 5]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import shutil
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _hwm_kb() -> int:
    """Peak resident memory of this process's own image (VmHWM, kB). Not ru_maxrss: a spawned child's ru_maxrss
    starts at its parent's RSS at the fork (Linux keeps the larger across exec), so every part would report at
    least the plan process's memory."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _reset_hwm() -> None:
    """Start VmHWM again from the current RSS (Linux: /proc/self/clear_refs), so that the plan's and the merge's
    peaks are read apart; where that cannot be done the figure is the process's peak so far."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _run_part(args) -> tuple[int, float, int, float]:
    out_dir, options, part = args
    from georef_core.steps.contract import Workspace
    from georef_core.steps.dense_tiles import part as run_part

    t0 = time.perf_counter()
    ws = Workspace(out_dir, out_dir)
    ws.part_dir("dense", part["index"]).mkdir(parents=True, exist_ok=True)
    run_part(ws, options, part, None, {})
    return part["index"], time.perf_counter() - t0, _hwm_kb(), _cpu_s()


def _makespan(part_s: list[float], workers: int) -> float:
    """Wall time of ``part_s`` (in the order given) on ``workers`` processes that each take the next part when
    free (as Pool.map with chunksize 1 hands them out)."""
    free = [0.0] * max(1, workers)
    for t in part_s:
        k = free.index(min(free))
        free[k] += t
    return max(free)


def _one_run(args) -> tuple[float, int, float]:
    out_dir, options = args
    from georef_core.steps.dense import run_dense

    t0 = time.perf_counter()
    run_dense(out_dir, dict(options, tiles=1))
    return time.perf_counter() - t0, _hwm_kb(), _cpu_s()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=200)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--tiles", type=int, default=0, help="0: the step's automatic count")
    ap.add_argument("--processes", default="1,2")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--tile-margin", type=float, default=0.25, help="footprints (the step's tile_margin)")
    ap.add_argument("--max-image-size", type=int, default=1600)
    ap.add_argument("--survey", type=Path)
    ap.add_argument("--one-run", action="store_true", help="also the step in one run (tiles 1): time and peak RSS")
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_scale_dense"))
    args = ap.parse_args(argv)

    from simulated_surveys import simulated_survey
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps.contract import Workspace
    from georef_core.steps.dense_tiles import merge, plan

    survey = args.survey
    if survey is None:
        survey, dt = simulated_survey(args.work, args.images, args.seed)
        if survey is None:
            return 2
        if dt is not None:
            print(f"simulated {args.images} images in {dt:.1f} s = {dt / args.images:.2f} s per image "
                  f"(1000 images: ~{1000 * dt / args.images / 60:.0f} min)")
    n_img = len(json.loads((survey / "truth" / "camera_poses.json").read_text()).get("images") or []) or args.images
    options = {"tiles": args.tiles, "tile_margin": args.tile_margin, "workers": args.threads,
               "max_image_size": args.max_image_size}
    results = {}
    for P in [int(x) for x in args.processes.split(",")]:
        run = args.work / f"run_p{P}"
        shutil.rmtree(run, ignore_errors=True)
        oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")
        ws = Workspace(run, run)
        _reset_hwm()
        t0, c0 = time.perf_counter(), _cpu_s()
        parts = [dict(p, index=k) for k, p in enumerate(plan(ws, options, {}))]
        t_plan, cpu_main = time.perf_counter() - t0, _cpu_s() - c0
        plan_peak_mb = _hwm_kb() / 1024   # this process during the plan (VmHWM reset before it)
        plan_s = (parts[0].get("grid") or {}).get("plan_s") or {}
        print(f"plan: {t_plan:.1f} s ({', '.join(f'{k} {v:.1f}' for k, v in plan_s.items())}), {len(parts)} parts; "
              f"this process's peak RSS (VmHWM) during the plan {plan_peak_mb:.0f} MB", flush=True)
        if len(parts) < 2:
            print("one tile: set --tiles 2 or more")
            return 2
        t1 = time.perf_counter()
        ctx = mp.get_context("spawn")
        done = []
        # phase 1 (depth parts), then phase 2 (the tiles read the depth maps: their "after")
        phase_s = {}
        for phase in ("depth", "radiometry", "fuse"):
            tp = time.perf_counter()
            with ctx.Pool(P, maxtasksperchild=1) as pool:
                done += [d + (phase,) for d in pool.map(_run_part, [(run, options, p) for p in parts
                                                                     if p.get("phase", "fuse") == phase],
                                                        chunksize=1)]
            phase_s[phase] = time.perf_counter() - tp
            mine = [d for d in done if d[4] == phase]
            if mine:
                print(f"  {phase}: {len(mine)} parts, {phase_s[phase]:.1f} s wall, part times "
                      f"{min(d[1] for d in mine):.1f}-{max(d[1] for d in mine):.1f} s, peak RSS (VmHWM) of the "
                      f"largest {max(d[2] for d in mine) / 1024:.0f} MB; load average {os.getloadavg()[0]:.2f}",
                      flush=True)
        t_parts = time.perf_counter() - t1
        _reset_hwm()
        t2, c2 = time.perf_counter(), _cpu_s()
        summary = merge(ws, options, parts, None, {})
        t_merge, cpu_main = time.perf_counter() - t2, cpu_main + _cpu_s() - c2
        merge_peak_mb = _hwm_kb() / 1024
        wall = time.perf_counter() - t0
        peak_child_mb = max(d[2] for d in done) / 1024
        peak = {ph: max((d[2] / 1024 for d in done if d[4] == ph), default=0.0)
                for ph in ("depth", "radiometry", "fuse")}
        results[P] = {"wall": wall, "plan": t_plan, "parts": t_parts, "merge": t_merge, "summary": summary,
                      "peak_part_mb": peak_child_mb, "peak_depth_part_mb": peak["depth"],
                      "peak_tile_part_mb": peak["fuse"], "peak_radiometry_part_mb": peak["radiometry"],
                      "phase_s": phase_s, "plan_s": plan_s, "peak_main_after_plan_mb": plan_peak_mb,
                      "peak_main_mb": max(plan_peak_mb, merge_peak_mb), "peak_merge_mb": merge_peak_mb,
                      "cpu_s": cpu_main + sum(d[3] for d in done),
                      "cpu_depth_s": sum(d[3] for d in done if d[4] == "depth"),
                      "cpu_tiles_s": sum(d[3] for d in done if d[4] == "fuse"), "cpu_plan_merge_s": cpu_main,
                      "part_s": sorted(round(d[1], 1) for d in done)}
        tl = summary["tiles"]
        print(f"\nP = {P} processes x {args.threads} thread(s), {len(parts)} parts ({len(tl['per_depth_part'])} depth "
              f"parts, then {tl['count']} tiles {tl['shape']}), {n_img} images: depth maps computed "
              f"{tl['depth_maps_computed']} (twice: {len(tl['depth_maps_computed_twice'])}); tiles fused "
              f"{tl['images_processed']} tile-images (overlap factor {tl['overlap_factor']}): wall {wall:.1f} s = "
              f"{wall / n_img:.2f} s per image (plan {t_plan:.1f}, parts {t_parts:.1f}, merge {t_merge:.1f}); "
              f"part times {results[P]['part_s']}")
        r = results[P]
        # a projection from this run's part times: the phases one after the other (each waits for the last
        # part of the one before), plan and merge serial; part times as measured here (on a loaded machine)
        by_phase = {ph: [d[1] for d in done if d[4] == ph] for ph in ("depth", "radiometry", "fuse")}
        proj = {w: t_plan + t_merge + sum(_makespan(ts, w) for ts in by_phase.values()) for w in (1, 2, 4, 8)}
        serial = t_plan + t_merge + sum(by_phase["radiometry"])
        f_serial = serial / proj[1]
        r.update(projected_wall_s=proj, serial_fraction=f_serial)
        print(f"  projection from the part times (not measured): 1 worker {proj[1]:.0f} s, 2: {proj[2]:.0f} s, "
              f"4: {proj[4]:.0f} s, 8: {proj[8]:.0f} s; 4 vs 1: {proj[1] / proj[4]:.2f}x; serial (plan + "
              f"radiometry + merge) {serial:.1f} s = fraction {f_serial:.3f} of the 1-worker time (Amdahl "
              f"bound 4 workers: {1 / (f_serial + (1 - f_serial) / 4):.2f}x)")
        print(f"  CPU {r['cpu_s']:.1f} s (depth parts {r['cpu_depth_s']:.1f}, tiles {r['cpu_tiles_s']:.1f}, plan + "
              f"merge {r['cpu_plan_merge_s']:.1f})")
        print(f"  peak RSS (VmHWM): largest depth part {peak['depth']:.0f} MB, radiometry part "
              f"{peak['radiometry']:.0f} MB, largest tile {peak['fuse']:.0f} MB, main process: plan "
              f"{plan_peak_mb:.0f} MB, merge {merge_peak_mb:.0f} MB; load average {os.getloadavg()[0]:.2f}")
    if args.one_run:
        run = args.work / "run_one"
        shutil.rmtree(run, ignore_errors=True)
        oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")
        with mp.get_context("spawn").Pool(1) as pool:
            t_one, rss_one, cpu_one = pool.apply(_one_run, ((run, options),))
        r0 = next(iter(results.values()))
        print(f"\none run (tiles 1, 1 process): {t_one:.1f} s = {t_one / n_img:.2f} s per image, CPU {cpu_one:.1f} s, "
              f"peak RSS {rss_one / 1024:.0f} MB; tiles / one run: CPU {r0['cpu_s'] / cpu_one:.2f}, time "
              f"{r0['wall'] / t_one:.2f}, peak memory {r0['peak_part_mb'] / (rss_one / 1024):.2f}")
        r0.update(one_run_s=t_one, one_run_cpu_s=cpu_one, one_run_peak_mb=rss_one / 1024)
    base = results.get(1)
    r1 = next(iter(results.values()))
    t = r1["summary"]["timings_s"]
    print(f"\nstage times summed over the tiles (P = {next(iter(results))}), per image of the survey:")
    for k, v in t.items():
        print(f"  {k:<16}{v:9.1f} s {v / n_img:8.3f} s/image")
    if base:
        for P, r in results.items():
            if P == 1:
                continue
            s = base["wall"] / r["wall"]
            s_parts = base["parts"] / r["parts"]
            p = min(1.0, max(0.0, (1 - 1 / s) / (1 - 1 / P)))
            s4 = 1 / ((1 - p) + p / 4)
            print(f"speed-up {P} vs 1 process: {s:.2f}x overall ({s_parts:.2f}x on the parts); parallel fraction "
                  f"(Amdahl) {p:.3f}; projected 4 workers on 4+ free cores: {s4:.2f}x (a projection)")
        serial = base["plan"] + base["merge"]
        p_direct = base["parts"] / base["wall"]
        print(f"serial part of the 1-process run (plan + merge): {serial:.1f} s of {base['wall']:.1f} s; with tiles "
              f"balanced, 4 workers: {1 / ((1 - p_direct) + p_direct / 4):.2f}x (a projection from the timings)")
    (args.work / "scale_dense_result.json").write_text(json.dumps(
        {str(P): {k: v for k, v in r.items() if k != "summary"} for P, r in results.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
