"""Cut and fill of a surveyed surface against a design surface inside a polygon, on-grade share within a
tolerance, and which cells differ significantly from the design given the survey's measured accuracy.

Per DSM cell (height at the cell centre, as a DSM is defined), ``d = surveyed - design``:

* ``cut_m3`` = sum of coverage x cell area x max(d, 0): the surveyed surface stands **above** the design,
  material to **remove**; ``fill_m3`` = the same of max(-d, 0): below the design, material to **place**;
  ``net_m3 = cut_m3 - fill_m3`` (positive: material to remove overall). Coverage is the exact fraction of
  the cell inside the polygon (georef_core.volumes.coverage), so the quantities converge on the integral
  over the polygon.
* on grade: |d| <= tolerance t.
* significance: a cell's height error (1 sigma) is ``sigma_cell = sqrt(dsm_sigma^2 + vertical_rmse^2 +
  design_sigma^2)``: the DSM's own noise, the survey's vertical check-point RMSE (what is left of the
  georeferencing at the check points) and the design's own error (0 for a design: exact by definition).
  A difference smaller than ``k sigma_cell`` (k = 1.96: 95 %) cannot be told from zero.
* classes (class GeoTIFF, with a colour table): 1 cut (d > t and significant), 2 fill (d < -t and
  significant), 3 on grade (|d| <= t), 4 not significant (outside the tolerance, |d| < k sigma_cell: the
  survey cannot say whether that cell is off grade), 5 no data (inside the polygon, no DSM height or no
  design); 0 outside the polygon (nodata).

Uncertainty of the volumes (1 sigma, m^3), the volume module's DSM error model
(georef_core.volumes.uncertainty): a random field (dsm_sigma per cell, Gaussian correlation over L) through
the cells of each quantity, plus a vertical bias common to the survey whose 1 sigma is the check-point
vertical RMSE (fully correlated: vertical_rmse x area for the net; for cut and fill the secant (cut(d + b) - cut(d - b)) / 2), plus the
design's own sigma likewise when given; combined in quadrature. The random field enters cut (fill) through
each cell's weight x P(d + n > 0) (P(d + n < 0)), the derivative of its expected cut (fill). Noise also inflates gross cut
and fill (a cell truly on the design reads as cut or fill half the time): ``noise_inflation_m3`` is the
expected amount by which each of them is inflated by the random noise (E[max(d + n, 0)] - max(d, 0) summed
over the cells; it cancels in the net).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn, no_progress
from ..volumes.coverage import polygon_coverage
from ..volumes.polygons import AreaPolygon, crs_label
from ..volumes.raster_io import GridWindow, RasterInfo, WindowReader, open_elevation_raster, open_float_geotiff_writer
from ..volumes.uncertainty import Z95, NoiseModel, block_size_for, correlated_sum_sigma
from .design_surface import DesignSurface

CLASS_OUTSIDE, CLASS_CUT, CLASS_FILL, CLASS_ON_GRADE, CLASS_NOT_SIGNIFICANT, CLASS_NO_DATA = range(6)
CLASS_NAMES = {CLASS_OUTSIDE: "outside the polygon", CLASS_CUT: "cut (above design, significant)",
               CLASS_FILL: "fill (below design, significant)", CLASS_ON_GRADE: "on grade (within tolerance)",
               CLASS_NOT_SIGNIFICANT: "not significant (outside tolerance, within the survey's uncertainty)",
               CLASS_NO_DATA: "no data (no DSM height or no design)"}
CLASS_COLOURS = {CLASS_OUTSIDE: (0, 0, 0, 0), CLASS_CUT: (214, 39, 40, 255), CLASS_FILL: (31, 119, 180, 255),
                 CLASS_ON_GRADE: (44, 160, 44, 255), CLASS_NOT_SIGNIFICANT: (190, 190, 190, 255),
                 CLASS_NO_DATA: (60, 60, 60, 255)}
OUTPUT_NAMES = {"difference": "difference.tif", "classes": "classes.tif", "contours": "contours.geojson",
                "quantities": "cut_fill.json"}
STRIP_CELLS = 4_000_000
CONTOUR_CELLS = 16_000_000  # the difference is contoured on at most this many cells (decimated above)
DEFAULT_VERTICAL_RMSE_M = 0.02  # as the volume model's default bias when no check points are known


@dataclass
class CutFillOptions:
    tolerance_m: float = 0.05
    k: float = 1.96
    dsm_sigma_m: float | None = None  # default: dense_summary.json next to the DSM, else 5 cm
    vertical_rmse_m: float | None = None  # default: the run's check-point residuals.json, else 2 cm
    correlation_length_m: float | None = None  # default: dense_summary.json, else 1 m
    design_sigma_m: float = 0.0
    max_uncovered_fraction: float = 0.01  # of the polygon without design surface, else an error
    max_nodata_fraction: float = 0.05  # of the polygon without DSM heights, else an error

    def check(self) -> None:
        for name in ("tolerance_m", "k", "design_sigma_m", "max_uncovered_fraction", "max_nodata_fraction"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ProcessingError(f"{name} must be a number >= 0 (got {v!r})")
        for name in ("dsm_sigma_m", "vertical_rmse_m", "correlation_length_m"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise ProcessingError(f"{name} must be >= 0 (got {v!r})")


def _run_dir_of(dsm_path: Path, run_dir) -> Path | None:
    if run_dir is not None:
        return Path(run_dir)
    # a run folder's DSM is <run>/dense/dsm.tif (or <run>/dtm/dtm.tif): the run is two levels up
    return dsm_path.parent.parent if dsm_path.parent.name in ("dense", "dtm") else None


def check_point_vertical_rmse(run_dir) -> tuple[float | None, str]:
    """The georef step's check-point vertical RMSE (residuals.json statistics dz rmse_m) of a run folder."""
    if run_dir is None:
        return None, "no run folder"
    p = Path(run_dir) / "residuals.json"
    try:
        st = json.loads(p.read_text())["statistics"]
        if st.get("n"):
            return float(st["dz"]["rmse_m"]), f"{p}: {st['n']} check point(s), vertical RMSE"
        return None, f"{p}: no check points"
    except (OSError, ValueError, KeyError, TypeError):
        return None, f"no check-point table ({p.name}) in {run_dir}"


