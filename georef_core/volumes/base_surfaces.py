"""Base surfaces under a volume: what the material is measured above (and the void below).

Methods (``--base``):

* ``lowest`` / ``highest``: a horizontal plane at a low / high percentile (default 2 / 98) of the
  outline heights after a running median along the outline (about 1 m): no single pixel decides.
* ``mean``: horizontal plane at the mean outline height (samples beyond 3.5 robust sigma from the
  median left out).
* ``plane``: best-fit inclined plane through the outline heights, robust (iteratively reweighted
  least squares, Tukey biweight, scale from the MAD); its RMS is reported.
* ``tin``: linear interpolation over a Delaunay triangulation of the outline samples (the "triangulated
  outline" of survey software), evaluated at every cell centre.
* ``elevation:Z``: horizontal plane at Z (the DSM's height system).
* ``surface:FILE.tif``: another raster (design surface, an earlier survey's DSM), resampled bilinearly
  onto the DSM grid (any CRS).

Each base is a plain object with ``to_dict()`` (its parameters: enough to rebuild it on another survey,
see :func:`base_from_dict`, which is how a stockpile record locks its base) and, for the kernel, either
a plane in window pixel coordinates (``plane_in_window``) or a per-cell grid (``grid_in_window``).
For the uncertainty, the linear outline bases also give the weight of each outline sample in the
base's integral over the polygon (``sample_weights``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from ..errors import ProcessingError
from .outline import OutlineSamples, running_median_profile
from .raster_io import GridWindow

OUTLINE_METHODS = ("lowest", "highest", "mean", "plane", "tin")
METHODS = OUTLINE_METHODS + ("elevation", "surface")


@dataclass
class BaseSpec:
    """A requested base: a method and, for ``elevation``/``surface``, its value."""

    method: str
    elevation_m: float | None = None
    surface_path: str | None = None
    percentile: float | None = None  # lowest/highest: default 2 / 98

    @classmethod
    def parse(cls, text: str) -> "BaseSpec":
        t = str(text).strip()
        key, _, value = t.partition(":")
        key = key.lower()
        if key == "elevation":
            try:
                z = float(value)
            except ValueError:
                raise ValueError(f"base {t!r}: elevation:Z needs a number, e.g. elevation:112.5") from None
            if not math.isfinite(z):
                raise ValueError(f"base {t!r}: elevation must be finite")
            return cls("elevation", elevation_m=z)
        if key == "surface":
            if not value:
                raise ValueError(f"base {t!r}: surface:FILE.tif needs a file")
            return cls("surface", surface_path=value)
        if key in OUTLINE_METHODS and not value:
            return cls(key)
        raise ValueError(f"unknown base {t!r}: use one of lowest, highest, mean, plane, tin, elevation:Z, surface:FILE.tif")

    def label(self) -> str:
        if self.method == "elevation":
            return f"elevation:{self.elevation_m:g}"
        if self.method == "surface":
            return f"surface:{self.surface_path}"
        return self.method


@dataclass
class BaseSurface:
    """Common interface. ``depends_on_dsm``: computed from this DSM's own outline, so a constant vertical
    bias of the DSM cancels in the volume."""

    method: str
    description: str = ""
    fit: dict = field(default_factory=dict)
    depends_on_dsm: bool = True
    sigma_m: float = 0.0  # uncertainty of the base itself when it does not come from this DSM (1 sigma, m)
    sigma_source: str = ""

    def plane_in_window(self, window: GridWindow):
        """(q0, qu, qv): base = q0 + qu * u + qv * v at pixel coordinates (u, v) of ``window``, or None."""
        return None

    def grid_in_window(self, window: GridWindow, crs, coverage: np.ndarray | None):
        """Base height at each cell centre of ``window`` (float32, NaN where undefined), or None."""
        return None

    def reset_weights(self) -> None:
        """Forget the integral weights accumulated by ``grid_in_window`` (before a new integration)."""
        return None

    def sample_weights(self, moments: dict):
        """(sample indices, weights m^2): the base's integral over the polygon as a linear combination of
        outline heights, for outline bases that are linear in them; None otherwise."""
        return None

    def mean_height_over(self, moments: dict) -> float | None:
        """Mean base height over the polygon from the coverage moments (A, centroid), planes only."""
        return None

    def to_dict(self) -> dict:
        raise NotImplementedError


@dataclass
class ConstantBase(BaseSurface):
    elevation_m: float = 0.0
    percentile: float | None = None
    _used: np.ndarray | None = field(default=None, repr=False)  # outline samples averaged (mean base)

    def plane_in_window(self, window):
        return (float(self.elevation_m), 0.0, 0.0)

    def mean_height_over(self, moments):
        return float(self.elevation_m)

    def sample_weights(self, moments):
        if self.method != "mean" or self._used is None or not len(self._used):
            return None
        return self._used, np.full(len(self._used), moments["area_m2"] / len(self._used))

    def to_dict(self):
        d = {"method": self.method, "elevation_m": float(self.elevation_m)}
        if self.percentile is not None:
            d["percentile"] = self.percentile
        return d


@dataclass
class PlaneBase(BaseSurface):
    """z = z_ref + dz_dx (x - x_ref) + dz_dy (y - y_ref) in the DSM CRS."""

    x_ref: float = 0.0
    y_ref: float = 0.0
    z_ref_m: float = 0.0
    dz_dx: float = 0.0
    dz_dy: float = 0.0
    _design: tuple | None = field(default=None, repr=False)  # (indices, X, weights) of the robust fit

    def height_at(self, x, y):
        return self.z_ref_m + self.dz_dx * (np.asarray(x) - self.x_ref) + self.dz_dy * (np.asarray(y) - self.y_ref)

    def plane_in_window(self, window):
        q0 = self.z_ref_m + self.dz_dx * (window.x0 - self.x_ref) + self.dz_dy * (window.y0 - self.y_ref)
        return (float(q0), float(self.dz_dx * window.dx), float(self.dz_dy * window.dy))

    def mean_height_over(self, moments):
        return float(self.height_at(moments["centroid_x"], moments["centroid_y"]))

    def sample_weights(self, moments):
        if self._design is None:
            return None
        idx, X, w = self._design
        m = np.array([moments["area_m2"], moments["area_m2"] * (moments["centroid_x"] - self.x_ref),
                      moments["area_m2"] * (moments["centroid_y"] - self.y_ref)])
        N = X.T @ (w[:, None] * X)
        return idx, w * (X @ np.linalg.solve(N, m))

    def to_dict(self):
        return {"method": "plane", "x_ref": float(self.x_ref), "y_ref": float(self.y_ref),
                "z_ref_m": float(self.z_ref_m), "dz_dx": float(self.dz_dx), "dz_dy": float(self.dz_dy),
                "equation": "z = z_ref_m + dz_dx*(x - x_ref) + dz_dy*(y - y_ref)  (DSM CRS)",
                "slope_percent": round(100 * math.hypot(self.dz_dx, self.dz_dy), 3)}


@njit(cache=True)
def _rasterize_triangles(tri, pu, pv, pz, nrows, ncols, cov, cell_area, out, assigned, ck):
    """Linear interpolation over triangles (pixel coordinates) at cell centres; each cell is taken by the
    first triangle containing its centre. ``ck[k]`` accumulates the integral weight of vertex k
    (coverage x barycentric coordinate x cell area)."""
    for t in range(tri.shape[0]):
        a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
        det = (pv[b] - pv[c]) * (pu[a] - pu[c]) + (pu[c] - pu[b]) * (pv[a] - pv[c])
        if abs(det) < 1e-12:
            continue
        vmin = min(pv[a], min(pv[b], pv[c]))
        vmax = max(pv[a], max(pv[b], pv[c]))
        i0 = max(int(math.ceil(vmin - 0.5 - 1e-9)), 0)
        i1 = min(int(math.floor(vmax - 0.5 + 1e-9)), nrows - 1)
        for i in range(i0, i1 + 1):
            y = i + 0.5
            xlo = 1e300
            xhi = -1e300
            for e in range(3):
                p = tri[t, e]
                q = tri[t, (e + 1) % 3]
                ylo = min(pv[p], pv[q])
                yhi = max(pv[p], pv[q])
                if y < ylo - 1e-9 or y > yhi + 1e-9:
                    continue
                if yhi - ylo < 1e-12:
                    xa = min(pu[p], pu[q])
                    xb = max(pu[p], pu[q])
                else:
                    xa = pu[p] + (y - pv[p]) * (pu[q] - pu[p]) / (pv[q] - pv[p])
                    xb = xa
                xlo = min(xlo, xa)
                xhi = max(xhi, xb)
            if xhi < xlo:
                continue
            j0 = max(int(math.ceil(xlo - 0.5 - 1e-9)), 0)
            j1 = min(int(math.floor(xhi - 0.5 + 1e-9)), ncols - 1)
            for j in range(j0, j1 + 1):
                if assigned[i, j]:
                    continue
                x = j + 0.5
                l1 = ((pv[b] - pv[c]) * (x - pu[c]) + (pu[c] - pu[b]) * (y - pv[c])) / det
                l2 = ((pv[c] - pv[a]) * (x - pu[c]) + (pu[a] - pu[c]) * (y - pv[c])) / det
                l3 = 1.0 - l1 - l2
                out[i, j] = l1 * pz[a] + l2 * pz[b] + l3 * pz[c]
                assigned[i, j] = True
                w = cov[i, j]
                if w > 0.0:
                    ck[a] += w * l1 * cell_area
                    ck[b] += w * l2 * cell_area
                    ck[c] += w * l3 * cell_area


def rasterize_tin(points_uvz: np.ndarray, triangles: np.ndarray, nrows: int, ncols: int):
    """Linear interpolation of a TIN at the cell centres of an ``nrows x ncols`` grid: ``points_uvz`` (n, 3)
    in pixel coordinates of the grid (column, row, height), ``triangles`` (m, 3) vertex indices. Returns
    (heights float32 with NaN where no triangle holds the cell centre, boolean mask of covered cells)."""
    tri = np.ascontiguousarray(triangles, dtype=np.int64)
    out = np.full((nrows, ncols), np.nan, np.float32)
    assigned = np.zeros((nrows, ncols), np.bool_)
    if len(tri) and nrows and ncols:
        pu = np.ascontiguousarray(points_uvz[:, 0], dtype=np.float64)
        pv = np.ascontiguousarray(points_uvz[:, 1], dtype=np.float64)
        pz = np.ascontiguousarray(points_uvz[:, 2], dtype=np.float64)
        cov = np.zeros((nrows, ncols), np.float32)  # no integral weights wanted: coverage 0 everywhere
        _rasterize_triangles(tri, pu, pv, pz, nrows, ncols, cov, 0.0, out, assigned, np.zeros(len(pu)))
    return out, assigned


@dataclass
class TinBase(BaseSurface):
    """Linear interpolation over the Delaunay triangulation of points (x, y, z) in the DSM CRS; cells
    outside the triangulation's hull take the nearest point's height."""

    points_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    _indices: np.ndarray | None = field(default=None, repr=False)  # outline sample index of each point
    _ck: np.ndarray | None = field(default=None, repr=False)

    _tri: np.ndarray | None = field(default=None, repr=False)

    def reset_weights(self):
        self._ck = None

    def grid_in_window(self, window, crs, coverage):
        """Heights at the cell centres of ``window`` (a whole window or one strip of it); the vertices'
        integral weights (coverage x barycentric x cell area) accumulate over calls."""
        from scipy.spatial import Delaunay, cKDTree

        pts = self.points_xyz
        if self._tri is None:
            xy = pts[:, :2] - pts[:, :2].mean(axis=0)
            try:
                self._tri = Delaunay(xy).simplices.astype(np.int64)
            except Exception as exc:
                raise ProcessingError(f"the outline samples cannot be triangulated for the TIN base ({exc})") from None
        pu, pv = window.to_pixel(pts[:, 0], pts[:, 1])
        pu, pv = np.ascontiguousarray(pu), np.ascontiguousarray(pv)
        out = np.full((window.nrows, window.ncols), np.nan, np.float32)
        assigned = np.zeros((window.nrows, window.ncols), np.bool_)
        cov = coverage if coverage is not None else np.zeros((window.nrows, window.ncols), np.float32)
        if self._ck is None:
            self._ck = np.zeros(len(pts))
        _rasterize_triangles(self._tri, pu, pv, np.ascontiguousarray(pts[:, 2], dtype=np.float64), window.nrows,
                             window.ncols, cov, window.cell_area_m2, out, assigned, self._ck)
        missing = ~assigned & (cov > 0)
        if missing.any():  # coverage beyond the hull (edge cells): nearest outline point
            ii, jj = np.nonzero(missing)
            _, k = cKDTree(np.column_stack([pu, pv])).query(np.column_stack([jj + 0.5, ii + 0.5]))
            out[ii, jj] = pts[k, 2]
            np.add.at(self._ck, k, cov[ii, jj] * window.cell_area_m2)
        return out

    def sample_weights(self, moments):
        if self._indices is None or self._ck is None:
            return None
        return self._indices, self._ck

    def to_dict(self):
        return {"method": "tin", "points_xyz_m": np.round(self.points_xyz, 4).tolist(),
                "interpolation": "linear on the Delaunay triangulation of the points; nearest point outside its hull"}


@dataclass
class SurfaceBase(BaseSurface):
    """Another raster (design surface or earlier DSM), bilinear onto the DSM grid."""

    path: str = ""
    offset_m: float = 0.0  # added to the surface's heights (vertical alignment of two surveys)
    _resampler: object = field(default=None, repr=False)

    def grid_in_window(self, window, crs, coverage):
        from .raster_io import WindowResampler

        if self._resampler is None or self._resampler.dst_crs != crs:
            self._resampler = WindowResampler(self.path, crs, "base surface")
        g = self._resampler(window)
        if self.offset_m:
            g += np.float32(self.offset_m)
        return g

    def to_dict(self):
        d = {"method": "surface", "path": str(self.path), "sigma_m": self.sigma_m}
        if self.offset_m:
            d["offset_m"] = self.offset_m
        return d


# ------------------------------------------------------------------------------------------------------
# fitting from outline samples


def _robust_scale(r: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(r - np.median(r)))) if r.size else 0.0


def fit_plane_robust(x, y, z, max_iter: int = 30):
    """Tukey-biweight IRLS plane z = b0 + b1 (x - xr) + b2 (y - yr); returns (x_ref, y_ref, beta, weights,
    residuals)."""
    xr, yr = float(np.mean(x)), float(np.mean(y))
    X = np.column_stack([np.ones_like(x), x - xr, y - yr])
    w = np.ones_like(z)
    beta = np.linalg.lstsq(X, z, rcond=None)[0]
    for _ in range(max_iter):
        r = z - X @ beta
        s = max(_robust_scale(r), 1e-3)
        c = 4.685 * s
        w_new = np.where(np.abs(r) < c, (1.0 - (r / c) ** 2) ** 2, 0.0)
        if np.count_nonzero(w_new) < 3:
            break
        N = X.T @ (w_new[:, None] * X)
        beta_new = np.linalg.solve(N, X.T @ (w_new * z))
        done = np.max(np.abs(beta_new - beta)) < 1e-9
        beta, w = beta_new, w_new
        if done:
            break
    return xr, yr, beta, w, z - X @ beta


def fit_outline_base(spec: BaseSpec, samples: OutlineSamples, smoothing_m: float = 1.0) -> BaseSurface:
    """The base of an outline method from the outline samples (NaN samples ignored)."""
    ok = np.flatnonzero(samples.valid)
    z = samples.z[ok]
    n_total = samples.n
    stats = {"n_samples": int(len(ok)), "n_samples_without_data": int(n_total - len(ok)),
             "sample_spacing_m": round(samples.spacing_m, 4), "outline_offset_m": round(samples.offset_m, 4),
             "outline_min_m": round(float(z.min()), 4), "outline_median_m": round(float(np.median(z)), 4),
             "outline_max_m": round(float(z.max()), 4)}
    m = spec.method
    if m in ("lowest", "highest"):
        p = spec.percentile if spec.percentile is not None else (2.0 if m == "lowest" else 98.0)
        zs = running_median_profile(samples, smoothing_m)[ok]
        zb = float(np.percentile(zs, p))
        stats.update(percentile=p, smoothing_window_m=smoothing_m)
        return ConstantBase(m, f"horizontal plane at the {p:g}th percentile of the outline heights "
                               f"(running median over {smoothing_m:g} m)", stats, True, elevation_m=zb, percentile=p)
    if m == "mean":
        med, s = float(np.median(z)), _robust_scale(z)
        keep = np.abs(z - med) <= max(3.5 * s, 1e-3)
        stats["n_rejected"] = int((~keep).sum())
        return ConstantBase("mean", "horizontal plane at the mean outline height", stats, True,
                            elevation_m=float(np.mean(z[keep])), _used=ok[keep])
    if m == "plane":
        if len(ok) < 3:
            raise ValueError("fewer than 3 outline samples with data")
        xr, yr, beta, w, r = fit_plane_robust(samples.x[ok], samples.y[ok], z)
        inl = w > 0
        stats.update(rms_m=round(float(np.sqrt(np.mean(r ** 2))), 4),
                     inlier_rms_m=round(float(np.sqrt(np.mean(r[inl] ** 2))), 4) if inl.any() else None,
                     max_abs_residual_m=round(float(np.max(np.abs(r))), 4), n_rejected=int((~inl).sum()))
        X = np.column_stack([np.ones(len(ok)), samples.x[ok] - xr, samples.y[ok] - yr])
        return PlaneBase("plane", "robust best-fit plane through the outline heights (Tukey biweight IRLS)", stats,
                         True, x_ref=xr, y_ref=yr, z_ref_m=float(beta[0]), dz_dx=float(beta[1]), dz_dy=float(beta[2]),
                         _design=(ok, X, w))
    if m == "tin":
        pts = np.column_stack([samples.x[ok], samples.y[ok], z])
        return TinBase("tin", "linear interpolation on the Delaunay triangulation of the outline samples", stats,
                       True, points_xyz=pts, _indices=ok)
    raise ValueError(f"{m!r} is not an outline base method")


def fixed_base(spec: BaseSpec, sigma_m: float = 0.0, sigma_source: str = "") -> BaseSurface:
    """Bases that do not come from the outline: ``elevation`` and ``surface``."""
    if spec.method == "elevation":
        return ConstantBase("elevation", f"horizontal plane at {spec.elevation_m:g} m", {}, False,
                            elevation_m=float(spec.elevation_m))
    if spec.method == "surface":
        p = Path(spec.surface_path)
        from .raster_io import open_elevation_raster

        open_elevation_raster(p, "base surface")  # validates (exists, CRS, ...) with a clear error
        return SurfaceBase("surface", f"surface {p.name} resampled bilinearly onto the DSM grid", {}, False,
                           sigma_m=sigma_m, sigma_source=sigma_source, path=str(p))
    raise ValueError(f"{spec.method!r} is not a fixed base")


def base_from_dict(d: dict, sigma_m: float = 0.0) -> BaseSurface:
    """Rebuild a base from its ``to_dict()`` parameters (a locked stockpile base). The result does not
    depend on the DSM it is applied to (``depends_on_dsm`` False); ``sigma_m`` is its own uncertainty."""
    m = d.get("method")
    if m in ("lowest", "highest", "mean", "elevation"):
        return ConstantBase(m, f"locked horizontal plane at {float(d['elevation_m']):g} m", {}, False, sigma_m,
                            elevation_m=float(d["elevation_m"]), percentile=d.get("percentile"))
    if m == "plane":
        return PlaneBase("plane", "locked plane", {}, False, sigma_m, x_ref=float(d["x_ref"]), y_ref=float(d["y_ref"]),
                         z_ref_m=float(d["z_ref_m"]), dz_dx=float(d["dz_dx"]), dz_dy=float(d["dz_dy"]))
    if m == "tin":
        pts = np.asarray(d["points_xyz_m"], dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
            raise ValueError("locked TIN base needs at least 3 points [x, y, z]")
        return TinBase("tin", f"locked TIN of {len(pts)} outline points", {}, False, sigma_m, points_xyz=pts)
    if m == "surface":
        return SurfaceBase("surface", f"locked surface {Path(d['path']).name}", {}, False,
                           float(d.get("sigma_m", sigma_m)), path=str(d["path"]), offset_m=float(d.get("offset_m", 0.0)))
    raise ValueError(f"unknown base method {m!r} in stored parameters")
