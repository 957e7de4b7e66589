"""Change between two surveys: a DSM difference map, cut/fill over the common area and per polygon, and
a stable-ground check.

Conventions (earthworks progress): ``dz = after - before``; ``cut_m3`` is the volume where the ground
went down (material removed), ``fill_m3`` where it went up (material placed), ``net_m3 = fill_m3 -
cut_m3`` (net material added). The "before" DSM is resampled bilinearly onto the "after" DSM's grid (any
CRS); the common area is where both have data.

Stable ground: polygons the user marks as unchanged (roads, pads, buildings' roofs are not ground...).
Their dz must agree: median |dz| and RMS dz both within a tolerance (default 5 cm), else the result
is flagged with the numbers. Their median dz is the measured relative vertical bias of the two surveys;
with ``align=True`` it is removed (the before surface is shifted by it) before the volumes.

Uncertainty: dz noise sigma_dz = sqrt(sigma_before^2 + sigma_after^2) with the same correlation model
as volumes (:mod:`.uncertainty`), plus the relative bias x area: the measured stable median (when
stable areas are given) else sqrt(b_before^2 + b_after^2). ``lod95_m`` = 1.96 sigma_dz is the level of
detection of a single cell; cut/fill restricted to |dz| > lod95 are also reported.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn, no_progress
from .base_surfaces import SurfaceBase
from .coverage import coverage_grid
from .polygons import AreaPolygon, crs_label
from .raster_io import GridWindow, WindowReader, WindowResampler, open_elevation_raster, open_float_geotiff_writer
from .uncertainty import Z95, NoiseModel, block_size_for, correlated_sum_sigma
from .volume import VolumeOptions, check_inside, compute_volume


@dataclass
class StableCheck:
    name: str
    area_m2: float
    median_dz_m: float
    median_abs_dz_m: float
    rms_dz_m: float
    mean_dz_m: float
    ok: bool
    tolerance_m: float

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("area_m2", "median_dz_m", "median_abs_dz_m", "rms_dz_m", "mean_dz_m"):
            d[k] = round(d[k], 4)
        return d


@dataclass
class ChangeResult:
    before: str
    after: str
    crs: str
    cell_size_m: float
    common: dict  # whole common area: cut/fill/net, areas, uncertainty, LoD
    polygons: list = field(default_factory=list)  # per polygon: cut/fill/net (change conventions) + uncertainty
    stable: list = field(default_factory=list)  # StableCheck.to_dict() per stable polygon
    stable_ok: bool | None = None
    vertical_offset_m: float = 0.0  # removed from dz (align=True)
    flags: list = field(default_factory=list)
    noise: dict = field(default_factory=dict)
    dz_path: str | None = None
    timings_s: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["conventions"] = ("dz = after - before; cut_m3: volume where the ground went down (material removed); "
                            "fill_m3: where it went up (material placed); net_m3 = fill_m3 - cut_m3")
        return d


def _common_window(info_a, info_b) -> GridWindow:
    from rasterio.warp import transform_bounds

    bb = info_b.bounds
    if info_b.crs != info_a.crs:
        bb = transform_bounds(info_b.crs.to_wkt(), info_a.crs.to_wkt(), *bb, densify_pts=21)
    ba = info_a.bounds
    x0, y0, x1, y1 = max(ba[0], bb[0]), max(ba[1], bb[1]), min(ba[2], bb[2]), min(ba[3], bb[3])
    if x1 <= x0 or y1 <= y0:
        raise ProcessingError(f"the DSMs {info_b.path.name} and {info_a.path.name} do not overlap")
    w = info_a.window_for_bounds(x0, y0, x1, y1, margin_cells=0)
    if w is None:
        raise ProcessingError(f"the DSMs {info_b.path.name} and {info_a.path.name} do not overlap")
    return w


def _stable_check(info_a, before: WindowResampler, poly: AreaPolygon, tol: float) -> StableCheck:
    """dz statistics over a stable polygon (cells weighted by coverage; weighted median)."""
    p = poly.to_crs(info_a.crs)
    check_inside(info_a, p)
    x0, y0, x1, y1 = p.geometry.bounds
    win = info_a.window_for_bounds(x0, y0, x1, y1, 1)
    with WindowReader(info_a) as r:
        za = r.read(win)
    dz = (za - before(win)).astype(np.float64)
    cov = coverage_grid(p.geometry, win, np.float64)
    m = (cov > 0) & np.isfinite(dz)
    if not m.any():
        raise InputFileError(poly.source, f"stable area {poly.name!r}: no cell with data in both DSMs")
    d, wts = dz[m], cov[m]
    order = np.argsort(d)
    cw = np.cumsum(wts[order])
    med = float(d[order][np.searchsorted(cw, 0.5 * cw[-1])])
    ad = np.abs(d)
    order = np.argsort(ad)
    cw = np.cumsum(wts[order])
    med_abs = float(ad[order][np.searchsorted(cw, 0.5 * cw[-1])])
    rms = float(np.sqrt(np.sum(wts * d * d) / wts.sum()))
    mean = float(np.sum(wts * d) / wts.sum())
    area = float(wts.sum() * win.cell_area_m2)
    return StableCheck(poly.name, area, med, med_abs, rms, mean, med_abs <= tol and rms <= tol, tol)


def compute_change(before_path, after_path, out_dir=None, polygons: list[AreaPolygon] | None = None,
                   stable: list[AreaPolygon] | None = None, tolerance_m: float = 0.05, align: bool = False,
                   noise_before: NoiseModel | None = None, noise_after: NoiseModel | None = None,
                   progress: ProgressFn | None = None) -> ChangeResult:
    """Difference map (``out_dir/dz.tif`` when ``out_dir`` is given), common-area and per-polygon cut/fill,
    stable-ground check. See the module docstring."""
    progress = progress or no_progress
    t0 = time.perf_counter()
    info_a = open_elevation_raster(after_path, "after DSM")
    info_b = open_elevation_raster(before_path, "before DSM")
    nb = noise_before or NoiseModel.for_dsm(before_path)
    na = noise_after or NoiseModel.for_dsm(after_path)
    L = max(na.correlation_length_m, nb.correlation_length_m)
    sigma_dz = math.hypot(na.sigma_z_m, nb.sigma_z_m)
    before = WindowResampler(before_path, info_a.crs, "before DSM")
    flags: list[str] = []

    # ---- stable ground ---------------------------------------------------------------------------
    progress("stable", 0, 3)
    checks = [_stable_check(info_a, before, p, tolerance_m) for p in (stable or [])]
    stable_ok = None
    offset = 0.0
    if checks:
        stable_ok = all(c.ok for c in checks)
        for c in checks:
            if not c.ok:
                flags.append(f"stable area {c.name!r} moved: median |dz| {c.median_abs_dz_m:.3f} m, RMS "
                             f"{c.rms_dz_m:.3f} m, median dz {c.median_dz_m:+.3f} m (tolerance {tolerance_m:.3f} m)")
        wsum = sum(c.area_m2 for c in checks)
        rel_bias = sum(c.median_dz_m * c.area_m2 for c in checks) / wsum
        bias_src = "median dz over the stable areas"
        if align:
            offset = rel_bias
            rel_bias = 0.0 if stable_ok else rel_bias
            bias_src = "removed (aligned on the stable areas)" if stable_ok else bias_src + " (alignment unreliable)"
    else:
        rel_bias = math.hypot(na.height_bias_m, nb.height_bias_m)
        bias_src = "sqrt(b_before^2 + b_after^2) (no stable areas given: not checked)"
        if align:
            raise ProcessingError("vertical alignment needs stable areas (--stable)")
    noise = {"sigma_dz_m": sigma_dz, "correlation_length_m": L, "relative_bias_m": rel_bias,
             "relative_bias_source": bias_src, "before": nb.to_dict(), "after": na.to_dict()}

    # ---- whole common area, strip by strip --------------------------------------------------------
    progress("difference", 1, 3)
    win = _common_window(info_a, info_b)
    lod = Z95 * sigma_dz
    block = block_size_for(win.nrows, win.ncols)
    coarse = np.zeros((-(-win.nrows // block), -(-win.ncols // block)))
    sums = np.zeros(6)  # valid cells, cut, fill, cut>lod, fill>lod, nodata cells
    step = max(info_a.block_rows, 1) * max(1, 4_000_000 // (win.ncols * max(info_a.block_rows, 1)))
    dz_path = Path(out_dir) / "dz.tif" if out_dir is not None else None
    writer = None
    try:
        if dz_path is not None:
            writer = open_float_geotiff_writer(dz_path, win, info_a.crs, "dz = after - before (m)",
                                               {"BEFORE": Path(before_path).name, "AFTER": Path(after_path).name,
                                                "VERTICAL_OFFSET_REMOVED_M": offset})
        from rasterio.windows import Window

        with WindowReader(info_a) as reader:
            r = 0
            while r < win.nrows:
                n = min(step - (win.row0 + r) % step, win.nrows - r)
                sub = win.sub(r, n)
                dz = reader.read(sub) - before(sub) - np.float32(offset)
                ok = np.isfinite(dz)
                d = np.where(ok, dz, 0.0).astype(np.float64)
                sums += [ok.sum(), np.sum(np.maximum(-d, 0)), np.sum(np.maximum(d, 0)),
                         np.sum(np.where(d < -lod, -d, 0)), np.sum(np.where(d > lod, d, 0)), (~ok).sum()]
                rows = (r + np.arange(n)) // block
                cnt = np.add.reduceat(ok.astype(np.float64), np.arange(0, win.ncols, block), axis=1)
                np.add.at(coarse, rows, cnt)
                if writer is not None:
                    writer.write(dz.astype(np.float32), 1, window=Window(0, r, win.ncols, n))
                r += n
    finally:
        if writer is not None:
            writer.close()
    a = win.cell_area_m2
    valid_area = sums[0] * a
    if sums[0] == 0:
        raise ProcessingError(f"the DSMs {Path(before_path).name} and {Path(after_path).name} have no cell with data "
                              "in common")
    cut, fill = sums[1] * a, sums[2] * a
    s_noise = correlated_sum_sigma(coarse * a, block, win.dx, win.dy, sigma_dz, L)
    s_bias = abs(rel_bias) * valid_area
    sig = math.hypot(s_noise, s_bias)
    common = {"cut_m3": round(cut, 3), "fill_m3": round(fill, 3), "net_m3": round(fill - cut, 3),
              "valid_area_m2": round(valid_area, 3), "nodata_area_m2": round(sums[5] * a, 3),
              "extent": [win.x0, win.y0 + win.nrows * win.dy, win.x0 + win.ncols * win.dx, win.y0],
              "lod95_m": round(lod, 4), "cut_beyond_lod_m3": round(sums[3] * a, 3),
              "fill_beyond_lod_m3": round(sums[4] * a, 3),
              "uncertainty": {"sigma_m3": round(sig, 3), "ci95_m3": round(Z95 * sig, 3),
                              "components_m3": {"dz_noise_m3": round(s_noise, 3), "relative_bias_m3": round(s_bias, 3)}}}

    # ---- polygons ----------------------------------------------------------------------------------
    progress("polygons", 2, 3)
    per = []
    if polygons:
        model = NoiseModel(na.sigma_z_m, rel_bias, L, {"height_bias_m": bias_src})
        opts = VolumeOptions(surface_sigma_m=nb.sigma_z_m, base_model_spread=False)
        base = SurfaceBase("surface", f"before DSM {Path(before_path).name}", {}, False, nb.sigma_z_m,
                           "before DSM noise model", path=str(before_path), offset_m=offset)
        for p in polygons:
            v = compute_volume(info_a, p, base, opts, model)
            per.append({"name": v.name, "cut_m3": round(v.fill_m3, 3), "fill_m3": round(v.cut_m3, 3),
                        "net_m3": round(v.net_m3, 3), "area_m2": round(v.area_m2, 3),
                        "filled_nodata_m2": round(v.filled_nodata_m2, 3), "uncertainty": v.uncertainty,
                        "warnings": v.warnings})
    progress("done", 3, 3)
    return ChangeResult(str(before_path), str(after_path), crs_label(info_a.crs), round(info_a.cell_size_m, 6), common,
                        per, [c.to_dict() for c in checks], stable_ok, round(offset, 4), flags,
                        {k: (round(v, 4) if isinstance(v, float) else v) for k, v in noise.items()},
                        str(dz_path) if dz_path is not None else None,
                        {"total_s": round(time.perf_counter() - t0, 3)})