def accuracy_model(dsm_path, options: CutFillOptions, run_dir=None) -> tuple[NoiseModel, dict]:
    """The DSM error model for the comparison: (NoiseModel with sigma_z = the DSM noise and height_bias =
    the check-point vertical RMSE, {'sigma_cell_m', 'sources'})."""
    dsm_path = Path(dsm_path)
    rd = _run_dir_of(dsm_path, run_dir)
    dsm_for_summary = dsm_path
    if not dsm_path.with_name("dense_summary.json").exists() and rd is not None \
            and (rd / "dense" / "dense_summary.json").exists():
        dsm_for_summary = rd / "dense" / "dsm.tif"  # a DTM of the run: the dense step's noise figures
    try:
        base = NoiseModel.for_dsm(dsm_for_summary, options.dsm_sigma_m, 0.0, options.correlation_length_m)
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    sources = {"dsm_sigma_m": base.sources["sigma_z_m"], "correlation_length_m": base.sources["correlation_length_m"]}
    if options.vertical_rmse_m is not None:
        rmse, sources["vertical_rmse_m"] = float(options.vertical_rmse_m), "given"
    else:
        rmse, why = check_point_vertical_rmse(rd)
        if rmse is None:
            rmse, sources["vertical_rmse_m"] = DEFAULT_VERTICAL_RMSE_M, f"default ({why})"
        else:
            sources["vertical_rmse_m"] = why
    model = NoiseModel(base.sigma_z_m, rmse, base.correlation_length_m,
                       {"sigma_z_m": sources["dsm_sigma_m"], "height_bias_m": sources["vertical_rmse_m"],
                        "correlation_length_m": sources["correlation_length_m"]})
    sigma_cell = math.sqrt(model.sigma_z_m ** 2 + rmse ** 2 + options.design_sigma_m ** 2)
    return model, {"sigma_cell_m": sigma_cell, "sources": sources}


