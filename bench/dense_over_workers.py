"""The tiled dense step through the real platform: the API, an embedded database (SQLite), local storage and
a real Celery worker process (prefork, ``--concurrency K``), against the simulator's truth and against the
same survey in one part (``tiles`` 1).

Simulates a survey (``georef simulate --images N --seed S --image-size W H``, with its GNSS logs, so that the
gnss and georef steps give cm-level orientations), uploads it (truth/ left out) and runs, each on a fresh
worker: a preparation run (gnss + georef, reused by hash by every later run), then for each K in
``--concurrency`` the dense step forced again (``rerun`` from dense) with ``tiles`` T, then once with ``tiles``
1 on a 1-process worker. Prints per run: the wall time of each step (started_at .. finished_at), the dense
step's phases and per-part times with the worker process that ran each (the run_step_parts table: worker =
host:pid of the Celery child), the peak RSS (VmHWM, /proc/<pid>/status, sampled every 0.5 s) of each worker
child and the load average; the speed-up of K = 2 over K = 1; each DSM against truth/dsm.tif over the work
area (georef_core.dense.dsm_compare: RMSE, median, p95 |dz| of the measured cells, completeness); and the
tiled DSM against the one-part DSM along the tile cuts (cells within ``--band`` cells of an inner core edge)
and elsewhere (median / p95 |dz| of tiled - one part; and each DSM - truth in the band and elsewhere).

    nice -n 10 .venv/bin/python bench/dense_over_workers.py [--images 24] [--seed 5] [--image-size 640 480]
        [--tiles 4] [--concurrency 2,1] [--max-image-size 800] [--no-one-part] [--work DIR] [--band 3]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def _simulate(work: Path, images: int, seed: int, size: tuple[int, int]) -> Path:
    from georef_core.cli.main import main as georef

    survey = work / f"survey_{images}_{size[0]}x{size[1]}_seed{seed}"
    if (survey / "truth" / "dsm.tif").is_file():
        return survey
    shutil.rmtree(survey, ignore_errors=True)
    t0 = time.perf_counter()
    if georef(["simulate", str(survey), "--images", str(images), "--seed", str(seed), "--image-size",
               str(size[0]), str(size[1]), "--quiet"]):
        raise SystemExit(f"georef simulate {survey} failed")
    print(f"simulated {survey.name} in {time.perf_counter() - t0:.1f} s", flush=True)
    return survey


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...: comm may hold spaces, so split after its closing parenthesis
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            out.append(int(d.name))
    return out


def _vm(pid: int) -> dict:
    out = {}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(("VmHWM:", "VmRSS:")):
                out[line.split(":")[0]] = int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return out


class Monitor:
    """Samples the worker's children every ``every_s``: their peak RSS (VmHWM, kB) and the 1-min load."""

    def __init__(self, pid: int, every_s: float = 0.5):
        self.pid, self.every_s = pid, every_s
        self.hwm_kb: dict[int, int] = {}
        self.load: list[float] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._loop, daemon=True)
        self._t.start()

    def _loop(self):
        while not self._stop.is_set():
            for c in _children(self.pid):
                v = _vm(c).get("VmHWM")
                if v:
                    self.hwm_kb[c] = max(self.hwm_kb.get(c, 0), v)
            self.load.append(os.getloadavg()[0])
            self._stop.wait(self.every_s)

    def stop(self):
        self._stop.set()
        self._t.join()


def _start_worker(p, name: str, concurrency: int, timeout_s: float = 120):
    """A real Celery worker process with the prefork pool, ``concurrency`` children, as deployed
    (tests/backend/platform_helpers.start_worker)."""
    from tests.backend.platform_helpers import start_worker

    return start_worker(p, "".join(ch if ch.isalnum() else "-" for ch in name), timeout_s=timeout_s,
                        concurrency=concurrency)


def _t(s: str | None) -> float | None:
    return datetime.fromisoformat(s).timestamp() if s else None


