"""A seeded synthetic point cloud with a known bare earth, to judge the DTM's ground classification
(georef_core.dtm) under vegetation and machines, and the DSM the dense step would grid from it.

The site (site coordinates x east, y north, metres, centred on 0):

* **terrain**: a plane of random slope (up to 4 %) plus two undulations (0.3-0.7 m, 12-30 m wavelengths);
* a **stockpile** on it: a ridge pile (a crest segment 0-8 m long, 3-5 m high, flanks at 33-38 deg) with a sharp
  crest and a sharp toe;
* a **cut batter**: the ground east of a line is cut down 1.5-3 m by a batter of slope 1:1 to 1:1.5 (45-34 deg),
  with sharp top and toe edges, the cut floor flat beyond;
* **trees**: crowns of radius 1.5-4 m, half ellipsoids 1.5-5 m deep whose rim is 1-4 m above the ground (the
  trunk is not seen from above), **bushes**: half ellipsoids on the ground, radius 0.5-1.8 m, 0.4-1.8 m high;
  gaps in the foliage (0.4 m patches, 15 % of a tree's crown, 5 % of a bush's) let the ground be seen;
* **machines** (georef_core.sim.machines: an excavator, a truck, a box) standing on the ground;
* **grass**: patches where the ground points carry 0-10 cm of grass (the truth terrain is under it).

The points are drawn uniformly at ``points_per_m2`` and take the height of what is seen from above (plus
``noise_m``; canopy points ``canopy_noise_m``); the DSM is their median per cell with its holes filled, as
the dense step grids its cloud (georef_core.dense.dsm_raster). :func:`evaluate_ground_filter` runs the DTM
step's classifier and interpolation on it and measures them against the truth (docs/deliverables.md,
"Vegetation, machines, crests and batters").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .machines import Machine, make_machine

KINDS = ("open", "pile", "batter", "tree", "bush", "machine")


@dataclass
class BareEarthSceneOptions:
    size_m: tuple[float, float] = (56.0, 40.0)
    resolution_m: float = 0.125  # DSM cell (the classification cell 0.5 m is 4 of them)
    points_per_m2: float = 200.0
    noise_m: float = 0.03  # ground and machine points (1 sigma)
    canopy_noise_m: float = 0.15  # foliage is rough and matched less well
    n_trees: int = 5
    n_bushes: int = 10
    machines: tuple[str, ...] = ("excavator", "truck", "box")
    tree_gap_share: float = 0.15
    bush_gap_share: float = 0.05
    grass_patches: int = 3


@dataclass
class Plant:
    kind: str  # "tree" or "bush"
    cx: float
    cy: float
    radius_m: float
    rim_m: float  # crown rim above the ground (0 for a bush)
    depth_m: float  # crown top above its rim
    ground_z: float = 0.0  # terrain at the centre (the plant stands on it)

    def top(self, x, y) -> np.ndarray:
        """Crown top height at (x, y); -inf outside the crown."""
        r2 = ((np.asarray(x) - self.cx) ** 2 + (np.asarray(y) - self.cy) ** 2) / self.radius_m ** 2
        inside = r2 < 1.0
        h = self.ground_z + self.rim_m + self.depth_m * np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))
        return np.where(inside, h, -np.inf)

    @property
    def height_m(self) -> float:
        return self.rim_m + self.depth_m


@dataclass
class BareEarthScene:
    options: BareEarthSceneOptions
    seed: int
    half_w: float
    half_h: float
    plane: tuple[float, float, float]  # z0, gx, gy
    waves: list  # (amplitude, kx, ky, phase)
    pile: dict  # {"a": (x, y), "b": (x, y), "height_m", "slope"}
    batter: dict  # {"x0", "angle_rad", "depth_m", "slope"}: the cut edge line x' = x0 (x' along the normal)
    plants: list[Plant] = field(default_factory=list)
    machines: list[Machine] = field(default_factory=list)
    grass: list = field(default_factory=list)  # (cx, cy, radius)
    gap_draw: np.ndarray | None = None  # a uniform draw per 0.4 m patch: foliage gap where below the share
    gap_cell_m: float = 0.4

    # ---- the truth ------------------------------------------------------------------------------------
    def batter_coord(self, x, y) -> np.ndarray:
        """Distance (m) beyond the cut's top edge, along the cut's normal (negative: uncut side)."""
        a = self.batter["angle_rad"]
        return np.asarray(x) * math.cos(a) + np.asarray(y) * math.sin(a) - self.batter["x0"]

    def crest_distance(self, x, y) -> np.ndarray:
        (ax, ay), (bx, by) = self.pile["a"], self.pile["b"]
        dx, dy = bx - ax, by - ay
        L2 = dx * dx + dy * dy
        px, py = np.asarray(x) - ax, np.asarray(y) - ay
        t = np.clip((px * dx + py * dy) / L2, 0.0, 1.0) if L2 > 0 else 0.0
        return np.hypot(px - t * dx, py - t * dy)

    def pile_height(self, x, y) -> np.ndarray:
        return np.maximum(0.0, self.pile["height_m"] - self.pile["slope"] * self.crest_distance(x, y))

    def natural(self, x, y) -> np.ndarray:
        x, y = np.asarray(x, float), np.asarray(y, float)
        z0, gx, gy = self.plane
        z = z0 + gx * x + gy * y
        for amp, kx, ky, ph in self.waves:
            z = z + amp * np.sin(kx * x + ky * y + ph)
        return z

    def terrain(self, x, y) -> np.ndarray:
        """The bare earth: natural ground, the cut and the pile."""
        d = self.batter_coord(x, y)
        cut = np.clip(d * self.batter["slope"], 0.0, self.batter["depth_m"])
        return self.natural(x, y) - cut + self.pile_height(x, y)

    def objects_top(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """(highest object top at (x, y) or -inf, index of that object: plants first, then machines; -1 none)."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        top = np.full(x.shape, -np.inf)
        idx = np.full(x.shape, -1, np.int32)
        for i, obj in enumerate(list(self.plants) + list(self.machines)):
            t = obj.top(x, y)
            hit = t > top
            top = np.where(hit, t, top)
            idx = np.where(hit, i, idx)
        return top, idx

    def object_kind(self, idx: np.ndarray) -> np.ndarray:
        """"tree", "bush", "machine" or "" per object index."""
        names = np.array([p.kind for p in self.plants] + ["machine"] * len(self.machines) + [""])
        return names[np.where(idx >= 0, idx, len(names) - 1)]

    def grass_height(self, x, y, rng) -> np.ndarray:
        out = np.zeros(np.shape(x))
        for cx, cy, r in self.grass:
            inside = np.hypot(np.asarray(x) - cx, np.asarray(y) - cy) < r
            out = np.where(inside, rng.uniform(0.0, 0.10, np.shape(x)), out)
        return out

    # ---- what a survey would see --------------------------------------------------------------------------
    def points(self, seed_offset: int = 0):
        """(x, y, z, truth): the cloud (site coordinates) and per point its truth: 0 ground (also grass and
        ground seen through a gap), 1 tree, 2 bush, 3 machine."""
        o = self.options
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 77, seed_offset]))
        n = int(o.points_per_m2 * 4 * self.half_w * self.half_h)
        x = rng.uniform(-self.half_w, self.half_w, n)
        y = rng.uniform(-self.half_h, self.half_h, n)
        ground = self.terrain(x, y) + self.grass_height(x, y, rng)
        top, idx = self.objects_top(x, y)
        kind = self.object_kind(idx)
        plant = (kind == "tree") | (kind == "bush")
        share = np.where(kind == "tree", o.tree_gap_share, o.bush_gap_share)
        gap = plant & (self._gap_draw(x, y) < share)
        seen_obj = np.isfinite(top) & (top > ground) & ~gap
        z = np.where(seen_obj, top, ground)
        sigma = np.where(seen_obj & plant, o.canopy_noise_m, o.noise_m)
        z = z + rng.normal(0.0, 1.0, n) * sigma
        truth = np.zeros(n, np.uint8)
        truth[seen_obj & (kind == "tree")] = 1
        truth[seen_obj & (kind == "bush")] = 2
        truth[seen_obj & (kind == "machine")] = 3
        return x, y, z, truth

    def _gap_draw(self, x, y) -> np.ndarray:
        c = self.gap_cell_m
        i = np.clip(((np.asarray(y) + self.half_h) / c).astype(int), 0, self.gap_draw.shape[0] - 1)
        j = np.clip(((np.asarray(x) + self.half_w) / c).astype(int), 0, self.gap_draw.shape[1] - 1)
        return self.gap_draw[i, j]

    def dsm(self):
        """(DSM float64 north-up with the dense step's gridding and hole filling, its transform in site
        coordinates, cell-centre x and y, the cloud (x, y, z, truth))."""
        from ..dense.dsm_raster import RasterGrid, bin_median, fill_holes

        r = self.options.resolution_m
        grid = RasterGrid(-self.half_w, self.half_h, r, int(round(2 * self.half_w / r)), int(round(2 * self.half_h / r)))
        x, y, z, truth = self.points()
        med, _cnt = bin_median(grid, x, y, z)
        dsm, _mask = fill_holes(med, max_gap_cells=max(2.0, 1.0 / r))
        X, Y = grid.centres()
        return np.asarray(dsm, np.float64), grid.transform, X, Y, (x, y, z, truth)


