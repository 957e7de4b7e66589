"""Stockpiles of analytic shape whose volume above their base plane is known in closed form.

Every pile stands on a *base plane* ``z_base(x, y) = z0 + gx (x - cx) + gy (y - cy)`` (site coordinates:
grid offsets in metres from the site origin, ellipsoidal heights). Its surface is
``z_base(x, y) + h(x, y)`` with ``h >= 0`` a *vertical* thickness, and its volume is the integral of ``h``
over the plane's horizontal projection, so a tilted base (a pile on a slope) keeps the flat-base
formula. The terrain under a pile and a margin around it is replaced by the base plane exactly (a
"pad"), so that integrating ``DSM - base plane`` over the footprint gives the analytic volume.

Volumes are in project-CRS units: grid square metres times metres of height. The ground volume (true
metric area) is ``volume / k**2`` with ``k`` the projection's point scale factor at the pile, given as
``volume_ground_m3`` in the truth.

Shapes (all side slopes are straight lines in vertical section):

* ``cone``: radius ``R``, height ``H``. ``V = pi R^2 H / 3``.
* ``frustum`` (truncated cone): base radius ``R``, top radius ``r``, height ``H``.
  ``V = pi H (R^2 + R r + r^2) / 3``.
* ``windrow``: an elongated pile whose toe is a stadium: every point within ``R`` of a straight
  segment of length ``L``; the crest is the set within ``r`` of it (flat top of width ``2r``, or a
  sharp ridge when ``r = 0``). A trapezoidal prism with half-frustum ends:
  ``V = L H (R + r) + pi H (R^2 + R r + r^2) / 3``.
* ``hip`` (truncated rectangular pyramid, sloped ends): base ``2a x 2b``, side slope ``s`` (rise/run)
  on all four sides, height ``H <= s b``; top ``2(a-w) x 2(b-w)`` with ``w = H / s``. A prismatoid:
  ``V = H (A_base + 4 A_mid + A_top) / 6``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

MATERIALS = ("gravel", "sand", "crushed_stone", "topsoil", "clay")


@dataclass
class Stockpile:
    """Base class: centre ``(cx, cy)`` in site coordinates, base plane, orientation ``theta`` (rad,
    counter-clockwise from grid east, for elongated shapes)."""

    name: str
    cx: float
    cy: float
    z0: float = 0.0
    gx: float = 0.0
    gy: float = 0.0
    theta: float = 0.0
    material: str = "gravel"
    kind: str = field(default="", init=False)

    # -- geometry helpers ----------------------------------------------------------------------
    def _local(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        dx = np.asarray(x, dtype=float) - self.cx
        dy = np.asarray(y, dtype=float) - self.cy
        c, s = math.cos(self.theta), math.sin(self.theta)
        return c * dx + s * dy, -s * dx + c * dy

    def base_height(self, x, y) -> np.ndarray:
        return self.z0 + self.gx * (np.asarray(x, dtype=float) - self.cx) + self.gy * (np.asarray(y, dtype=float) - self.cy)

    def surface(self, x, y) -> np.ndarray:
        return self.base_height(x, y) + self.height(x, y)

    # -- to implement --------------------------------------------------------------------------
    def height(self, x, y) -> np.ndarray:  # vertical thickness above the base plane
        raise NotImplementedError

    def footprint_sdf(self, x, y) -> np.ndarray:  # signed horizontal distance to the toe (< 0 inside)
        raise NotImplementedError

    @property
    def volume(self) -> float:
        raise NotImplementedError

    @property
    def footprint_area(self) -> float:
        raise NotImplementedError

    @property
    def max_height(self) -> float:
        raise NotImplementedError

    @property
    def bounding_radius(self) -> float:
        raise NotImplementedError

    def footprint_polygon(self, n: int = 256) -> np.ndarray:
        """Toe outline, (n, 2) site coordinates, counter-clockwise, not closed."""
        raise NotImplementedError

    def shape_parameters(self) -> dict:
        raise NotImplementedError

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "shape": self.kind,
            "material": self.material,
            "centre_site_xy_m": [self.cx, self.cy],
            "base_plane": {"z0_m": self.z0, "dz_dx": self.gx, "dz_dy": self.gy,
                           "equation": "z = z0 + dz_dx*(x - cx) + dz_dy*(y - cy)"},
            "theta_rad": self.theta,
            "parameters": self.shape_parameters(),
            "volume_m3": self.volume,
            "footprint_area_m2": self.footprint_area,
            "max_height_m": self.max_height,
        }

    def _circle(self, radius: float, n: int) -> np.ndarray:
        a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
        return np.stack([self.cx + radius * np.cos(a), self.cy + radius * np.sin(a)], axis=-1)


class _RoundFootprint:
    """Footprint of a pile with a circular toe of radius ``radius`` and height ``h`` (cone, frustum)."""

    radius: float
    h: float

    def footprint_sdf(self, x, y):
        u, v = self._local(x, y)
        return np.hypot(u, v) - self.radius

    @property
    def footprint_area(self):
        return math.pi * self.radius**2

    @property
    def max_height(self):
        return self.h

    @property
    def bounding_radius(self):
        return self.radius

    def footprint_polygon(self, n=256):
        return self._circle(self.radius, n)


@dataclass
class Cone(_RoundFootprint, Stockpile):
    radius: float = 8.0
    h: float = 5.0

    def __post_init__(self) -> None:
        self.kind = "cone"

    def height(self, x, y):
        u, v = self._local(x, y)
        return self.h * np.maximum(0.0, 1.0 - np.hypot(u, v) / self.radius)

    @property
    def volume(self):
        return math.pi * self.radius**2 * self.h / 3.0

    def shape_parameters(self):
        return {"radius_m": self.radius, "height_m": self.h,
                "side_slope_deg": math.degrees(math.atan2(self.h, self.radius))}


@dataclass
class Frustum(_RoundFootprint, Stockpile):
    radius: float = 10.0
    top_radius: float = 3.0
    h: float = 4.0

    def __post_init__(self) -> None:
        self.kind = "frustum"

    def height(self, x, y):
        u, v = self._local(x, y)
        r = np.hypot(u, v)
        return self.h * np.clip((self.radius - r) / (self.radius - self.top_radius), 0.0, 1.0)

    @property
    def volume(self):
        R, r = self.radius, self.top_radius
        return math.pi * self.h * (R * R + R * r + r * r) / 3.0

    def shape_parameters(self):
        return {"radius_m": self.radius, "top_radius_m": self.top_radius, "height_m": self.h,
                "side_slope_deg": math.degrees(math.atan2(self.h, self.radius - self.top_radius))}


@dataclass
class Windrow(Stockpile):
    length: float = 25.0  # length of the straight crest segment (toe length is length + 2 radius)
    radius: float = 5.0  # half width of the toe
    top_radius: float = 1.0  # half width of the flat crest (0: sharp ridge)
    h: float = 3.5

    def __post_init__(self) -> None:
        self.kind = "windrow"

    def _dist_to_axis(self, x, y):
        u, v = self._local(x, y)
        du = np.maximum(np.abs(u) - 0.5 * self.length, 0.0)
        return np.hypot(du, v)

    def height(self, x, y):
        d = self._dist_to_axis(x, y)
        return self.h * np.clip((self.radius - d) / (self.radius - self.top_radius), 0.0, 1.0)

    def footprint_sdf(self, x, y):
        return self._dist_to_axis(x, y) - self.radius

    @property
    def volume(self):
        R, r, H = self.radius, self.top_radius, self.h
        return self.length * H * (R + r) + math.pi * H * (R * R + R * r + r * r) / 3.0

    @property
    def footprint_area(self):
        return 2 * self.radius * self.length + math.pi * self.radius**2

    @property
    def max_height(self):
        return self.h

    @property
    def bounding_radius(self):
        return 0.5 * self.length + self.radius

    def footprint_polygon(self, n=256):
        half = max(n // 2, 8)
        a1 = np.linspace(-np.pi / 2, np.pi / 2, half)
        a2 = np.linspace(np.pi / 2, 3 * np.pi / 2, half)
        L2, R = 0.5 * self.length, self.radius
        pts = np.concatenate([
            np.stack([L2 + R * np.cos(a1), R * np.sin(a1)], -1),
            np.stack([-L2 + R * np.cos(a2), R * np.sin(a2)], -1),
        ])
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.stack([self.cx + c * pts[:, 0] - s * pts[:, 1], self.cy + s * pts[:, 0] + c * pts[:, 1]], -1)

    def shape_parameters(self):
        return {"crest_length_m": self.length, "toe_half_width_m": self.radius,
                "crest_half_width_m": self.top_radius, "height_m": self.h,
                "toe_length_m": self.length + 2 * self.radius,
                "side_slope_deg": math.degrees(math.atan2(self.h, self.radius - self.top_radius))}


@dataclass
class HipPile(Stockpile):
    half_length: float = 12.0  # a, along theta
    half_width: float = 7.0  # b
    slope: float = 0.65  # rise / run on all four sides
    h: float = 3.5  # must be <= slope * half_width

    def __post_init__(self) -> None:
        self.kind = "hip"
        if self.h > self.slope * min(self.half_length, self.half_width) + 1e-12:
            raise ValueError("hip pile: height exceeds slope * half_width (top would vanish)")

    def height(self, x, y):
        u, v = self._local(x, y)
        d_in = np.minimum(self.half_length - np.abs(u), self.half_width - np.abs(v))
        return np.clip(self.slope * d_in, 0.0, self.h)

    def footprint_sdf(self, x, y):
        u, v = self._local(x, y)
        qx = np.abs(u) - self.half_length
        qy = np.abs(v) - self.half_width
        outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
        return outside + np.minimum(np.maximum(qx, qy), 0.0)

    @property
    def volume(self):
        a, b, H = self.half_length, self.half_width, self.h
        w = H / self.slope
        a_base = 4 * a * b
        a_top = 4 * (a - w) * (b - w)
        a_mid = 4 * (a - w / 2) * (b - w / 2)
        return H * (a_base + 4 * a_mid + a_top) / 6.0

    @property
    def footprint_area(self):
        return 4 * self.half_length * self.half_width

    @property
    def max_height(self):
        return self.h

    @property
    def bounding_radius(self):
        return math.hypot(self.half_length, self.half_width)

    def footprint_polygon(self, n=256):
        a, b = self.half_length, self.half_width
        pts = np.array([[a, -b], [a, b], [-a, b], [-a, -b]], dtype=float)
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.stack([self.cx + c * pts[:, 0] - s * pts[:, 1], self.cy + s * pts[:, 0] + c * pts[:, 1]], -1)

    def shape_parameters(self):
        return {"half_length_m": self.half_length, "half_width_m": self.half_width,
                "side_slope_rise_per_run": self.slope, "height_m": self.h,
                "top_half_length_m": self.half_length - self.h / self.slope,
                "top_half_width_m": self.half_width - self.h / self.slope,
                "side_slope_deg": math.degrees(math.atan(self.slope))}


def make_pile(kind: str, name: str, rng: np.random.Generator, scale: float, material: str) -> Stockpile:
    """A pile of ``kind`` with random dimensions (scaled by ``scale``), centred at (0, 0), base z0 = 0."""
    rep = math.radians(rng.uniform(30.0, 36.0))  # angle of repose
    t = math.tan(rep)
    theta = float(rng.uniform(0.0, np.pi))
    if kind in ("cone", "slope_cone"):
        R = float(rng.uniform(7.0, 10.0)) * scale
        return Cone(name=name, cx=0.0, cy=0.0, theta=theta, material=material, radius=R, h=R * t)
    if kind == "frustum":
        R = float(rng.uniform(9.0, 12.0)) * scale
        r = float(rng.uniform(0.25, 0.4)) * R
        return Frustum(name=name, cx=0.0, cy=0.0, theta=theta, material=material, radius=R, top_radius=r, h=(R - r) * t)
    if kind == "windrow":
        R = float(rng.uniform(4.5, 6.0)) * scale
        r = float(rng.uniform(0.1, 0.25)) * R
        L = float(rng.uniform(3.5, 5.0)) * R
        return Windrow(name=name, cx=0.0, cy=0.0, theta=theta, material=material, length=L, radius=R,
                       top_radius=r, h=(R - r) * t)
    if kind == "hip":
        b = float(rng.uniform(6.0, 8.0)) * scale
        a = float(rng.uniform(1.6, 2.2)) * b
        H = float(rng.uniform(0.55, 0.8)) * b * t
        return HipPile(name=name, cx=0.0, cy=0.0, theta=theta, material=material, half_length=a,
                       half_width=b, slope=t, h=H)
    raise ValueError(f"unknown stockpile kind {kind!r}")
