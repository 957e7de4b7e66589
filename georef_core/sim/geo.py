"""Coordinate frames of a simulated site: the simulator uses the project frame of
:mod:`georef_core.project_frame` (project CRS, ECEF, local ENU) under the name ``SiteFrame``.

The site (terrain, stockpiles, targets, DSM) is *defined* in the project CRS; the physics (flight,
camera attitude, ray casting) is done in the local ENU frame, so the rendered world is the true 3-D
shape of a height field defined in the project CRS.
"""

from __future__ import annotations

from ..project_frame import ProjectFrame as SiteFrame, utm_epsg_for

__all__ = ["SiteFrame", "utm_epsg_for"]
