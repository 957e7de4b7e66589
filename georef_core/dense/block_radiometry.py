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
* one small part (the dense step's third phase, after every depth part) pools the parts' observations, tests
  each (point, view k) against view k's OWN depth map, which exists for every image by then (a depth part's
  z-buffer holds only its own maps: an occluder only another part's images see is in none of them), dropping
  the hidden ones (:func:`hidden_in_own_maps`; maps read one at a time; a view without a map keeps the depth
  part's test), and solves the model of ``ortho_radiometry.estimate_radiometry`` once (per-image log gains,
  their mean 0 over the block; per-camera vignetting); :func:`solve_block` -> ``radiometry.json``;
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
                       rel_tol: float = 0.005, abs_tol_m: float = 0.05, with_points: bool = False):
    """Radiometric observations of ground points sampled from the depth maps ``depth_maps`` ({view index: map on
    ``grids[view]``}) in every view of ``views`` that sees them (module docstring). Views are read one at a
    time (colour, their own scale). ``with_points``: returns (observations, the points' ENU coordinates (N, 3),
    indexed by ``observations.point``) - the radiometry part tests them again against every view's own map."""
    pts, zpts = [], []
    for i, d in sorted(depth_maps.items()):
        v, u = _lattice(d, points_per_image)
        if len(v):
            pts.append(_points(grids[i], d, v, u))
        v, u = _lattice(d, zbuffer_points)
        if len(v):
            zpts.append(_points(grids[i], d, v, u))
    if not pts:
        empty = RadiometricObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                                        np.zeros((0, 3), np.float32))
        return (empty, np.zeros((0, 3))) if with_points else empty
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

    obs = observe(views, P, visible)
    return (obs, P) if with_points else obs


def save_observations(path: Path, obs: RadiometricObservations, views, points_enu_m: np.ndarray | None = None) -> None:
    """The observations with their views by name and camera key (``radiometry_obs.npz``); ``points_enu_m``: the
    observed points' ENU coordinates (indexed by ``obs.point``), for the block's occlusion test."""
    extra = {} if points_enu_m is None else {"point_enu_m": np.asarray(points_enu_m, np.float64).reshape(-1, 3)}
    np.savez(path, point=obs.point.astype(np.int64), view=obs.view.astype(np.int32),
             rho=obs.rho.astype(np.float32), rgb=obs.rgb.astype(np.float32),
             names=np.array([v.name for v in views]), cameras=np.array([camera_key(v) for v in views]), **extra)


def hidden_in_own_maps(xyz_enu_m: np.ndarray, view: np.ndarray, names: list, depth_map_of, rel_tol: float = 0.005,
                       abs_tol_m: float = 0.05) -> tuple[np.ndarray, dict]:
    """Which observations (point ``xyz_enu_m[i]`` seen in view ``view[i]``, named ``names[view[i]]``) are hidden
    by the surface that view's OWN depth map holds at the point's pixel: the point's camera depth z (m) is more than
    ``d + rel_tol * z + abs_tol_m`` (d: the map's depth at the nearest map pixel; 0.5 % + 5 cm, the depth parts'
    z-buffer rule). ``depth_map_of(name)`` -> (pinhole grid view, depth map (H, W), camera-z metres, NaN: none)
    or None (no map: the observation is kept, as the depth part's z-buffer left it). A point outside the map,
    behind the camera or on a NaN pixel is kept. Maps are read one at a time (memory: one map). Returns
    (hidden mask, figures: observations tested against a map, hidden, views with / without a map, seconds)."""
    t0 = time.perf_counter()
    view = np.asarray(view, np.int64)
    hidden = np.zeros(len(view), bool)
    finite = np.all(np.isfinite(xyz_enu_m), axis=1)
    tested = with_map = without_map = 0
    order = np.argsort(view, kind="stable")
    sorted_view = view[order]
    starts = np.flatnonzero(np.r_[True, sorted_view[1:] != sorted_view[:-1]]) if len(order) else np.zeros(0, int)
    ends = np.r_[starts[1:], len(order)]
    for a, b in zip(starts, ends):
        got = depth_map_of(str(names[sorted_view[a]]))
        if got is None:
            without_map += 1
            continue
        grid, depth = got
        with_map += 1
        idx = order[a:b]
        idx = idx[finite[idx]]
        if not len(idx):
            continue
        uv, z = grid.project_pinhole(xyz_enu_m[idx])
        u = np.rint(uv[:, 0])
        v = np.rint(uv[:, 1])
        on = ((z > 0) & np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u < depth.shape[1])
              & (v < depth.shape[0]))
        d = np.full(len(idx), np.nan)
        d[on] = depth[v[on].astype(np.int64), u[on].astype(np.int64)]
        ok = np.isfinite(d)
        tested += int(ok.sum())
        hid = np.zeros(len(idx), bool)
        hid[ok] = z[ok] > d[ok] + rel_tol * z[ok] + abs_tol_m
        hidden[idx[hid]] = True
        del depth
    return hidden, {"tested": tested, "hidden": int(hidden.sum()), "views_with_map": with_map,
                    "views_without_map": without_map, "rel_tol": rel_tol, "abs_tol_m": abs_tol_m,
                    "seconds": round(time.perf_counter() - t0, 3)}


