"""A seeded Monte Carlo of the change between two surveys of the valley scene (tests/design/scenes.py), for judging
the stated sigma of georef_core.design.surface_change: May has the cone (1 m) and the pit (0.8 m deep); by June
the cone was dug out and 0.2 m below the design over 3 m and the pit filled to 0.3 m deep (analytic volumes).
Each seed draws, for each survey, a DSM noise field (sigma, Gaussian correlation exp(-(d/L)^2)) and a vertical bias
b_i = c + u_i with c common to both surveys; June is flown on a grid shifted by a random fraction of a cell. The
difference rasters (surveyed - design) are written directly (the design cancels in the change)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tests.design import scenes
from tests.volumes.synthetic import cone_height, cone_volume

OVERCUT = dict(cx=scenes.BUMP["cx"], cy=scenes.BUMP["cy"], radius=3.0, h=0.2)
LATER_PIT = {**scenes.PIT, "h": 0.3}


def truth() -> dict:
    removed = cone_volume(scenes.BUMP["radius"], scenes.BUMP["h"]) + cone_volume(OVERCUT["radius"], OVERCUT["h"])
    placed = cone_volume(scenes.PIT["radius"], scenes.PIT["h"] - LATER_PIT["h"])
    return {"cut_moved_m3": removed, "fill_placed_m3": placed, "net_change_m3": placed - removed}


def _may(E, N):
    return (cone_height(**scenes.BUMP)(E, N)
            - cone_height(scenes.PIT["cx"], scenes.PIT["cy"], scenes.PIT["radius"], scenes.PIT["h"])(E, N))


def _june(E, N):
    return (-cone_height(**OVERCUT)(E, N)
            - cone_height(LATER_PIT["cx"], LATER_PIT["cy"], LATER_PIT["radius"], LATER_PIT["h"])(E, N))


def correlated_noise(rng, shape, res_m: float, sigma_m: float, correlation_length_m: float) -> np.ndarray:
    """A Gaussian field with correlation exp(-(d/L)^2): white noise through a Gaussian kernel of std L/2,
    scaled to ``sigma_m``."""
    from scipy.ndimage import gaussian_filter

    white = rng.standard_normal(shape)
    if correlation_length_m <= 0:
        return sigma_m * white
    f = gaussian_filter(white, correlation_length_m / 2 / res_m, mode="wrap")
    return sigma_m * f / f.std()


def write_difference(path: Path, fn, offset_m: tuple[float, float], extra: np.ndarray | None) -> Path:
    import rasterio
    from affine import Affine

    res = scenes.RES
    n = int(round(scenes.SIZE_M / res)) - 1   # one cell less: the shifted grid stays inside the scene
    e0, n_top = scenes.E0 + offset_m[0], scenes.N0 + offset_m[1] + n * res
    E, N = np.meshgrid(e0 + (np.arange(n) + 0.5) * res, n_top - (np.arange(n) + 0.5) * res)
    z = fn(E, N) + (extra[:n, :n] if extra is not None else 0.0)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32",
                       crs=f"EPSG:{scenes.EPSG}", transform=Affine(res, 0, e0, 0, -res, n_top)) as ds:
        ds.write(z.astype(np.float32), 1)
    return Path(path)


def area_geometry() -> dict:
    ring = [[float(x), float(y)] for x, y in scenes.AREA]
    return {"type": "Polygon", "coordinates": [ring + [ring[0]]]}


def one_seed(seed: int, folder: Path, noise_m: float = 0.02, correlation_length_m: float = 1.0,
             common_bias_m: float = 0.015, own_bias_m: float = 0.01) -> dict:
    """Both difference rasters of one seed, their stated accuracy and the bias they were drawn with."""
    from georef_core.design.surface_change import SurveyAccuracy

    rng = np.random.default_rng(seed)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = int(round(scenes.SIZE_M / scenes.RES))
    c = rng.normal(0.0, common_bias_m)
    shift = tuple(float(v) for v in rng.uniform(0.0, scenes.RES, 2))
    files = {}
    for name, fn, off in (("may", _may, (0.0, 0.0)), ("june", _june, shift)):
        field = correlated_noise(rng, (n, n), scenes.RES, noise_m, correlation_length_m) + c + rng.normal(0, own_bias_m)
        files[name] = write_difference(folder / f"{name}.tif", fn, off, field)
    acc = SurveyAccuracy(noise_m, math.hypot(common_bias_m, own_bias_m), correlation_length_m)
    return {"may": files["may"], "june": files["june"], "accuracy": acc, "shift_m": shift}