def build_bare_earth_scene(seed: int, options: BareEarthSceneOptions | None = None) -> BareEarthScene:
    o = options or BareEarthSceneOptions()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 9001]))
    hw, hh = o.size_m[0] / 2, o.size_m[1] / 2
    ang = rng.uniform(0, 2 * np.pi)
    g = rng.uniform(0.0, 0.04)
    plane = (100.0, g * math.cos(ang), g * math.sin(ang))
    waves = []
    for _ in range(2):
        wl, th = rng.uniform(12.0, 30.0), rng.uniform(0, np.pi)
        k = 2 * np.pi / wl
        waves.append((rng.uniform(0.3, 0.7), k * math.cos(th), k * math.sin(th), rng.uniform(0, 2 * np.pi)))
    # the pile in the western third, the cut's edge in the eastern third (its normal within 25 deg of east)
    h = rng.uniform(3.0, 5.0)
    slope = math.tan(math.radians(rng.uniform(33.0, 38.0)))
    crest = rng.uniform(0.0, 8.0)
    ca = rng.uniform(0, np.pi)
    cx, cy = -hw / 2.6 + rng.uniform(-2, 2), rng.uniform(-3, 3)
    pile = {"a": (cx - crest / 2 * math.cos(ca), cy - crest / 2 * math.sin(ca)),
            "b": (cx + crest / 2 * math.cos(ca), cy + crest / 2 * math.sin(ca)), "height_m": h, "slope": slope}
    batter = {"x0": hw / 3 + rng.uniform(-2, 2), "angle_rad": math.radians(rng.uniform(-25, 25)),
              "depth_m": rng.uniform(1.5, 3.0), "slope": rng.uniform(1.0 / 1.5, 1.0)}
    lat_shape = (int(np.ceil(2 * hh / 0.4)) + 1, int(np.ceil(2 * hw / 0.4)) + 1)
    sc = BareEarthScene(options=o, seed=seed, half_w=hw, half_h=hh, plane=plane, waves=waves, pile=pile,
                        batter=batter, gap_draw=rng.uniform(0, 1, lat_shape))

    # objects: away from the site edge, the pile and the batter (1 m), and from each other (1 m)
    placed: list[tuple[float, float, float]] = []  # x, y, radius

    def spot(radius: float):
        for _ in range(400):
            x = rng.uniform(-hw + radius + 2, hw - radius - 2)
            y = rng.uniform(-hh + radius + 2, hh - radius - 2)
            if sc.crest_distance(x, y) < h / slope + radius + 1.0:
                continue
            d = float(sc.batter_coord(x, y))
            if -radius - 1.0 < d < batter["depth_m"] / batter["slope"] + radius + 1.0:
                continue
            if any(math.hypot(x - px, y - py) < radius + pr + 1.0 for px, py, pr in placed):
                continue
            placed.append((x, y, radius))
            return x, y
        return None

    for kind in o.machines:
        m = make_machine(kind, f"{kind} {len(sc.machines) + 1}", rng)
        at = spot(m.bounding_radius)
        if at is None:
            continue
        m.cx, m.cy = at
        pts = m.outline_points(0.25)
        m.base_z = float(np.max(sc.terrain(pts[:, 0], pts[:, 1])))
        sc.machines.append(m)
    for kind, n in (("tree", o.n_trees), ("bush", o.n_bushes)):
        for _ in range(n):
            if kind == "tree":
                r, rim, depth = rng.uniform(1.5, 4.0), rng.uniform(1.0, 4.0), rng.uniform(1.5, 5.0)
            else:
                r, rim, depth = rng.uniform(0.5, 1.8), 0.0, rng.uniform(0.4, 1.8)
            at = spot(r)
            if at is None:
                continue
            sc.plants.append(Plant(kind, at[0], at[1], r, rim, depth, float(sc.terrain(*at))))
    for _ in range(o.grass_patches):
        sc.grass.append((rng.uniform(-hw, hw), rng.uniform(-hh, hh), rng.uniform(4.0, 8.0)))
    return sc


