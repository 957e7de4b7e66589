"""Analytic design scenes: a piecewise-planar design (a valley: two planes meeting along a north-south line,
both falling 2 % to the south) and a surveyed surface = design + a cone (cut) + a conical pit (fill), with
closed-form volumes and on-grade areas. The design is written as a GeoTIFF grid, a LandXML TIN (N E Z)
and a DXF of 3DFACEs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tests.volumes.synthetic import E0, EPSG, N0, cone_height, cone_volume, write_dsm, write_geojson

SIZE_M = 40.0
RES = 0.1
XC, YC = E0 + 20.0, N0 + 20.0  # the valley line is x = XC
Z0 = 112.0
GRADE_N = 0.02  # rises 2 % to the north
SIDE = 0.05  # each side rises 5 % away from the valley line
BUMP = dict(cx=XC - 8.0, cy=YC + 1.0, radius=6.0, h=1.0)  # cut: 37.70 m3
PIT = dict(cx=XC + 9.0, cy=YC - 4.0, radius=5.0, h=0.8)  # fill: 20.94 m3
# the design area: an irregular hexagon holding both shapes, edges not on the grid
AREA = np.array([[XC - 16.3, YC - 12.7], [XC + 2.1, YC - 15.9], [XC + 16.6, YC - 11.2], [XC + 15.2, YC + 13.4],
                 [XC - 1.7, YC + 16.1], [XC - 15.8, YC + 9.3]])


def design_height(E, N):
    return Z0 + GRADE_N * (N - YC) + SIDE * np.abs(E - XC)


def cut_volume() -> float:
    return cone_volume(BUMP["radius"], BUMP["h"])


def fill_volume() -> float:
    return cone_volume(PIT["radius"], PIT["h"])


def area_m2() -> float:
    x, y = AREA[:, 0], AREA[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y)))


def off_grade_area(tolerance: float) -> float:
    """Area where |d| > t: inside each cone, d > t for r < R (1 - t / H)."""
    return sum(math.pi * (c["radius"] * max(0.0, 1.0 - tolerance / c["h"])) ** 2 for c in (BUMP, PIT))


def surveyed_height(E, N, bump=BUMP, pit=PIT):
    return (design_height(E, N) + cone_height(bump["cx"], bump["cy"], bump["radius"], bump["h"])(E, N)
            - cone_height(pit["cx"], pit["cy"], pit["radius"], pit["h"])(E, N))


def write_scene(folder, bump=BUMP, pit=PIT, noise_sigma: float = 0.0, seed: int = 0) -> dict:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)

    def surveyed(E, N):
        z = surveyed_height(E, N, bump, pit)
        return z + rng.normal(0.0, noise_sigma, z.shape) if noise_sigma else z

    dsm = write_dsm(folder / "dsm.tif", surveyed, (SIZE_M, SIZE_M), RES, block_rows=100000)
    poly = write_geojson(folder / "area.geojson", {"design area": AREA})
    return {"dsm": dsm, "polygon": poly}


def tin_vertices() -> tuple[np.ndarray, np.ndarray]:
    """The design as a TIN: (points E N Z, triangles); exact (the design is planar on each side)."""
    xs = [E0 - 1.0, XC, E0 + SIZE_M + 1.0]
    ys = [N0 - 1.0, N0 + SIZE_M + 1.0]
    pts = np.array([[x, y, design_height(x, y)] for y in ys for x in xs])
    # 0 1 2 along the south edge, 3 4 5 along the north edge
    tris = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    return pts, tris


def write_design_geotiff(path, res: float = 0.2) -> Path:
    """The design as a grid whose cell centres fall on the valley line (bilinear is exact on each side)."""
    return write_dsm(path, design_height, (SIZE_M + 2 * res, SIZE_M + 2 * res), res,
                     origin=(E0 - res - res / 2, N0 - res - res / 2))


def write_design_landxml(path, namespace: str = "http://www.landxml.org/schema/LandXML-1.2", feet: bool = False,
                         extra_surface: bool = False, epsg: int | None = None) -> Path:
    pts, tris = tin_vertices()
    f = 1.0 / 0.3048 if feet else 1.0
    units = ('<Imperial linearUnit="foot" areaUnit="squareFoot" volumeUnit="cubicFeet"/>' if feet
             else '<Metric linearUnit="meter" areaUnit="squareMeter" volumeUnit="cubicMeter"/>')
    pnts = "\n".join(f'<P id="{100 + k}">{y * f:.4f} {x * f:.4f} {z * f:.5f}</P>' for k, (x, y, z) in enumerate(pts))
    faces = "\n".join(f"<F>{100 + a} {100 + b} {100 + c}</F>" for a, b, c in tris)
    surf = (f'<Surface name="FG design"><Definition surfType="TIN"><Pnts>\n{pnts}\n</Pnts><Faces>\n{faces}\n'
            '</Faces></Definition></Surface>')
    other = ""
    if extra_surface:  # an existing-ground surface 3 m lower, listed first
        pnts2 = "\n".join(f'<P id="{k + 1}">{y * f:.4f} {x * f:.4f} {(z - 3) * f:.5f}</P>' for k, (x, y, z) in enumerate(pts))
        faces2 = "\n".join(f"<F>{a + 1} {b + 1} {c + 1}</F>" for a, b, c in tris)
        other = (f'<Surface name="EG"><Definition surfType="TIN"><Pnts>\n{pnts2}\n</Pnts><Faces>\n{faces2}\n'
                 '</Faces></Definition></Surface>')
    cs = f'<CoordinateSystem epsgCode="{epsg}"/>' if epsg else ""
    xmlns = f' xmlns="{namespace}"' if namespace else ""
    Path(path).write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<LandXML{xmlns} version="1.2">\n<Units>{units}'
                          f'</Units>{cs}\n<Surfaces>{other}{surf}</Surfaces>\n</LandXML>\n')
    return Path(path)


def write_design_dxf(path, quads: bool = True, polyface: bool = False) -> Path:
    """The design as 3DFACEs (quads split by the reader, or triangles), or as one polyface mesh."""
    import ezdxf

    pts, tris = tin_vertices()
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    msp = doc.modelspace()
    if polyface:
        mesh = msp.add_polyface(dxfattribs={"layer": "DESIGN"})
        mesh.append_faces([[tuple(pts[i]) for i in t] for t in tris])
        mesh.optimize()
    elif quads:
        for quad in ([0, 1, 4, 3], [1, 2, 5, 4]):
            msp.add_3dface([tuple(pts[i]) for i in quad], dxfattribs={"layer": "DESIGN"})
    else:
        for t in tris:
            msp.add_3dface([tuple(pts[i]) for i in t], dxfattribs={"layer": "DESIGN"})
    doc.saveas(path)
    return Path(path)


__all__ = ["AREA", "BUMP", "EPSG", "PIT", "area_m2", "cut_volume", "design_height", "fill_volume", "off_grade_area",
           "write_design_dxf", "write_design_geotiff", "write_design_landxml", "write_scene"]
