"""Design progress between two surveys, surface against surface: the earlier and the later survey's
differences to the design (each run's design step ``difference.tif``: surveyed - design, NaN outside the
design area) compared cell by cell on the later survey's grid, inside the design area.

Per cell of the later grid, ``delta = d_later - d_earlier`` (= later surface - earlier surface: the design
cancels exactly where both were compared with the same design):

* ``cut_moved_m3`` = sum of w max(-delta, 0): where the ground went **down** (material removed);
  ``fill_placed_m3`` = sum of w max(delta, 0): where it went **up** (material placed);
  ``net_change_m3`` = sum of w delta = fill_placed - cut_moved (the change of the net to design: positive,
  more material above the design than before). w = the exact fraction of the cell inside the area x its area.
* ``cut_below_design_m3``: the part of the material removed that lay below the design (over-excavation,
  where the later surface is under the design and lower than before); ``fill_above_design_m3``: the part of
  the material placed above the design.
* The earlier difference is resampled bilinearly onto the later grid (skipped when both grids are the same);
  its cells next to the area's edge are first extended by the nearest valid value (up to 2 cells), so that the
  later grid's edge cells keep a value.

Uncertainty (1 sigma, m^3), from both surveys' stated accuracy:

* **DSM noise**: each survey's (a random field, sigma per cell, Gaussian correlation exp(-(d/L)^2) over its length)
  through each quantity's cell weights (for cut_moved each cell weighted by P(delta + noise < 0), for fill_placed
  by P(delta + noise > 0): smooth across delta = 0); the two surveys' fields independent.
* **Vertical bias, with a part common to both surveys**: survey i's bias b_i = c + u_i, c common to both (the
  same control points / base coordinates under both georeferencings), var(b_i) = vertical_rmse_i^2,
  var(c) = common_bias_m^2 (at most the smaller vertical RMSE), u_l and u_e independent. Every quantity depends on
  the biases only through delta + (b_l - b_e), whose sigma is
  beta = sqrt(rmse_l^2 + rmse_e^2 - 2 common_bias_m^2): area x beta for the net, the secant
  (q(delta + beta) - q(delta - beta)) / 2 for cut_moved and fill_placed (an unchanged cell counts beta/2).
  common_bias_m = 0 is the independent case.
* **Resampling** (only where the earlier grid is not the later one): bilinear interpolation at the fractional
  offset (tx, ty) of a later cell centre in the earlier grid errs by ~ 1/2 [tx(1-tx) g_x + ty(1-ty) g_y], g the
  earlier surface's second differences along x and y (its local roughness; exact on a plane). Per cell
  eps = 1/2 [tx(1-tx) sqrt(max(g_x^2 - v, 0)) + ty(1-ty) sqrt(max(g_y^2 - v, 0))], v = sigma_e^2 (6 - 8 rho(h) +
  2 rho(2h)) the earlier DSM noise's own share of g^2 (rho(h) = exp(-(h/L)^2), h the cell size); the eps of the
  cells taken as one field correlated like the earlier DSM noise (its L) through the quantity's weights.
* The area compared in one survey only x the RMS of delta (net).

``noise_inflation_m3``: what random per-cell errors (both DSMs' noise and eps) add, on average, to each of the
gross cut_moved and fill_placed: sum of w (s phi(r) - |delta| Phi(-r)), s = sqrt(sigma_l^2 + sigma_e^2 + eps^2),
r = |delta| / s (0 for a change under k s: taken as unchanged). Stated beside them, not taken off.

The design's own error does not enter: the same design is subtracted from both surfaces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputFileError, ProcessingError
from ..volumes.coverage import polygon_coverage
from ..volumes.raster_io import GridWindow
from ..volumes.uncertainty import Z95, block_size_for, correlated_sum_sigma
from .cut_fill import block_sums   # one block-sum (the sigma of correlated cells) for both

STRIP_CELLS = 4_000_000
FILL_CELLS = 2   # the earlier difference is extended this many cells beyond its valid cells before resampling


@dataclass
class SurveyAccuracy:
    """A survey's stated accuracy (its design step's cut_fill.json ``significance``)."""

    dsm_sigma_m: float
    vertical_rmse_m: float
    correlation_length_m: float

    @classmethod
    def from_cut_fill(cls, doc: dict, where: str = "cut_fill.json") -> "SurveyAccuracy":
        sig = (doc or {}).get("significance") or {}
        try:
            vals = [float(sig[k]) for k in ("dsm_sigma_m", "vertical_rmse_m", "correlation_length_m")]
        except (KeyError, TypeError, ValueError):
            raise ProcessingError(f"{where}: no significance.dsm_sigma_m / vertical_rmse_m / correlation_length_m "
                                  "(the survey's accuracy)") from None
        if not all(math.isfinite(v) and v >= 0 for v in vals):
            raise ProcessingError(f"{where}: the survey's accuracy must be finite numbers >= 0 (got {vals})")
        return cls(*vals)


def _grid_of(ds) -> GridWindow:
    t = ds.transform
    if t.b != 0 or t.d != 0 or t.e >= 0:
        raise InputFileError(ds.name, "a north-up grid expected (no rotation)")
    return GridWindow(0, 0, ds.height, ds.width, t.c, t.f, t.a, t.e)


def _same_grid(a: GridWindow, b: GridWindow) -> bool:
    tol = 1e-6 * abs(a.dx)
    return (a.nrows, a.ncols) == (b.nrows, b.ncols) and all(
        abs(x - y) <= tol for x, y in ((a.x0, b.x0), (a.y0, b.y0), (a.dx, b.dx), (a.dy, b.dy)))


def _extend_nearest(a: np.ndarray, cells: int) -> np.ndarray:
    """NaN cells within ``cells`` of a valid cell take the nearest valid cell's value."""
    from scipy.ndimage import distance_transform_edt

    bad = ~np.isfinite(a)
    if not bad.any() or bad.all():
        return a
    dist, (ii, jj) = distance_transform_edt(bad, return_indices=True)
    out = a.copy()
    near = bad & (dist <= cells)
    out[near] = a[ii[near], jj[near]]
    return out


