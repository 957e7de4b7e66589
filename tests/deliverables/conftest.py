"""Seeded synthetic scenes for the deliverables tests: an analytic surface (a tilted plane plus a Gaussian
hill, EPSG:32632, 0.25 m cells) with DSM-like noise and a no-data hole, written as a GeoTIFF; and a small
run folder around it (orthophoto, volumes, residuals, surveyed points)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

EPSG = 32632
X0, Y0 = 500_000.0, 5_000_060.0       # top-left corner
CELL_M = 0.25
N = 240                                # 60 m x 60 m
HILL = {"x": X0 + 30.0, "y": Y0 - 30.0, "h": 6.0, "s": 8.0}
HOLE = (X0 + 40.0, Y0 - 20.0, X0 + 48.0, Y0 - 12.0)   # xmin, ymin, xmax, ymax of the no-data square


def truth_height(x, y):
    """The analytic surface (metres): 100 m + a 2 % slope to the east + a 6 m Gaussian hill (sigma 8 m)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    r2 = (x - HILL["x"]) ** 2 + (y - HILL["y"]) ** 2
    return 100.0 + 0.02 * (x - X0) + HILL["h"] * np.exp(-r2 / (2 * HILL["s"] ** 2))


def truth_gradient(x, y):
    x, y = np.asarray(x, float), np.asarray(y, float)
    g = HILL["h"] * np.exp(-((x - HILL["x"]) ** 2 + (y - HILL["y"]) ** 2) / (2 * HILL["s"] ** 2)) / HILL["s"] ** 2
    return 0.02 - g * (x - HILL["x"]), -g * (y - HILL["y"])


def in_hole(x, y, margin=0.0):
    x0, y0, x1, y1 = HOLE
    return (x > x0 + margin) & (x < x1 - margin) & (y > y0 + margin) & (y < y1 - margin)


def write_surface(path, noise_m=0.02, hole=True, seed=7, crs=f"EPSG:{EPSG}", nodata=-9999.0, all_nodata=False):
    import rasterio
    from rasterio.transform import from_origin

    xc = X0 + (np.arange(N) + 0.5) * CELL_M
    yc = Y0 - (np.arange(N) + 0.5) * CELL_M
    xx, yy = np.meshgrid(xc, yc)
    z = truth_height(xx, yy) + np.random.default_rng(seed).normal(0.0, noise_m, xx.shape)
    if hole:
        z[in_hole(xx, yy)] = nodata
    if all_nodata:
        z[:] = nodata
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=N, height=N, count=1, dtype="float32", crs=crs,
                       transform=from_origin(X0, Y0, CELL_M, CELL_M), nodata=nodata) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def write_ortho(path):
    import rasterio
    from rasterio.transform import from_origin

    n = 300                                  # 0.2 m pixels over the same 60 m
    rgb = np.zeros((3, n, n), np.uint8)
    rgb[0] = np.linspace(0, 255, n)[None, :]
    rgb[1] = np.linspace(0, 255, n)[:, None]
    rgb[2] = 128
    rgb[:, :20, :] = 0                       # a no-data strip along the north edge
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8", crs=f"EPSG:{EPSG}",
                       transform=from_origin(X0, Y0, 0.2, 0.2), nodata=0) as ds:
        ds.write(rgb)
    return path


PILES = {"north pile": [(X0 + 5, Y0 - 15), (X0 + 15, Y0 - 15), (X0 + 15, Y0 - 5), (X0 + 5, Y0 - 5)],
         "south pile": [(X0 + 5, Y0 - 55), (X0 + 20, Y0 - 55), (X0 + 20, Y0 - 45), (X0 + 5, Y0 - 45)]}
POINTS = [("CP1", "control", X0 + 10.0, Y0 - 30.0), ("CK1", "check", X0 + 30.0, Y0 - 30.0),
          ("CK2", "check", X0 + 50.0, Y0 - 50.0)]


@pytest.fixture()
def run_folder(tmp_path):
    """A run folder (dense/, volumes/, residuals.json) and its survey folder (gcp/points.csv)."""
    return make_run_folder(tmp_path)


def make_run_folder(tmp_path):
    """The run_folder fixture's folders under ``tmp_path`` (also for module-scoped fixtures)."""
    run, survey = tmp_path / "run", tmp_path / "survey"
    write_surface(run / "dense" / "dsm.tif")
    write_ortho(run / "dense" / "ortho.tif")
    (run / "volumes").mkdir(parents=True)
    fc = {"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": f"EPSG:{EPSG}"}},
          "features": [{"type": "Feature", "properties": {"name": n, "id": n},
                        "geometry": {"type": "Polygon", "coordinates": [ring + [ring[0]]]}}
                       for n, ring in ((k, [list(p) for p in v]) for k, v in PILES.items())]}
    (run / "volumes" / "stockpiles_lowest.geojson").write_text(json.dumps(fc))
    recs = [{"stockpile_id": n, "stockpile_name": n, "base": "lowest", "volume_m3": 10.0 + k, "fill_m3": 0.5,
             "cut_m3": 10.5 + k, "area_m2": 100.0 + 50 * k, "details": {"sigma_m3": 0.2, "ci95_m3": 0.39}}
            for k, n in enumerate(PILES)]
    (run / "volumes" / "volumes.json").write_text(json.dumps({"crs": f"EPSG:{EPSG}", "units": "m3",
                                                               "stockpiles": recs}))
    (run / "residuals.json").write_text(json.dumps({"kind": "check points", "crs": f"EPSG:{EPSG}", "points": [
        {"name": "CK1", "role": "check", "dx_m": 0.01, "dy_m": -0.02, "dz_m": 0.03, "d3_m": 0.0374, "n_images": 5},
        {"name": "CK2", "role": "check", "dx_m": -0.01, "dy_m": 0.0, "dz_m": -0.02, "d3_m": 0.0224, "n_images": 4}]}))
    (survey / "gcp").mkdir(parents=True)
    lines = ["name,easting,northing,height,role"]
    lines += [f"{n},{x:.3f},{y:.3f},{float(truth_height(x, y)):.3f},{r}" for n, r, x, y in POINTS]
    (survey / "gcp" / "points.csv").write_text("\n".join(lines) + "\n")
    return run, survey