def _run_on_worker(p, api, label: str, concurrency: int, start, timeout_s: float) -> dict:
    """Starts a fresh worker, posts the run (``start()`` -> run id), waits, stops the worker; the run's steps,
    its dense parts (from run_step_parts) and the children's peak RSS."""
    from backend.models.runs import RunStepPart
    from sqlalchemy import select
    from tests.backend.platform_helpers import stop_worker, wait_run

    w = _start_worker(p, label, concurrency)
    mon = Monitor(w.proc.pid)
    t0 = time.perf_counter()
    run_id = start()
    final = wait_run(api, run_id, timeout_s=timeout_s)
    wall = time.perf_counter() - t0
    mon.stop()
    stop_worker(w)
    p.workers.remove(w)
    if final["state"] != "succeeded":
        raise SystemExit(f"{label}: run {final['state']}: {final.get('error')} "
                         f"{[(s['name'], s['state'], s.get('error')) for s in final['step_details']]}")
    steps = {}
    for s in final["step_details"]:
        a, b = _t(s["started_at"]), _t(s["finished_at"])
        steps[s["name"]] = {"state": s["state"], "wall_s": (b - a) if a and b else None,
                            "reused": bool(s.get("reused_from_step_id")), "summary": s.get("summary") or {},
                            "started": a, "finished": b}
    # a split step is claimed twice (the plan, then the merge); its started_at is the plan's claim (jobs.claim_step
    # keeps it through the merge: issue 26); the step's first log line is kept as a cross-check (the earlier of the two)
    for name, s in steps.items():
        r = api.get(f"/api/v1/runs/{run_id}/logs", params={"limit": 5, "step": name})
        assert r.status_code == 200, r.text
        logs = r.json()
        logs = logs["items"] if isinstance(logs, dict) else logs
        mine = [_t(e["created_at"]) for e in logs if e.get("step_name") == name]
        s["first_log"] = min(mine) if mine else None
        if s["first_log"] and s["finished"] and not s["reused"]:
            s["wall_s"] = s["finished"] - min(s["first_log"], s["started"] or s["first_log"])
    with p.db().session() as db:
        rows = db.scalars(select(RunStepPart).where(RunStepPart.run_id == run_id).order_by(RunStepPart.index))
        parts = [{"index": r.index, "phase": (r.descriptor or {}).get("phase", "fuse"), "worker": r.worker,
                  "state": r.state, "start": r.started_at.timestamp() if r.started_at else None,
                  "end": r.finished_at.timestamp() if r.finished_at else None,
                  "images": len((r.descriptor or {}).get("images") or [])} for r in rows]
    for q in parts:
        q["seconds"] = (q["end"] - q["start"]) if q["start"] and q["end"] else None
    return {"label": label, "run_id": run_id, "concurrency": concurrency, "wall_s": wall, "steps": steps,
            "parts": parts, "child_peak_mb": {pid: kb / 1024 for pid, kb in mon.hwm_kb.items()},
            "load_median": float(np.median(mon.load)) if mon.load else None,
            "load_range": [min(mon.load), max(mon.load)] if mon.load else None}


def _print_run(r: dict) -> None:
    print(f"\n== {r['label']}: worker --concurrency {r['concurrency']}, run wall {r['wall_s']:.1f} s (post to "
          f"finished); load average (1 min) median {r['load_median']:.2f}, {r['load_range'][0]:.2f}-"
          f"{r['load_range'][1]:.2f}")
    for name, s in r["steps"].items():
        extra = " (reused)" if s["reused"] else ""
        ws = f"{s['wall_s']:.1f} s" if s["wall_s"] is not None else "-"
        print(f"  step {name:<8} {s['state']:<10} {ws}{extra}")
    parts = r["parts"]
    dense = r["steps"].get("dense", {})
    if parts:
        for ph in ("depth", "radiometry", "fuse"):
            mine = [q for q in parts if q["phase"] == ph and q["seconds"] is not None]
            if not mine:
                continue
            span = max(q["end"] for q in mine) - min(q["start"] for q in mine)
            print(f"  phase {ph:<10} {len(mine)} parts, {span:.1f} s wall, part times "
                  + ", ".join(f"{q['index']}:{q['seconds']:.1f}" for q in mine) + " s")
        first = min(q["start"] for q in parts if q["start"])
        last = max(q["end"] for q in parts if q["end"])
        if dense.get("first_log") and dense.get("finished"):
            print(f"  dense: plan (first log line to first part) {first - dense['first_log']:.1f} s, parts "
                  f"{last - first:.1f} s, "
                  f"merge (last part to finished) {dense['finished'] - last:.1f} s")
        by_worker: dict[str, list[int]] = {}
        for q in parts:
            by_worker.setdefault(q["worker"] or "?", []).append(q["index"])
        for wk, idx in by_worker.items():
            print(f"  worker process {wk}: parts {idx}")
    peaks = sorted(r["child_peak_mb"].items())
    print("  peak RSS (VmHWM) of the worker children: "
          + ", ".join(f"pid {pid} {mb:.0f} MB" for pid, mb in peaks))


