"""Machines parked on a simulated site: trucks, excavators and plain boxes made of rectangular blocks with
vertical sides and flat tops (what a bare-earth filter must remove; stockpiles are ground and must stay).

A machine stands on the bare earth: its base level is the highest bare-earth height under its footprint, so
no block dips into the ground; each block's top is ``base_z + height_m``. The machine is a height field
(the simulated world is one): a boom is a block down to the ground, no overhangs.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

MACHINE_KINDS = ("truck", "excavator", "box")
PAINTS = {  # body colours (display values), drawn per machine
    "yellow": (0.86, 0.66, 0.12),
    "orange": (0.88, 0.45, 0.12),
    "white": (0.86, 0.86, 0.84),
    "blue": (0.20, 0.33, 0.62),
}


@dataclass
class Block:
    """A rectangle in the machine frame (u forward along the heading, v to the left), with its top height."""

    u: float  # centre (m)
    v: float
    length_m: float  # along u
    width_m: float  # along v
    height_m: float  # top above the machine's base level


@dataclass
class Machine:
    name: str
    kind: str
    cx: float  # site coordinates of the machine frame's origin
    cy: float
    heading_rad: float  # of the u axis, counter-clockwise from grid east
    blocks: list[Block] = field(default_factory=list)
    base_z: float = 0.0  # ellipsoidal height the blocks stand on (max bare earth under the footprint)
    paint: str = "yellow"

    # ---- geometry -----------------------------------------------------------------------------------
    def to_local(self, x, y):
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        dx = np.asarray(x, dtype=float) - self.cx
        dy = np.asarray(y, dtype=float) - self.cy
        return c * dx + s * dy, -s * dx + c * dy

    def to_site(self, u, v):
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        return self.cx + c * u - s * v, self.cy + s * u + c * v

    def block_sdf(self, b: Block, x, y) -> np.ndarray:
        u, v = self.to_local(x, y)
        qx = np.abs(u - b.u) - b.length_m / 2
        qy = np.abs(v - b.v) - b.width_m / 2
        return np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0)) + np.minimum(np.maximum(qx, qy), 0.0)

    def footprint_sdf(self, x, y) -> np.ndarray:
        """Signed distance (m) to the union of the blocks: negative inside."""
        return np.min(np.stack([self.block_sdf(b, x, y) for b in self.blocks]), axis=0)

    def top(self, x, y) -> np.ndarray:
        """Height of the machine's top at (x, y); -inf outside its footprint."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        out = np.full(x.shape, -np.inf)
        for b in self.blocks:
            inside = self.block_sdf(b, x, y) <= 0.0
            out = np.where(inside, np.maximum(out, self.base_z + b.height_m), out)
        return out

    @property
    def bounding_radius(self) -> float:
        return max(math.hypot(abs(b.u) + b.length_m / 2, abs(b.v) + b.width_m / 2) for b in self.blocks)

    @property
    def height_m(self) -> float:
        return max(b.height_m for b in self.blocks)

    def block_corners(self, b: Block) -> np.ndarray:
        """(4, 2) site coordinates of a block's corners, counter-clockwise."""
        hu, hv = b.length_m / 2, b.width_m / 2
        u = np.array([b.u - hu, b.u + hu, b.u + hu, b.u - hu])
        v = np.array([b.v - hv, b.v - hv, b.v + hv, b.v + hv])
        x, y = self.to_site(u, v)
        return np.stack([x, y], -1)

    def outline_points(self, step: float = 0.5) -> np.ndarray:
        """Points along every block's edges (site coordinates), for clearance tests."""
        key = (step, tuple((b.u, b.v, b.length_m, b.width_m) for b in self.blocks))
        cached = getattr(self, "_outline_local", None)
        if cached is None or cached[0] != key:
            pts = []
            for b in self.blocks:
                hu, hv = b.length_m / 2, b.width_m / 2
                cu = np.array([b.u - hu, b.u + hu, b.u + hu, b.u - hu])
                cv = np.array([b.v - hv, b.v - hv, b.v + hv, b.v + hv])
                for k in range(4):
                    a = np.array([cu[k], cv[k]])
                    e = np.array([cu[(k + 1) % 4], cv[(k + 1) % 4]])
                    n = max(2, int(math.ceil(np.hypot(*(e - a)) / step)) + 1)
                    t = np.linspace(0.0, 1.0, n)[:, None]
                    pts.append(a + t * (e - a))
            cached = (key, np.concatenate(pts))
            self._outline_local = cached
        local = cached[1]
        x, y = self.to_site(local[:, 0], local[:, 1])
        return np.stack([x, y], -1)

    def footprint_area(self, step: float = 0.05) -> float:
        """Area (m2) of the union of the blocks (numerical, on a ``step`` grid in the machine frame)."""
        r = self.bounding_radius
        g = np.arange(-r, r + step, step)
        U, V = np.meshgrid(g, g)
        inside = np.zeros(U.shape, bool)
        for b in self.blocks:
            inside |= (np.abs(U - b.u) <= b.length_m / 2) & (np.abs(V - b.v) <= b.width_m / 2)
        return float(inside.sum() * step * step)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["heading_deg"] = math.degrees(self.heading_rad)
        d["height_m"] = self.height_m
        d["footprint_area_m2"] = self.footprint_area()
        return d