def _check_inside(info: RasterInfo, poly: AreaPolygon) -> None:
    from ..volumes.volume import check_inside

    check_inside(info, poly)


def block_sums(a: np.ndarray, block: int) -> np.ndarray:
    """Sum over square blocks of ``block`` cells (the array's rows start on a block boundary)."""
    ny, nx = -(-a.shape[0] // block) * block, -(-a.shape[1] // block) * block
    if (ny, nx) != a.shape:
        p = np.zeros((ny, nx), a.dtype)
        p[:a.shape[0], :a.shape[1]] = a
        a = p
    return a.reshape(ny // block, block, nx // block, block).sum(axis=(1, 3))


def _write_classes(path: Path, window: GridWindow, crs):
    import rasterio
    from rasterio.crs import CRS as RioCRS

    profile = {"driver": "GTiff", "width": window.ncols, "height": window.nrows, "count": 1, "dtype": "uint8",
               "crs": RioCRS.from_wkt(crs.to_wkt()), "transform": window.transform, "nodata": CLASS_OUTSIDE,
               "compress": "deflate"}
    if window.ncols >= 256 and window.nrows >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    ds = rasterio.open(path, "w", **profile)
    ds.write_colormap(1, {k: v for k, v in CLASS_COLOURS.items()})
    ds.set_band_description(1, "cut/fill class against the design")
    ds.update_tags(**{f"CLASS_{k}": v for k, v in CLASS_NAMES.items()})
    return ds


def _to_cog(tmp: dict) -> None:
    """difference.tif and classes.tif (written strip by strip) rewritten as cloud-optimised GeoTIFFs: the web
    map tiles and the browser's COG reader read them by overview and window (classes: nearest overviews)."""
    from ..dense.cog_writer import geotiff_to_cog

    for key, resampling in (("difference", "AVERAGE"), ("classes", "NEAREST")):
        src = tmp[key]
        cog = src.with_name(src.name + ".cog")
        try:
            geotiff_to_cog(src, cog, overview_resampling=resampling)
            cog.replace(src)
        finally:
            cog.unlink(missing_ok=True)


def _contours(diff: np.ndarray, x0: float, y0: float, dx: float, dy: float, levels: dict) -> list[dict]:
    """GeoJSON LineString features of the difference at each level (cell-centre grid, NaN as no data)."""
    import contourpy

    if diff.shape[0] < 2 or diff.shape[1] < 2 or not np.isfinite(diff).any():
        return []
    xs = x0 + (np.arange(diff.shape[1]) + 0.5) * dx
    ys = y0 + (np.arange(diff.shape[0]) + 0.5) * dy
    z = np.ma.masked_invalid(diff.astype(np.float64))
    gen = contourpy.contour_generator(xs, ys, z, line_type=contourpy.LineType.Separate)
    feats = []
    for label, level in levels.items():
        for line in gen.lines(level):
            if len(line) < 2 or (len(line) < 5 and np.allclose(line[0], line[-1])):
                continue  # a loop around one or two cells: noise, not an edge
            feats.append({"type": "Feature", "properties": {"level_m": round(float(level), 4), "label": label},
                          "geometry": {"type": "LineString",
                                       "coordinates": np.round(line, 3).tolist()}})
    return feats


def compute_cut_fill(dsm, design: DesignSurface, polygon: AreaPolygon, out_dir=None,
                     options: CutFillOptions | None = None, run_dir=None, progress: ProgressFn | None = None) -> dict:
    """Cut/fill of ``dsm`` (path or RasterInfo) against ``design`` inside ``polygon`` (any CRS). Writes into
    ``out_dir`` (when given) difference.tif, classes.tif, contours.geojson and cut_fill.json (the returned
    document)."""
    from scipy.special import ndtr

    o = options or CutFillOptions()
    o.check()
    progress = progress or no_progress
    t0 = time.perf_counter()
    info = dsm if isinstance(dsm, RasterInfo) else open_elevation_raster(dsm, "surveyed surface")
    poly = polygon.to_crs(info.crs)
    _check_inside(info, poly)
    model, acc = accuracy_model(info.path, o, run_dir)
    sigma_cell = acc["sigma_cell_m"]
    threshold = o.k * sigma_cell
    t = float(o.tolerance_m)
    design.prepare(info.crs)
    x0b, y0b, x1b, y1b = poly.geometry.bounds
    window = info.window_for_bounds(x0b, y0b, x1b, y1b, 2)
    cov_all = polygon_coverage(poly.geometry, window)
    a_cell = window.cell_area_m2
    block = block_size_for(window.nrows, window.ncols)
    rows_per = max(block, (max(STRIP_CELLS // max(window.ncols, 1), 1) // block) * block)
    cshape = (-(-window.nrows // block), -(-window.ncols // block))
    U = {k: np.zeros(cshape) for k in ("all", "cut", "fill")}
    s = {k: 0.0 for k in ("cut", "fill", "area", "on_grade", "expected_on_grade",
                          "surely_on_grade", "possibly_on_grade", "not_significant", "sig_cut", "sig_fill",
                          "cut_beyond_t", "fill_beyond_t", "no_design", "no_dsm", "inflation", "polygon",
                          "sum_d", "sum_d2", "cls_cut", "cls_fill", "cut_up", "cut_down",
                          "fill_up", "fill_down")}
    s["d_min"], s["d_max"] = math.inf, -math.inf
    stride = max(1, math.ceil(math.sqrt(window.nrows * window.ncols / CONTOUR_CELLS)))
    small = []  # decimated difference for the contours
    out = Path(out_dir) if out_dir is not None else None
    diff_ds = cls_ds = None
    tmp = {}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        tmp = {k: out / (v + ".part") for k, v in OUTPUT_NAMES.items()}
        diff_ds = open_float_geotiff_writer(tmp["difference"], window, info.crs,
                                            "surveyed minus design (m); NaN outside the polygon or without data",
                                            {"UNITS": "m", "DIFFERENCE": "surveyed - design", "DESIGN": design.path.name})
        cls_ds = _write_classes(tmp["classes"], window, info.crs)
    sig_noise = model.sigma_z_m
    try:
        from rasterio.windows import Window

        with WindowReader(info) as reader:
            n_strips = -(-window.nrows // rows_per)
            for k, r0 in enumerate(range(0, window.nrows, rows_per)):
                progress("cut/fill", k, n_strips)
                n = min(rows_per, window.nrows - r0)
                sub = window.sub(r0, n)
                cov = cov_all.rows(r0, n).dense(np.float64)
                inside = cov > 0
                z = reader.read(sub).astype(np.float64)
                g = design.heights_on(sub).astype(np.float64)
                d = z - g
                no_design = inside & ~np.isfinite(g)
                no_dsm = inside & np.isfinite(g) & ~np.isfinite(z)
                ok = inside & np.isfinite(d)
                w = np.where(ok, cov * a_cell, 0.0)
                dz = np.where(ok, d, 0.0)
                ad = np.abs(dz)
                pos = dz > 0
                s["polygon"] += float(cov.sum()) * a_cell
                s["no_design"] += float(cov[no_design].sum()) * a_cell
                s["no_dsm"] += float(cov[no_dsm].sum()) * a_cell
                s["area"] += float(w.sum())
                s["cut"] += float(np.sum(w * np.maximum(dz, 0.0)))
                s["fill"] += float(np.sum(w * np.maximum(-dz, 0.0)))
                # cut and fill with the whole surface shifted by +-b (the vertical bias's secant sensitivity)
                b = model.height_bias_m
                s["cut_up"] += float(np.sum(w * np.maximum(dz + b, 0.0)))
                s["cut_down"] += float(np.sum(w * np.maximum(dz - b, 0.0)))
                s["fill_up"] += float(np.sum(w * np.maximum(-dz - b, 0.0)))
                s["fill_down"] += float(np.sum(w * np.maximum(-dz + b, 0.0)))
                s["sum_d"] += float(np.sum(w * dz))
                s["sum_d2"] += float(np.sum(w * dz * dz))
                s["cut_beyond_t"] += float(np.sum(w * np.maximum(dz - t, 0.0)))
                s["fill_beyond_t"] += float(np.sum(w * np.maximum(-dz - t, 0.0)))
                on = ok & (ad <= t)
                s["on_grade"] += float(w[on].sum())
                if sigma_cell > 0:
                    p_on = ndtr((t - dz) / sigma_cell) - ndtr((-t - dz) / sigma_cell)
                else:
                    p_on = on.astype(float)
                s["expected_on_grade"] += float(np.sum(w * p_on))
                s["surely_on_grade"] += float(w[ok & (ad + threshold <= t)].sum())
                s["possibly_on_grade"] += float(w[ok & (ad - threshold <= t)].sum())
                nsig = ok & ~on & (ad < threshold)
                s["not_significant"] += float(w[nsig].sum())
                cut_c = ok & (dz > t) & (ad >= threshold)
                fill_c = ok & (dz < -t) & (ad >= threshold)
                s["cls_cut"] += float(w[cut_c].sum())
                s["cls_fill"] += float(w[fill_c].sum())
                s["sig_cut"] += float(np.sum(w[cut_c] * dz[cut_c]))
                s["sig_fill"] += float(np.sum(-w[fill_c] * dz[fill_c]))
                if sig_noise > 0:
                    # E[max(d + n, 0)] - max(d, 0) = s phi(d/s) - |d| Phi(-|d|/s) at the true d: cells whose
                    # difference is not significant are taken to be on the design (d = 0; the measured d
                    # would understate it 2.4 times there), the others at their measured d
                    r = np.where(ad < threshold, 0.0, ad / sig_noise)
                    phi = np.exp(-0.5 * r * r) / math.sqrt(2 * math.pi)
                    s["inflation"] += float(np.sum(w * sig_noise * (phi - r * ndtr(-r))))
                    # sensitivity of the expected cut to a cell's height: P(d + n > 0) (smooth across d = 0)
                    w_cut = w * ndtr(dz / sig_noise)
                else:
                    w_cut = np.where(pos, w, 0.0)
                if ok.any():
                    s["d_min"] = min(s["d_min"], float(dz[ok].min()))
                    s["d_max"] = max(s["d_max"], float(dz[ok].max()))
                c0 = r0 // block
                for key, wk in (("all", w), ("cut", w_cut), ("fill", w - w_cut)):
                    bs = block_sums(wk, block)
                    U[key][c0:c0 + bs.shape[0]] += bs
                first = (-r0) % stride
                small.append(np.where(ok, d, np.nan)[first::stride, ::stride].astype(np.float32))
                if diff_ds is not None:
                    win = Window(0, r0, window.ncols, n)
                    diff_ds.write(np.where(ok, d, np.nan).astype(np.float32), 1, window=win)
                    cls = np.full(d.shape, CLASS_OUTSIDE, np.uint8)
                    cls[inside & ~ok] = CLASS_NO_DATA
                    cls[on] = CLASS_ON_GRADE
                    cls[nsig] = CLASS_NOT_SIGNIFICANT
                    cls[cut_c] = CLASS_CUT
                    cls[fill_c] = CLASS_FILL
                    cls_ds.write(cls, 1, window=win)
    except BaseException:
        for ds in (diff_ds, cls_ds):
            if ds is not None:
                ds.close()
        for p in tmp.values():
            p.unlink(missing_ok=True)
        raise
    for ds in (diff_ds, cls_ds):
        if ds is not None:
            ds.close()

    def fail(where, problem):
        for p in tmp.values():
            p.unlink(missing_ok=True)
        raise InputFileError(where, problem)

    A = s["polygon"]
    if A <= 0:
        fail(polygon.source or "polygon", f"polygon {poly.name!r} covers no cell of the DSM {info.path.name}")
    if s["no_design"] > o.max_uncovered_fraction * A:
        fail(design.path, f"the design surface {design.name!r} does not cover {s['no_design']:.2f} m^2 "
                          f"({100 * s['no_design'] / A:.1f} %) of polygon {poly.name!r} (at most "
                          f"{100 * o.max_uncovered_fraction:g} % may be uncovered)")
    if s["no_dsm"] > o.max_nodata_fraction * A:
        fail(info.path, f"{s['no_dsm']:.2f} m^2 ({100 * s['no_dsm'] / A:.1f} %) of polygon {poly.name!r} has no "
                        f"surveyed heights (at most {100 * o.max_nodata_fraction:g} % may be missing)")
    if s["area"] <= 0:
        fail(info.path, f"no cell of polygon {poly.name!r} has both a surveyed and a design height")
    warnings = []
    if s["no_design"] > 0:
        warnings.append(f"{s['no_design']:.2f} m^2 ({100 * s['no_design'] / A:.2f} %) of the polygon is not covered "
                        "by the design surface: left out of the quantities")
    if s["no_dsm"] > 0:
        warnings.append(f"{s['no_dsm']:.2f} m^2 ({100 * s['no_dsm'] / A:.2f} %) of the polygon has no surveyed "
                        "heights: left out of the quantities")

    # ---- uncertainty -----------------------------------------------------------------------------------
    area = s["area"]
    rms_d = math.sqrt(max(s["sum_d2"] / area, 0.0))

    def sigma_of(key, bias_m3):
        noise = correlated_sum_sigma(U[key], block, window.dx, window.dy, model.sigma_z_m, model.correlation_length_m)
        design_m3 = bias_m3 * o.design_sigma_m / model.height_bias_m if model.height_bias_m > 0 else (
            o.design_sigma_m * area if key == "all" else 0.0)
        comp = {"dsm_noise_m3": noise, "vertical_bias_m3": bias_m3, "design_m3": design_m3,
                "unmeasured_m3": (s["no_design"] + s["no_dsm"]) * rms_d if key == "all" else 0.0}
        tot = math.sqrt(sum(v * v for v in comp.values()))
        return {"sigma_m3": round(tot, 4), "ci95_m3": round(Z95 * tot, 4),
                "components_m3": {k: round(v, 4) for k, v in comp.items()}}

    unc = {"cut_m3": sigma_of("cut", 0.5 * (s["cut_up"] - s["cut_down"])),
           "fill_m3": sigma_of("fill", 0.5 * (s["fill_down"] - s["fill_up"])),
           "net_m3": sigma_of("all", model.height_bias_m * area)}
    progress("contours", 0, 1)
    small_d = np.concatenate(small, axis=0) if small else np.zeros((0, 0), np.float32)
    levels = {f"+{t:g} m (tolerance band edge, cut side)": t, f"-{t:g} m (tolerance band edge, fill side)": -t}
    if t == 0:
        levels = {"0 m (on design)": 0.0}
    feats = _contours(small_d, window.x0, window.y0, window.dx * stride, window.dy * stride, levels)
    share = lambda v: round(v / area, 5)  # noqa: E731
    doc = {
        "dsm": {"path": str(info.path), "crs": info.crs_label(), "cell_size_m": round(info.cell_size_m, 6)},
        "design": design.describe(),
        "polygon": {"name": poly.name, "source": polygon.source, "crs": crs_label(polygon.crs),
                    "area_m2": round(poly.area_m2, 4)},
        "tolerance_m": t, "k": o.k,
        "cut_m3": round(s["cut"], 4), "fill_m3": round(s["fill"], 4), "net_m3": round(s["cut"] - s["fill"], 4),
        "uncertainty": unc,
        "noise_inflation_m3": round(s["inflation"], 4),
        "cut_beyond_tolerance_m3": round(s["cut_beyond_t"], 4), "fill_beyond_tolerance_m3": round(s["fill_beyond_t"], 4),
        "significant_cut_m3": round(s["sig_cut"], 4), "significant_fill_m3": round(s["sig_fill"], 4),
        "area_m2": round(area, 4),
        "on_grade": {"share": share(s["on_grade"]), "area_m2": round(s["on_grade"], 4),
                     "expected_share": share(s["expected_on_grade"]),
                     "surely_share": share(s["surely_on_grade"]), "possibly_share": share(s["possibly_on_grade"]),
                     "notes": ("share: cells with |d| <= tolerance; expected_share: sum of each cell's probability of "
                               "being within tolerance given sigma_cell; surely: |d| + k sigma_cell <= tolerance; "
                               "possibly: |d| - k sigma_cell <= tolerance")},
        "classes_m2": {"cut": round(s["cls_cut"], 4), "fill": round(s["cls_fill"], 4), "on_grade": round(s["on_grade"], 4),
                       "not_significant": round(s["not_significant"], 4),
                       "no_data": round(s["no_design"] + s["no_dsm"], 4)},
        "significance": {"sigma_cell_m": round(sigma_cell, 5), "threshold_m": round(threshold, 5),
                         "dsm_sigma_m": model.sigma_z_m, "vertical_rmse_m": model.height_bias_m,
                         "design_sigma_m": o.design_sigma_m, "correlation_length_m": model.correlation_length_m,
                         "sources": acc["sources"],
                         "rule": "not significant when |d| < k * sigma_cell, sigma_cell = sqrt(dsm_sigma^2 + "
                                 "vertical_rmse^2 + design_sigma^2)"},
        "difference_m": {"mean": round(s["sum_d"] / area, 5), "rms": round(rms_d, 5),
                         "min": round(s["d_min"], 5), "max": round(s["d_max"], 5)},
        "no_design_m2": round(s["no_design"], 4), "no_dsm_m2": round(s["no_dsm"], 4),
        "warnings": warnings,
        "conventions": ("d = surveyed - design; cut_m3: surveyed above design (material to remove); fill_m3: "
                        "surveyed below design (material to place); net_m3 = cut_m3 - fill_m3 (DSM-CRS grid m^2 x m)"),
        "classes": {str(k): v for k, v in CLASS_NAMES.items()},
        "timings_s": {"total_s": round(time.perf_counter() - t0, 3)},
    }
    if out is not None:
        gj = {"type": "FeatureCollection", "name": "design difference contours",
              "crs": {"type": "name", "properties": {"name": info.crs_label()}}, "features": feats}
        tmp["contours"].write_text(json.dumps(gj))
        doc["outputs"] = {k: str(out / v) for k, v in OUTPUT_NAMES.items()}
        tmp["quantities"].write_text(json.dumps(doc, indent=1))
        try:
            _to_cog(tmp)
        except BaseException:
            for p in tmp.values():
                p.unlink(missing_ok=True)
            raise
        for k, v in OUTPUT_NAMES.items():
            tmp[k].replace(out / v)
    doc["contours"] = len(feats)
    progress("done", 1, 1)
    return doc


def options_from(values: dict | None) -> CutFillOptions:
    """CutFillOptions from a dict of its field names (None values: the defaults)."""
    names = set(CutFillOptions.__dataclass_fields__)
    vals = {k: v for k, v in (values or {}).items() if k in names and v is not None}
    return CutFillOptions(**vals)


def options_dict(o: CutFillOptions) -> dict:
    return asdict(o)
