"""Design TINs from DXF drawings (read with ezdxf): the model space's 3DFACE entities, polyface meshes
(POLYLINE with the polyface flag) and MESH entities. A quadrilateral face (a 3DFACE whose fourth corner
differs from its third, or a 4-vertex polyface face) is split into two triangles along its 1-3 diagonal;
larger faces are fanned. Vertices shared by several faces (equal to 0.1 mm) are merged.

DXF carries no CRS: coordinates are taken in the site CRS. ``$INSUNITS`` gives the length unit: feet
(2), US survey feet (21), inches (1), millimetres (4) and centimetres (5) are converted to metres with a
note; metres (6) and unitless (0, taken as metres, noted) are used as they are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .design_surface import TinDesign

INSUNITS_TO_M = {0: (1.0, "unitless"), 1: (0.0254, "inches"), 2: (0.3048, "feet"), 4: (1e-3, "millimetres"),
                 5: (1e-2, "centimetres"), 6: (1.0, "metres"), 21: (1200.0 / 3937.0, "US survey feet")}
MERGE_M = 1e-4


def _triangles_of(vertices: list) -> list:
    """A face's corners (consecutive duplicates dropped) as triangles (fan from the first corner)."""
    pts = []
    for v in vertices:
        t = (float(v[0]), float(v[1]), float(v[2]))
        if not pts or t != pts[-1]:
            pts.append(t)
    if len(pts) > 1 and pts[0] == pts[-1]:
        pts.pop()
    return [(pts[0], pts[k], pts[k + 1]) for k in range(1, len(pts) - 1)]


def read_dxf_tin(path, site_crs=None) -> TinDesign:
    try:
        import ezdxf
        from ezdxf.render import MeshBuilder
    except ImportError:  # pragma: no cover - a dependency of the package
        raise InputFileError(path, "reading DXF needs the ezdxf package (pip install ezdxf)") from None
    p = Path(path)
    try:
        doc = ezdxf.readfile(str(p))
    except IOError as exc:
        raise InputFileError(p, f"cannot be read ({exc})") from None
    except ezdxf.DXFError as exc:
        raise InputFileError(p, f"not a valid DXF file ({exc})") from None
    code = int(doc.header.get("$INSUNITS", 0) or 0)
    if code not in INSUNITS_TO_M:
        raise InputFileError(p, f"$INSUNITS = {code}: a length unit that is not read (metres, millimetres, "
                                "centimetres, feet, US survey feet, inches are)")
    factor, unit_name = INSUNITS_TO_M[code]
    notes = []
    if code == 0:
        notes.append("no drawing units ($INSUNITS 0): coordinates taken as metres")
    elif factor != 1.0:
        notes.append(f"drawing units {unit_name}: converted to metres (x {factor:.10g})")
    notes.append("DXF has no CRS: coordinates taken in the site CRS")

    tris: list = []
    counts = {"3DFACE": 0, "polyface": 0, "MESH": 0}
    layers: set = set()
    msp = doc.modelspace()
    for e in msp:
        kind = e.dxftype()
        if kind == "3DFACE":
            corners = [e.dxf.vtx0, e.dxf.vtx1, e.dxf.vtx2, e.dxf.vtx3]
            tris.extend(_triangles_of(corners))
            counts["3DFACE"] += 1
        elif kind == "POLYLINE" and getattr(e, "is_poly_face_mesh", False):
            mesh = MeshBuilder.from_polyface(e)
            verts = mesh.vertices
            for f in mesh.faces:
                tris.extend(_triangles_of([verts[i] for i in f]))
            counts["polyface"] += 1
        elif kind == "MESH":
            mesh = MeshBuilder.from_mesh(e)
            verts = mesh.vertices
            for f in mesh.faces:
                tris.extend(_triangles_of([verts[i] for i in f]))
            counts["MESH"] += 1
        else:
            continue
        layers.add(e.dxf.layer)
    if not tris:
        found = sorted({e.dxftype() for e in msp})
        raise InputFileError(p, "no 3DFACE, polyface mesh or MESH entity in the model space (entities found: "
                                f"{', '.join(found) if found else 'none'}): a design TIN is drawn as 3D faces")
    corners = np.asarray(tris, dtype=np.float64).reshape(-1, 3) * factor
    key = np.round(corners / MERGE_M).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    points = corners[first]
    faces = inverse.reshape(-1, 3)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    if not keep.any():
        raise InputFileError(p, "every 3D face is degenerate (its corners coincide)")
    what = ", ".join(f"{n} {k}" for k, n in counts.items() if n)
    notes.append(f"{what} on layer(s) {', '.join(sorted(layers))}: {int(keep.sum())} triangles, {len(points)} vertices")
    crs = site_crs
    if isinstance(crs, str):
        from pyproj import CRS

        crs = CRS.from_user_input(crs)
    return TinDesign(p, p.stem, crs, notes, points_xyz=points, faces=faces[keep])
