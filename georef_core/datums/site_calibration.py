"""Site calibration (localisation): the site's local grid from control points known both in the projected
CRS (from GNSS: E, N and a height h in the calibration's height datum) and in the local grid (e, n, H), as a
surveying controller computes it.

Horizontal: a 4-parameter similarity about the centroid (E0, N0) of the horizontal points,

    e = e0 + a (E - E0) - b (N - N0)        a = s cos(theta), b = s sin(theta)
    n = n0 + b (E - E0) + a (N - N0)

solved by least squares (unknowns e0, n0, a, b; at least 3 points, so that the residuals check something),
with sigma0^2 = sum(v^2) / (2 m - 4) and the parameters' sigmas from sigma0^2 (A^T A)^-1 (scale and
rotation propagated from a and b).

Vertical: an inclined plane on the height differences dz = H - h of the vertical points about their own
centroid (E0v, N0v):

    dz = c0 + c_n (N - N0v) + c_e (E - E0v)

(3 or more points; 1 or 2 points give a constant shift only, none leaves the heights unchanged).

Residuals: given local coordinate minus calibrated one (dE, dN, dH), per point, with their RMS and maximum.
A calibration is a JSON file (``format: georef-site-calibration``) holding the parameters, their sigmas and
the points with their residuals; read_calibration reads it back and the transformation is applied from the
stored parameters (points, and height rasters resampled onto a north-up local grid).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .raster_heights import pixel_to_map
from ..errors import InputFileError, ProcessingError

FORMAT = "georef-site-calibration"
USES = ("hv", "h", "v")


@dataclass
class ControlPair:
    name: str
    source_m: tuple[float, float, float]    # E, N (projected CRS) and h (the calibration's height datum)
    local_m: tuple[float, float, float]     # e, n, H in the local grid
    use: str = "hv"                         # hv: both, h: horizontal only, v: vertical only


@dataclass
class SiteCalibration:
    crs: str
    height_datum: str
    origin_source_m: tuple[float, float]          # (E0, N0): centroid of the horizontal points
    origin_local_m: tuple[float, float]           # (e0, n0): the image of (E0, N0)
    a: float
    b: float
    vertical_model: str                           # "inclined plane", "constant" or "none"
    vertical_origin_m: tuple[float, float]        # (E0v, N0v)
    c0_m: float = 0.0
    slope_north: float = 0.0                      # m per m of northing
    slope_east: float = 0.0
    sigmas: dict = field(default_factory=dict)
    pairs: list[ControlPair] = field(default_factory=list)
    name: str = ""

    @property
    def scale(self) -> float:
        return math.hypot(self.a, self.b)

    @property
    def rotation_rad(self) -> float:
        return math.atan2(self.b, self.a)

    # -------------------------------------------------------------------------------------- transformation
    def to_local(self, e_m, n_m, h_m=None):
        """Projected (E, N[, h]) -> local (e, n[, H]) (arrays or scalars)."""
        E, N = np.asarray(e_m, float), np.asarray(n_m, float)
        dE, dN = E - self.origin_source_m[0], N - self.origin_source_m[1]
        e = self.origin_local_m[0] + self.a * dE - self.b * dN
        n = self.origin_local_m[1] + self.b * dE + self.a * dN
        if h_m is None:
            return e, n
        return e, n, np.asarray(h_m, float) + self.height_shift_m(E, N)

    def height_shift_m(self, e_m, n_m) -> np.ndarray:
        """dz = H - h of the vertical adjustment at projected (E, N)."""
        E, N = np.asarray(e_m, float), np.asarray(n_m, float)
        return (self.c0_m + self.slope_north * (N - self.vertical_origin_m[1])
                + self.slope_east * (E - self.vertical_origin_m[0]))

    def to_source(self, e_m, n_m, h_m=None):
        """Local (e, n[, H]) -> projected (E, N[, h]): the inverse."""
        de = np.asarray(e_m, float) - self.origin_local_m[0]
        dn = np.asarray(n_m, float) - self.origin_local_m[1]
        s2 = self.a ** 2 + self.b ** 2
        E = self.origin_source_m[0] + (self.a * de + self.b * dn) / s2
        N = self.origin_source_m[1] + (-self.b * de + self.a * dn) / s2
        if h_m is None:
            return E, N
        return E, N, np.asarray(h_m, float) - self.height_shift_m(E, N)

    def residuals(self) -> list[dict]:
        """Per point: given local minus calibrated (dE, dN for horizontal points, dH for vertical ones)."""
        out = []
        for p in self.pairs:
            e, n, H = self.to_local(*p.source_m)
            r = {"name": p.name, "use": p.use}
            r["dE_m"] = float(p.local_m[0] - e) if "h" in p.use else None
            r["dN_m"] = float(p.local_m[1] - n) if "h" in p.use else None
            r["dH_m"] = float(p.local_m[2] - H) if ("v" in p.use and self.vertical_model != "none") else None
            out.append(r)
        return out

    def statistics(self) -> dict:
        res = self.residuals()
        dh = np.array([math.hypot(r["dE_m"], r["dN_m"]) for r in res if r["dE_m"] is not None])
        dv = np.array([r["dH_m"] for r in res if r["dH_m"] is not None])
        return {"n_horizontal": int(dh.size), "n_vertical": int(dv.size),
                "rms_horizontal_m": float(np.sqrt(np.mean(dh ** 2))) if dh.size else None,
                "max_horizontal_m": float(dh.max()) if dh.size else None,
                "rms_vertical_m": float(np.sqrt(np.mean(dv ** 2))) if dv.size else None,
                "max_vertical_m": float(np.abs(dv).max()) if dv.size else None}

    # ----------------------------------------------------------------------------------------------- file
    def to_dict(self) -> dict:
        return {
            "format": FORMAT, "version": 1, "name": self.name, "crs": self.crs, "height_datum": self.height_datum,
            "convention": "local = calibration(projected); residual = given local - calibrated (metres)",
            "horizontal": {"model": "similarity (4 parameters) about the centroid",
                           "origin_source_m": list(self.origin_source_m), "origin_local_m": list(self.origin_local_m),
                           "a": self.a, "b": self.b, "scale": self.scale,
                           "scale_ppm": (self.scale - 1.0) * 1e6, "rotation_deg": math.degrees(self.rotation_rad)},
            "vertical": {"model": self.vertical_model, "origin_source_m": list(self.vertical_origin_m),
                         "constant_m": self.c0_m, "slope_north": self.slope_north, "slope_east": self.slope_east,
                         "formula": "dz = constant + slope_north (N - N0) + slope_east (E - E0)"},
            "sigmas": self.sigmas,
            "points": [{"name": p.name, "use": p.use, "source_m": list(p.source_m), "local_m": list(p.local_m),
                        "residual_m": {k: r[k] for k in ("dE_m", "dN_m", "dH_m")}}
                       for p, r in zip(self.pairs, self.residuals())],
            "statistics": self.statistics()}

    def summary(self) -> dict:
        """What a step summary keeps: the parameters, their sigmas, the residuals per point (no coordinates)
        and their statistics."""
        d = self.to_dict()
        return {"name": self.name, "crs": self.crs, "height_datum": self.height_datum,
                "horizontal": {k: d["horizontal"][k] for k in ("scale", "scale_ppm", "rotation_deg", "origin_source_m",
                                                               "origin_local_m")},
                "vertical": {k: d["vertical"][k] for k in ("model", "constant_m", "slope_north", "slope_east")},
                "sigmas": dict(self.sigmas), "residuals": self.residuals(), "statistics": self.statistics()}

    def write(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    def format_text(self) -> str:
        lines = [f"site calibration {self.name or ''} ({self.crs}, heights {self.height_datum})".replace("  ", " "),
                 f"  scale {self.scale:.9f} ({(self.scale - 1) * 1e6:+.1f} ppm), rotation "
                 f"{math.degrees(self.rotation_rad):+.6f} deg, shift at centroid E {self.origin_source_m[0]:.3f} N "
                 f"{self.origin_source_m[1]:.3f} -> e {self.origin_local_m[0]:.3f} n {self.origin_local_m[1]:.3f}",
                 f"  vertical ({self.vertical_model}): constant {self.c0_m:+.4f} m, slope N "
                 f"{self.slope_north * 1e6:+.1f} ppm, slope E {self.slope_east * 1e6:+.1f} ppm",
                 f"  {'point':<12} {'use':<3} {'dE m':>8} {'dN m':>8} {'dH m':>8}"]
        for r in self.residuals():
            f = ["     n/a" if r[k] is None else f"{r[k]:8.4f}" for k in ("dE_m", "dN_m", "dH_m")]
            lines.append(f"  {r['name']:<12} {r['use']:<3} {' '.join(f)}")
        st = self.statistics()
        for lab, key in (("RMS", "rms"), ("max", "max")):
            hv, vv = st[f"{key}_horizontal_m"], st[f"{key}_vertical_m"]
            lines.append(f"  {lab:<16} horizontal {'n/a' if hv is None else f'{hv:.4f}'} m, vertical "
                         f"{'n/a' if vv is None else f'{vv:.4f}'} m")
        return "\n".join(lines)


def solve_calibration(pairs: list[ControlPair], crs: str = "", height_datum: str = "ellipsoidal",
                      name: str = "") -> SiteCalibration:
    """The least-squares calibration of these control pairs (module docstring)."""
    for p in pairs:
        if p.use not in USES:
            raise ProcessingError(f"control point {p.name}: use {p.use!r} is not one of {', '.join(USES)}")
    hor = [p for p in pairs if "h" in p.use]
    ver = [p for p in pairs if "v" in p.use]
    if len(hor) < 3:
        raise ProcessingError(f"a site calibration needs at least 3 horizontal control points (got {len(hor)}): "
                              "with 2 the similarity fits exactly and nothing checks it")
    S = np.array([p.source_m[:2] for p in hor], float)
    L = np.array([p.local_m[:2] for p in hor], float)
    s0 = S.mean(axis=0)
    d = S - s0
    m = len(hor)
    A = np.zeros((2 * m, 4))
    A[0::2, 0] = 1.0
    A[1::2, 1] = 1.0
    A[0::2, 2], A[0::2, 3] = d[:, 0], -d[:, 1]
    A[1::2, 2], A[1::2, 3] = d[:, 1], d[:, 0]
    y = L.reshape(-1)
    if np.linalg.matrix_rank(A) < 4:
        raise ProcessingError("the horizontal control points coincide: no similarity can be fitted")
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    v = y - A @ x
    dof = 2 * m - 4
    s0h2 = float(v @ v) / dof if dof > 0 else float("nan")
    Q = np.linalg.inv(A.T @ A)
    sx = np.sqrt(np.clip(np.diag(Q) * s0h2, 0.0, None))
    a, b = float(x[2]), float(x[3])
    s = math.hypot(a, b)
    # scale and rotation from (a, b): J = d(s, theta)/d(a, b)
    J = np.array([[a / s, b / s], [-b / s ** 2, a / s ** 2]])
    Cst = J @ (Q[2:, 2:] * s0h2) @ J.T
    sigmas = {"sigma0_horizontal_m": math.sqrt(s0h2) if dof > 0 else None, "dof_horizontal": dof,
              "shift_e_m": float(sx[0]), "shift_n_m": float(sx[1]), "a": float(sx[2]), "b": float(sx[3]),
              "scale": float(math.sqrt(max(Cst[0, 0], 0.0))), "rotation_deg": math.degrees(math.sqrt(max(Cst[1, 1], 0.0)))}
    cal = SiteCalibration(crs=crs, height_datum=height_datum, origin_source_m=(float(s0[0]), float(s0[1])),
                          origin_local_m=(float(x[0]), float(x[1])), a=a, b=b, vertical_model="none",
                          vertical_origin_m=(float(s0[0]), float(s0[1])), pairs=list(pairs), name=name)
    if ver:
        V = np.array([p.source_m for p in ver], float)
        dz = np.array([p.local_m[2] for p in ver], float) - V[:, 2]
        o = V[:, :2].mean(axis=0)
        cal.vertical_origin_m = (float(o[0]), float(o[1]))
        if len(ver) >= 3:
            B = np.column_stack([np.ones(len(ver)), V[:, 1] - o[1], V[:, 0] - o[0]])
            if np.linalg.matrix_rank(B) < 3:
                raise ProcessingError("the vertical control points lie on a line: no inclined plane can be fitted "
                                      "(use them for a constant shift: 'v' on one or two points only)")
            c, *_ = np.linalg.lstsq(B, dz, rcond=None)
            w = dz - B @ c
            vdof = len(ver) - 3
            s0v2 = float(w @ w) / vdof if vdof > 0 else float("nan")
            sc = np.sqrt(np.clip(np.diag(np.linalg.inv(B.T @ B)) * s0v2, 0.0, None))
            cal.vertical_model = "inclined plane"
            cal.c0_m, cal.slope_north, cal.slope_east = float(c[0]), float(c[1]), float(c[2])
            sigmas.update(sigma0_vertical_m=math.sqrt(s0v2) if vdof > 0 else None, dof_vertical=vdof,
                          constant_m=float(sc[0]) if vdof > 0 else None,
                          slope_north=float(sc[1]) if vdof > 0 else None, slope_east=float(sc[2]) if vdof > 0 else None)
        else:
            cal.vertical_model = "constant"
            cal.c0_m = float(dz.mean())
            vdof = len(ver) - 1
            s0v = float(np.std(dz, ddof=1)) if vdof > 0 else None
            sigmas.update(sigma0_vertical_m=s0v, dof_vertical=vdof,
                          constant_m=s0v / math.sqrt(len(ver)) if s0v is not None else None)
    # None, not NaN, where there is no redundancy (JSON has no NaN)
    cal.sigmas = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in sigmas.items()}
    return cal


def read_calibration(path) -> SiteCalibration:
    """A calibration file written by SiteCalibration.write; InputFileError naming what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "calibration file not found")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(path, f"not a JSON file ({exc})") from None
    return calibration_from_dict(doc, path)


