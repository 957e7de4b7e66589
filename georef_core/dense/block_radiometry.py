"""One orthophoto radiometry for a whole tiled block: every image's exposure gains and every camera's vignetting
solved once, from observations gathered where each image's depth map is computed, and used by every tile.

A tiled dense run (steps/dense_tiles.py) used to estimate the radiometry in each tile from the tile's own DSM,
with its own gauge: an image at a tile's rim, seen in a small part of that tile's DSM, got a different gain in
each tile (3.4 % RMS apart on a 102-image block), which no per-tile offset can take out, so the tiles of one
image disagreed along the cuts. Here:

* each depth part, once it has its images' depth maps, samples a lattice of ground points from every map
  (``points_per_image``, back-projected along the map's pinhole rays) and observes them in every image the
  part holds (its images and their stereo partners) that sees them: inside the image and not hidden, by a
  z-buffer of the same maps' points (a coarse depth image of each view; views outside the part's maps' reach
  accept the point). Colours are read as ``ortho_radiometry.observe`` reads them (blurred by 1.5 px);
  :func:`depth_observations` -> ``radiometry_obs.npz``;
* one small part (the dense step's third phase, after every depth part) pools the parts' observations and
  solves the model of ``ortho_radiometry.estimate_radiometry`` once (per-image log gains, their mean 0 over the
  block; per-camera vignetting); :func:`solve_block` -> ``radiometry.json``;
* every tile mosaics with that model (:func:`model_for_views`): an image has one gain in every tile, so tiles
  of one image agree and the merge has nothing left to harmonise.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from .ortho_radiometry import RadiometricObservations, RadiometryModel, estimate_radiometry, observe

OBS_FILE = "radiometry_obs.npz"
MODEL_FILE = "radiometry.json"


def camera_key(view) -> str:
    """The camera of a view as the radiometry groups images (same full size and intrinsics): a text key."""
    s = view.full_width / view.width
    return (f"{view.full_width}x{view.full_height} f{float(view.K[0, 0] * s):.1f} "
            f"c{float(view.K[0, 2] * s):.1f},{float(view.K[1, 2] * s):.1f}")


def _lattice(depth: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(v, u) of about ``n`` finite pixels of a depth map, on a regular lattice."""
    finite = np.isfinite(depth)
    have = int(finite.sum())
    if have == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    step = max(1, int(np.ceil(np.sqrt(have / max(1, n)))))
    v, u = np.nonzero(finite[::step, ::step])
    return v * step, u * step


def _points(grid, depth: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
    return grid.centre_enu_m + depth[v, u].astype(np.float64)[:, None] * grid.rays_enu(u, v)


def depth_observations(views, grids, depth_maps: dict, points_per_image: int = 400, zbuffer_points: int = 30000,
                       rel_tol: float = 0.005, abs_tol_m: float = 0.05) -> RadiometricObservations:
    """Radiometric observations of ground points sampled from the depth maps ``depth_maps`` ({view index: map on
    ``grids[view]``}) in every view of ``views`` that sees them (module docstring). Views are read one at a
    time (colour, their own scale)."""
    pts, zpts = [], []
    for i, d in sorted(depth_maps.items()):
        v, u = _lattice(d, points_per_image)
        if len(v):
            pts.append(_points(grids[i], d, v, u))
        v, u = _lattice(d, zbuffer_points)
        if len(v):
            zpts.append(_points(grids[i], d, v, u))
    if not pts:
        return RadiometricObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                                       np.zeros((0, 3), np.float32))
    P = np.vstack(pts)
    Z = np.vstack(zpts)
    # z-buffer pixel: about 1.5 z-buffer points apart as the maps' own images see them
    spacing = [np.sqrt(grids[i].width * grids[i].height / max(1, zbuffer_points)) * views[i].width / grids[i].width
               for i in depth_maps]
    zb_px = max(2.0, 1.5 * float(np.median(spacing)))
    cache: dict[int, np.ndarray] = {}

    def zbuffer(k: int) -> np.ndarray:
        if k not in cache:
            cache.clear()
            view = views[k]
            zw, zh = int(np.ceil(view.width / zb_px)) + 1, int(np.ceil(view.height / zb_px)) + 1
            zbuf = np.full(zh * zw, np.inf, np.float32)
            uv, z = view.project_distorted(Z)
            good = (z > 0) & view.inside(uv)
            ui = np.floor((uv[good, 0] + 0.5) / zb_px).astype(np.int64)
            vi = np.floor((uv[good, 1] + 0.5) / zb_px).astype(np.int64)
            np.minimum.at(zbuf, vi * zw + ui, z[good].astype(np.float32))
            cache[k] = zbuf.reshape(zh, zw)
        return cache[k]

    def visible(k, uv, z):
        zb = zbuffer(k)
        ui = np.clip(np.floor((uv[:, 0] + 0.5) / zb_px).astype(np.int64), 0, zb.shape[1] - 1)
        vi = np.clip(np.floor((uv[:, 1] + 0.5) / zb_px).astype(np.int64), 0, zb.shape[0] - 1)
        return z <= zb[vi, ui] + rel_tol * z + abs_tol_m   # inf (no map sees there): accepted

    return observe(views, P, visible)


