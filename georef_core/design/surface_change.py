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

Uncertainty (1 sigma, m^3), each survey's stated accuracy, the two surveys independent of each other (two
flights, two georeferencings): its DSM noise (a random field, sigma per cell, Gaussian correlation over its
length) through each quantity's cell weights (for cut_moved each cell weighted by P(delta + noise < 0), for
fill_placed by P(delta + noise > 0): smooth across delta = 0), and its vertical bias (1 sigma = its check-point
vertical RMSE, common to all its cells: area x bias for the net, the secant (q(delta + b) - q(delta - b)) / 2
for cut_moved and fill_placed), plus the area compared in one survey only x the RMS of delta. The design's
own error does not enter: the same design is subtracted from both surfaces.
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

    def __init__(self, ds, later_grid: GridWindow, later_crs):
        self.ds = ds
        self.grid = _grid_of(ds)
        self.same = _same_grid(self.grid, later_grid) and (ds.crs is None or later_crs is None or ds.crs == later_crs)
        self.later_crs = later_crs

    def __call__(self, window: GridWindow) -> np.ndarray:
        from rasterio.enums import Resampling
        from rasterio.warp import reproject, transform_bounds
        from rasterio.windows import Window

        if self.same:
            return self.ds.read(1, window=Window(window.col0, window.row0, window.ncols, window.nrows),
                                masked=True).filled(np.nan).astype(np.float64)
        x0, x1 = window.x0, window.x0 + window.ncols * window.dx
        y1, y0 = window.y0, window.y0 + window.nrows * window.dy
        if self.ds.crs is not None and self.later_crs is not None and self.ds.crs != self.later_crs:
            x0, y0, x1, y1 = transform_bounds(self.later_crs, self.ds.crs, x0, y0, x1, y1)
        g = self.grid
        m = FILL_CELLS + 3
        c0 = max(int(math.floor((x0 - g.x0) / g.dx)) - m, 0)
        c1 = min(int(math.ceil((x1 - g.x0) / g.dx)) + m, g.ncols)
        r0 = max(int(math.floor((y1 - g.y0) / g.dy)) - m, 0)
        r1 = min(int(math.ceil((y0 - g.y0) / g.dy)) + m, g.nrows)
        out = np.full((window.nrows, window.ncols), np.nan, np.float64)
        if c1 <= c0 or r1 <= r0:
            return out
        src = self.ds.read(1, window=Window(c0, r0, c1 - c0, r1 - r0), masked=True).filled(np.nan).astype(np.float64)
        src = _extend_nearest(src, FILL_CELLS)
        sub = g.sub(r0, r1 - r0, c0, c1 - c0)
        reproject(source=src, destination=out, src_transform=sub.transform, src_crs=self.ds.crs, src_nodata=np.nan,
                  dst_transform=window.transform, dst_crs=self.later_crs or self.ds.crs, dst_nodata=np.nan,
                  resampling=Resampling.bilinear)
        return out