def calibration_from_dict(doc, where) -> SiteCalibration:
    """A calibration from its JSON document (SiteCalibration.to_dict); ``where`` names it in the
    InputFileError (a file, or the setting that held it)."""
    path = where
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise InputFileError(path, f"not a site calibration (its 'format' is not {FORMAT!r})")
    if doc.get("version") != 1:
        raise InputFileError(path, f"calibration version {doc.get('version')!r}: this Georef reads version 1")
    try:
        h, v = doc["horizontal"], doc["vertical"]
        pairs = [ControlPair(str(p["name"]), tuple(float(c) for c in p["source_m"]),
                             tuple(float(c) for c in p["local_m"]), str(p.get("use", "hv"))) for p in doc.get("points", [])]
        cal = SiteCalibration(
            crs=str(doc.get("crs", "")), height_datum=str(doc.get("height_datum", "ellipsoidal")),
            origin_source_m=tuple(float(c) for c in h["origin_source_m"]),
            origin_local_m=tuple(float(c) for c in h["origin_local_m"]), a=float(h["a"]), b=float(h["b"]),
            vertical_model=str(v["model"]), vertical_origin_m=tuple(float(c) for c in v["origin_source_m"]),
            c0_m=float(v["constant_m"]), slope_north=float(v["slope_north"]), slope_east=float(v["slope_east"]),
            sigmas=dict(doc.get("sigmas") or {}), pairs=pairs, name=str(doc.get("name", "")))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputFileError(path, f"incomplete or malformed calibration ({type(exc).__name__}: {exc})") from None
    if len(cal.origin_source_m) != 2 or len(cal.origin_local_m) != 2 or not (cal.a or cal.b):
        raise InputFileError(path, "malformed horizontal parameters (origins need 2 values, a and b not both 0)")
    return cal


