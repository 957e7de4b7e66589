"""LandXML TIN surfaces (schema 1.0, 1.1, 1.2; or no namespace).

What is read, for the chosen ``<Surfaces>/<Surface>``:

* ``<Definition><Pnts><P id="..">northing easting elevation</P>``: LandXML writes a point as **N E Z**
  (northing first). The reader swaps them to (easting, northing, height). Points without ``id`` take
  their 1-based position.
* ``<Faces><F>id id id</F>``: triangles by point id; faces flagged invisible (``i="1"``: outside the
  surface's boundary) are left out. A face naming a point that is not in ``<Pnts>`` is an error naming
  the face. A surface without faces (``surfType="grid"`` point sets) is triangulated (Delaunay) and a
  note says so.
* ``<Units><Metric linearUnit=..>`` or ``<Imperial linearUnit="foot"|"USSurveyFoot"|"inch">``: lengths are
  converted to metres and a note says by which factor.
* ``<CoordinateSystem epsgCode=.. | ogcWktCode=..>``: the surface's CRS (else the site's).

Several surfaces: choose one by ``surface_name``; without it a file with one surface is fine, one with
several is an error listing their names.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .design_surface import TinDesign

LENGTH_TO_M = {"meter": 1.0, "metre": 1.0, "millimeter": 1e-3, "centimeter": 1e-2, "kilometer": 1e3,
               "foot": 0.3048, "internationalfoot": 0.3048, "ussurveyfoot": 1200.0 / 3937.0, "inch": 0.0254}
NAMESPACE = re.compile(r"^\{http://www\.landxml\.org/schema/LandXML-(1\.0|1\.1|1\.2)\}")


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _children(el, name: str) -> list:
    return [c for c in el if _local(c.tag) == name]


def _child(el, name: str):
    for c in el:
        if _local(c.tag) == name:
            return c
    return None


def _units(root, p: Path) -> tuple[float, str | None]:
    """(metres per file length unit, a note when not metres)."""
    units = _child(root, "Units")
    if units is None:
        return 1.0, "no <Units> element: lengths taken as metres"
    for system in ("Metric", "Imperial"):
        u = _child(units, system)
        if u is None:
            continue
        lin = (u.get("linearUnit") or ("meter" if system == "Metric" else "foot")).strip()
        f = LENGTH_TO_M.get(lin.lower().replace(" ", ""))
        if f is None:
            raise InputFileError(p, f"<{system} linearUnit={lin!r}>: unknown length unit (known: "
                                    f"{', '.join(sorted(LENGTH_TO_M))})")
        if f == 1.0:
            return 1.0, None
        return f, f"{system.lower()} lengths in {lin}: converted to metres (x {f:.10g})"
    return 1.0, "no Metric or Imperial units declared: lengths taken as metres"


def _crs(root, p: Path, site_crs):
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    cs = _child(root, "CoordinateSystem")
    if cs is not None:
        for attr in ("epsgCode", "ogcWktCode"):
            v = (cs.get(attr) or "").strip()
            if v:
                try:
                    return CRS.from_user_input(int(v) if v.isdigit() else v), f"CRS from <CoordinateSystem {attr}>"
                except CRSError as exc:
                    raise InputFileError(p, f"<CoordinateSystem {attr}={v!r}> is not understood ({exc})") from None
    if site_crs is None:
        return None, None
    return (site_crs if not isinstance(site_crs, str) else CRS.from_user_input(site_crs)), "CRS: the site's"


def read_landxml(path, surface_name: str | None = None, site_crs=None) -> TinDesign:
    import xml.etree.ElementTree as ET

    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except ET.ParseError as exc:
        line = getattr(exc, "position", (None,))[0]
        raise InputFileError(p, f"not well-formed XML ({exc})", line) from None
    except OSError as exc:
        raise InputFileError(p, f"cannot be read ({exc})") from None
    if _local(root.tag) != "LandXML":
        raise InputFileError(p, f"not a LandXML file (root element <{_local(root.tag)}>)")
    if root.tag.startswith("{") and not NAMESPACE.match(root.tag):
        raise InputFileError(p, f"unknown LandXML namespace {root.tag.split('}')[0][1:]!r} (1.0, 1.1 and 1.2 are read)")
    factor, unit_note = _units(root, p)
    surfaces = [s for group in _children(root, "Surfaces") for s in _children(group, "Surface")]
    if not surfaces:
        raise InputFileError(p, "no <Surface> in the file (a LandXML design surface is a <Surfaces><Surface> "
                                "with <Definition><Pnts> and <Faces>)")
    names = [s.get("name") or f"surface {k + 1}" for k, s in enumerate(surfaces)]
    if surface_name is None:
        if len(surfaces) > 1:
            raise InputFileError(p, f"{len(surfaces)} surfaces in the file ({', '.join(repr(n) for n in names)}): "
                                    "choose one by name")
        k = 0
    else:
        if surface_name not in names:
            raise InputFileError(p, f"no surface named {surface_name!r} (the file has "
                                    f"{', '.join(repr(n) for n in names)})")
        k = names.index(surface_name)
    surf, name = surfaces[k], names[k]
    crs, crs_note = _crs(root, p, site_crs)
    notes = [n for n in (unit_note, crs_note) if n]

    definition = _child(surf, "Definition")
    if definition is None:
        raise InputFileError(p, f"surface {name!r} has no <Definition> (no points or faces)")
    pnts = _child(definition, "Pnts")
    pts_el = _children(pnts, "P") if pnts is not None else []
    if len(pts_el) < 3:
        raise InputFileError(p, f"surface {name!r} has {len(pts_el)} points in <Pnts>: a TIN needs at least 3")
    ids = [(e.get("id") or str(i + 1)).strip() for i, e in enumerate(pts_el)]
    values = []
    for i, e in enumerate(pts_el):
        t = (e.text or "").split()
        if len(t) != 3:
            raise InputFileError(p, f"surface {name!r}, point {ids[i]!r}: expected 'northing easting elevation', "
                                    f"got {(e.text or '').strip()!r}")
        values.append(t)
    try:
        nez = np.array(values, dtype=np.float64)
    except ValueError as exc:
        raise InputFileError(p, f"surface {name!r}: a point coordinate is not a number ({exc})") from None
    # LandXML order is northing, easting, elevation
    xyz = np.column_stack([nez[:, 1], nez[:, 0], nez[:, 2]]) * factor
    index = {pid: i for i, pid in enumerate(ids)}
    if len(index) != len(ids):
        notes.append(f"{len(ids) - len(index)} repeated point id(s): the last definition is used")

    faces_el = _child(definition, "Faces")
    if faces_el is None or not _children(faces_el, "F"):
        from scipy.spatial import Delaunay

        faces = Delaunay(xyz[:, :2] - xyz[:, :2].mean(axis=0)).simplices
        notes.append(f"surface {name!r} has no <Faces>: its {len(xyz)} points were triangulated (Delaunay)")
    else:
        rows, hidden = [], 0
        for f in _children(faces_el, "F"):
            if (f.get("i") or "0").strip() == "1":
                hidden += 1
                continue
            t = (f.text or "").split()
            if len(t) != 3:
                raise InputFileError(p, f"surface {name!r}: face {(f.text or '').strip()!r} does not have 3 point ids")
            try:
                rows.append([index[v] for v in t])
            except KeyError as exc:
                raise InputFileError(p, f"surface {name!r}: face {' '.join(t)!r} references point id {exc.args[0]!r} "
                                        "which is not in <Pnts>") from None
        if hidden:
            notes.append(f"{hidden} invisible face(s) (i=\"1\") left out")
        if not rows:
            raise InputFileError(p, f"surface {name!r}: every face is invisible: no surface left")
        faces = np.array(rows, dtype=np.int64)
    return TinDesign(p, name, crs, notes, points_xyz=xyz, faces=faces)