def surface_change(earlier_difference, later_difference, area, earlier: SurveyAccuracy, later: SurveyAccuracy,
                   k: float = 1.96) -> dict:
    """The change between two surveys of the same design, cell by cell (module docstring). ``*_difference``:
    the design step's difference.tif of each survey (paths); ``area``: the design area as a shapely geometry
    or a GeoJSON geometry dict in the later difference's CRS. Returns the quantities, their 1-sigma and
    components, the areas compared and notes."""
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
            earlier_on = _EarlierOnLaterGrid(ds_e, grid, ds_l.crs)
            cov_all = polygon_coverage(geom, grid)
            a_cell = grid.cell_area_m2
            block = block_size_for(grid.nrows, grid.ncols)
            rows_per = max(block, (max(STRIP_CELLS // max(grid.ncols, 1), 1) // block) * block)
            cshape = (-(-grid.nrows // block), -(-grid.ncols // block))
            U = {key: np.zeros(cshape) for key in ("all", "cut", "fill")}
            sig_l, sig_e = later.dsm_sigma_m, earlier.dsm_sigma_m
            sig_d = math.hypot(sig_l, sig_e)
            keys = ("area", "polygon", "one_only", "cut", "fill", "net", "cut_below", "fill_above", "sum_d2",
                    "inflation", "cut_up_l", "cut_dn_l", "fill_up_l", "fill_dn_l", "cut_up_e", "cut_dn_e",
                    "fill_up_e", "fill_dn_e")
            s = dict.fromkeys(keys, 0.0)
            from rasterio.windows import Window

            for r0 in range(0, grid.nrows, rows_per):
                n = min(rows_per, grid.nrows - r0)
                sub = grid.sub(r0, n)
                cov = cov_all.rows(r0, n).dense(np.float64)
                inside = cov > 0
                d_l = ds_l.read(1, window=Window(0, r0, grid.ncols, n), masked=True).filled(np.nan).astype(np.float64)
                d_e = earlier_on(sub)
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
                # each survey's vertical bias: the later surface shifted by +-b (delta + b), the earlier (delta - b)
                for tag, b, sign in (("l", later.vertical_rmse_m, 1.0), ("e", earlier.vertical_rmse_m, -1.0)):
                    up, dn = dd + sign * b, dd - sign * b
                    s[f"cut_up_{tag}"] += float(np.sum(w * np.maximum(-up, 0.0)))
                    s[f"cut_dn_{tag}"] += float(np.sum(w * np.maximum(-dn, 0.0)))
                    s[f"fill_up_{tag}"] += float(np.sum(w * np.maximum(up, 0.0)))
                    s[f"fill_dn_{tag}"] += float(np.sum(w * np.maximum(dn, 0.0)))
                if sig_d > 0:
                    ad = np.abs(dd)
                    r = np.where(ad < k * sig_d, 0.0, ad / sig_d)   # not significant: taken as unchanged
                    phi = np.exp(-0.5 * r * r) / math.sqrt(2 * math.pi)
                    s["inflation"] += float(np.sum(w * sig_d * (phi - r * ndtr(-r))))
                    w_cut = w * ndtr(-dd / sig_d)
                else:
                    w_cut = np.where(dd < 0, w, 0.0)
                c0 = r0 // block
                for key, wk in (("all", w), ("cut", w_cut), ("fill", w - w_cut)):
                    bs = block_sums(wk, block)
                    U[key][c0:c0 + bs.shape[0]] += bs
    finally:
        ds_l.close()
    if s["area"] <= 0:
        raise ProcessingError(f"{later_difference} and {earlier_difference}: no cell of the design area has a "
                              "difference to the design in both surveys")
    area_m2 = s["area"]
    rms = math.sqrt(max(s["sum_d2"] / area_m2, 0.0))

    def sigma(key, bias_l, bias_e):
        comp = {"dsm_noise_later_m3": correlated_sum_sigma(U[key], block, grid.dx, grid.dy, sig_l,
                                                           later.correlation_length_m),
                "dsm_noise_earlier_m3": correlated_sum_sigma(U[key], block, grid.dx, grid.dy, sig_e,
                                                             earlier.correlation_length_m),
                "vertical_bias_later_m3": abs(bias_l), "vertical_bias_earlier_m3": abs(bias_e),
                "unmeasured_m3": s["one_only"] * rms if key == "all" else 0.0}
        tot = math.sqrt(sum(v * v for v in comp.values()))
        return {"sigma_m3": round(tot, 4), "ci95_m3": round(Z95 * tot, 4),
                "components_m3": {c: round(v, 4) for c, v in comp.items()}}

    unc = {"cut_moved_m3": sigma("cut", 0.5 * (s["cut_dn_l"] - s["cut_up_l"]), 0.5 * (s["cut_dn_e"] - s["cut_up_e"])),
           "fill_placed_m3": sigma("fill", 0.5 * (s["fill_up_l"] - s["fill_dn_l"]),
                                   0.5 * (s["fill_up_e"] - s["fill_dn_e"])),
           "net_change_m3": sigma("all", later.vertical_rmse_m * area_m2, earlier.vertical_rmse_m * area_m2)}
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
            "accuracy": {"earlier": vars(earlier), "later": vars(later)},
            "notes": notes}