class _EarlierOnLaterGrid:
    """The earlier difference raster on windows of the later grid (bilinear; the same grid read directly)."""

    def __init__(self, ds, later_grid: GridWindow, later_crs, noise_var_m2: float = 0.0):
        self.ds = ds
        self.grid = _grid_of(ds)
        self.noise_var = noise_var_m2   # the earlier DSM noise's share of a squared second difference
        self.same = _same_grid(self.grid, later_grid) and (ds.crs is None or later_crs is None or ds.crs == later_crs)
        self.later_crs = later_crs

    def __call__(self, window: GridWindow) -> tuple[np.ndarray, np.ndarray]:
        """(the earlier difference on ``window``, the per-cell 1-sigma resampling error eps in m: module
        docstring; zeros when the grids are the same)."""
        from rasterio.enums import Resampling
        from rasterio.warp import reproject, transform_bounds
        from rasterio.windows import Window

        if self.same:
            vals = self.ds.read(1, window=Window(window.col0, window.row0, window.ncols, window.nrows),
                                masked=True).filled(np.nan).astype(np.float64)
            return vals, np.zeros_like(vals)
        x0, x1 = window.x0, window.x0 + window.ncols * window.dx
        y1, y0 = window.y0, window.y0 + window.nrows * window.dy
        other_crs = self.ds.crs is not None and self.later_crs is not None and self.ds.crs != self.later_crs
        if other_crs:
            x0, y0, x1, y1 = transform_bounds(self.later_crs, self.ds.crs, x0, y0, x1, y1)
        g = self.grid
        m = FILL_CELLS + 3
        c0 = max(int(math.floor((x0 - g.x0) / g.dx)) - m, 0)
        c1 = min(int(math.ceil((x1 - g.x0) / g.dx)) + m, g.ncols)
        r0 = max(int(math.floor((y1 - g.y0) / g.dy)) - m, 0)
        r1 = min(int(math.ceil((y0 - g.y0) / g.dy)) + m, g.nrows)
        out = np.full((window.nrows, window.ncols), np.nan, np.float64)
        if c1 <= c0 or r1 <= r0:
            return out, np.zeros_like(out)
        src = self.ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True).filled(np.nan).astype(np.float64)
        src = _extend_nearest(src, FILL_CELLS)
        sub = g.sub(r0, r1 - r0, c0, c1 - c0)
        kw = dict(src_transform=sub.transform, src_crs=self.ds.crs, src_nodata=np.nan, dst_transform=window.transform,
                  dst_crs=self.later_crs or self.ds.crs, dst_nodata=np.nan, resampling=Resampling.bilinear)
        reproject(source=src, destination=out, **kw)
        rough = []   # the earlier surface's roughness along x and y, noise removed, on the later grid
        for axis in (1, 0):
            g2 = _second_difference(src, axis) ** 2 - self.noise_var
            g2 = np.where(np.isfinite(g2), np.maximum(g2, 0.0), 0.0)
            on = np.zeros_like(out)
            reproject(source=g2, destination=on, **{**kw, "src_nodata": None, "dst_nodata": None})
            rough.append(np.sqrt(np.maximum(on, 0.0)))
        if other_crs:   # the offsets vary over the window: the worst, t = 1/2
            fx = fy = np.full(1, 0.25)
        else:
            u = (window.x0 + (np.arange(window.ncols) + 0.5) * window.dx - g.x0) / g.dx - 0.5
            v = (window.y0 + (np.arange(window.nrows) + 0.5) * window.dy - g.y0) / g.dy - 0.5
            tx, ty = u - np.floor(u), v - np.floor(v)
            fx, fy = tx * (1 - tx), ty * (1 - ty)
        eps = 0.5 * (fx[None, :] * rough[0] + fy[:, None] * rough[1])
        return out, np.where(np.isfinite(out), eps, 0.0)


