"""Compile every numba kernel of georef_core ahead of use, into numba's on-disk cache.

The kernels are ``@njit(cache=True)``: the first process that calls one compiles it (the GNSS kernels take
one to a few minutes on two cores) and writes the machine code next to the module
(``georef_core/<pkg>/__pycache__/*.nbi|*.nbc``, or under ``$NUMBA_CACHE_DIR`` when that is set); every later
process loads it in milliseconds. ``make install`` runs this module once (``georef warmup``,
``python -m georef_core.warmup``), so the first ``georef gnss solve`` and the demo's first run compile
nothing.

The kernels are reached through the same public code paths production uses (files written and read back,
the solve, the volume computation), on a tiny simulated survey and a tiny DSM: the argument types, hence
the cached signatures, are those of production. :data:`STAGES` names the kernels each stage calls from
Python; the kernels those call are compiled with them (:func:`covered`), and the tests check that the
stages cover every kernel of the package (:func:`discover_dispatchers`).

numba's cache is keyed by each module's source file (a hash of its content; the index files are named
after the function and its line): editing a kernel module invalidates its entries, and the next call
compiles again (``georef gnss solve`` says so before it starts,
see :func:`gnss_kernels_cached`). It does not notice an edited kernel of another module that a cached one
calls (the old code runs on inside the caller): the warm-up drops the cache entries of every caller of a
kernel whose entry is missing or stale before it compiles (:func:`drop_stale_callers`). A cache directory
must be writable by the process that reads it, or numba ignores it (a read-only installation: set
``NUMBA_CACHE_DIR``, as the Dockerfile does).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

PACKAGE_DIR = Path(__file__).resolve().parent

# measured on 2 shared cores (docs/gnss.md, "Speed"): the GNSS kernels from an empty cache, 80-110 s
GNSS_COMPILE_ESTIMATE_S = 100


# ------------------------------------------------------------------------------------------ the stages

def _survey(tmp: Path) -> dict:
    """A 20-epoch simulated survey (static base, rover 40 m away, all five systems, L1+L2, one camera
    event) near the shipped navigation file's station, written as RINEX 3.04 and 2.11."""
    import numpy as np

    from .gnss.frames import geodetic_to_ecef_m
    from .gnss.gnss_time import calendar_to_gps_time_s
    from .gnss.rinex_nav import read_rinex_nav
    from .sim.gnss_observations import epoch_grid, simulate_survey, static_trajectory, write_survey_gnss
    from .sim.survey_gnss import SHIPPED_NAV, receiver_options

    nav = read_rinex_nav(SHIPPED_NAV)
    base = np.asarray(geodetic_to_ecef_m(np.radians(35.1347), np.radians(136.9776), 50.0), dtype=float)
    rover = base + np.array([30.0, 20.0, 10.0])
    t0 = float(calendar_to_gps_time_s(2024, 6, 24, 8, 20, 0))
    epochs = epoch_grid(t0, 19.0, 1.0)
    pos, vel = static_trajectory(rover)
    s = simulate_survey(nav, pos, vel, epochs, base, epochs, rover_options=receiver_options("l1l2", "rover"),
                        base_options=receiver_options("l1l2", "base"), seed=1, events_gps_s=np.array([t0 + 5.5]))
    out = {"rover_ecef_m": rover}
    for version in (3, 2):
        w = write_survey_gnss(tmp / f"rinex{version}", s.rover, s.base, [SHIPPED_NAV], rinex_version=version)
        out[version] = (w["rover"][0], w["base"][0], w["nav"])
    return out


def _gnss_read(tmp: Path, data: dict) -> None:
    from .gnss.input_files import load_navigation, load_observations

    for version in (3, 2):
        rover, base, navs = data[version]
        load_observations(rover)
        load_observations(base)
        load_navigation(navs)


def _gnss_solve(tmp: Path, data: dict) -> None:
    from .gnss.rtk_options import RtkOptions
    from .steps.gnss_solve import run_gnss_solve

    rover, base, navs = data[3]
    run_gnss_solve(rover, base, navs, tmp / "solve" / "dual.pos", RtkOptions(n_bands=2))
    known = tuple(float(v) for v in data["rover_ecef_m"])
    rover, base, navs = data[2]
    run_gnss_solve(rover, base, navs, tmp / "solve" / "single.pos",
                   RtkOptions(n_bands=1, mode="known-start", known_start_position_ecef_m=known,
                              filter_direction="forward"))


