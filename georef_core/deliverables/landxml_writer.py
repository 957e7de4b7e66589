"""The surveyed surface as a LandXML 1.2 TIN (Civil 3D, Trimble Business Center, 12d, Carlson read it).

The TIN is a regular grid of vertices ``spacing_m`` apart (a whole number of cells of the surface), each
quad split into two triangles along the diagonal whose two heights differ least (the diagonal that follows
a ridge or a toe rather than cutting across it). A vertex takes the height of the surface smoothed by a
Gaussian of half the spacing (so a vertex stands for its neighbourhood, not for one noisy cell); a vertex
on a no-data cell is left out and so are the triangles that would use it: the TIN stops at no-data.
``tin_from_surface`` also reports how far the TIN departs from the surface at the surface's cells
(RMS, 95th percentile and maximum |dz|, on up to 200 000 cells).

The file: Units Metric (metres, square and cubic metres), CoordinateSystem with the EPSG code of the
horizontal CRS, its OGC WKT (the CRS stating the heights) and the vertical datum by name, one Surface
whose Definition (surfType TIN) lists Pnts (``P``: northing easting elevation, LandXML's order) and
Faces (``F``: three point ids)."""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..errors import ProcessingError
from .contours import smooth_surface
from .surface import Surface

LANDXML_NS = "http://www.landxml.org/schema/LandXML-1.2"
MAX_TIN_POINTS = 250_000


