"""Procedural ground texture of the site, with the sun's Lambertian shading and cast shadows baked in.

The texture is a raster in *site coordinates* (project-CRS grid offsets), texel size ``texel_m``
(default: the nominal ground sampling distance). It is composed in two stages:

* a "material" raster 4x coarser carries the colours: soil / gravel ground mottled by multi-octave
  noise, sand patches, vegetation outside the work area, scattered stones, the clay pit, compacted
  roads with wheel tracks, ditches, random vehicle tracks, stockpile materials, and the irradiance
  ``ambient + direct * max(0, n.s) * shadow`` from the surface normals and a shadow map;
* at full resolution it is upsampled and modulated by band-limited grain noise whose strength depends
  on the material, then the square 2x2 checker targets are painted (anti-aliased) on top.

All noise is synthesised by a Laplacian-pyramid of white noise (no tiles, no repetition) from a
:class:`numpy.random.Generator` seeded by the site seed, so the texture is deterministic.
Colours are display values in [0, 1] (no gamma handling). Because Lambertian shading does not depend
on the viewer and the sun does not move during a survey, baking it in is exact for this model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

COLOURS = {
    "soil": (0.47, 0.385, 0.30),
    "ground_gravel": (0.54, 0.52, 0.485),
    "sand_patch": (0.70, 0.62, 0.47),
    "grass": (0.31, 0.38, 0.19),
    "dry_grass": (0.55, 0.52, 0.34),
    "road": (0.63, 0.60, 0.55),
    "clay": (0.56, 0.43, 0.33),
    "pit_floor": (0.42, 0.34, 0.28),
    "gravel": (0.58, 0.57, 0.54),
    "sand": (0.76, 0.66, 0.47),
    "crushed_stone": (0.66, 0.655, 0.64),
    "topsoil": (0.29, 0.23, 0.18),
    "target_white": (0.90, 0.90, 0.89),
    "target_black": (0.05, 0.05, 0.05),
}
GRAIN = {  # strength of the fine grain modulation per material
    "soil": 0.16, "ground_gravel": 0.26, "grass": 0.30, "road": 0.12, "clay": 0.12,
    "gravel": 0.30, "sand": 0.09, "crushed_stone": 0.34, "topsoil": 0.20,
}


@dataclass
class TextureOptions:
    texel_m: float | None = None  # None: the nominal GSD (flight height / focal in pixels), at least 0.012 m
    coarse_factor: int = 4  # material raster is this many texels per cell (power of 2)
    sun_azimuth_deg: float = 150.0  # true azimuth of the sun
    sun_elevation_deg: float = 50.0
    ambient: float = 0.38  # share of diffuse sky light on a flat, unshadowed surface
    n_vehicle_tracks: int = 14
    stone_density_per_m2: float = 0.6
    # weakly textured patches, none by default (seeded scenes keep their images): ((x, y, radius_m, kind), ...)
    # in site coordinates; kind "soil": a graded soil pad whose only texture is a soft mottling 1-3 m across
    # (no grain, stones or tracks: nothing at the scale of a matching window), "water": uniform (a pond's
    # surface: nothing to match at any scale). Only the texture changes, not the ground's shape.
    weak_patches: tuple = ()


WEAK_PATCH_COLOURS = {"soil": (0.50, 0.41, 0.32), "water": (0.20, 0.24, 0.25)}


# ---- noise helpers -------------------------------------------------------------------------------
def _up2_axis(a: np.ndarray, axis: int) -> np.ndarray:
    """Bilinear x2 upsampling along one axis, half-pixel aligned, edges clamped."""
    a = np.moveaxis(a, axis, 0)
    prev = np.concatenate([a[:1], a[:-1]], axis=0)
    nxt = np.concatenate([a[1:], a[-1:]], axis=0)
    out = np.empty((2 * a.shape[0],) + a.shape[1:], dtype=a.dtype)
    out[0::2] = 0.75 * a + 0.25 * prev
    out[1::2] = 0.75 * a + 0.25 * nxt
    return np.moveaxis(out, 0, axis)


def upsample2(a: np.ndarray) -> np.ndarray:
    return _up2_axis(_up2_axis(a, 0), 1)


def fractal_noise(shape: tuple[int, int], rng: np.random.Generator, levels: int, gain: float = 0.7,
                  finest_amp: float = 1.0, dtype=np.float32) -> np.ndarray:
    """Zero-mean, unit-std noise with octaves from 1 cell up to 2**levels cells (pyramid synthesis).

    ``gain`` is the amplitude ratio of an octave to the next coarser one (< 1: smoother)."""
    sizes = [tuple(shape)]
    for _ in range(levels):
        h, w = sizes[-1]
        sizes.append((h // 2 + 2, w // 2 + 2))
    sizes = sizes[::-1]
    a = rng.standard_normal(sizes[0], dtype=np.float32).astype(dtype)
    amp = finest_amp / gain**levels
    a *= amp
    for l in range(1, len(sizes)):
        amp *= gain
        a = upsample2(a)[: sizes[l][0], : sizes[l][1]]
        a += amp * rng.standard_normal(sizes[l], dtype=np.float32).astype(dtype)
    a -= a.mean()
    a /= a.std() + 1e-12
    return a


def _smooth(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _mix(base: np.ndarray, colour, w: np.ndarray) -> np.ndarray:
    c = np.asarray(colour, dtype=np.float32)
    return base + (c - base) * w[..., None]


# ---- texture -----------------------------------------------------------------------------------------
def _pack_rgba(rgb_u8: np.ndarray) -> np.ndarray:
    h, w = rgb_u8.shape[:2]
    out = np.zeros((h, w, 4), dtype=np.uint8)
    out[..., :3] = rgb_u8
    return out.view(np.uint32).reshape(h, w)


def _halve_packed(a: np.ndarray) -> np.ndarray:
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    out = np.empty((h // 2, w // 2), dtype=np.uint32)
    rows = 1024
    for r0 in range(0, h, rows):
        blk = a[r0:min(r0 + rows, h), :w].view(np.uint8).reshape(-1, w, 4).astype(np.uint16)
        blk = (blk[0::2, 0::2] + blk[1::2, 0::2] + blk[0::2, 1::2] + blk[1::2, 1::2] + 2) // 4
        out[r0 // 2:r0 // 2 + blk.shape[0]] = np.ascontiguousarray(blk.astype(np.uint8)).view(np.uint32).reshape(blk.shape[:2])
    return out


class SiteTexture:
    """Mip-mapped RGB texture over a box of site coordinates, texels packed as little-endian RGBA
    ``uint32`` (one gather per texel). Level 0 texel = ``texel_m``; level ``l`` averages 2**l."""

    single_level_tolerance = 0.2  # level of detail within this of an integer: no blending between levels

    def __init__(self, x0: float, y0: float, texel_m: float, level0_packed: np.ndarray):
        self.x0 = float(x0)
        self.y0 = float(y0)
        self.texel_m = float(texel_m)
        self.levels = [level0_packed]
        while min(self.levels[-1].shape[:2]) > 64 and len(self.levels) < 9:
            self.levels.append(_halve_packed(self.levels[-1]))

    @classmethod
    def from_rgb(cls, x0, y0, texel_m, rgb_u8: np.ndarray) -> "SiteTexture":
        return cls(x0, y0, texel_m, _pack_rgba(np.ascontiguousarray(rgb_u8)))

    @property
    def shape(self):
        return self.levels[0].shape

    def rgb(self, level: int = 0) -> np.ndarray:
        a = self.levels[level]
        return a.view(np.uint8).reshape(a.shape[0], a.shape[1], 4)[..., :3]

    def _bilinear(self, level: int, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        a = self.levels[level]
        h, w = a.shape
        inv = 1.0 / (self.texel_m * (1 << level))
        fx = ((x - (self.x0 + 0.5 / inv)) * inv).astype(np.float32)
        fy = ((y - (self.y0 + 0.5 / inv)) * inv).astype(np.float32)
        ix = np.clip(np.floor(fx), 0, w - 2)
        iy = np.clip(np.floor(fy), 0, h - 2)
        tx = np.clip(fx - ix, 0.0, 1.0)[:, None]
        ty = np.clip(fy - iy, 0.0, 1.0)[:, None]
        i00 = iy.astype(np.int64)
        i00 *= w
        i00 += ix.astype(np.int64)
        flat = a.reshape(-1)
        n = len(x)

        def g(idx):
            return flat[idx].view(np.uint8).reshape(n, 4)[:, :3].astype(np.float32)

        c00 = g(i00)
        i00 += 1
        top = g(i00)
        top -= c00
        top *= tx
        top += c00
        i00 += w
        c11 = g(i00)
        i00 -= 1
        bot = g(i00)
        c11 -= bot
        c11 *= tx
        bot += c11
        bot -= top
        bot *= ty
        top += bot
        return top

    def sample(self, x: np.ndarray, y: np.ndarray, footprint_m: float) -> np.ndarray:
        """Mip-mapped RGB in [0, 255] at site points (N,) for one pixel footprint (m): bilinear in the
        two levels around it, blended linearly (trilinear filtering with a per-image level of detail)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        nlev = len(self.levels)
        lod = min(max(math.log2(max(float(footprint_m), 1e-9) / self.texel_m), 0.0), nlev - 1.0)
        l0 = min(int(math.floor(lod)), nlev - 1)
        f = lod - l0
        if f < self.single_level_tolerance or f > 1.0 - self.single_level_tolerance or l0 + 1 >= nlev:
            return self._bilinear(min(int(round(lod)), nlev - 1), x, y)  # close to a level: bilinear only
        c0 = self._bilinear(l0, x, y)
        c1 = self._bilinear(l0 + 1, x, y)
        c1 -= c0
        c1 *= np.float32(f)
        c0 += c1
        return c0