def _gnss_judge(tmp: Path, data: dict) -> None:
    """The carrier-phase consistency checks of the engine comparison (bench, tests) and the LAMBDA search
    as a function (lambda_search.mlambda_search)."""
    import numpy as np

    from .gnss.atmosphere_kernels import TROPO_MODELS, troposphere
    from .gnss.input_files import load_navigation, load_observations
    from .gnss.lambda_search import mlambda_search
    from .gnss.phase_consistency import anchored_rms_m, epoch_pair_rms_m
    from .gnss.ppk import prepare
    from .gnss.rtk_options import RtkOptions

    rover, base, navs = data[3]
    opts = RtkOptions(n_bands=2)
    d = prepare(load_observations(rover).observations, load_observations(base).observations,
                load_navigation(navs), opts)[0]
    n = len(d.time_s)
    pos = np.tile(np.asarray(data["rover_ecef_m"], dtype=float), (n, 1))
    fixed = np.ones(n, dtype=bool)
    epoch_pair_rms_m(d, opts, pos, fixed)
    anchored_rms_m(d, opts, pos, fixed, pos, np.array([0, n - 1]))
    q = np.array([[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]])
    mlambda_search(np.array([0.3, -1.2, 2.6]), q, 2)
    troposphere(TROPO_MODELS["saastamoinen"], 0.6, 50.0, 0.5, 0.7)


def _volumes(tmp: Path, data: dict) -> None:
    """A cone on a 60 x 60 float32 DSM, measured over a plane and a TIN base, and as a change between two
    surveys."""
    import numpy as np
    import rasterio
    from affine import Affine
    from pyproj import CRS
    from shapely.geometry import Polygon

    from .volumes.change import compute_change
    from .volumes.coverage import coverage_grid, polygon_coverage
    from .volumes.polygons import AreaPolygon
    from .volumes.raster_io import GridWindow
    from .volumes.volume import compute_volume

    res, n, e0, n0 = 0.5, 60, 512_000.0, 5_123_000.0
    e = e0 + (np.arange(n) + 0.5) * res
    north = n0 + n * res - (np.arange(n) + 0.5) * res
    east, nn = np.meshgrid(e, north)
    paths = []
    for k, h in enumerate((3.0, 4.0)):
        z = (100.0 + h * np.maximum(0.0, 1.0 - np.hypot(east - e0 - 15, nn - n0 - 15) / 8.0)).astype(np.float32)
        p = tmp / f"dsm{k}.tif"
        with rasterio.open(p, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:32633",
                           transform=Affine(res, 0, e0, 0, -res, n0 + n * res)) as ds:
            ds.write(z, 1)
        paths.append(p)
    a = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = Polygon(np.column_stack([e0 + 15 + 10 * np.cos(a), n0 + 15 + 10 * np.sin(a)]))
    poly = AreaPolygon("pile", ring, CRS.from_epsg(32633))
    for base in ("plane", "tin", "lowest"):
        compute_volume(paths[1], poly, base)
    compute_change(paths[0], paths[1], tmp / "change", polygons=[poly])
    window = GridWindow(row0=0, col0=0, nrows=n, ncols=n, x0=e0, y0=n0 + n * res, dx=res, dy=-res)
    coverage_grid(ring, window)
    polygon_coverage(ring, window).covered_area_cells()


def _tiles(tmp: Path, data: dict) -> None:
    """A 300 x 300 px RGB orthophoto with overviews written as a tiled KMZ (the super-overlay's tile drawer)."""
    import numpy as np
    import rasterio
    from affine import Affine
    from rasterio.enums import Resampling

    from .deliverables.kmz_writer import write_kmz

    n = 300
    rgb = np.full((3, n, n), 120, np.uint8)
    rgb[:, :, :20] = 0                       # some no-data: PNG tiles as well as JPEG
    p = tmp / "ortho.tif"
    with rasterio.open(p, "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8", crs="EPSG:32633",
                       transform=Affine(0.05, 0, 512_000.0, 0, -0.05, 5_123_000.0), nodata=0) as ds:
        ds.write(rgb)
        ds.build_overviews([2, 4], Resampling.average)
    write_kmz(p, tmp / "ortho.kmz", tile_threshold_px=128)


@dataclass(frozen=True)
class Stage:
    group: str                    # "gnss" (what a solve calls) | "gnss-checks" (bench, tests) | "volumes" | "tiles"
    label: str
    entry_points: tuple[str, ...]  # kernels this stage calls from Python ("module.function")
    run: Callable[[Path, dict], None]


_G = "georef_core.gnss."
_V = "georef_core.volumes."