@dataclass
class Tin:
    xyz_m: np.ndarray        # (n, 3) easting, northing, height
    faces: np.ndarray        # (m, 3) 0-based vertex indices, counter-clockwise seen from above
    spacing_m: float
    deviation: dict          # |TIN - surface| at the surface's cells: rms_m, p95_m, max_m, n_cells

    def area_2d_m2(self) -> float:
        a, b, c = (self.xyz_m[self.faces[:, i], :2] for i in range(3))
        u, v = b - a, c - a
        return float(0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum())

    def area_3d_m2(self) -> float:
        a, b, c = (self.xyz_m[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def default_spacing(surface: Surface, minimum_m: float = 0.5, max_points: int = MAX_TIN_POINTS) -> float:
    """The smallest whole number of cells that is at least ``minimum_m`` and keeps the vertices under
    ``max_points``."""
    cell = surface.cell_m
    n_valid = int(np.isfinite(surface.z_m).sum())
    k = max(1, math.ceil(minimum_m / cell - 1e-9), math.ceil(math.sqrt(n_valid / max_points)))
    return k * cell


def tin_from_surface(surface: Surface, spacing_m: float | None = None) -> Tin:
    if spacing_m is None:
        spacing_m = default_spacing(surface)
    cell = surface.cell_m
    k = max(1, int(round(spacing_m / cell)))
    z_s = smooth_surface(surface.z_m, k / 2.0) if k > 1 else surface.z_m
    rows = np.arange(0, surface.z_m.shape[0], k)
    cols = np.arange(0, surface.z_m.shape[1], k)
    g = z_s[np.ix_(rows, cols)]
    valid = np.isfinite(g)
    if valid.sum() < 3:
        raise ProcessingError(f"{surface.path}: too few valid heights for a TIN at {k * cell:g} m spacing")
    ids = np.full(g.shape, -1, np.int64)
    ids[valid] = np.arange(int(valid.sum()))
    xs, ys = surface.x_m[cols], surface.y_m[rows]
    jj, ii = np.meshgrid(np.arange(len(cols)), np.arange(len(rows)))
    xyz = np.column_stack([xs[jj[valid]], ys[ii[valid]], g[valid]])
    # quad corners: a (i, j), b (i, j+1), c (i+1, j), d (i+1, j+1); rows go south, so a-b-c is clockwise seen
    # from above: faces are written a, c, b (counter-clockwise)
    a, b, c, d = ids[:-1, :-1], ids[:-1, 1:], ids[1:, :-1], ids[1:, 1:]
    za, zb, zc, zd = g[:-1, :-1], g[:-1, 1:], g[1:, :-1], g[1:, 1:]
    with np.errstate(invalid="ignore"):
        diag_ad = (b < 0) | (c < 0) | ((a >= 0) & (d >= 0) & (np.abs(za - zd) <= np.abs(zb - zc)))
    tris = []
    for p, q, r, use in ((a, c, d, diag_ad), (a, d, b, diag_ad), (a, c, b, ~diag_ad), (b, c, d, ~diag_ad)):
        ok = use & (p >= 0) & (q >= 0) & (r >= 0)
        tris.append(np.column_stack([p[ok], q[ok], r[ok]]))
    faces = np.concatenate(tris)
    if len(faces) == 0:
        raise ProcessingError(f"{surface.path}: no triangle of valid heights at {k * cell:g} m spacing")
    return Tin(xyz, faces, k * cell, _deviation(surface.z_m, rows, cols, g, diag_ad, k))


def _deviation(z: np.ndarray, rows: np.ndarray, cols: np.ndarray, g: np.ndarray, diag_ad: np.ndarray, k: int,
               max_cells: int = 200_000) -> dict:
    """|TIN - surface| at (a sample of) the surface's valid cells inside the TIN: each cell's height on its
    triangle (the quad of the vertex grid it falls in, split as the TIN splits it) against its own."""
    r, c = np.nonzero(np.isfinite(z))
    if len(r) > max_cells:
        pick = np.random.default_rng(0).choice(len(r), max_cells, replace=False)
        r, c = r[pick], c[pick]
    qi, qj = r // k, c // k
    inside = (qi < len(rows) - 1) & (qj < len(cols) - 1)
    r, c, qi, qj = r[inside], c[inside], qi[inside], qj[inside]
    v, u = (r - rows[qi]) / k, (c - cols[qj]) / k          # fractions south and east within the quad
    za, zb, zc, zd = g[qi, qj], g[qi, qj + 1], g[qi + 1, qj], g[qi + 1, qj + 1]
    ad = diag_ad[qi, qj]
    zi = np.where(ad,
                  np.where(v >= u, za + (zc - za) * v + (zd - zc) * u, za + (zb - za) * u + (zd - zb) * v),
                  np.where(u + v <= 1, za + (zb - za) * u + (zc - za) * v,
                           zd + (zc - zd) * (1 - u) + (zb - zd) * (1 - v)))
    dz = np.abs(zi - z[r, c])
    dz = dz[np.isfinite(dz)]
    if dz.size == 0:
        return {"n_cells": 0}
    return {"n_cells": int(dz.size), "rms_m": round(float(np.sqrt(np.mean(dz ** 2))), 4),
            "p95_m": round(float(np.percentile(dz, 95)), 4), "max_m": round(float(dz.max()), 4)}


def write_landxml(path, tin: Tin, surface: Surface, name: str = "DSM", description: str = "") -> Path:
    """Writes the TIN as LandXML 1.2 (see the module's description)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0)
    horiz = surface.crs
    epsg = horiz.to_epsg()
    cs = {"name": horiz.name, "horizontalDatum": horiz.datum.name if horiz.datum else "",
          "verticalDatum": surface.vertical_datum, "ogcWktCode": surface.crs_3d.to_wkt(),
          "projectedCoordinateSystemName": horiz.name}
    if epsg:
        cs["epsgCode"] = str(epsg)
    attrs = lambda d: " ".join(f"{k}={quoteattr(str(v))}" for k, v in d.items())  # noqa: E731
    z = tin.xyz_m[:, 2]
    with open(path, "w", encoding="utf-8") as f:
        f.write('<?xml version="1.0" encoding="UTF-8"?>\n')
        f.write(f'<LandXML xmlns="{LANDXML_NS}" version="1.2" date="{now.date().isoformat()}" '
                f'time="{now.time().isoformat()}" language="English" readOnly="false">\n')
        f.write(' <Units><Metric areaUnit="squareMeter" linearUnit="meter" volumeUnit="cubicMeter" '
                'temperatureUnit="celsius" pressureUnit="milliBars" angularUnit="decimal degrees" '
                'directionUnit="decimal degrees"/></Units>\n')
        f.write(f" <CoordinateSystem {attrs(cs)}/>\n")
        f.write(f' <Application name="Georef" manufacturer="Georef" desc={quoteattr(description or "drone survey")} '
                f'timeStamp="{now.isoformat().replace("+00:00", "")}"/>\n')
        f.write(" <Surfaces>\n")
        f.write(f"  <Surface {attrs({'name': name, 'desc': description or name})}>\n")
        f.write(f'   <Definition surfType="TIN" area2DSurf="{tin.area_2d_m2():.3f}" area3DSurf="{tin.area_3d_m2():.3f}" '
                f'elevMax="{z.max():.3f}" elevMin="{z.min():.3f}">\n')
        f.write("    <Pnts>\n")
        f.writelines(f'     <P id="{i + 1}">{n:.3f} {e:.3f} {h:.3f}</P>\n'
                     for i, (e, n, h) in enumerate(tin.xyz_m.tolist()))
        f.write("    </Pnts>\n    <Faces>\n")
        f.writelines(f"     <F>{p} {q} {r}</F>\n" for p, q, r in (tin.faces + 1).tolist())
        f.write("    </Faces>\n   </Definition>\n  </Surface>\n </Surfaces>\n</LandXML>\n")
    return path
