"""Site simulator: a whole directly-georeferenced drone survey of an earthworks site with ground truth.

Deterministic from a seed. Entry point: :func:`simulate_site`. Modules:

* :mod:`.geo` project CRS / ECEF / local ENU frames of the site
* :mod:`.site`, :mod:`.stockpiles`, :mod:`.machines` terrain, pit, roads, analytic stockpiles, targets, machines
* :mod:`.texture` procedural ground texture with baked sun shading
* :mod:`.flight` flight plan, true antenna trajectory and attitude, camera events
* :mod:`.camera` pinhole + Brown distortion camera
* :mod:`.render` ray-cast rendering (Open3D) and JPEG/EXIF writing
* :mod:`.truth` truth files
* :mod:`.gnss_observations` raw GNSS observations (code, phase, Doppler, C/N0) of a rover and a base
* :mod:`.survey_gnss` the survey's rover/, base/, nav/ RINEX files and GNSS truth (:class:`GnssOptions`);
  ``data/base.nav`` is the shipped multi-GNSS broadcast navigation file (see ``data/PROVENANCE.txt``)
* :mod:`.scenario` :func:`simulate_site`, :class:`SimulationOptions`, :class:`SimulationResult`

Command line: ``georef simulate OUT_DIR --seed N`` (= ``python -m georef_core.sim``).

Rendering needs ``open3d`` (``open3d-cpu``), ``Pillow`` and ``piexif``; the DSM needs ``rasterio``.
The site, flight and truth geometry need only numpy / scipy / pyproj.
"""

from .camera import CameraModel, CameraOptions
from .flight import CameraEvent, FlightOptions, FlightPlan, Trajectory, plan_flight, simulate_flight
from .geo import SiteFrame, utm_epsg_for
from .site import Site, SiteOptions, Target, build_site
from .stockpiles import Cone, Frustum, HipPile, Stockpile, Windrow
from .survey_gnss import GnssOptions

__all__ = [
    "CameraEvent", "CameraModel", "CameraOptions", "Cone", "FlightOptions", "FlightPlan", "Frustum", "GnssOptions",
    "HipPile",
    "RenderOptions", "SimulationOptions", "SimulationResult", "Site", "SiteFrame", "SiteOptions", "Stockpile", "Target",
    "TextureOptions", "Trajectory", "Windrow", "build_site", "plan_flight", "simulate_flight", "simulate_site",
    "utm_epsg_for",
]


def __getattr__(name):  # lazy: rendering imports (open3d, PIL) only when asked for
    if name in ("simulate_site", "SimulationOptions", "SimulationResult"):
        from . import scenario

        return getattr(scenario, name)
    if name == "RenderOptions":
        from .render import RenderOptions

        return RenderOptions
    if name == "TextureOptions":
        from .texture import TextureOptions

        return TextureOptions
    raise AttributeError(name)
