"""A design surface (the levels the site is built to) on a DSM's grid.

Two kinds, one interface (:meth:`DesignSurface.heights_on`: the design height at every cell centre of a
grid window, NaN where the design does not reach):

* :class:`TinDesign`: a triangulated surface (LandXML ``<Surface>``, DXF 3DFACE / polyface mesh). Heights
  are the linear interpolation on its own triangles (the triangles the designer drew, not a
  re-triangulation), rasterised at cell centres by the volume module's TIN rasteriser
  (:func:`georef_core.volumes.base_surfaces.rasterize_tin`). Cells whose centre is in no triangle are
  uncovered (NaN).
* :class:`GridDesign`: a GeoTIFF grid, resampled bilinearly onto the DSM grid (any CRS) by the volume
  module's :class:`~georef_core.volumes.raster_io.WindowResampler`.

Coordinates are metres in the site CRS; readers convert feet and say so in ``notes``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputFileError
from ..volumes.raster_io import GridWindow


@dataclass
class DesignSurface:
    """Common part: where it came from, its CRS (None: the site's, i.e. the DSM's) and what the reader did."""

    path: Path
    name: str
    crs: object = None  # pyproj.CRS or None (taken to be the DSM's CRS)
    notes: list = field(default_factory=list)
    sigma_m: float = 0.0  # 1-sigma height error of the design itself (a design is usually exact)

    kind = "surface"

    def prepare(self, dst_crs) -> None:
        """Make ``heights_on`` work in ``dst_crs`` (the DSM's CRS)."""

    def heights_on(self, window: GridWindow) -> np.ndarray:
        raise NotImplementedError

    def bounds(self) -> tuple[float, float, float, float] | None:
        """(xmin, ymin, xmax, ymax) in the prepared CRS, when cheap to know."""
        return None

    def describe(self) -> dict:
        return {"path": str(self.path), "name": self.name, "kind": self.kind, "notes": list(self.notes),
                "crs": None if self.crs is None else _crs_label(self.crs)}


def _crs_label(crs) -> str:
    epsg = crs.to_epsg()
    return f"EPSG:{epsg}" if epsg else crs.name


@dataclass
class TinDesign(DesignSurface):
    """Triangles ``faces`` (m, 3) over vertices ``points_xyz`` (n, 3: easting, northing, height; metres)."""

    points_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    _xyz: np.ndarray | None = field(default=None, repr=False)  # in the DSM's CRS after prepare()

    kind = "tin"

    def __post_init__(self):
        self.points_xyz = np.asarray(self.points_xyz, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if len(self.faces) == 0:
            raise InputFileError(self.path, f"design surface {self.name!r} has no triangles")
        if self.faces.min() < 0 or self.faces.max() >= len(self.points_xyz):
            raise InputFileError(self.path, f"design surface {self.name!r}: a face references a point that "
                                            "does not exist")
        if not np.all(np.isfinite(self.points_xyz)):
            raise InputFileError(self.path, f"design surface {self.name!r} has non-finite coordinates")
        a, b, c = (self.points_xyz[self.faces[:, k], :2] for k in range(3))
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        if not np.any(np.abs(area2) > 0):
            raise InputFileError(self.path, f"design surface {self.name!r}: every triangle is degenerate "
                                            "(vertical or collinear)")

    def prepare(self, dst_crs) -> None:
        xyz = self.points_xyz
        if self.crs is not None and dst_crs is not None and self.crs != dst_crs:
            from pyproj import Transformer

            tr = Transformer.from_crs(self.crs, dst_crs, always_xy=True)
            x, y = tr.transform(xyz[:, 0], xyz[:, 1])
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
                raise InputFileError(self.path, f"the design's points cannot be transformed from "
                                                f"{_crs_label(self.crs)} to the DSM's CRS")
            xyz = np.column_stack([x, y, xyz[:, 2]])
        self._xyz = xyz

    @property
    def xyz(self) -> np.ndarray:
        return self.points_xyz if self._xyz is None else self._xyz

    def bounds(self):
        used = self.xyz[np.unique(self.faces)]
        return (float(used[:, 0].min()), float(used[:, 1].min()), float(used[:, 0].max()), float(used[:, 1].max()))

    def heights_on(self, window: GridWindow) -> np.ndarray:
        from ..volumes.base_surfaces import rasterize_tin

        xyz = self.xyz
        u, v = window.to_pixel(xyz[:, 0], xyz[:, 1])
        # only the triangles that reach the window (the rasteriser clips, this just skips the rest)
        fu, fv = u[self.faces], v[self.faces]
        near = ((fu.max(axis=1) >= 0) & (fu.min(axis=1) <= window.ncols)
                & (fv.max(axis=1) >= 0) & (fv.min(axis=1) <= window.nrows))
        out, _ = rasterize_tin(np.column_stack([u, v, xyz[:, 2]]), self.faces[near], window.nrows, window.ncols)
        return out

    def describe(self) -> dict:
        d = super().describe()
        d.update(n_points=int(len(self.points_xyz)), n_triangles=int(len(self.faces)),
                 height_range_m=[round(float(self.points_xyz[:, 2].min()), 4),
                                 round(float(self.points_xyz[:, 2].max()), 4)])
        return d


@dataclass
class GridDesign(DesignSurface):
    """A GeoTIFF of design heights (metres), any CRS, bilinear onto the DSM grid."""

    _resampler: object = field(default=None, repr=False)

    kind = "grid"

    def prepare(self, dst_crs) -> None:
        from ..volumes.raster_io import WindowResampler

        self._resampler = WindowResampler(self.path, dst_crs, "design surface")

    def heights_on(self, window: GridWindow) -> np.ndarray:
        if self._resampler is None:
            raise RuntimeError("GridDesign.prepare() first")
        return self._resampler(window)

    def describe(self) -> dict:
        d = super().describe()
        if self._resampler is not None:
            info = self._resampler.info
            d.update(crs=info.crs_label(), cell_size_m=round(info.cell_size_m, 6), width=info.width,
                     height=info.height, resampling="bilinear onto the DSM grid")
        return d


def read_design(path, surface_name: str | None = None, crs=None) -> DesignSurface:
    """A design surface from a LandXML (.xml/.landxml), DXF (.dxf) or GeoTIFF (.tif/.tiff) file, chosen by
    its content (the extension only when the content is ambiguous). ``surface_name``: which LandXML
    surface (default: the only one, else an error listing them). ``crs``: the site CRS (pyproj CRS or
    text) for files that do not declare one (DXF, LandXML without CoordinateSystem)."""
    p = Path(path)
    if not p.exists():
        raise InputFileError(p, "file not found")
    if not p.is_file():
        raise InputFileError(p, "not a file")
    with open(p, "rb") as fh:
        head = fh.read(4096)
    ext = p.suffix.lower()
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        from .grid_reader import read_grid_design

        return read_grid_design(p)
    text = head.lstrip(b"\xef\xbb\xbf").lstrip()
    if text.startswith(b"<") or ext in (".xml", ".landxml"):
        from .landxml_reader import read_landxml

        return read_landxml(p, surface_name, crs)
    if ext == ".dxf" or b"SECTION" in head[:512]:
        from .dxf_reader import read_dxf_tin

        return read_dxf_tin(p, crs)
    if ext in (".tif", ".tiff"):
        raise InputFileError(p, "not a TIFF file (bad header)")
    raise InputFileError(p, "unknown design surface format: expected LandXML (.xml), DXF (.dxf) or GeoTIFF (.tif)")
