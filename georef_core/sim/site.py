"""Simulated earthworks site: terrain, pit, roads, hillside, stockpiles on pads, ground targets.

Everything is a closed-form function of site coordinates ``(x, y)`` (grid offsets in metres from the
site origin ``(E0, N0)`` of the project CRS) returning ellipsoidal heights (m). ``Site.surface`` is the
truth surface (what the DSM samples and what is rendered); ``Site.bare_earth`` is the surface without the
machines (``SiteOptions.machines``; stockpiles are bare earth: what a DTM keeps); ``Site.ground`` is the
bare earth without the stockpiles; ``Site.terrain`` is the natural terrain before the stockpile pads are
levelled. Without machines (the default) ``surface`` and ``bare_earth`` are the same.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .geo import SiteFrame, utm_epsg_for
from .machines import MACHINE_KINDS, Machine, make_machine
from .stockpiles import MATERIALS, Stockpile, make_pile

DEFAULT_PILES = ("cone", "frustum", "windrow", "hip", "slope_cone")


@dataclass
class SiteOptions:
    # site origin (centre), WGS84: near Nagoya, where the shipped broadcast navigation file's satellites are
    # visible (georef_core/sim/data/base.nav holds only the satellites its receiver there tracked)
    lat_deg: float = 35.13
    lon_deg: float = 136.97
    epsg: int | None = None  # project CRS; None: the UTM zone of (lat, lon)
    ground_height_m: float = 80.0  # ellipsoidal height of the ground at the origin (approx.)
    size_m: tuple[float, float] = (160.0, 100.0)  # extent of the work area along grid E and N
    regional_slope_pct: float = 2.0  # gradient of the regional plane (random direction)
    undulation_m: float = 0.8  # amplitude of the broad undulations
    micro_relief_m: float = 0.04  # amplitude of the metre-scale relief
    hillside: bool = True  # a ramp (tanh step) across part of the site, where "slope_cone" stands
    hillside_rise_m: float = 4.0  # (rise and half width are multiplied by the stockpile scale)
    hillside_half_width_m: float = 15.0  # tanh length: max slope = rise / (2 * half width)
    pit: bool = True
    pit_depth_m: float = 4.0
    pit_wall_deg: float = 24.0  # mean wall angle
    n_roads: int = 2  # 0..2: a straight haul road and a curved (circular arc) one
    road_width_m: float = 7.0
    stockpiles: tuple[str, ...] = DEFAULT_PILES  # kinds: cone, frustum, windrow, hip, slope_cone
    stockpile_scale: float | None = None  # None: min(1, min(size_m) / 100)
    pad_margin_m: float = 2.0  # base plane exact up to this distance outside a toe
    pad_blend_m: float = 5.0  # then blends into the terrain over this distance
    n_targets: int = 9
    n_control: int = 5  # targets used as control (corners + centre first), the rest are check points
    target_size_m: float = 1.0  # side of the square (2x2 checker) target
    target_margin_m: float = 6.0  # targets kept this far inside the work area
    # machines (trucks, excavators, boxes: blocks with vertical sides, 2.5-4 m tall, 3-10 m footprints) parked on
    # open ground, away from the piles, the pit, the roads and the targets; 0 (the default) keeps a site as it was
    machines: int = 0
    machine_kinds: tuple[str, ...] = MACHINE_KINDS


@dataclass
class Target:
    name: str
    x: float  # site coordinates of the centre (grid offsets, m)
    y: float
    z: float  # ellipsoidal height of the ground at the centre
    size_m: float
    rotation_rad: float  # of the checker pattern, counter-clockwise from grid east
    role: str  # "control" or "check"


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _rounded_box_sdf(u, v, hu, hv, r):
    qx = np.abs(u) - (hu - r)
    qy = np.abs(v) - (hv - r)
    return np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0)) + np.minimum(np.maximum(qx, qy), 0.0) - r


@dataclass
class Road:
    kind: str  # "line" or "arc"
    # line: point (px, py) and unit direction (dx, dy); arc: centre (px, py), radius
    px: float
    py: float
    dx: float = 1.0
    dy: float = 0.0
    radius: float = 0.0
    width: float = 7.0

    def signed_distance(self, x, y):
        """Signed lateral offset from the centre line (m)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if self.kind == "line":
            return (x - self.px) * (-self.dy) + (y - self.py) * self.dx
        return np.hypot(x - self.px, y - self.py) - self.radius

    def along(self, x, y):
        """Coordinate along the road (m)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if self.kind == "line":
            return (x - self.px) * self.dx + (y - self.py) * self.dy
        return np.arctan2(y - self.py, x - self.px) * self.radius

    def centreline(self, length: float, step: float = 1.0) -> np.ndarray:
        """Points along the centre line (line: centred on p; arc: the whole circle if shorter)."""
        if self.kind == "line":
            t = np.arange(-length / 2, length / 2 + step, step)
            return np.stack([self.px + t * self.dx, self.py + t * self.dy], -1)
        n = int(min(2 * np.pi * self.radius, length) / step) + 2
        a = np.linspace(0, 2 * np.pi, n)
        return np.stack([self.px + self.radius * np.cos(a), self.py + self.radius * np.sin(a)], -1)


class Site:
    """A generated site. Build with :func:`build_site`."""

    def __init__(self, options: SiteOptions, seed: int):
        self.options = options
        self.seed = int(seed)
        ss = np.random.SeedSequence([self.seed, 101])
        rng = np.random.default_rng(ss)
        o = options
        epsg = o.epsg or utm_epsg_for(o.lat_deg, o.lon_deg)
        from pyproj import Transformer

        e0, n0 = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(o.lon_deg, o.lat_deg)
        self.frame = SiteFrame(epsg=int(epsg), origin_e=float(round(e0)), origin_n=float(round(n0)),
                               h_ref=float(o.ground_height_m))
        self.half_w = 0.5 * float(o.size_m[0])
        self.half_h = 0.5 * float(o.size_m[1])
        scale = o.stockpile_scale if o.stockpile_scale is not None else min(1.0, min(o.size_m) / 100.0)
        self.scale = float(scale)
        self.machines: list[Machine] = []  # placed last, from their own random stream (sites without keep their draws)
        self.machines_requested = int(o.machines)

        # ---- natural terrain ---------------------------------------------------------------
        az = rng.uniform(0, 2 * np.pi)
        g = o.regional_slope_pct / 100.0
        self.plane = (float(o.ground_height_m), g * math.cos(az), g * math.sin(az))
        nb = 10
        span = max(self.half_w, self.half_h) + 150.0
        self.bumps = np.stack([
            rng.uniform(-span, span, nb), rng.uniform(-span, span, nb),
            rng.uniform(15.0, 45.0, nb), rng.normal(0.0, o.undulation_m, nb),
        ], axis=-1)
        nw = 14
        ang = rng.uniform(0, 2 * np.pi, nw)
        wl = rng.uniform(2.5, 9.0, nw)
        self.waves = np.stack([
            2 * np.pi / wl * np.cos(ang), 2 * np.pi / wl * np.sin(ang), rng.uniform(0, 2 * np.pi, nw),
            o.micro_relief_m * rng.uniform(0.3, 1.0, nw) / math.sqrt(nw / 2),
        ], axis=-1)
        # the hillside: a tanh ramp whose centre line runs along one of the long edges of the work area,
        # inset so that the pile standing on it ("slope_cone") fits inside; (px, py, nx, ny): the ramp
        # rises towards +n from the line through p
        hw, hh = self.half_w, self.half_h
        self.hill_rise = float(o.hillside_rise_m) * self.scale
        self.hill_half_width = float(o.hillside_half_width_m) * self.scale
        inset = 10.0 * self.scale + 3.0
        side = int(rng.integers(0, 2))
        sgn = -1.0 if side == 0 else 1.0
        if hw >= hh:
            self.hill = (0.0, sgn * (hh - inset), 0.0, -sgn)
        else:
            self.hill = (sgn * (hw - inset), 0.0, -sgn, 0.0)
        self.hill = tuple(float(v) for v in self.hill)

        for _attempt in range(40):
            if self._layout(rng):
                break
        else:
            raise ValueError(f"could not lay out {len(o.stockpiles)} stockpiles, the pit and roads on a "
                             f"{tuple(o.size_m)} m site; enlarge the site, lower stockpile_scale or use fewer stockpiles")

        # ---- targets --------------------------------------------------------------------------------
        self.targets: list[Target] = self._place_targets(rng)
        if o.machines > 0:
            self.machines = self._place_machines(np.random.default_rng(np.random.SeedSequence([self.seed, 102])))

    def _layout(self, rng) -> bool:
        """One random try at placing the roads, the pit and the stockpiles; False when something did not fit."""
        o = self.options
        hw, hh = self.half_w, self.half_h
        # ---- roads --------------------------------------------------------------------------
        self.roads = []
        if o.n_roads >= 1:
            # across the work area's short side (so it crosses the hillside once)
            a = rng.uniform(-0.35, 0.35) + (np.pi / 2 if hw >= hh else 0.0)
            off = rng.uniform(-0.4, 0.4) * max(hw, hh)
            d = (math.cos(a), math.sin(a))
            self.roads.append(Road("line", px=-d[1] * off, py=d[0] * off, dx=d[0], dy=d[1], width=o.road_width_m))
        if o.n_roads >= 2:
            rad = float(rng.uniform(1.3, 2.0) * max(hw, hh))
            ca = rng.uniform(0, 2 * np.pi)
            # a large circle whose arc cuts across one corner region of the site
            rr = rad + 0.6 * min(hw, hh)
            self.roads.append(Road("arc", px=math.cos(ca) * rr, py=math.sin(ca) * rr, radius=rad,
                                   width=o.road_width_m * 0.85))

        # ---- pit -------------------------------------------------------------------------------
        self.pit = None
        if o.pit:
            depth = float(o.pit_depth_m) * max(self.scale, 0.4)
            wall = depth / math.tan(math.radians(o.pit_wall_deg))
            hu = float(rng.uniform(8.0, 14.0)) * self.scale + wall
            hv = float(rng.uniform(5.0, 8.0)) * self.scale + wall
            self.pit = {"hu": hu, "hv": hv, "r": min(hu, hv) * 0.45, "depth": depth, "wall": wall,
                        "theta": float(rng.uniform(0, np.pi))}
            for _ in range(300):
                self.pit["cx"] = float(rng.uniform(-hw * 0.8, hw * 0.8))
                self.pit["cy"] = float(rng.uniform(-hh * 0.8, hh * 0.8))
                if self._pit_ok():
                    break
            else:
                return False

        # ---- stockpiles: the slope pile first, then the largest -------------------------------------
        self.piles = []
        mats = list(MATERIALS)
        made = []
        for i, kind in enumerate(o.stockpiles):
            material = mats[int(rng.integers(0, len(mats)))]
            made.append((i, kind, make_pile(kind, f"SP{i + 1:02d}_{kind}", rng, self.scale, material)))
        made.sort(key=lambda t: (t[1] != "slope_cone", -t[2].footprint_area, t[0]))
        placed_piles = []
        for i, kind, pile in made:
            for _ in range(400):
                if kind == "slope_cone" and o.hillside:
                    px_, py_, nx_, ny_ = self.hill
                    t_ = rng.uniform(-1, 1) * (hw if abs(nx_) < 0.5 else hh) * 0.7
                    cx, cy = px_ - ny_ * t_, py_ + nx_ * t_
                else:
                    cx, cy = rng.uniform(-hw, hw), rng.uniform(-hh, hh)
                pile.cx, pile.cy = float(cx), float(cy)
                if self._pile_ok(pile, kind):
                    break
            else:
                return False
            self.piles.append(pile)
            placed_piles.append((i, pile))
        self.piles = [p for _, p in sorted(placed_piles, key=lambda t: t[0])]
        for pile in self.piles:
            pile.gx = pile.gy = 0.0
            if pile.name.endswith("slope_cone"):
                gx, gy = self._terrain_gradient(pile.cx, pile.cy)
                pile.gx, pile.gy = float(gx), float(gy)
            pile.z0 = float(self.terrain(pile.cx, pile.cy))
        return True

    # ------------------------------------------------------------------------------------------------
    def _pit_ok(self) -> bool:
        p = self.pit
        c, s = math.cos(p["theta"]), math.sin(p["theta"])
        corners = np.array([[p["hu"], p["hv"]], [-p["hu"], p["hv"]], [-p["hu"], -p["hv"]], [p["hu"], -p["hv"]]])
        cx = p["cx"] + c * corners[:, 0] - s * corners[:, 1]
        cy = p["cy"] + s * corners[:, 0] + c * corners[:, 1]
        if np.any(np.abs(cx) > self.half_w - 2.0) or np.any(np.abs(cy) > self.half_h - 2.0):
            return False
        for road in self.roads:
            pts = road.centreline(2 * (self.half_w + self.half_h) + 400.0)
            if np.min(self.pit_sdf(pts[:, 0], pts[:, 1])) < road.width / 2 + 3.0:
                return False
        if self.options.hillside:
            if not self._clear_of_hill(cx, cy, 1.2):
                return False
        return True

    def _clear_of_hill(self, x, y, factor: float) -> bool:
        px, py, nx, ny = self.hill
        sd = (np.asarray(x) - px) * nx + (np.asarray(y) - py) * ny
        return bool(np.min(np.abs(sd)) >= factor * self.hill_half_width and np.ptp(np.sign(sd)) == 0)

    def pit_sdf(self, x, y):
        p = self.pit
        c, s = math.cos(p["theta"]), math.sin(p["theta"])
        dx = np.asarray(x, dtype=float) - p["cx"]
        dy = np.asarray(y, dtype=float) - p["cy"]
        return _rounded_box_sdf(c * dx + s * dy, -s * dx + c * dy, p["hu"], p["hv"], p["r"])

    def _pile_ok(self, pile: Stockpile, kind: str) -> bool:
        o = self.options
        poly = pile.footprint_polygon(96)
        if np.any(np.abs(poly[:, 0]) > self.half_w - 1.0) or np.any(np.abs(poly[:, 1]) > self.half_h - 1.0):
            return False
        for other in self.piles:  # no pile's exact pad may reach into another's blend zone
            if np.min(other.footprint_sdf(poly[:, 0], poly[:, 1])) < 2 * o.pad_margin_m + o.pad_blend_m + 1.0:
                return False
        for road in self.roads:
            sd = road.signed_distance(poly[:, 0], poly[:, 1])
            if np.min(np.abs(sd)) < road.width / 2 + 2.5 or np.ptp(np.sign(sd)) > 0:
                return False
        if self.pit is not None and np.min(self.pit_sdf(poly[:, 0], poly[:, 1])) < o.pad_margin_m + o.pad_blend_m + 1.0:
            return False
        if o.hillside and kind != "slope_cone" and not self._clear_of_hill(poly[:, 0], poly[:, 1], 1.2):
            return False
        return True

    def _place_targets(self, rng) -> list[Target]:
        o = self.options
        n = int(o.n_targets)
        if n <= 0:
            return []
        m = o.target_margin_m
        hw, hh = self.half_w - m, self.half_h - m
        # corners and centre first (the control set), then a jittered stratified fill
        anchors = [(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh), (0.0, 0.0)]
        ncols = max(2, int(math.ceil(math.sqrt(max(n - 5, 1) * hw / max(hh, 1e-6)))))
        nrows = max(2, int(math.ceil(max(n - 5, 1) / ncols)))
        extra = []
        for r in range(nrows):
            for c in range(ncols):
                extra.append((-hw + (c + 0.5) * 2 * hw / ncols, -hh + (r + 0.5) * 2 * hh / nrows))
        order = rng.permutation(len(extra))
        cands = anchors + [extra[i] for i in order]
        targets: list[Target] = []
        for k, (ax, ay) in enumerate(cands):
            if len(targets) >= n:
                break
            for attempt in range(400):
                jit = 0.0 if attempt == 0 and k < 5 else min(6.0 + attempt * 0.25, 0.35 * min(hw, hh))
                x = float(np.clip(ax + rng.uniform(-jit, jit), -hw, hw))
                y = float(np.clip(ay + rng.uniform(-jit, jit), -hh, hh))
                if self._target_ok(x, y, targets):
                    rot = float(rng.uniform(0, np.pi / 2))
                    targets.append(Target(name="", x=x, y=y, z=0.0, size_m=o.target_size_m, rotation_rad=rot, role=""))
                    break
        for _ in range(4000):  # fill up with uniformly drawn positions
            if len(targets) >= n:
                break
            x, y = float(rng.uniform(-hw, hw)), float(rng.uniform(-hh, hh))
            if self._target_ok(x, y, targets):
                targets.append(Target(name="", x=x, y=y, z=0.0, size_m=o.target_size_m,
                                      rotation_rad=float(rng.uniform(0, np.pi / 2)), role=""))
        for i, t in enumerate(targets):
            t.name = f"T{i + 1:02d}"
            t.role = "control" if i < o.n_control else "check"
            t.z = float(self.surface(t.x, t.y))
        return targets

    def _target_ok(self, x, y, targets) -> bool:
        s = self.options.target_size_m
        for p in self.piles:
            if p.footprint_sdf(x, y) < s + 2.5:
                return False
        if self.pit is not None:
            d = float(self.pit_sdf(x, y))
            if -self.pit["wall"] - s - 1.0 < d < s + 1.5:
                return False
        for road in self.roads:  # keep off the ditches
            a = abs(float(road.signed_distance(x, y)))
            if road.width / 2 - s < a < road.width / 2 + 2.5 + s:
                return False
        sep = min(10.0, 0.25 * min(self.options.size_m) + 1.0)
        for t in targets:
            if math.hypot(t.x - x, t.y - y) < sep:
                return False
        return True

    def _place_machines(self, rng) -> list[Machine]:
        """Up to ``options.machines`` machines on open ground: inside the work area (3 m margin), 3 m clear of the
        piles' blend zones, the pit, the roads and their ditches, the targets and each other. Machines that do not
        fit after 400 tries are left out (``machines_requested`` keeps the number asked for)."""
        o = self.options
        kinds = tuple(o.machine_kinds) or MACHINE_KINDS
        placed: list[Machine] = []
        for i in range(int(o.machines)):
            m = make_machine(kinds[int(rng.integers(0, len(kinds)))], f"M{i + 1:02d}", rng)
            for _ in range(400):
                m.cx, m.cy = float(rng.uniform(-self.half_w, self.half_w)), float(rng.uniform(-self.half_h, self.half_h))
                m.heading_rad = float(rng.uniform(0, 2 * np.pi))
                if self._machine_ok(m, placed):
                    break
            else:
                continue
            pts = m.outline_points(0.5)
            inner = np.stack(m.to_site(*np.meshgrid(np.linspace(-1, 1, 5) * m.bounding_radius,
                                                    np.linspace(-1, 1, 5) * m.bounding_radius)), -1).reshape(-1, 2)
            inner = inner[m.footprint_sdf(inner[:, 0], inner[:, 1]) <= 0]
            allp = np.concatenate([pts, inner])
            m.base_z = float(np.max(self.bare_earth(allp[:, 0], allp[:, 1])))
            placed.append(m)
        return placed

    def _machine_ok(self, m: Machine, placed: list[Machine]) -> bool:
        o = self.options
        if abs(m.cx) > self.half_w - 3.0 or abs(m.cy) > self.half_h - 3.0:
            return False  # quick rejection: the centre is outside the margin already
        pts = m.outline_points(0.5)
        if np.any(np.abs(pts[:, 0]) > self.half_w - 3.0) or np.any(np.abs(pts[:, 1]) > self.half_h - 3.0):
            return False
        for p in self.piles:
            if np.min(p.footprint_sdf(pts[:, 0], pts[:, 1])) < o.pad_margin_m + o.pad_blend_m + 3.0:
                return False
        if self.pit is not None and np.min(self.pit_sdf(pts[:, 0], pts[:, 1])) < 3.0:
            return False
        for road in self.roads:
            sd = road.signed_distance(pts[:, 0], pts[:, 1])
            if np.min(np.abs(sd)) < road.width / 2 + 3.0 or np.ptp(np.sign(sd)) > 0:
                return False
        for t in self.targets:
            if float(m.footprint_sdf(t.x, t.y)) < t.size_m + 3.0:
                return False
        for other in placed:
            if np.min(other.footprint_sdf(pts[:, 0], pts[:, 1])) < 3.0:
                return False
        return True

    # ---- height functions ------------------------------------------------------------------------
    def terrain(self, x, y) -> np.ndarray:
        """Natural terrain (before pads and stockpiles), ellipsoidal height."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        z0, gx, gy = self.plane
        z = z0 + gx * x + gy * y
        for bx, by, bs, ba in self.bumps:
            z = z + ba * np.exp(-((x - bx) ** 2 + (y - by) ** 2) / (2 * bs * bs))
        for kx, ky, ph, a in self.waves:
            z = z + a * np.sin(kx * x + ky * y + ph)
        if self.options.hillside:
            px, py, nx, ny = self.hill
            s = (x - px) * nx + (y - py) * ny
            z = z + 0.5 * self.hill_rise * (1.0 + np.tanh(s / self.hill_half_width))
        if self.pit is not None:
            d = self.pit_sdf(x, y)
            z = z - self.pit["depth"] * _smoothstep(-d / self.pit["wall"])
        for road in self.roads:
            a = np.abs(road.signed_distance(x, y))
            hwid = road.width / 2
            crown = 0.12 * (1.0 - _smoothstep(a / hwid)) + 0.05 * (1.0 - _smoothstep((a - hwid) / 0.8))
            ditch = -0.3 * np.exp(-(((a - hwid - 1.3) / 0.6) ** 2))
            z = z + crown + ditch
        return z

    def _terrain_gradient(self, x, y, h=0.05):
        gx = (self.terrain(x + h, y) - self.terrain(x - h, y)) / (2 * h)
        gy = (self.terrain(x, y + h) - self.terrain(x, y - h)) / (2 * h)
        return float(gx), float(gy)

    def pad_weight(self, pile: Stockpile, x, y) -> np.ndarray:
        o = self.options
        d = pile.footprint_sdf(x, y)
        return 1.0 - _smoothstep((d - o.pad_margin_m) / o.pad_blend_m)

    def _near(self, pile: Stockpile, x, y, extra: float) -> np.ndarray:
        r = pile.bounding_radius + extra
        return (np.abs(x - pile.cx) <= r) & (np.abs(y - pile.cy) <= r)

    def ground(self, x, y) -> np.ndarray:
        """Terrain with the stockpile pads levelled to their base planes (the surface without piles)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        z = np.array(self.terrain(x, y), dtype=float)
        o = self.options
        for p in self.piles:
            m = self._near(p, x, y, o.pad_margin_m + o.pad_blend_m + 0.1)
            if not np.any(m):
                continue
            xm, ym = x[m], y[m]
            w = self.pad_weight(p, xm, ym)
            z[m] = w * p.base_height(xm, ym) + (1.0 - w) * z[m]
        return z

    def bare_earth(self, x, y) -> np.ndarray:
        """Ground plus stockpiles, without the machines: the truth of a bare-earth DTM (ellipsoidal height, m)."""
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        z = self.ground(x, y)
        for p in self.piles:
            m = self._near(p, x, y, 0.1)
            if np.any(m):
                z[m] += p.height(x[m], y[m])
        return z if z.ndim else float(z)

    def surface(self, x, y) -> np.ndarray:
        """The truth surface: ground plus stockpiles plus machines (ellipsoidal height, m)."""
        z = self.bare_earth(x, y)
        if not self.machines:
            return z
        x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
        z = np.array(z, dtype=float)
        for mc in self.machines:
            r = mc.bounding_radius + 0.1
            near = (np.abs(x - mc.cx) <= r) & (np.abs(y - mc.cy) <= r)
            if np.any(near):
                z[near] = np.maximum(z[near], mc.top(x[near], y[near]))
        return z if z.ndim else float(z)

    def machine_index(self, x, y) -> np.ndarray:
        """Index of the machine standing on each point (inside its footprint), -1 elsewhere."""
        x = np.asarray(x, dtype=float)
        out = np.full(np.broadcast(x, np.asarray(y)).shape, -1, dtype=np.int16)
        for i, mc in enumerate(self.machines):
            out[mc.footprint_sdf(x, y) <= 0] = i
        return out

    def surface_grid(self, x0: float, y0: float, nx: int, ny: int, step: float, block_rows: int = 256,
                     fn=None) -> np.ndarray:
        """``surface`` (or ``fn``, e.g. ``bare_earth``) at ``(x0 + j*step, y0 + i*step)``, shape (ny, nx),
        evaluated by row blocks."""
        fn = fn or self.surface
        out = np.empty((ny, nx), dtype=np.float64)
        xs = x0 + np.arange(nx) * step
        for i0 in range(0, ny, block_rows):
            ys = y0 + np.arange(i0, min(ny, i0 + block_rows)) * step
            xx, yy = np.meshgrid(xs, ys)
            out[i0:i0 + len(ys)] = fn(xx, yy)
        return out

    def pile_index(self, x, y) -> np.ndarray:
        """Index of the stockpile covering each point (its toe inside), -1 elsewhere."""
        x = np.asarray(x, dtype=float)
        out = np.full(x.shape, -1, dtype=np.int16)
        for i, p in enumerate(self.piles):
            out[p.footprint_sdf(x, y) < 0] = i
        return out

    def base_station_site_xy(self) -> tuple[float, float]:
        """A suggested GNSS base-station point: just outside a corner of the work area, off every feature."""
        x, y = -self.half_w - 6.0, -self.half_h - 6.0
        for _ in range(50):
            if all(p.footprint_sdf(x, y) > 5.0 for p in self.piles) and all(
                    abs(float(r.signed_distance(x, y))) > r.width / 2 + 3.0 for r in self.roads):
                break
            x -= 2.0
        return float(x), float(y)

    def base_station_ecef(self, antenna_height_m: float = 1.8) -> np.ndarray:
        """ECEF of a base antenna ``antenna_height_m`` above the ground at :meth:`base_station_site_xy`."""
        x, y = self.base_station_site_xy()
        h = float(self.surface(x, y)) + antenna_height_m
        return self.frame.grid_to_ecef(x + self.frame.origin_e, y + self.frame.origin_n, h)

    # ---- description --------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "options": asdict(self.options),
            "frame": self.frame.to_dict(),
            "site_coordinates": "x = E - origin_E, y = N - origin_N (project CRS grid metres); z ellipsoidal height",
            "work_area_site_xy_m": [[-self.half_w, -self.half_h], [self.half_w, self.half_h]],
            "regional_plane": {"z0": self.plane[0], "dz_dx": self.plane[1], "dz_dy": self.plane[2]},
            "hillside": None if not self.options.hillside else {
                "point_xy": list(self.hill[:2]), "rise_direction_xy": list(self.hill[2:]),
                "rise_m": self.hill_rise, "half_width_m": self.hill_half_width},
            "pit": self.pit,
            "roads": [asdict(r) for r in self.roads],
            "stockpiles": [p.to_dict() for p in self.piles],
            "targets": [asdict(t) for t in self.targets],
            **({"machines": [m.to_dict() for m in self.machines], "machines_requested": self.machines_requested}
               if self.machines_requested else {}),
            "suggested_base_station": {
                "site_xy_m": list(self.base_station_site_xy()),
                "ground_h_m": float(self.surface(*self.base_station_site_xy())),
                "antenna_height_above_ground_m": 1.8,
                "antenna_ecef_m": self.base_station_ecef(1.8).tolist(),
                "note": "not used by the image simulation; for the GNSS observation simulator",
            },
        }


def build_site(options: SiteOptions | None = None, seed: int = 0) -> Site:
    return Site(options or SiteOptions(), seed)