def save_observations(path: Path, obs: RadiometricObservations, views) -> None:
    """The observations with their views by name and camera key (``radiometry_obs.npz``)."""
    np.savez(path, point=obs.point.astype(np.int64), view=obs.view.astype(np.int32),
             rho=obs.rho.astype(np.float32), rgb=obs.rgb.astype(np.float32),
             names=np.array([v.name for v in views]), cameras=np.array([camera_key(v) for v in views]))


def solve_block(obs_files: list[Path], vignetting: bool = True, max_points: int = 60000) -> dict:
    """The block's radiometry from the depth parts' observation files: one estimate_radiometry over all of
    them (points of different files are different points; beyond ``max_points`` points, every k-th point, so
    the solve's cost stays bounded on a large block: ~60 000 points are thousands of pairs per image up to
    several hundred images). Returns the JSON of ``radiometry.json``:
    ``images`` {name: [log gain R, G, B, observations]}, ``camera_of_image`` {name: key}, ``cameras`` {key:
    vignetting coefficients (3 channels x degree)}, ``summary`` (RadiometryModel.summary), ``seconds``."""
    t0 = time.perf_counter()
    index: dict[str, int] = {}
    cam_of: dict[str, str] = {}
    P, V, R, C = [], [], [], []
    offset = 0
    for f in obs_files:
        with np.load(f) as z:
            names, cams = [str(x) for x in z["names"]], [str(x) for x in z["cameras"]]
            for n, c in zip(names, cams):
                index.setdefault(n, len(index))
                cam_of.setdefault(n, c)
            if not len(z["point"]):
                continue
            remap = np.array([index[n] for n in names], np.int64)
            P.append(z["point"] + offset)
            offset += int(z["point"].max()) + 1
            V.append(remap[z["view"]])
            R.append(z["rho"].astype(np.float64))
            C.append(z["rgb"])
    names = sorted(index, key=index.get)
    keys = sorted(set(cam_of.values()))
    camera_of_view = np.array([keys.index(cam_of[n]) for n in names], np.int64)
    if P:
        obs = RadiometricObservations(np.concatenate(P), np.concatenate(V), np.concatenate(R), np.concatenate(C))
        if offset > max_points:
            keep = obs.point % int(np.ceil(offset / max_points)) == 0
            obs = RadiometricObservations(obs.point[keep], obs.view[keep], obs.rho[keep], obs.rgb[keep])
    else:
        obs = RadiometricObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                                      np.zeros((0, 3), np.float32))
    model = estimate_radiometry(obs, len(names), camera_of_view, vignetting=vignetting)
    solved = model.n_points > 0 and np.isfinite(model.residual_nmad)
    return {"solved": bool(solved),
            "images": {n: [*(round(float(x), 6) for x in model.log_gain[k]), int(model.observations[k])]
                       for k, n in enumerate(names)},
            "camera_of_image": cam_of,
            "cameras": {key: model.vignetting_coef[m].tolist() for m, key in enumerate(keys)},
            "observations": int(len(obs.point)),
            "summary": model.summary() if solved else None,
            "seconds": round(time.perf_counter() - t0, 3)}


def read_block_model(path: Path) -> dict | None:
    """``radiometry.json`` when it holds a solved model, else None (the tiles then estimate their own)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return data if data.get("solved") else None


def model_for_views(block: dict, views) -> RadiometryModel:
    """The block's model for these views (by name; an image the block did not observe keeps gain 1)."""
    keys = sorted(block["cameras"])
    degree = len(next(iter(block["cameras"].values()))[0]) if keys else 3
    coef = np.zeros((len(keys) + 1, 3, degree))
    for m, key in enumerate(keys):
        coef[m] = np.asarray(block["cameras"][key], float)
    log_gain = np.zeros((len(views), 3))
    counts = np.zeros(len(views), np.int64)
    cam = np.full(len(views), len(keys), np.int64)        # an unknown camera: no vignetting correction
    for k, v in enumerate(views):
        g = block["images"].get(v.name)
        if g is not None:
            log_gain[k] = g[:3]
            counts[k] = int(g[3]) if len(g) > 3 else 0
        key = block["camera_of_image"].get(v.name)
        key = camera_key(v) if key is None else key
        if key in block["cameras"]:
            cam[k] = keys.index(key)
    s = block.get("summary") or {}
    return RadiometryModel(log_gain, cam, coef, counts, int(s.get("points", 0)),
                           float(s.get("pair_nmad_percent", float("nan"))) / 100.0)