def _download(api, run_id: str, rel: str, dest: Path) -> Path:
    r = api.get(f"/api/v1/runs/{run_id}/results/files/{rel}")
    if r.status_code != 200:
        raise SystemExit(f"{rel} of run {run_id}: HTTP {r.status_code} {r.text[:200]}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_bytes(r.content)
    return dest


def _work_area(survey: Path) -> tuple[float, float, float, float]:
    site = json.loads((survey / "truth" / "site.json").read_text())
    f, wa = site["frame"], site["work_area_site_xy_m"]
    return (f["origin_E_m"] + wa[0][0], f["origin_N_m"] + wa[0][1], f["origin_E_m"] + wa[1][0],
            f["origin_N_m"] + wa[1][1])


def _read(path: Path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(1, masked=True).filled(np.nan).astype(np.float64), ds.transform


def _truth_on(path_truth: Path, transform, shape, crs) -> np.ndarray:
    import rasterio
    from rasterio.warp import Resampling, reproject

    out = np.full(shape, np.nan)
    with rasterio.open(path_truth) as t:
        src = t.read(1).astype(np.float64)
        if t.nodata is not None:
            src[src == t.nodata] = np.nan
        reproject(src, out, src_transform=t.transform, src_crs=t.crs, dst_transform=transform, dst_crs=crs,
                  resampling=Resampling.average, src_nodata=np.nan, dst_nodata=np.nan)
    return out


def _on_grid(path: Path, transform, shape, crs) -> np.ndarray:
    """A DSM on another DSM's grid (nearest cell: the tiled and the one-part grids share the cell size and
    lie on its multiples, so each cell is taken as it is; their extents differ)."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    out = np.full(shape, np.nan)
    with rasterio.open(path) as ds:
        src = ds.read(1, masked=True).filled(np.nan).astype(np.float64)
        reproject(src, out, src_transform=ds.transform, src_crs=ds.crs, dst_transform=transform, dst_crs=crs,
                  resampling=Resampling.nearest, src_nodata=np.nan, dst_nodata=np.nan)
    return out


def _band_mask(transform, shape, cores: list, band_cells: int) -> np.ndarray:
    """Cells whose centre lies within ``band_cells`` cells of an inner edge of a tile core (an edge that is not
    on the block's outer boundary)."""
    res = abs(transform.a)
    rows, cols = np.indices(shape)
    e = transform.c + (cols + 0.5) * transform.a
    n = transform.f + (rows + 0.5) * transform.e
    west = min(c[0] for c in cores)
    south = min(c[1] for c in cores)
    east = max(c[2] for c in cores)
    north = max(c[3] for c in cores)
    xs = sorted({c[0] for c in cores if c[0] > west + res / 2} | {c[2] for c in cores if c[2] < east - res / 2})
    ys = sorted({c[1] for c in cores if c[1] > south + res / 2} | {c[3] for c in cores if c[3] < north - res / 2})
    m = np.zeros(shape, bool)
    for x in xs:
        m |= np.abs(e - x) <= band_cells * res
    for y in ys:
        m |= np.abs(n - y) <= band_cells * res
    return m


def _q(d: np.ndarray) -> str:
    if d.size == 0:
        return "no cells"
    a = np.abs(d)
    return (f"n {d.size}, median {1000 * np.median(d):+.3f} mm, median |dz| {1000 * np.median(a):.3f} mm, "
            f"p95 |dz| {1000 * np.percentile(a, 95):.3f} mm, RMSE {1000 * np.sqrt(np.mean(d * d)):.3f} mm, "
            f"max |dz| {1000 * np.max(a):.1f} mm")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=24)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--image-size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"))
    ap.add_argument("--tiles", type=int, default=4)
    ap.add_argument("--concurrency", default="2,1", help="worker processes (prefork) for the tiled runs")
    ap.add_argument("--max-image-size", type=int, default=800)
    ap.add_argument("--no-one-part", action="store_true", help="skip the tiles = 1 run")
    ap.add_argument("--band", type=int, default=3, help="cells either side of a tile cut counted as the seam")
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per run")
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_dense_workers"))
    args = ap.parse_args(argv)
    if args.tiles < 2:
        ap.error("--tiles: 2 or more (the one-part run is made anyway)")

    args.work.mkdir(parents=True, exist_ok=True)
    survey = _simulate(args.work, args.images, args.seed, tuple(args.image_size))
    n_img = len(list((survey / "images").glob("*")))
    from georef_core.dense.dsm_compare import compare_dsm
    from tests.backend.platform_helpers import Api, add_user, close_platform, make_platform, upload_bytes, zip_folder

    tag = f"{args.images}_{args.image_size[0]}_s{args.seed}"
    pdir = args.work / f"platform_{tag}"
    shutil.rmtree(pdir, ignore_errors=True)
    p = make_platform(pdir, "embedded", queue="densew")
    results = []
    try:
        add_user(p, "dense@example.org", org_admin=True)
        api = Api(p, "dense@example.org")
        meta = json.loads((survey / "survey.json").read_text())
        site = api.post("/api/v1/sites", json={"name": "dense", "crs": meta["project_crs"]}).json()
        sv = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": f"dense {tag}"}).json()
        t0 = time.perf_counter()
        r = upload_bytes(api, sv["id"], "survey.zip", zip_folder(survey, skip=("truth/",)), chunk=8 << 20)
        assert r.status_code == 200, r.text
        print(f"survey {survey.name}: {n_img} images of {args.image_size[0]} x {args.image_size[1]} px, uploaded "
              f"in {time.perf_counter() - t0:.1f} s; platform: embedded (SQLite, local storage, Celery over "
              f"SQLite), prefork workers; {os.cpu_count()} CPUs", flush=True)

        def post_prep():
            return api.post(f"/api/v1/surveys/{sv['id']}/runs", json={"steps": ["gnss", "georef"]}).json()["id"]

        prep = _run_on_worker(p, api, "prep (gnss + georef)", 2, post_prep, args.timeout)
        _print_run(prep)
        dense_opts = {"tiles": args.tiles, "max_image_size": args.max_image_size, "workers": 1}

        def rerun(opts):
            def go():
                r = api.post(f"/api/v1/runs/{prep['run_id']}/rerun",
                             json={"from_step": "dense", "settings": {"dense": opts}})
                assert r.status_code in (200, 201), r.text
                return r.json()["id"]
            return go

        for k in [int(x) for x in args.concurrency.split(",")]:
            res = _run_on_worker(p, api, f"tiles {args.tiles}, K {k}", k, rerun(dense_opts), args.timeout)
            _print_run(res)
            results.append(res)
        if not args.no_one_part:
            res = _run_on_worker(p, api, "tiles 1 (one part), K 1", 1, rerun(dict(dense_opts, tiles=1)),
                                 args.timeout)
            _print_run(res)
            results.append(res)
        for res in results:
            d = args.work / f"out_{tag}" / res["label"].split(",")[0].replace(" ", "") / f"K{res['concurrency']}"
            res["dsm"] = _download(api, res["run_id"], "dense/dsm.tif", d / "dsm.tif")
            res["mask"] = _download(api, res["run_id"], "dense/dsm_filled_mask.tif", d / "dsm_filled_mask.tif")
    finally:
        close_platform(p)

    tiled = [r for r in results if r["parts"]]
    speed = {r["concurrency"]: r for r in tiled}
    print()
    if 1 in speed and 2 in speed:
        a, b = speed[1], speed[2]
        da, db_ = a["steps"]["dense"]["wall_s"], b["steps"]["dense"]["wall_s"]
        print(f"speed-up of the dense step, K 2 vs K 1 (same tiles, same machine): {da / db_:.2f}x ({da:.1f} s -> "
              f"{db_:.1f} s); load median {a['load_median']:.2f} (K 1), {b['load_median']:.2f} (K 2)")
        pa = {ph: sum(q["seconds"] for q in a["parts"] if q["phase"] == ph) for ph in ("depth", "radiometry", "fuse")}
        pb = {ph: sum(q["seconds"] for q in b["parts"] if q["phase"] == ph) for ph in ("depth", "radiometry", "fuse")}
        print(f"  summed part seconds K 1 {sum(pa.values()):.1f}, K 2 {sum(pb.values()):.1f} (ratio "
              f"{sum(pb.values()) / sum(pa.values()):.2f}: > 1 when the two processes slow each other)")

    truth = survey / "truth" / "dsm.tif"
    bounds = _work_area(survey)
    for r in results:
        c = compare_dsm(r["dsm"], truth, r["mask"], bounds=bounds)
        r["truth"] = c
        m = c["measured"]
        print(f"{r['label']}: DSM - truth over the work area, measured cells {m['n']}: RMSE {100 * m['rmse_m']:.2f} cm, "
              f"median {100 * m['median_m']:+.2f} cm, p95 |dz| {100 * m['p95_abs_m']:.2f} cm; with filled cells "
              f"RMSE {100 * c['all']['rmse_m']:.2f} cm; completeness {100 * c['completeness']:.2f} %")
    one = next((r for r in results if not r["parts"]), None)
    if one is not None and tiled:
        import rasterio

        z1, tr1 = _read(one["dsm"])
        with rasterio.open(one["dsm"]) as ds:
            crs = ds.crs
        tt = _truth_on(truth, tr1, z1.shape, crs)
        cores = [t["core"] for t in tiled[0]["steps"]["dense"]["summary"]["tiles"]["per_tile"]]
        band = _band_mask(tr1, z1.shape, cores, args.band)
        print(f"\nseams: {len(cores)} tile cores, band = {args.band} cells ({args.band * abs(tr1.a):.2f} m) either side "
              f"of an inner cut; cells of the one-part DSM's grid")
        for r in tiled:
            zt = _on_grid(r["dsm"], tr1, z1.shape, crs)
            both = np.isfinite(zt) & np.isfinite(z1)
            d = zt - z1
            print(f"  {r['label']} - one part, band: {_q(d[both & band])}")
            print(f"  {r['label']} - one part, elsewhere: {_q(d[both & ~band])}")
            for nm, m in (("band", band), ("elsewhere", ~band)):
                print(f"    {nm}: cells with a height in the tiled DSM only {int((np.isfinite(zt) & ~np.isfinite(z1) & m).sum())}"
                      f", in the one-part DSM only {int((~np.isfinite(zt) & np.isfinite(z1) & m).sum())}")
            ok = np.isfinite(tt)
            for name, z in ((r["label"], zt), ("one part", z1)):
                v = np.isfinite(z) & ok
                print(f"  {name} - truth, band: {_q((z - tt)[v & band])}; elsewhere: {_q((z - tt)[v & ~band])}")
    out = args.work / f"dense_over_workers_{tag}.json"
    out.write_text(json.dumps([{k: (str(v) if isinstance(v, Path) else v) for k, v in r.items()} for r in
                               results + []], indent=1, default=str))
    print(f"\nwritten {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