def make_machine(kind: str, name: str, rng: np.random.Generator) -> Machine:
    """A machine of ``kind`` (truck, excavator, box) with drawn dimensions, at the origin; footprints 3-10 m,
    overall heights 2.5-4 m."""
    blocks: list[Block] = []
    if kind == "truck":  # cab in front, dump body behind
        w = float(rng.uniform(2.4, 2.6))
        body = float(rng.uniform(4.5, 6.0))
        cab = 2.2
        blocks = [Block(u=cab / 2, v=0.0, length_m=cab, width_m=w, height_m=float(rng.uniform(3.0, 3.4))),
                  Block(u=-body / 2, v=0.0, length_m=body, width_m=w, height_m=float(rng.uniform(2.7, 3.6)))]
    elif kind == "excavator":  # tracks, the house on them (set back) and the boom resting forward
        tl = float(rng.uniform(4.2, 5.0))
        tw = float(rng.uniform(2.8, 3.3))
        hl, hw = 3.6, 2.7
        boom = float(rng.uniform(3.0, 4.5))
        blocks = [Block(u=0.0, v=0.0, length_m=tl, width_m=tw, height_m=1.3),
                  Block(u=-0.4, v=0.0, length_m=hl, width_m=hw, height_m=float(rng.uniform(3.0, 3.5))),
                  Block(u=-0.4 + hl / 2 + boom / 2, v=-0.3, length_m=boom, width_m=0.9,
                        height_m=float(rng.uniform(2.5, 2.9)))]
    elif kind == "box":  # a site cabin, a container, a generator
        length = float(rng.uniform(4.0, 10.0))
        width = float(rng.uniform(3.0, min(length, 7.0)))
        blocks = [Block(u=0.0, v=0.0, length_m=length, width_m=width, height_m=float(rng.uniform(2.5, 4.0)))]
    else:
        raise ValueError(f"unknown machine kind {kind!r}; kinds are {', '.join(MACHINE_KINDS)}")
    paint = list(PAINTS)[int(rng.integers(0, len(PAINTS)))]
    return Machine(name=name, kind=kind, cx=0.0, cy=0.0, heading_rad=float(rng.uniform(0, 2 * np.pi)),
                   blocks=blocks, paint=paint)


def machines_geojson(site) -> dict:
    """truth/machines.geojson: one MultiPolygon per machine (its blocks, project CRS, z = block top)."""
    f = site.frame
    feats = []
    for m in site.machines:
        polys = []
        for b in m.blocks:
            c = m.block_corners(b)
            ring = [[float(x + f.origin_e), float(y + f.origin_n), float(m.base_z + b.height_m)] for x, y in c]
            polys.append([ring + [ring[0]]])
        props = m.to_dict()
        props["note"] = ("blocks with vertical sides and flat tops standing on the bare earth at base_z; "
                         "truth/dtm.tif is the surface without them")
        feats.append({"type": "Feature", "properties": props, "geometry": {"type": "MultiPolygon", "coordinates": polys}})
    return {"type": "FeatureCollection", "name": "machines",
            "crs": {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{f.epsg}"}}, "features": feats}