def sun_vector_enu(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])


def generate_texture(site, bounds: tuple[float, float, float, float], texel_m: float, options: TextureOptions,
                     shadow_fn=None, progress=None) -> tuple[SiteTexture, dict]:
    """Build the texture over ``bounds`` (xmin, ymin, xmax, ymax, site coordinates).

    ``shadow_fn(x, y) -> [0, 1]`` gives the direct-sun visibility at site points (1: lit); None: no
    cast shadows. Returns the texture and a dict of facts (sizes, sun vector)."""
    o = options
    F = int(o.coarse_factor)
    rng = np.random.default_rng(np.random.SeedSequence([site.seed, 303]))
    xmin, ymin, xmax, ymax = bounds
    cs = texel_m * F  # coarse cell
    wc = int(math.ceil((xmax - xmin) / cs))
    hc = int(math.ceil((ymax - ymin) / cs))
    xc = xmin + (np.arange(wc) + 0.5) * cs
    yc = ymin + (np.arange(hc) + 0.5) * cs
    X, Y = np.meshgrid(xc, yc)

    def step(msg):
        if progress:
            progress(msg)

    step("texture: heights and shading")
    Z = site.surface_grid(xmin + 0.5 * cs, ymin + 0.5 * cs, wc, hc, cs)
    gy, gx = np.gradient(Z, cs)
    nrm = np.stack([-gx, -gy, np.ones_like(Z)], -1)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    sun_enu = sun_vector_enu(o.sun_azimuth_deg, o.sun_elevation_deg)
    r_grid = site.frame.R_enu_to_grid_axes(site.frame.origin_e, site.frame.origin_n, site.frame.h_ref)
    sun = r_grid @ sun_enu
    direct = np.clip(nrm @ sun, 0.0, None) / sun[2]
    if shadow_fn is not None:
        direct = direct * shadow_fn(X, Y)
    irr = (o.ambient + (1.0 - o.ambient) * direct).astype(np.float32)
    del gx, gy, nrm

    step("texture: materials")
    levels_c = max(3, int(math.log2(max(wc, hc))) - 2)
    n1 = fractal_noise((hc, wc), rng, levels_c, gain=0.75)
    n2 = fractal_noise((hc, wc), rng, levels_c, gain=0.7)
    n3 = fractal_noise((hc, wc), rng, levels_c, gain=0.8)
    n4 = fractal_noise((hc, wc), rng, 4, gain=0.9)  # fine mottling (~0.5-2 m)
    col = np.empty((hc, wc, 3), dtype=np.float32)
    col[:] = np.asarray(COLOURS["soil"], dtype=np.float32)
    grain = np.full((hc, wc), GRAIN["soil"], dtype=np.float32)
    w = _smooth(0.5 + 0.6 * n1).astype(np.float32)
    col = _mix(col, COLOURS["ground_gravel"], w)
    grain += (GRAIN["ground_gravel"] - GRAIN["soil"]) * w
    col = _mix(col, COLOURS["sand_patch"], (_smooth((n2 - 0.9) / 0.6) * 0.8).astype(np.float32))
    # vegetation outside the work area (with an irregular edge)
    out_d = np.maximum(np.abs(X) - site.half_w, np.abs(Y) - site.half_h) + 6.0 * n3
    veg = _smooth((out_d - 6.0) / 5.0).astype(np.float32)
    grass = _mix(np.broadcast_to(np.asarray(COLOURS["dry_grass"], np.float32), col.shape).copy(), COLOURS["grass"],
                 _smooth(0.5 + 0.8 * n2).astype(np.float32))
    col = col + (grass - col) * veg[..., None]
    grain += (GRAIN["grass"] - grain) * veg
    # pit: clay walls, darker damp floor
    if site.pit is not None:
        pd = site.pit_sdf(X, Y)
        inside = _smooth(-pd / 0.6).astype(np.float32)
        col = _mix(col, COLOURS["clay"], inside * 0.9)
        floor = _smooth((-pd - site.pit["wall"]) / 2.0).astype(np.float32)
        col = _mix(col, COLOURS["pit_floor"], floor * _smooth(0.6 + 0.5 * n3).astype(np.float32))
        grain += (GRAIN["clay"] - grain) * inside
    # roads: compacted surface, wheel tracks, ditch edges
    for road in site.roads:
        sd = road.signed_distance(X, Y)
        a = np.abs(sd)
        hw = road.width / 2
        on = _smooth((hw + 0.25 * n4 - a) / 0.35).astype(np.float32)
        col = _mix(col, COLOURS["road"], on * 0.9)
        grain += (GRAIN["road"] - grain) * on
        lane = hw / 2
        trk = np.zeros_like(on)
        for off in (-lane - 0.95, -lane + 0.95, lane - 0.95, lane + 0.95):
            trk = np.maximum(trk, np.exp(-(((sd - off) / 0.28) ** 2)))
        col *= (1.0 - 0.22 * trk * on * _smooth(0.7 + 0.4 * n4))[..., None]
        ditch = np.exp(-(((a - hw - 1.3) / 0.7) ** 2)).astype(np.float32)
        col = _mix(col, COLOURS["grass"], ditch * 0.55 * _smooth(0.5 + 0.7 * n2).astype(np.float32))
    # random vehicle tracks (pairs of wheel ruts along circular arcs) on open ground
    for _ in range(o.n_vehicle_tracks):
        rad = rng.uniform(25.0, 160.0)
        ang = rng.uniform(0, 2 * np.pi)
        cx = rng.uniform(-site.half_w, site.half_w) + rad * math.cos(ang)
        cy = rng.uniform(-site.half_h, site.half_h) + rad * math.sin(ang)
        a0 = ang + np.pi + rng.uniform(-0.3, 0.3)
        span = rng.uniform(25.0, 80.0) / rad
        gauge = rng.uniform(1.7, 2.3)
        arc = a0 + np.linspace(-span / 2, span / 2, 64)
        ax_, ay_ = cx + rad * np.cos(arc), cy + rad * np.sin(arc)
        j0 = int(np.clip((ax_.min() - 3 - xmin) / cs, 0, wc))
        j1 = int(np.clip((ax_.max() + 3 - xmin) / cs + 1, 0, wc))
        i0 = int(np.clip((ay_.min() - 3 - ymin) / cs, 0, hc))
        i1 = int(np.clip((ay_.max() + 3 - ymin) / cs + 1, 0, hc))
        if j1 <= j0 or i1 <= i0:
            continue
        Xs, Ys = X[i0:i1, j0:j1], Y[i0:i1, j0:j1]
        r = np.hypot(Xs - cx, Ys - cy)
        th = np.angle(np.exp(1j * (np.arctan2(Ys - cy, Xs - cx) - a0)))
        along = _smooth((span / 2 - np.abs(th)) * rad / 4.0)
        ruts = np.exp(-(((r - rad - gauge / 2) / 0.22) ** 2)) + np.exp(-(((r - rad + gauge / 2) / 0.22) ** 2))
        col[i0:i1, j0:j1] *= (1.0 - (0.18 * ruts * along * _smooth(0.6 + 0.5 * n4[i0:i1, j0:j1]))).astype(np.float32)[..., None]
    # stockpiles (material colour inside the toe, soft 0.3 m edge)
    for p in site.piles:
        r = p.bounding_radius + 1.0
        j0, j1 = int(np.clip((p.cx - r - xmin) / cs, 0, wc)), int(np.clip((p.cx + r - xmin) / cs + 1, 0, wc))
        i0, i1 = int(np.clip((p.cy - r - ymin) / cs, 0, hc)), int(np.clip((p.cy + r - ymin) / cs + 1, 0, hc))
        if j1 <= j0 or i1 <= i0:
            continue
        win = (slice(i0, i1), slice(j0, j1))
        m = _smooth((0.15 - p.footprint_sdf(X[win], Y[win])) / 0.3).astype(np.float32)
        base = np.asarray(COLOURS.get(p.material, COLOURS["gravel"]), np.float32)
        pc = base[None, None, :] * (1.0 + 0.07 * n2[win] + 0.05 * n4[win])[..., None]
        col[win] += (pc - col[win]) * m[..., None]
        grain[win] += (GRAIN.get(p.material, 0.25) - grain[win]) * m
    # machines: painted bodies, mottled so that they can be matched (no rng drawn: sites keep their textures)
    for mc in getattr(site, "machines", ()):
        from .machines import PAINTS

        r = mc.bounding_radius + 0.5
        j0, j1 = int(np.clip((mc.cx - r - xmin) / cs, 0, wc)), int(np.clip((mc.cx + r - xmin) / cs + 1, 0, wc))
        i0, i1 = int(np.clip((mc.cy - r - ymin) / cs, 0, hc)), int(np.clip((mc.cy + r - ymin) / cs + 1, 0, hc))
        if j1 <= j0 or i1 <= i0:
            continue
        win = (slice(i0, i1), slice(j0, j1))
        m = _smooth((0.05 - mc.footprint_sdf(X[win], Y[win])) / 0.1).astype(np.float32)
        paint = np.asarray(PAINTS.get(mc.paint, PAINTS["yellow"]), np.float32)
        pc = paint[None, None, :] * (1.0 + 0.12 * n4[win] + 0.06 * n2[win])[..., None]
        col[win] += (pc - col[win]) * m[..., None]
        grain[win] += (0.15 - grain[win]) * m
    # scattered stones (dark and light), 4-25 cm, on the ground and the piles
    area = (xmax - xmin) * (ymax - ymin)
    ns = int(o.stone_density_per_m2 * area)
    sx = rng.uniform(0, wc, ns)
    sy = rng.uniform(0, hc, ns)
    sv = rng.choice([-1.0, 1.0], ns, p=[0.55, 0.45]) * rng.uniform(0.15, 0.45, ns)
    acc = np.zeros((hc, wc), dtype=np.float32)
    np.add.at(acc, (sy.astype(np.int64), sx.astype(np.int64)), sv.astype(np.float32))
    from scipy.ndimage import gaussian_filter

    acc = gaussian_filter(acc, 0.6) * 2.5
    col *= (1.0 + np.clip(acc, -0.6, 0.6) * (1.0 - veg))[..., None]
    # broad brightness variation and a little hue variation
    col *= (1.0 + 0.06 * n3 + 0.05 * n1)[..., None]
    col[..., 2] *= 1.0 + 0.03 * n2
    for px, py, pr, kind in o.weak_patches:
        if kind not in WEAK_PATCH_COLOURS:
            raise ValueError(f"weak texture patch kind {kind!r}: use one of {', '.join(WEAK_PATCH_COLOURS)}")
        m = _smooth((pr - np.hypot(X - px, Y - py)) / 0.3).astype(np.float32)
        flat = np.broadcast_to(np.asarray(WEAK_PATCH_COLOURS[kind], np.float32), col.shape).copy()
        if kind == "soil":
            soft = gaussian_filter(n4, 1.0 / cs)
            flat *= (1.0 + 0.10 * soft / (soft.std() + 1e-6))[..., None]
        col += (flat - col) * m[..., None]
        grain *= 1.0 - m
    col *= irr[..., None]
    del X, Y, Z, n1, n2, n3, n4, irr

    step("texture: full-resolution grain and targets")
    hf, wf = hc * F, wc * F
    # full-res fine grain: white noise at 1 texel plus bilinearly upsampled white noise at 2 texels
    half = rng.standard_normal((hc * F // 2, wc * F // 2), dtype=np.float32)
    tile_seed = int(rng.integers(0, 2**62))
    level0 = np.empty((hf, wf), dtype=np.uint32)
    white = np.asarray(COLOURS["target_white"], np.float32)
    black = np.asarray(COLOURS["target_black"], np.float32)
    tgt_irr = [float(_irr_at(site, t.x, t.y, sun, o, shadow_fn)) for t in site.targets]
    # column interpolation (x F, half-pixel aligned) shared by every tile
    cj = (np.arange(wf, dtype=np.float64) + 0.5) / F - 0.5
    cj0 = np.clip(np.floor(cj).astype(np.int64), 0, wc - 1)
    cj1 = np.minimum(cj0 + 1, wc - 1)
    cwx = np.clip(cj - cj0, 0.0, 1.0).astype(np.float32)[None, :]
    hj = (np.arange(wf, dtype=np.float64) + 0.5) / 2 - 0.5
    hj0 = np.clip(np.floor(hj).astype(np.int64), 0, wf // 2 - 1)
    hj1 = np.minimum(hj0 + 1, wf // 2 - 1)
    hwx = np.clip(hj - hj0, 0.0, 1.0).astype(np.float32)[None, :]
    cg = np.concatenate([col, grain[..., None]], axis=-1)
    rows = 256
    for ti, r0 in enumerate(range(0, hf, rows)):
        r1 = min(r0 + rows, hf)
        ri = (np.arange(r0, r1, dtype=np.float64) + 0.5) / F - 0.5
        ri0 = np.clip(np.floor(ri).astype(np.int64), 0, hc - 1)
        ri1 = np.minimum(ri0 + 1, hc - 1)
        wy = np.clip(ri - ri0, 0.0, 1.0).astype(np.float32)[:, None]
        # rows then columns, colour (3) and grain (1) together
        rr = cg[ri0] + (cg[ri1] - cg[ri0]) * wy[..., None]
        blk = rr[:, cj0] + (rr[:, cj1] - rr[:, cj0]) * cwx[..., None]
        hi = (np.arange(r0, r1, dtype=np.float64) + 0.5) / 2 - 0.5
        hi0 = np.clip(np.floor(hi).astype(np.int64), 0, hf // 2 - 1)
        hi1 = np.minimum(hi0 + 1, hf // 2 - 1)
        hwy = np.clip(hi - hi0, 0.0, 1.0).astype(np.float32)[:, None]
        hr = half[hi0] + (half[hi1] - half[hi0]) * hwy
        fine = hr[:, hj0] + (hr[:, hj1] - hr[:, hj0]) * hwx
        fine *= 0.8
        trng = np.random.default_rng(np.random.SeedSequence([tile_seed, ti]))
        fine += 0.6 * trng.standard_normal(fine.shape, dtype=np.float32)
        fine *= blk[..., 3]
        fine += 1.0
        rgb = blk[..., :3] * fine[..., None]
        y_lo = ymin + r0 * texel_m
        y_hi = ymin + r1 * texel_m
        for t, e in zip(site.targets, tgt_irr):
            _paint_target(rgb, t, e, xmin, y_lo, y_hi, texel_m, white, black)
        rgb *= 255.0
        rgb += 0.5
        np.clip(rgb, 0, 255, out=rgb)
        out = np.zeros(rgb.shape[:2] + (4,), dtype=np.uint8)
        out[..., :3] = rgb
        level0[r0:r1] = out.view(np.uint32).reshape(rgb.shape[:2])
    del half, col, grain

    step("texture: mip levels")
    tex = SiteTexture(xmin, ymin, texel_m, level0)
    facts = {"texel_m": texel_m, "shape": [int(hf), int(wf)], "x0": xmin, "y0": ymin,
             "sun_enu": sun_enu.tolist(), "sun_azimuth_deg": o.sun_azimuth_deg, "sun_elevation_deg": o.sun_elevation_deg}
    return tex, facts


def _paint_target(rgb, t, irradiance, xmin, y_lo, y_hi, texel_m, white, black) -> None:
    """Paint a 2x2 checker target (anti-aliased) into a tile of rows covering [y_lo, y_hi)."""
    half = t.size_m / 2
    r = half * math.sqrt(2) + 2 * texel_m
    if t.y + r < y_lo or t.y - r >= y_hi:
        return
    wf = rgb.shape[1]
    j0 = max(int((t.x - r - xmin) / texel_m), 0)
    j1 = min(int((t.x + r - xmin) / texel_m) + 1, wf)
    i0 = max(int((t.y - r - y_lo) / texel_m), 0)
    i1 = min(int((t.y + r - y_lo) / texel_m) + 1, rgb.shape[0])
    if j1 <= j0 or i1 <= i0:
        return
    xs = xmin + (np.arange(j0, j1) + 0.5) * texel_m - t.x
    ys = y_lo + (np.arange(i0, i1) + 0.5) * texel_m - t.y
    XX, YY = np.meshgrid(xs, ys)
    c, s = math.cos(t.rotation_rad), math.sin(t.rotation_rad)
    u = c * XX + s * YY
    v = -s * XX + c * YY
    su = 2 * np.clip(0.5 + u / texel_m, 0, 1) - 1
    sv = 2 * np.clip(0.5 + v / texel_m, 0, 1) - 1
    chk = (0.5 + 0.5 * su * sv).astype(np.float32)
    inside = (np.clip(0.5 + (half - np.abs(u)) / texel_m, 0, 1)
              * np.clip(0.5 + (half - np.abs(v)) / texel_m, 0, 1)).astype(np.float32)
    tgt = (black + (white - black) * chk[..., None]) * np.float32(irradiance)
    blk = rgb[i0:i1, j0:j1]
    blk += (tgt - blk) * inside[..., None]


def _irr_at(site, x, y, sun, o: TextureOptions, shadow_fn) -> float:
    h = 0.05
    gx = float(site.surface(x + h, y) - site.surface(x - h, y)) / (2 * h)
    gy = float(site.surface(x, y + h) - site.surface(x, y - h)) / (2 * h)
    n = np.array([-gx, -gy, 1.0])
    n /= np.linalg.norm(n)
    d = max(float(n @ sun), 0.0) / sun[2]
    if shadow_fn is not None:
        d *= float(np.asarray(shadow_fn(np.array([x]), np.array([y])))[0])
    return o.ambient + (1.0 - o.ambient) * d