def _second_difference(a: np.ndarray, axis: int) -> np.ndarray:
    """z[k-1] - 2 z[k] + z[k+1] along ``axis`` (NaN at the ends and next to NaN)."""
    out = np.full_like(a, np.nan)
    if a.shape[axis] < 3:
        return out
    if axis == 1:
        out[:, 1:-1] = a[:, :-2] - 2 * a[:, 1:-1] + a[:, 2:]
    else:
        out[1:-1] = a[:-2] - 2 * a[1:-1] + a[2:]
    return out


def second_difference_noise_var(sigma_m: float, correlation_length_m: float, cell_m: float) -> float:
    """Variance of a second difference of the DSM noise alone (Gaussian correlation exp(-(d/L)^2))."""
    if correlation_length_m <= 0:
        rho1 = rho2 = 0.0
    else:
        rho1 = math.exp(-(cell_m / correlation_length_m) ** 2)
        rho2 = math.exp(-(2 * cell_m / correlation_length_m) ** 2)
    return sigma_m * sigma_m * max(6 - 8 * rho1 + 2 * rho2, 0.0)


def surface_change(earlier_difference, later_difference, area, earlier: SurveyAccuracy, later: SurveyAccuracy,
                   k: float = 1.96, common_bias_m: float = 0.0) -> dict:
    """The change between two surveys of the same design, cell by cell (module docstring). ``*_difference``:
    the design step's difference.tif of each survey (paths); ``area``: the design area as a shapely geometry
    or a GeoJSON geometry dict in the later difference's CRS; ``common_bias_m``: 1 sigma of the vertical bias
    common to both surveys (0: independent; clipped to the smaller vertical RMSE). Returns the quantities, their
    1-sigma and components, the areas compared and notes."""
    import rasterio
    from scipy.special import ndtr
    from shapely.geometry import shape

    geom = shape(area) if isinstance(area, dict) else area
    if geom.is_empty or geom.area <= 0:
        raise ProcessingError("the design area is empty")
    try:
        ds_l = rasterio.open(later_difference)
    except Exception as exc:   # rasterio's own error types
        raise InputFileError(later_difference, f"not a readable GeoTIFF ({exc})") from None
    try:
        try:
            ds_e = rasterio.open(earlier_difference)
        except Exception as exc:
            raise InputFileError(earlier_difference, f"not a readable GeoTIFF ({exc})") from None
        with ds_e:
            grid = _grid_of(ds_l)
            g_e = _grid_of(ds_e)
            earlier_on = _EarlierOnLaterGrid(ds_e, grid, ds_l.crs, second_difference_noise_var(
                earlier.dsm_sigma_m, earlier.correlation_length_m, max(abs(g_e.dx), abs(g_e.dy))))
            cov_all = polygon_coverage(geom, grid)
            a_cell = grid.cell_area_m2
            block = block_size_for(grid.nrows, grid.ncols)
            rows_per = max(block, (max(STRIP_CELLS // max(grid.ncols, 1), 1) // block) * block)
            cshape = (-(-grid.nrows // block), -(-grid.ncols // block))
            U = {key: np.zeros(cshape) for key in ("all", "cut", "fill")}
            U_rs = {key: np.zeros(cshape) for key in ("all", "cut", "fill")}   # weights x resampling error
            sig_l, sig_e = later.dsm_sigma_m, earlier.dsm_sigma_m
            sig_d = math.hypot(sig_l, sig_e)
            common = min(max(float(common_bias_m), 0.0), later.vertical_rmse_m, earlier.vertical_rmse_m)
            beta = math.sqrt(max(later.vertical_rmse_m ** 2 + earlier.vertical_rmse_m ** 2 - 2 * common ** 2, 0.0))
            keys = ("area", "polygon", "one_only", "cut", "fill", "net", "cut_below", "fill_above", "sum_d2",
                    "inflation", "cut_up", "cut_dn", "fill_up", "fill_dn", "eps_sum")
            s = dict.fromkeys(keys, 0.0)
            from rasterio.windows import Window

            for r0 in range(0, grid.nrows, rows_per):
                n = min(rows_per, grid.nrows - r0)
                sub = grid.sub(r0, n)
                cov = cov_all.rows(r0, n).dense(np.float64)
                inside = cov > 0
                d_l = ds_l.read(1, window=Window(0, r0, grid.ncols, n), masked=True).filled(np.nan).astype(np.float64)
                d_e, eps = earlier_on(sub)
                ok = inside & np.isfinite(d_l) & np.isfinite(d_e)
                either = inside & (np.isfinite(d_l) | np.isfinite(d_e))
                s["polygon"] += float(cov.sum()) * a_cell
                s["one_only"] += float(cov[either & ~ok].sum()) * a_cell
                w = np.where(ok, cov * a_cell, 0.0)
                dl = np.where(ok, d_l, 0.0)
                de = np.where(ok, d_e, 0.0)
                dd = dl - de
                s["area"] += float(w.sum())
                s["cut"] += float(np.sum(w * np.maximum(-dd, 0.0)))
                s["fill"] += float(np.sum(w * np.maximum(dd, 0.0)))
                s["net"] += float(np.sum(w * dd))
                s["sum_d2"] += float(np.sum(w * dd * dd))
                # removed below the design: the lowering's interval [dl, de] below 0; placed above: [de, dl] above 0
                s["cut_below"] += float(np.sum(w * np.where(dd < 0, np.maximum(np.minimum(de, 0.0) - dl, 0.0), 0.0)))
                s["fill_above"] += float(np.sum(w * np.where(dd > 0, np.maximum(dl - np.maximum(de, 0.0), 0.0), 0.0)))
                # the surveys' relative vertical bias b_l - b_e (1 sigma beta): delta shifted by +-beta
                up, dn = dd + beta, dd - beta
                s["cut_up"] += float(np.sum(w * np.maximum(-up, 0.0)))
                s["cut_dn"] += float(np.sum(w * np.maximum(-dn, 0.0)))
                s["fill_up"] += float(np.sum(w * np.maximum(up, 0.0)))
                s["fill_dn"] += float(np.sum(w * np.maximum(dn, 0.0)))
                eps = np.where(ok, eps, 0.0)
                s["eps_sum"] += float(np.sum(w * eps))
                # per cell: both DSMs' noise and the resampling error (random signs: they inflate gross quantities)
                sd = np.sqrt(sig_d * sig_d + eps * eps)
                pos = sd > 0
                safe = np.where(pos, sd, 1.0)
                ad = np.abs(dd)
                r = np.where(ad < k * sd, 0.0, ad / safe)   # not significant: taken as unchanged
                phi = np.exp(-0.5 * r * r) / math.sqrt(2 * math.pi)
                s["inflation"] += float(np.sum(np.where(pos, w * sd * (phi - r * ndtr(-r)), 0.0)))
                w_cut = np.where(pos, w * ndtr(-dd / safe), np.where(dd < 0, w, 0.0))
                c0 = r0 // block
                for key, wk in (("all", w), ("cut", w_cut), ("fill", w - w_cut)):
                    bs = block_sums(wk, block)
                    U[key][c0:c0 + bs.shape[0]] += bs
                    if not earlier_on.same:
                        bs = block_sums(wk * eps, block)
                        U_rs[key][c0:c0 + bs.shape[0]] += bs
    finally:
        ds_l.close()
    if s["area"] <= 0:
        raise ProcessingError(f"{later_difference} and {earlier_difference}: no cell of the design area has a "
                              "difference to the design in both surveys")
    area_m2 = s["area"]
    rms = math.sqrt(max(s["sum_d2"] / area_m2, 0.0))

    def sigma(key, bias):
        comp = {"dsm_noise_later_m3": correlated_sum_sigma(U[key], block, grid.dx, grid.dy, sig_l,
                                                           later.correlation_length_m),
                "dsm_noise_earlier_m3": correlated_sum_sigma(U[key], block, grid.dx, grid.dy, sig_e,
                                                             earlier.correlation_length_m),
                "vertical_bias_m3": abs(bias),
                "resampling_m3": correlated_sum_sigma(U_rs[key], block, grid.dx, grid.dy, 1.0,
                                                      earlier.correlation_length_m),
                "unmeasured_m3": s["one_only"] * rms if key == "all" else 0.0}
        tot = math.sqrt(sum(v * v for v in comp.values()))
        return {"sigma_m3": round(tot, 4), "ci95_m3": round(Z95 * tot, 4),
                "components_m3": {c: round(v, 4) for c, v in comp.items()}}

    unc = {"cut_moved_m3": sigma("cut", 0.5 * (s["cut_dn"] - s["cut_up"])),
           "fill_placed_m3": sigma("fill", 0.5 * (s["fill_up"] - s["fill_dn"])),
           "net_change_m3": sigma("all", beta * area_m2)}
    notes = []
    if s["one_only"] > 0.001 * s["polygon"]:
        notes.append(f"{s['one_only']:.2f} m^2 ({100 * s['one_only'] / s['polygon']:.2f} %) of the design area has a "
                     "difference in one survey only: left out of the change (counted in its sigma)")
    return {"method": "surfaces",
            "cut_moved_m3": round(s["cut"], 4), "fill_placed_m3": round(s["fill"], 4),
            "net_change_m3": round(s["net"], 4),
            "cut_below_design_m3": round(s["cut_below"], 4), "fill_above_design_m3": round(s["fill_above"], 4),
            "sigma_m3": {key: v["sigma_m3"] for key, v in unc.items()}, "uncertainty": unc,
            "noise_inflation_m3": round(s["inflation"], 4),
            "area_m2": round(area_m2, 4), "one_survey_only_m2": round(s["one_only"], 4),
            "grid": {"cell_size_m": round(abs(grid.dx), 6), "rows": grid.nrows, "cols": grid.ncols,
                     "earlier_resampled": not earlier_on.same},
            "accuracy": {"earlier": vars(earlier), "later": vars(later), "common_bias_m": round(common, 6),
                         "relative_bias_m": round(beta, 6),
                         "resampling_mean_m": round(s["eps_sum"] / area_m2, 6)},
            "notes": notes}