STAGES: tuple[Stage, ...] = (
    Stage("gnss", "reading RINEX 3 and 2 observations and navigation", (
        _G + "rinex_obs_kernels.decode_fields", _G + "rinex_obs_kernels.pad_rows",
        _G + "rinex_obs_kernels.scan_rinex2_epochs", _G + "rinex_nav_kernels.record_fields",
        _G + "rinex_nav_kernels.record_epoch_fields"), _gnss_read),
    Stage("gnss", "solving (orbits, single point, slips, Kalman filter, ambiguities)", (
        _G + "ephemeris_kernels.select_records", _G + "ephemeris_kernels.kepler_states",
        _G + "ephemeris_kernels.glonass_states", _G + "spp_kernels.spp_all", _G + "spp_kernels.doppler_velocity",
        _G + "tdcp_slips._slips", _G + "rtk_kernels.filter_pass", _G + "fix_continuity.bridged_jump_rms"),
        _gnss_solve),
    Stage("gnss-checks", "phase-consistency checks, LAMBDA search, troposphere model", (
        _G + "fix_continuity.consecutive_jump_rms", _G + "rtk_kernels.phase_residuals",
        _G + "lambda_kernels.search_from_ltdl", _G + "atmosphere_kernels.troposphere"), _gnss_judge),
    Stage("volumes", "volumes (coverage, TIN base, integration, change)", (
        _V + "coverage._ring_deposits", _V + "coverage._merge_sorted", _V + "coverage._expand",
        _V + "base_surfaces._rasterize_triangles", _V + "integration._integrate_rows"), _volumes),
    Stage("tiles", "tiled KMZ (the tile drawer's warp)", (
        "georef_core.tiles.warp_kernel.bilinear_4_sample", "georef_core.tiles.warp_kernel.premultiplied_to_rgba"),
        _tiles),
)


# ------------------------------------------------------------------------------------------ discovery

def _is_dispatcher(obj) -> bool:
    from numba.core.dispatcher import Dispatcher

    return isinstance(obj, Dispatcher)


def qualified_name(dispatcher) -> str:
    f = dispatcher.py_func
    return f"{f.__module__}.{f.__qualname__}"


def discover_dispatchers() -> dict:
    """Every numba dispatcher defined in georef_core: the modules whose source mentions numba are imported
    (only those) and their module-level dispatchers collected, by qualified name."""
    found = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        if "__pycache__" in path.parts or "numba" not in path.read_text(encoding="utf-8", errors="replace"):
            continue
        rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
        name = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        if name == __name__:
            continue
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if _is_dispatcher(obj) and obj.py_func.__module__ == name:
                found[qualified_name(obj)] = obj
    return found


def _code_names(code) -> set[str]:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _code_names(c)
    return names


def callees(dispatcher) -> set:
    """Dispatchers a kernel calls (read from its bytecode: global names, and attributes of imported
    modules, that are dispatchers): compiled together with it."""
    f = dispatcher.py_func
    names = _code_names(f.__code__)
    out = set()
    for n in names:
        obj = f.__globals__.get(n)
        if _is_dispatcher(obj):
            out.add(obj)
        elif isinstance(obj, types.ModuleType):
            for attr in names:
                sub = getattr(obj, attr, None)
                if _is_dispatcher(sub):
                    out.add(sub)
    return out


def covered(entry_points, dispatchers: dict | None = None) -> set[str]:
    """Qualified names of the kernels compiled when ``entry_points`` (qualified names) are: themselves and
    everything they call, transitively."""
    dispatchers = discover_dispatchers() if dispatchers is None else dispatchers
    todo = [dispatchers[n] for n in entry_points]
    seen: set[str] = set()
    while todo:
        d = todo.pop()
        name = qualified_name(d)
        if name in seen:
            continue
        seen.add(name)
        todo.extend(callees(d))
    return seen


# ------------------------------------------------------------------------------------------ the cache

def _inlined(dispatcher) -> bool:
    return dispatcher.targetoptions.get("inline", "never") == "always"


def is_cached(dispatcher) -> bool | None:
    """Whether numba's cache holds an entry of this kernel for its current source (None: unknown).
    Reads the small index file only; nothing is loaded or compiled."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:   # noqa: BLE001 - numba internals changed: do not claim anything
        return None


def uncached(group: str | None = None, entry_points_only: bool = False) -> list[str]:
    """Kernels of the stages (of one group) without a cache entry for their current source. Kernels
    inlined into their callers (``inline="always"``) have no entry of their own and are skipped."""
    dispatchers = discover_dispatchers() if not entry_points_only else None
    names: set[str] = set()
    for st in STAGES:
        if group is None or st.group == group:
            names |= set(st.entry_points) if entry_points_only else covered(st.entry_points, dispatchers)
    if dispatchers is None:
        dispatchers = {}
        for n in names:
            mod, _, fn = n.rpartition(".")
            dispatchers[n] = getattr(importlib.import_module(mod), fn)
    return sorted(n for n in names if not _inlined(dispatchers[n]) and is_cached(dispatchers[n]) is False)


def gnss_kernels_cached() -> bool:
    """Whether the kernels a GNSS solve calls from Python are all in numba's cache (a few ms: the index
    files of the stages' entry points are read; their callees are compiled into them)."""
    return not uncached("gnss", entry_points_only=True)


