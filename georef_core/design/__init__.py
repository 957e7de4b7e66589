"""Design surfaces and cut/fill to design (docs/design.md).

* :func:`read_design`: a design surface from LandXML (TIN surfaces, 1.0/1.1/1.2), DXF (3DFACE, polyface
  mesh, MESH) or a GeoTIFF grid, in the site CRS, in metres.
* :func:`compute_cut_fill`: surveyed minus design inside a polygon: cut, fill, net, on-grade share within a
  tolerance, per-cell significance from the survey's accuracy, difference and class GeoTIFFs, contours.
"""

from .cut_fill import CutFillOptions, compute_cut_fill
from .design_surface import DesignSurface, GridDesign, TinDesign, read_design

__all__ = ["CutFillOptions", "DesignSurface", "GridDesign", "TinDesign", "compute_cut_fill", "read_design"]