_COLUMNS = {"name": ("name", "point", "id"),
            "E": ("easting_m", "e", "easting", "x"), "N": ("northing_m", "n", "northing", "y"),
            "h": ("height_m", "h", "height", "z"),
            "e": ("local_e_m", "local_e", "local_easting_m", "local_x"),
            "n": ("local_n_m", "local_n", "local_northing_m", "local_y"),
            "H": ("local_h_m", "local_h", "local_height_m", "local_z"), "use": ("use",)}


def read_control_pairs(path) -> list[ControlPair]:
    """A CSV of control pairs: name, easting_m, northing_m, height_m (projected CRS, the calibration's height
    datum), local_e_m, local_n_m, local_h_m (local grid) and optionally use (hv, h or v; default hv)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "control point file not found")
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith("#")]
    if len(rows) < 2:
        raise InputFileError(path, "needs a header line and at least one point")
    head = [c.strip().lower() for c in rows[0]]
    idx = {}
    for key, names in _COLUMNS.items():
        for nm in names:
            if nm in head:
                idx[key] = head.index(nm)
                break
    need = [k for k in ("name", "E", "N", "h", "e", "n", "H") if k not in idx]
    if need:
        raise InputFileError(path, "needs the columns name, easting_m, northing_m, height_m, local_e_m, local_n_m, "
                                   f"local_h_m (missing: {', '.join(_COLUMNS[k][0] for k in need)})", line=1)
    out = []
    for ln, r in enumerate(rows[1:], start=2):
        try:
            vals = {k: float(r[idx[k]]) for k in ("E", "N", "h", "e", "n", "H")}
        except (ValueError, IndexError):
            raise InputFileError(path, f"row {r!r}: a coordinate is missing or not a number", line=ln) from None
        use = r[idx["use"]].strip().lower() if "use" in idx and idx["use"] < len(r) and r[idx["use"]].strip() else "hv"
        if use not in USES:
            raise InputFileError(path, f"use {use!r} is not one of {', '.join(USES)}", line=ln)
        out.append(ControlPair(r[idx["name"]].strip(), (vals["E"], vals["N"], vals["h"]),
                               (vals["e"], vals["n"], vals["H"]), use))
    names = [p.name for p in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputFileError(path, f"duplicate point names: {', '.join(dup)}")
    return out


def calibrate_raster(cal: SiteCalibration, src_path, dst_path, cell_m: float | None = None) -> dict:
    """A height raster (projected CRS, the calibration's height datum) resampled onto a north-up grid of the
    local system (bilinear; a cell whose four neighbours are not all valid is no-data) with the vertical
    adjustment added. Its CRS is an engineering (local) CRS named after the calibration."""
    import rasterio
    from rasterio.transform import from_origin
    from scipy.ndimage import map_coordinates

    from ..dense.cog_writer import write_cog

    src_path = Path(src_path)
    if not src_path.is_file():
        raise InputFileError(src_path, "raster not found")
    try:
        with rasterio.open(src_path) as src:
            z = src.read(1).astype(np.float64)
            tr, nodata, tags = src.transform, src.nodata, src.tags()
    except rasterio.errors.RasterioIOError as exc:
        raise InputFileError(src_path, f"not a readable GeoTIFF ({exc})") from None
    if nodata is not None:
        z[z == nodata] = np.nan
    h, w = z.shape
    corners = np.array([pixel_to_map(tr, c, r) for c in (0, w) for r in (0, h)])
    le, ln = cal.to_local(corners[:, 0], corners[:, 1])
    cell = float(cell_m or abs(tr.a))
    e_min, n_max = math.floor(le.min() / cell) * cell, math.ceil(ln.max() / cell) * cell
    ow = int(math.ceil((le.max() - e_min) / cell))
    oh = int(math.ceil((n_max - ln.min()) / cell))
    out_tr = from_origin(e_min, n_max, cell, cell)
    out = np.full((oh, ow), np.nan, np.float32)
    inv = ~tr
    for r0 in range(0, oh, 512):
        rr, cc = np.mgrid[r0:min(oh, r0 + 512), 0:ow] + 0.5
        e, n = pixel_to_map(out_tr, cc, rr)
        E, N = cal.to_source(e, n)
        col, row = pixel_to_map(inv, E, N)
        zz = map_coordinates(z, [row - 0.5, col - 0.5], order=1, mode="constant", cval=np.nan, prefilter=False)
        out[r0:r0 + rr.shape[0]] = (zz + cal.height_shift_m(E, N)).astype(np.float32)
    out_nodata = -9999.0
    out[~np.isfinite(out)] = out_nodata
    wkt = (f'ENGCRS["{cal.name or "site grid"}",EDATUM["site calibration"],CS[Cartesian,2],'
           'AXIS["easting (E)",east,ORDER[1],LENGTHUNIT["metre",1]],'
           'AXIS["northing (N)",north,ORDER[2],LENGTHUNIT["metre",1]]]')
    new_tags = {k: v for k, v in tags.items() if k != "AREA_OR_POINT"}
    new_tags.update(HEIGHTS=f"local grid heights (site calibration {cal.name or ''} on {cal.height_datum})",
                    SITE_CALIBRATION=json.dumps({k: v for k, v in cal.to_dict().items()
                                                 if k in ("horizontal", "vertical", "crs", "height_datum")}))
    write_cog(dst_path, out, out_tr, 0, nodata=out_nodata, tags=new_tags, units="metre", crs=wkt)
    valid = int(np.count_nonzero(out != out_nodata))
    return {"path": str(dst_path), "cell_m": cell, "width": ow, "height": oh, "valid_cells": valid}