def drop_stale_callers(dispatchers: dict | None = None) -> list[str]:
    """Delete the cache index of every kernel that calls, directly or not, a kernel without a valid cache
    entry (edited since it was compiled, or never compiled): numba would otherwise load the caller with the
    callee's old code compiled into it. Returns the kernels whose entries were dropped."""
    dispatchers = discover_dispatchers() if dispatchers is None else dispatchers
    stale = {n for n, d in dispatchers.items() if not _inlined(d) and is_cached(d) is False}
    callers: dict[str, set[str]] = {}
    for n, d in dispatchers.items():
        for c in callees(d):
            callers.setdefault(qualified_name(c), set()).add(n)
    todo, affected = list(stale), set()
    while todo:
        for caller in callers.get(todo.pop(), ()):
            if caller not in affected:
                affected.add(caller)
                todo.append(caller)
    dropped = []
    for n in sorted(affected - stale):
        try:
            Path(dispatchers[n]._cache._cache_file._index_path).unlink(missing_ok=True)
            dropped.append(n)
        except (AttributeError, OSError):
            pass
    return dropped


# ------------------------------------------------------------------------------------------ running

GROUPS = ("gnss", "gnss-checks", "volumes", "tiles")


def warm_up(groups=GROUPS, progress: Callable[[str, int, int], None] | None = None) -> dict:
    """Run the stages of ``groups`` once: every kernel compiled (or found in the cache). ``progress(label,
    done, total)`` before each stage and at the end. Returns {"seconds": {label: s}, "uncached": [...]}."""
    import tempfile

    stages = [s for s in STAGES if s.group in groups]
    seconds = {}
    drop_stale_callers()
    with tempfile.TemporaryDirectory(prefix="georef-warmup-") as tmp_name:
        tmp = Path(tmp_name)
        data = _survey(tmp) if any(s.group.startswith("gnss") for s in stages) else {}
        for k, st in enumerate(stages):
            if progress:
                progress(st.label, k, len(stages))
            t0 = time.perf_counter()
            st.run(tmp, data)
            seconds[st.label] = time.perf_counter() - t0
    if progress:
        progress("done", len(stages), len(stages))
    missing = [n for g in groups for n in uncached(g)]
    return {"seconds": seconds, "uncached": missing}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="georef warmup", description=__doc__.split("\n\n")[0])
    add_arguments(ap)
    return run(ap.parse_args(argv))


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--gnss-only", action="store_true", help="only the GNSS kernels")
    ap.add_argument("--check", action="store_true",
                    help="compile nothing: list the kernels not in the cache (exit status 1 when any)")


def run(args) -> int:
    groups = ("gnss", "gnss-checks") if args.gnss_only else GROUPS
    if args.check:
        missing = [n for g in groups for n in uncached(g)]
        for n in missing:
            print(f"not cached: {n}")
        print(f"{'all kernels cached' if not missing else f'{len(missing)} kernel(s) not cached'}")
        return 1 if missing else 0
    t0 = time.perf_counter()
    first = [n for g in groups for n in uncached(g, entry_points_only=True)]
    if first:
        print(f"georef warmup: compiling the numba kernels into the cache (about {GNSS_COMPILE_ESTIMATE_S} s "
              f"for GNSS on two cores, once)", flush=True)

    def show(label, done, total):
        if done < total:
            print(f"  [{done + 1}/{total}] {label} ... ({time.perf_counter() - t0:.0f} s so far)", flush=True)

    res = warm_up(groups, show)
    # the modules' bytecode too: a process started with PYTHONDONTWRITEBYTECODE (the Dockerfile's, some CI and
    # dev shells) would otherwise compile ~40 modules from source at every `georef gnss solve` (docs/gnss.md)
    import compileall

    compileall.compile_dir(str(PACKAGE_DIR), quiet=1)
    if res["uncached"]:   # the commands still work: they compile these on first use
        print("georef warmup: warning: still not cached (numba could not write its cache?): "
              + ", ".join(res["uncached"]), file=sys.stderr)
        return 0
    print(f"georef warmup: every kernel in the cache ({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
