"""Volume of material above / void below a base surface inside a polygon, with its uncertainty.

Conventions (those of survey and drone-mapping software): ``cut_m3`` is the material above the base
(what would be cut to bring the ground down to the base: a stockpile), ``fill_m3`` the void below the
base (what would be filled: a pit), ``net_m3 = cut_m3 - fill_m3``. Never an absolute value.
Volumes are in DSM-CRS units: grid square metres x metres of height (the projection's scale factor is
not applied; divide by k^2 for true ground volume).

The integral is the midpoint rule on the DSM cells (heights at cell centres), each cell weighted by the
exact fraction of it inside the polygon.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn, no_progress
from .base_surfaces import OUTLINE_METHODS, BaseSpec, BaseSurface, PlaneBase, TinBase, fit_outline_base, fixed_base
from .coverage import polygon_coverage
from .integration import Integrator
from .nodata_fill import fill_holes
from .outline import block_means, sample_outline
from .polygons import AreaPolygon, crs_label
from .raster_io import GridWindow, RasterInfo, WindowReader, open_elevation_raster, read_window
from .uncertainty import (NoiseModel, block_size_for, combine, correlated_sum_sigma, normal_quantile,
                          smoothed_profile_sigma)


@dataclass
class VolumeOptions:
    """Knobs of the volume computation (defaults are the documented behaviour)."""

    percentile: float | None = None  # lowest/highest: percentile of the outline heights (default 2 / 98)
    smoothing_m: float = 1.0  # running median along the outline before the percentile (lowest/highest)
    outline_spacing_m: float | None = None  # default: one cell
    outline_offset_m: float | None = None  # default: 1.5 cells outward, or the DSM smoothing radius when larger
    max_fill_fraction: float = 0.05  # nodata inside the polygon filled up to this fraction of its area
    base_model_spread: bool = True  # compute mean/plane/TIN nets for the base-model uncertainty term
    surface_sigma_m: float | None = None  # noise of an imported base surface (default: its dense_summary.json or 0)
    # interpolated cells (the dense step's mask value 1, and no-data filled here): False: outside the stated
    # uncertainty, reported with their own bound ("not supported by measurement"); True: taken as measured
    accept_interpolated: bool = False


@dataclass
class VolumeResult:
    name: str
    cut_m3: float
    fill_m3: float
    net_m3: float
    area_m2: float
    base: dict
    uncertainty: dict
    base_nets_m3: dict = field(default_factory=dict)  # net with each outline base (method spread)
    filled_nodata_m2: float = 0.0
    dsm_interpolated_m2: float | None = None  # cells the dense step interpolated (dsm_filled_mask.tif), if known
    interpolated: dict = field(default_factory=dict)  # share, net and bound of the interpolated cells (module doc)
    base_height_sigma_m: float = 0.0  # 1 sigma of the mean base height (what a locked base carries)
    dsm: dict = field(default_factory=dict)
    polygon: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    timings_s: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("cut_m3", "fill_m3", "net_m3", "area_m2", "filled_nodata_m2"):
            d[k] = round(d[k], 4)
        d["base_height_sigma_m"] = round(d["base_height_sigma_m"], 5)
        d["conventions"] = ("cut_m3: material above the base; fill_m3: void below the base; net_m3 = cut_m3 - fill_m3 "
                            "(DSM-CRS grid m^2 x m)")
        return d


def _r(v, n=4):
    return None if v is None else round(float(v), n)


IN_MEMORY_CELLS = 16_000_000  # windows up to this size are read at once; larger ones stream in strips
STRIP_CELLS = 4_000_000  # about this many cells per strip (16 MB of float32)


class _DsmWindow:
    """The DSM window around one polygon, its coverage, and its heights: in memory (small windows, or
    once holes must be filled) or streamed from the file in row strips aligned on the file's blocks."""

    def __init__(self, info: RasterInfo, poly: AreaPolygon, margin_m: float, in_memory_cells: int | None = None):
        x0, y0, x1, y1 = poly.geometry.bounds
        self.info = info
        self.window = info.window_for_bounds(x0 - margin_m, y0 - margin_m, x1 + margin_m, y1 + margin_m, 2)
        self.cov = polygon_coverage(poly.geometry, self.window)
        self.block = block_size_for(self.window.nrows, self.window.ncols)
        self.z = None
        if self.window.nrows * self.window.ncols <= (IN_MEMORY_CELLS if in_memory_cells is None else in_memory_cells):
            self.load()
        self._dense = None

    def load(self) -> np.ndarray:
        if self.z is None:
            self.z = read_window(self.info, self.window)
        return self.z

    def read_sub(self, sub: GridWindow) -> np.ndarray:
        """Heights of a sub-window (from memory if loaded, else from the file)."""
        if self.z is not None:
            r, c = sub.row0 - self.window.row0, sub.col0 - self.window.col0
            return self.z[r:r + sub.nrows, c:c + sub.ncols]
        return read_window(self.info, sub)

    def dense(self) -> np.ndarray:
        if self._dense is None:
            self._dense = self.cov.dense(np.float32)
        return self._dense

    def strips(self) -> list[tuple[int, int]]:
        """(first row, rows) of the strips covering the rows the polygon reaches."""
        rp = self.cov.row_ptr
        used = np.flatnonzero(np.diff(rp) > 0)
        if not len(used):
            return []
        first, last = int(used[0]), int(used[-1]) + 1
        if self.z is not None:
            return [(first, last - first)]
        step = max(self.info.block_rows, 1)
        step *= max(1, STRIP_CELLS // (self.window.ncols * step))
        out = []
        r = first
        while r < last:
            nxt = min(((self.window.row0 + r) // step + 1) * step - self.window.row0, last)
            out.append((r, nxt - r))
            r = nxt
        return out


def check_inside(info: RasterInfo, poly: AreaPolygon) -> None:
    """InputFileError if ``poly`` (DSM CRS) is not entirely over the DSM's extent."""
    import shapely

    ext = shapely.box(*info.bounds)
    g = poly.geometry
    where = poly.source or "polygon"
    if not g.intersects(ext):
        b = g.bounds
        raise InputFileError(where, f"polygon {poly.name!r} lies outside the DSM {info.path.name} (polygon "
                                    f"{b[0]:.1f}..{b[2]:.1f} E, {b[1]:.1f}..{b[3]:.1f} N vs DSM {info.bounds[0]:.1f}.."
                                    f"{info.bounds[2]:.1f} E, {info.bounds[1]:.1f}..{info.bounds[3]:.1f} N in "
                                    f"{crs_label(info.crs)}): wrong CRS or wrong file?")
    outside = g.difference(ext).area
    if outside > 1e-9 * g.area:
        raise InputFileError(where, f"polygon {poly.name!r} extends {outside:.2f} m^2 ({100 * outside / g.area:.2f} %) "
                                    f"beyond the DSM {info.path.name}: no heights there")


def _noise_sigma_of(weights, w: _DsmWindow, model: NoiseModel, sigma: float | None = None) -> float:
    return correlated_sum_sigma(weights, w.block, w.window.dx, w.window.dy,
                                model.sigma_z_m if sigma is None else sigma, model.correlation_length_m)


def _deposit_samples(U: np.ndarray, w: _DsmWindow, samples, idx: np.ndarray, ck: np.ndarray, sign: float = -1.0) -> None:
    """Add ``sign * ck`` (m^2) at the coarse block of each outline sample ``idx``."""
    u, v = w.window.to_pixel(samples.x[idx], samples.y[idx])
    bi = np.clip(np.floor(v / w.block).astype(int), 0, U.shape[0] - 1)
    bj = np.clip(np.floor(u / w.block).astype(int), 0, U.shape[1] - 1)
    np.add.at(U, (bi, bj), sign * ck)


def _coarse_tin(samples, coarse: np.ndarray, w: _DsmWindow, a_cell: float):
    """Mean height over the polygon of a TIN on the outline (for the base-model spread, not for the volume):
    the outline averaged over runs of one coarse block, the TIN evaluated at the coarse block centres and
    weighted by their coverage. Returns (mean height, sample indices, weight of each sample in the TIN's
    integral over the polygon, m^2)."""
    b = w.block
    pts, group = block_means(samples, b)
    cw = GridWindow(0, 0, coarse.shape[0], coarse.shape[1], w.window.x0, w.window.y0, w.window.dx * b, w.window.dy * b)
    frac = (coarse * a_cell / cw.cell_area_m2).astype(np.float32)
    tin = TinBase("tin", points_xyz=pts)
    tin.grid_in_window(cw, None, frac)
    ck = tin._ck
    mean_h = float(np.sum(ck * pts[:, 2]) / np.sum(ck))
    idx = np.flatnonzero(group >= 0)
    members = np.bincount(group[idx], minlength=len(pts))
    c = ck[group[idx]] / members[group[idx]] * (np.sum(coarse) * a_cell / np.sum(ck))
    return mean_h, idx, c


class _FixedGrid(BaseSurface):
    """A grid base already evaluated on the whole window (after filling its holes)."""

    def __init__(self, inner: BaseSurface, grid: np.ndarray, full: GridWindow):
        self.__dict__.update(inner.__dict__)
        self._inner, self._grid, self._full = inner, grid, full

    def grid_in_window(self, window, crs, coverage):
        r, c = window.row0 - self._full.row0, window.col0 - self._full.col0
        return self._grid[r:r + window.nrows, c:c + window.ncols]

    def sample_weights(self, moments):
        return self._inner.sample_weights(moments)

    def to_dict(self):
        return self._inner.to_dict()


def _integrate_window(w: _DsmWindow, surface: BaseSurface, z_ref: float):
    """Run the kernel over the window, strip by strip (next strip read in a thread while the current one
    is integrated)."""
    from concurrent.futures import ThreadPoolExecutor

    acc = Integrator(w.cov, w.block, z_ref)
    surface.reset_weights()
    strips = w.strips()

    def run(r0, n, z):
        sub = w.window.sub(r0, n)
        plane = surface.plane_in_window(sub)
        grid = None
        if plane is None:
            cov = w.dense()[r0:r0 + n] if w._dense is not None else w.cov.rows(r0, n).dense(np.float32)
            grid = surface.grid_in_window(sub, w.info.crs, cov)
        acc.add(z, r0, plane, grid)

    if w.z is not None:
        for r0, n in strips:
            run(r0, n, w.z[r0:r0 + n])
        return acc.result()
    if not strips:
        return acc.result()
    rows_max = max(n for _, n in strips)
    bufs = [np.empty((rows_max, w.window.ncols), np.float32) for _ in range(2)]
    with WindowReader(w.info) as reader, ThreadPoolExecutor(1) as pool:
        def fetch(k):
            r0, n = strips[k]
            return pool.submit(reader.read, w.window.sub(r0, n), bufs[k % 2][:n])

        fut = fetch(0)
        for k, (r0, n) in enumerate(strips):
            z = fut.result()
            if k + 1 < len(strips):
                fut = fetch(k + 1)
            run(r0, n, z)
    return acc.result()


FILLED_MASK = "dsm_filled_mask.tif"  # written by the dense step next to dsm.tif: 0 measured, 1 interpolated, 255 none


def _filled_mask_window(w: _DsmWindow) -> np.ndarray | None:
    """The dense step's mask (``dsm_filled_mask.tif`` next to the DSM, same grid) over the window; None without
    one."""
    import rasterio
    from rasterio.windows import Window

    path = w.info.path.with_name(FILLED_MASK)
    if not path.exists():
        return None
    try:
        with rasterio.open(path) as ds:
            if (ds.width, ds.height) != (w.info.width, w.info.height) or \
                    not np.allclose(tuple(ds.transform)[:6], (w.info.dx, 0, w.info.x0, 0, w.info.dy, w.info.y0)):
                return None
            return ds.read(1, window=Window(w.window.col0, w.window.row0, w.window.ncols, w.window.nrows))
    except rasterio.errors.RasterioError:
        return None


MASK_INTERPOLATED = 1  # dsm_filled_mask.tif: 0 measured, 2 measured at coarse resolution, 1 interpolated, 255 none


def _interpolated_part(w: _DsmWindow, surface: BaseSurface, z_ref: float, interp: np.ndarray, sigma_z_m: float,
                       a_cell: float) -> dict:
    """The interpolated cells ``interp`` (window-sized bool) inside the polygon: their area, the net volume on
    them, and the bound: per connected interpolated area, its area inside the polygon x the height range of
    the measured cells around it (at least 3 sigma_z). Harmonic interpolation stays within its rim's heights;
    the bound says how far the volume on those cells moves if the unseen surface lies anywhere in that range."""
    from scipy import ndimage

    z = w.load()
    rows = np.flatnonzero(interp.any(axis=1))
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    cov = w.cov.rows(r0, r1 - r0).dense(np.float32)
    band = interp[r0:r1] & (cov > 0)
    if not band.any():
        return {"area_m2": 0.0, "net_m3": 0.0, "bound_m3": 0.0, "areas": 0}
    sub = w.window.sub(r0, r1 - r0)
    plane = surface.plane_in_window(sub)
    grid = None if plane is not None else surface.grid_in_window(sub, w.info.crs, cov)
    acc = Integrator(w.cov, w.block, z_ref)
    acc.add(np.where(band, z[r0:r1], np.float32(np.nan)).astype(np.float32), r0, plane, grid)
    sums = acc.result()
    labels, n = ndimage.label(interp, structure=np.ones((3, 3)))
    rim = ndimage.grey_dilation(labels, size=(3, 3)) * (~interp & np.isfinite(z))
    idx = np.arange(1, n + 1)
    hi = ndimage.maximum(z, rim, idx)
    lo = ndimage.minimum(z, rim, idx)
    rng = np.nan_to_num(np.asarray(hi, float) - np.asarray(lo, float), nan=0.0)
    h = np.maximum(rng, 3.0 * sigma_z_m)
    lab_band = labels[r0:r1]
    area_r = np.bincount(lab_band[band], weights=cov[band].astype(float), minlength=n + 1)[1:] * a_cell
    return {"area_m2": float(area_r.sum()), "net_m3": float((sums.cut - sums.fill) * a_cell),
            "bound_m3": float(np.sum(area_r * h)), "areas": int(np.count_nonzero(area_r > 0)),
            "largest_rim_range_m": float(rng[area_r > 0].max()) if np.any(area_r > 0) else 0.0}


def compute_volume(dsm, polygon: AreaPolygon, base, options: VolumeOptions | None = None,
                   noise: NoiseModel | None = None, progress: ProgressFn | None = None) -> VolumeResult:
    """Cut, fill and net volume of ``polygon`` (any CRS) on ``dsm`` (path or RasterInfo) above ``base``
    (a BaseSpec, a '--base' string, or a BaseSurface such as a locked stockpile base)."""
    o = options or VolumeOptions()
    progress = progress or no_progress
    t0 = time.perf_counter()
    timings = {}
    info = dsm if isinstance(dsm, RasterInfo) else open_elevation_raster(dsm)
    model = noise or NoiseModel.for_dsm(info.path)
    if isinstance(base, str):
        try:
            base = BaseSpec.parse(base)
        except ValueError as exc:
            raise ProcessingError(str(exc)) from None
    if isinstance(base, BaseSpec) and base.percentile is None and o.percentile is not None:
        base = BaseSpec(base.method, base.elevation_m, base.surface_path, o.percentile)
    poly = polygon.to_crs(info.crs)
    check_inside(info, poly)
    cell = info.cell_size_m
    # the base is sampled outside the outline, beyond the DSM's smoothing of the toe (1.5 cells at least)
    offset = max(1.5 * cell, model.smoothing_radius_m or 0.0) if o.outline_offset_m is None else o.outline_offset_m
    progress("read", 0, 4)
    w = _DsmWindow(info, poly, offset + 2 * cell)
    a_cell = w.window.cell_area_m2
    timings["read_s"] = time.perf_counter() - t0
    warnings: list[str] = []

    # ---- base ------------------------------------------------------------------------------------
    progress("base", 1, 4)
    t = time.perf_counter()
    samples = None
    spec = base if isinstance(base, BaseSpec) else None
    is_outline = spec is not None and spec.method in OUTLINE_METHODS
    if is_outline:
        if w.z is not None:
            samples = sample_outline(poly.geometry, w.window, w.read_sub, o.outline_spacing_m, offset)
        else:
            with WindowReader(info) as reader:
                samples = sample_outline(poly.geometry, w.window, reader.read, o.outline_spacing_m, offset)
        n_ok = int(samples.valid.sum())
        if n_ok < 3:
            raise InputFileError(info.path, f"the DSM has no data along the outline of {poly.name!r} "
                                            f"({n_ok} of {samples.n} samples): cannot derive a '{spec.method}' base")
        if n_ok < 0.5 * samples.n:
            warnings.append(f"only {n_ok} of {samples.n} outline samples have DSM data")
    if isinstance(base, BaseSurface):
        surface = base
    elif is_outline:
        try:
            surface = fit_outline_base(spec, samples, o.smoothing_m)
        except ValueError as exc:
            raise ProcessingError(f"{poly.name!r}: {exc}") from None
    else:
        s_sigma, s_src = 0.0, "imported surface taken as exact (give its sigma for another survey's DSM)"
        if spec.method == "surface":
            if o.surface_sigma_m is not None:
                s_sigma, s_src = float(o.surface_sigma_m), "given"
            else:
                sm = NoiseModel.for_dsm(spec.surface_path)
                if sm.sources.get("sigma_z_m", "").startswith("dense_summary"):
                    s_sigma, s_src = sm.sigma_z_m, f"{sm.sources['sigma_z_m']} next to the surface"
        surface = fixed_base(spec, s_sigma, s_src)
    timings["base_s"] = time.perf_counter() - t

    # ---- integration -----------------------------------------------------------------------------
    progress("integrate", 2, 4)
    t = time.perf_counter()
    if samples is not None and samples.valid.any():
        z_ref = float(np.median(samples.z[samples.valid]))
    else:
        z_ref = float(getattr(surface, "elevation_m", 0.0) or 0.0)
    sums = _integrate_window(w, surface, z_ref)
    filled_m2 = 0.0
    filled_here = None
    if sums.missing_base > 0:  # grid base (imported surface) without data under part of the polygon
        miss = sums.missing_base * a_cell
        where = getattr(surface, "path", "") or info.path
        if miss > o.max_fill_fraction * poly.area_m2:
            raise InputFileError(where, f"the base surface has no data under {miss:.2f} m^2 "
                                        f"({100 * miss / poly.area_m2:.1f} %) of {poly.name!r}")
        w.load()
        grid = surface.grid_in_window(w.window, info.crs, w.dense())
        fill_holes(grid, (w.dense() > 0) & ~np.isfinite(grid))
        surface = _FixedGrid(surface, grid, w.window)
        warnings.append(f"base surface: {miss:.2f} m^2 without data under the polygon interpolated")
        sums = _integrate_window(w, surface, z_ref)
    if sums.missing > 0:
        if sums.area <= 0:
            raise InputFileError(info.path, f"the DSM has no data inside polygon {poly.name!r}")
        frac = sums.missing / (sums.area + sums.missing)
        filled_m2 = sums.missing * a_cell
        if frac > o.max_fill_fraction:
            raise InputFileError(info.path, f"{filled_m2:.2f} m^2 ({100 * frac:.1f} %) of polygon {poly.name!r} has no "
                                            f"DSM data; at most {100 * o.max_fill_fraction:g} % is filled by interpolation")
        z = w.load()
        filled_here = ~np.isfinite(z)
        rep = fill_holes(z, (w.dense() > 0) & ~np.isfinite(z))
        filled_here &= np.isfinite(z)
        warnings.append(f"{filled_m2:.2f} m^2 without DSM data inside the polygon filled by interpolation "
                        f"({rep.n_holes} hole(s), largest {rep.largest_hole_cells} cells)")
        sums = _integrate_window(w, surface, z_ref)
    if sums.area <= 0:
        raise InputFileError(info.path, f"the DSM has no data inside polygon {poly.name!r}")
    mask = _filled_mask_window(w)
    interp = None if mask is None else mask == MASK_INTERPOLATED
    interpolated_m2 = None
    if interp is not None:
        interpolated_m2 = float(np.sum(w.cov.dense(np.float32)[interp], dtype=np.float64)) * a_cell if interp.any() \
            else 0.0
        frac = interpolated_m2 / poly.area_m2
        if frac > 0.01:
            warnings.append(f"{interpolated_m2:.2f} m^2 ({100 * frac:.1f} %) of the polygon was interpolated by the "
                            f"dense step ({FILLED_MASK})")
    if filled_here is not None:
        interp = filled_here if interp is None else (interp | filled_here)
    if interp is not None and interp.any():
        part = _interpolated_part(w, surface, z_ref, interp, model.sigma_z_m, a_cell)
    else:
        part = {"area_m2": 0.0, "net_m3": 0.0, "bound_m3": 0.0, "areas": 0}
    part["fraction"] = part["area_m2"] / poly.area_m2
    part["accepted"] = bool(o.accept_interpolated)
    if part["area_m2"] > 0 and not o.accept_interpolated:
        warnings.append(f"{part['area_m2']:.2f} m^2 ({100 * part['fraction']:.1f} %) of the polygon is interpolated, "
                        f"not measured: {part['net_m3']:.3f} m^3 of the net stand on it, within +-{part['bound_m3']:.3f}"
                        f" m^3 (not in the stated uncertainty; accept_interpolated to count it as measured)")
    timings["integrate_s"] = time.perf_counter() - t

    area = sums.area * a_cell
    cut, fill = sums.cut * a_cell, sums.fill * a_cell
    moments = {"area_m2": area, "centroid_x": w.window.x0 + w.window.dx * sums.sum_u / sums.area,
               "centroid_y": w.window.y0 + w.window.dy * sums.sum_v / sums.area}
    mean_z = z_ref + sums.sum_dz_ref / sums.area

    # ---- other outline bases (method spread) -----------------------------------------------------
    progress("uncertainty", 3, 4)
    t = time.perf_counter()
    nets, weights = {}, {}
    if is_outline and o.base_model_spread:
        for m in ("mean", "plane", "tin"):
            if m == "tin":
                if isinstance(surface, TinBase):
                    nets[m], weights[m] = cut - fill, surface.sample_weights(moments)
                else:
                    h, idx, c = _coarse_tin(samples, sums.coarse, w, a_cell)
                    nets[m], weights[m] = (mean_z - h) * area, (idx, c)
                continue
            alt = surface if m == surface.method else fit_outline_base(BaseSpec(m), samples, o.smoothing_m)
            nets[m] = (mean_z - alt.mean_height_over(moments)) * area
            weights[m] = alt.sample_weights(moments)

    # ---- uncertainty -----------------------------------------------------------------------------
    U = sums.coarse * a_cell
    sw = surface.sample_weights(moments) if surface.depends_on_dsm else None
    if sw is not None:
        _deposit_samples(U, w, samples, sw[0], sw[1])
    comp = {"dsm_noise_m3": _noise_sigma_of(U, w, model)}
    base_sigma_vol = 0.0
    if sw is not None:
        Ub = np.zeros_like(U)
        _deposit_samples(Ub, w, samples, sw[0], sw[1], 1.0)
        base_sigma_vol = _noise_sigma_of(Ub, w, model)
    elif surface.method in ("lowest", "highest") and surface.depends_on_dsm:
        p = surface.percentile / 100.0
        s_s = smoothed_profile_sigma(model.sigma_z_m, model.correlation_length_m, samples.spacing_m, o.smoothing_m)
        base_sigma_vol = area * s_s * math.sqrt(1.0 + normal_quantile(p) ** 2)
        comp["base_m3"] = base_sigma_vol
    elif surface.method == "surface" and surface.sigma_m > 0:
        base_sigma_vol = _noise_sigma_of(sums.coarse * a_cell, w, model, surface.sigma_m)
        comp["base_m3"] = base_sigma_vol
    elif not surface.depends_on_dsm and surface.sigma_m > 0:
        base_sigma_vol = area * surface.sigma_m
        comp["base_m3"] = base_sigma_vol
    comp["height_bias_m3"] = 0.0 if surface.depends_on_dsm else abs(model.height_bias_m) * area
    spread = 0.0
    if len(nets) >= 2:
        # spread of the interpolating bases beyond what the DSM noise alone makes them disagree by
        # (method of moments: E[s^2] under noise = mean over pairs of Var(net_i - net_j) / 2 for 3 methods)
        s2 = float(np.var(list(nets.values()), ddof=1))
        keys = [k for k in nets if weights.get(k) is not None]
        e2, npair = 0.0, 0
        for i in range(len(keys)):
            for j in range(i + 1, len(keys)):
                Ud = np.zeros_like(U)
                _deposit_samples(Ud, w, samples, *weights[keys[i]], 1.0)
                _deposit_samples(Ud, w, samples, *weights[keys[j]], -1.0)
                e2 += _noise_sigma_of(Ud, w, model) ** 2
                npair += 1
        noise_s2 = e2 / npair / 2.0 if npair else 0.0
        spread = math.sqrt(max(s2 - noise_s2, 0.0))
    comp["base_model_m3"] = spread
    # interpolated cells: a floor term when accepted as measured; else outside the stated uncertainty (own bound)
    comp["nodata_fill_m3"] = part["area_m2"] * model.sigma_z_m if o.accept_interpolated else 0.0
    tot = combine(comp)
    base_h_sigma = math.sqrt(base_sigma_vol ** 2 + spread ** 2) / area
    timings["uncertainty_s"] = time.perf_counter() - t
    timings["total_s"] = time.perf_counter() - t0
    progress("done", 4, 4)

    bdict = surface.to_dict()
    bdict["description"] = surface.description
    if surface.fit:
        bdict["fit"] = surface.fit
    bdict["depends_on_dsm"] = surface.depends_on_dsm
    if not surface.depends_on_dsm:
        bdict["sigma_m"] = surface.sigma_m
        if surface.sigma_source:
            bdict["sigma_source"] = surface.sigma_source
    unc = {"sigma_m3": _r(tot["sigma_m3"], 3), "ci95_m3": _r(tot["ci95_m3"], 3),
           "components_m3": {k: _r(v, 3) for k, v in comp.items()},
           "relative_sigma": _r(tot["sigma_m3"] / abs(cut - fill), 5) if cut - fill != 0 else None,
           "model": model.to_dict(),
           "notes": ("1 sigma from the DSM noise (sigma_z per cell, Gaussian correlation over correlation_length_m), "
                     "the base's own error, the vertical bias (0 when the base comes from this DSM: it cancels), the "
                     "spread of the mean/plane/TIN bases beyond noise, combined in quadrature; ci95 = 1.96 sigma. "
                     + ("Interpolated cells (filled here or by the dense step) accepted as measured: their area x "
                        "sigma_z is in it." if o.accept_interpolated else
                        "It covers the measured cells only: interpolated cells (filled here or by the dense step) "
                        "are not supported by measurement; their share of the net and its bound are in "
                        "'interpolated'.")),
           "covers": "all cells (interpolated ones accepted)" if o.accept_interpolated else "measured cells"}
    if not o.accept_interpolated and part["bound_m3"] > 0:
        unc["ci95_with_interpolated_bound_m3"] = _r(tot["ci95_m3"] + part["bound_m3"], 3)
    if isinstance(surface, PlaneBase) and surface.fit:
        unc["plane_fit_rms_m"] = surface.fit.get("rms_m")
    return VolumeResult(
        name=poly.name, cut_m3=cut, fill_m3=fill, net_m3=cut - fill, area_m2=area, base=bdict, uncertainty=unc,
        base_nets_m3={k: round(v, 3) for k, v in nets.items()}, filled_nodata_m2=filled_m2,
        dsm_interpolated_m2=None if interpolated_m2 is None else round(interpolated_m2, 4),
        interpolated={k: (round(v, 4) if isinstance(v, float) else v) for k, v in part.items()},
        base_height_sigma_m=base_h_sigma,
        dsm={"path": str(info.path), "crs": info.crs_label(), "cell_size_m": round(cell, 6),
             "window": [w.window.row0, w.window.col0, w.window.nrows, w.window.ncols]},
        polygon={"source": polygon.source, "crs": crs_label(polygon.crs), "area_m2": round(poly.area_m2, 4),
                 "centroid_xy": [round(moments["centroid_x"], 3), round(moments["centroid_y"], 3)]},
        warnings=warnings, timings_s={k: round(v, 4) for k, v in timings.items()})


def compute_volumes(dsm, polygons: list[AreaPolygon], base, options: VolumeOptions | None = None,
                    noise: NoiseModel | None = None, progress: ProgressFn | None = None) -> list[VolumeResult]:
    """One result per polygon (see :func:`compute_volume`)."""
    info = dsm if isinstance(dsm, RasterInfo) else open_elevation_raster(dsm)
    model = noise or NoiseModel.for_dsm(info.path)
    progress = progress or no_progress
    out = []
    for k, p in enumerate(polygons):
        progress("polygons", k, len(polygons))
        out.append(compute_volume(info, p, base, options, model))
    progress("polygons", len(polygons), len(polygons))
    return out