def _stats(d: np.ndarray) -> dict | None:
    d = d[np.isfinite(d)]
    if d.size == 0:
        return None
    a = np.abs(d)
    return {"cells": int(d.size), "rmse_m": round(float(np.sqrt(np.mean(d * d))), 4),
            "mean_m": round(float(d.mean()), 4), "p95_abs_m": round(float(np.percentile(a, 95)), 4),
            "max_abs_m": round(float(a.max()), 4)}


def _rate(bad: np.ndarray, among: np.ndarray) -> dict:
    n = int(among.sum())
    return {"cells": n, "rate": round(float(bad[among].mean()), 5) if n else None}


def evaluate_ground_filter(scene: BareEarthScene, options=None, classify=None) -> dict:
    """Runs the DTM step's classifier (georef_core.dtm.ground_filter.classify_dsm), its DTM
    (bare_earth.build_dtm) and its point classes on the scene's DSM and cloud, and measures them against the
    truth:

    * ``dtm_error``: DTM - truth terrain per region (RMSE, mean, p95 and max of |error|): ``open`` ground (1 m
      or more from every object, off the pile and the batter), ``pile``, ``batter``, ``under_trees``,
      ``under_bushes``, ``under_machines`` (the object footprints);
    * ``type_i``: ground cells (the DSM within 0.15 m of the truth terrain, grass included) classified
      non-ground, per region and on the pile's crest (within 1 m of the crest line) and the batter's edges
      (within 0.5 m of its top or toe line);
    * ``type_ii``: object cells (the DSM more than 0.3 m above the truth terrain) classified ground, per kind
      (trees, bushes 0.9 m high or more, bushes lower, machines);
    * ``points``: ground points (truth) not classed 2, and object points (more than 0.3 m above the terrain)
      classed 2.

    ``classify``: another classifier with classify_dsm's signature (a benchmark's reference)."""
    from ..dtm.bare_earth import build_dtm
    from ..dtm.ground_filter import GroundFilterOptions, classify_dsm
    from ..dtm.point_classes import CLASS_GROUND, classify_points

    o = options or GroundFilterOptions()
    r = scene.options.resolution_m
    dsm, transform, X, Y, (px, py, pz, ptruth) = scene.dsm()
    gc = (classify or classify_dsm)(dsm, r, o)
    dtm, _mask = build_dtm(dsm, gc.nonground, None, gc.provisional_ground)
    T = scene.terrain(X, Y)
    top, idx = scene.objects_top(X, Y)
    kind = scene.object_kind(idx)
    obj_dist = np.full(X.shape, np.inf)
    for p in scene.plants:
        obj_dist = np.minimum(obj_dist, np.hypot(X - p.cx, Y - p.cy) - p.radius_m)
    for m in scene.machines:
        obj_dist = np.minimum(obj_dist, m.footprint_sdf(X, Y))
    on_pile = scene.pile_height(X, Y) > 0
    d_b = scene.batter_coord(X, Y)
    b_width = scene.batter["depth_m"] / scene.batter["slope"]
    on_batter = (d_b > 0) & (d_b < b_width)
    region = {"open": (obj_dist > 1.0) & ~on_pile & ~on_batter, "pile": on_pile & (obj_dist > 1.0),
              "batter": on_batter & (obj_dist > 1.0), "under_trees": kind == "tree",
              "under_bushes": kind == "bush", "under_machines": kind == "machine"}
    err = dtm - T
    dsm_err = dsm - T
    ground_cell = np.abs(dsm_err) < 0.15
    object_cell = dsm_err > 0.3
    ng = gc.nonground
    crest = (scene.crest_distance(X, Y) < 1.0) & (obj_dist > 1.0)
    edges = ((np.abs(d_b) < 0.5) | (np.abs(d_b - b_width) < 0.5)) & (obj_dist > 1.0)
    bush_h = np.zeros(X.shape)
    for i, p in enumerate(scene.plants):
        bush_h[idx == i] = p.height_m
    out = {
        "seed": scene.seed,
        "objects": {"trees": sum(p.kind == "tree" for p in scene.plants),
                    "bushes": sum(p.kind == "bush" for p in scene.plants), "machines": len(scene.machines)},
        "dsm_error_open": _stats(dsm_err[region["open"]]),
        "dtm_error": {k: _stats(err[v]) for k, v in region.items()},
        "type_i": {**{k: _rate(ng, ground_cell & v) for k, v in region.items() if not k.startswith("under_m")},
                   "all": _rate(ng, ground_cell), "pile_crest": _rate(ng, ground_cell & crest),
                   "batter_edges": _rate(ng, ground_cell & edges)},
        "type_ii": {"all": _rate(~ng, object_cell), "trees": _rate(~ng, object_cell & (kind == "tree")),
                    "bushes_0.9m_up": _rate(~ng, object_cell & (kind == "bush") & (bush_h >= 0.9)),
                    "bushes_under_0.9m": _rate(~ng, object_cell & (kind == "bush") & (bush_h < 0.9)),
                    "machines": _rate(~ng, object_cell & (kind == "machine"))},
    }
    from affine import Affine

    cls, _dz = classify_points(np.column_stack([px, py, pz]), dtm, Affine(*transform[:6]), o.ground_tolerance_m,
                               o.low_noise_m)
    tp = scene.terrain(px, py)
    g = ptruth == 0
    above = pz - tp > 0.3
    out["points"] = {"ground_not_2": _rate(cls != CLASS_GROUND, g),
                     "ground_under_canopy_not_2": _rate(cls != CLASS_GROUND,
                                                        g & (scene.object_kind(scene.objects_top(px, py)[1])
                                                             == "tree")),
                     "objects_as_2": _rate(cls == CLASS_GROUND, (ptruth > 0) & above)}
    return out
