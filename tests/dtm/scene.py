"""A small simulated site with machines, turned into a run folder's dense/ outputs without images: the DSM is
the truth surface at cell centres plus seeded noise, the point cloud is sampled from the truth surface plus
noise (georef_core.sim.site: ``surface`` has the machines, ``bare_earth`` not)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from georef_core.sim.site import Site, SiteOptions, build_site

SITE = SiteOptions(size_m=(70.0, 46.0), stockpiles=("cone", "frustum", "hip"), stockpile_scale=0.75, pit=False,
                   hillside=False, n_roads=1, road_width_m=5.0, n_targets=5, n_control=3, target_margin_m=4.0,
                   pad_margin_m=1.5, pad_blend_m=3.0, machines=4)
NOISE_M = 0.03  # DSM / point noise (1 sigma), a dense DSM's figure on textured ground


@dataclass
class Scene:
    site: Site
    run: Path
    transform: Affine
    dsm: np.ndarray  # noisy DSM, north-up rows
    truth_surface: np.ndarray
    truth_bare: np.ndarray
    machine: np.ndarray  # bool: cells inside a machine footprint
    pile: np.ndarray  # pile index per cell (-1: none)
    x: np.ndarray  # site coordinates of the cell centres
    y: np.ndarray
    epsg: int


def make_scene(run: Path, seed: int = 3, resolution_m: float = 0.1, noise_m: float = NOISE_M,
               points_per_m2: float = 10.0, options: SiteOptions = SITE) -> Scene:
    from georef_core.dense.cog_writer import write_cog
    from georef_core.dense.point_cloud_io import write_point_cloud

    site = build_site(options, seed)
    f = site.frame
    r = resolution_m
    margin = 2.0
    w = int(round((2 * site.half_w + 2 * margin) / r))
    h = int(round((2 * site.half_h + 2 * margin) / r))
    west = f.origin_e - site.half_w - margin
    north = f.origin_n + site.half_h + margin
    transform = Affine(r, 0.0, west, 0.0, -r, north)
    xs = west - f.origin_e + (np.arange(w) + 0.5) * r
    ys = north - f.origin_n - (np.arange(h) + 0.5) * r
    X, Y = np.meshgrid(xs, ys)
    bare = site.bare_earth(X, Y)
    surf = bare.copy()  # = site.surface(X, Y), without evaluating the terrain twice
    for m in site.machines:
        surf = np.maximum(surf, m.top(X, Y))
    rng = np.random.default_rng(np.random.SeedSequence([seed, 4242]))
    dsm = (surf + rng.normal(0.0, noise_m, surf.shape)).astype(np.float32)
    dense = Path(run) / "dense"
    dense.mkdir(parents=True, exist_ok=True)
    write_cog(dense / "dsm.tif", dsm, transform, f.epsg, nodata=-9999.0)
    write_cog(dense / "dsm_filled_mask.tif", np.zeros(dsm.shape, np.uint8), transform, f.epsg, nodata=255,
              overview_resampling="NEAREST")
    n = int(points_per_m2 * (w * r) * (h * r))
    px = rng.uniform(xs[0] - r / 2, xs[-1] + r / 2, n)
    py = rng.uniform(ys[-1] - r / 2, ys[0] + r / 2, n)
    pz = site.surface(px, py) + rng.normal(0.0, noise_m, n)
    xyz = np.column_stack([px + f.origin_e, py + f.origin_n, pz])
    write_point_cloud(dense / "points.laz", xyz, np.full((n, 3), 128, np.uint8), f.epsg)
    (dense / "dense_summary.json").write_text(json.dumps({"dsm_vertical_rmse_m": noise_m,
                                                          "dsm_error_correlation_length_m": 0.0}))
    return Scene(site=site, run=Path(run), transform=transform, dsm=dsm.astype(np.float64), truth_surface=surf,
                 truth_bare=bare, machine=site.machine_index(X, Y) >= 0, pile=site.pile_index(X, Y), x=X, y=Y,
                 epsg=f.epsg)