def solve_block(obs_files: list[Path], vignetting: bool = True, max_points: int = 60000, depth_map_of=None,
                rel_tol: float = 0.005, abs_tol_m: float = 0.05) -> dict:
    """The block's radiometry from the depth parts' observation files: one estimate_radiometry over all of
    them (points of different files are different points; beyond ``max_points`` points, every k-th point, so
    the solve's cost stays bounded on a large block: ~60 000 points are thousands of pairs per image up to
    several hundred images). Returns the JSON of ``radiometry.json``:
    ``images`` {name: [log gain R, G, B, observations]}, ``camera_of_image`` {name: key}, ``cameras`` {key:
    vignetting coefficients (3 channels x degree)}, ``summary`` (RadiometryModel.summary), ``seconds``.
    ``depth_map_of`` (name -> (grid, depth map) or None; the radiometry part's, once every depth map exists):
    each observation is tested against its view's own depth map (:func:`hidden_in_own_maps`) and the hidden
    ones are dropped before the solve (``occlusion`` in the JSON: the figures); files without the points'
    coordinates, and views without a map, keep the depth parts' test."""
    t0 = time.perf_counter()
    index: dict[str, int] = {}
    cam_of: dict[str, str] = {}
    P, V, R, C, X = [], [], [], [], []
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
            n_pts = int(z["point"].max()) + 1
            offset += n_pts
            V.append(remap[z["view"]])
            R.append(z["rho"].astype(np.float64))
            C.append(z["rgb"])
            if depth_map_of is not None:   # the points' ENU coordinates (NaN: a file without them, untested)
                xyz = z["point_enu_m"] if "point_enu_m" in z.files else None
                X.append(xyz[:n_pts] if xyz is not None and len(xyz) >= n_pts else np.full((n_pts, 3), np.nan))
    names = sorted(index, key=index.get)
    occlusion = None
    keys = sorted(set(cam_of.values()))
    camera_of_view = np.array([keys.index(cam_of[n]) for n in names], np.int64)
    if P:
        obs = RadiometricObservations(np.concatenate(P), np.concatenate(V), np.concatenate(R), np.concatenate(C))
        keep = np.ones(len(obs.point), bool)
        if offset > max_points:
            keep = obs.point % int(np.ceil(offset / max_points)) == 0
        if depth_map_of is not None:   # the block's occlusion test: each view's own depth map
            xyz = np.concatenate(X)[obs.point[keep]]   # points (not observations) pooled: ~400 per image
            hid, occlusion = hidden_in_own_maps(xyz, obs.view[keep], names, depth_map_of, rel_tol, abs_tol_m)
            del xyz
            keep[np.flatnonzero(keep)[hid]] = False
        if not keep.all():
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
            **({"occlusion": occlusion} if occlusion is not None else {}),
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
