"""The block radiometry's occlusion test in each view's own depth map (dense/block_radiometry.py, the radiometry
part of steps/dense_tiles.py): a synthetic two-part block over flat ground with a wall that only the second
part's images see. The first part's observations of ground points behind the wall, in a partner image of the
second part, read the wall's colour; the first part's maps do not hold the wall, so its z-buffer accepts them.
Tested against the partner's own depth map (all maps exist once every depth part has run) they are dropped,
and that image's gain comes back to the truth; with no occluder nothing is dropped and the result is the same."""

from __future__ import annotations

import numpy as np

from georef_core.dense.block_radiometry import save_observations, solve_block
from georef_core.dense.camera_views import CameraView
from georef_core.dense.ortho_radiometry import RadiometricObservations

H_M = 50.0                                   # flying height above the ground (ground: up = 0 m, ENU)
WALL = (20.0, -60.0, 0.0, 22.0, 60.0, 15.0)  # min E, N, U, max E, N, U (m): a 15 m wall, 2 m thick
NOISE = 0.03                                 # per observation (log): texture, blur, registration
TRUE_LOG_GAIN = {"a0": 0.02, "a1": -0.03, "a2": 0.01, "a3": 0.04, "b0": -0.05, "b1": 0.03, "b2": 0.0, "b3": -0.02}


def _view(name: str, east_m: float) -> CameraView:
    K = np.array([[600.0, 0, 399.5], [0, 600.0, 299.5], [0, 0, 1]])
    R = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])   # looking straight down, image x east
    return CameraView(name, None, 800, 600, K, np.zeros(5), R, np.array([east_m, 0.0, H_M]), 800, 600)


def _depth_map(view: CameraView, wall) -> np.ndarray:
    """Camera-z depth (m) of the first surface along each pixel's ray: the ground, or the wall's box."""
    v, u = np.mgrid[0:view.height, 0:view.width]
    r = view.rays_enu(u.ravel(), v.ravel())
    C = view.centre_enu_m
    t = -C[2] / r[:, 2]                                          # the ground plane (up = 0)
    if wall is not None:
        lo, hi = np.array(wall[:3]), np.array(wall[3:])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - C) / r, (hi - C) / r
        t_in = np.nanmax(np.minimum(t1, t2), axis=1)
        t_out = np.nanmin(np.maximum(t1, t2), axis=1)
        hit = (t_in <= t_out) & (t_in > 0)
        t = np.where(hit & (t_in < t), t_in, t)
    return t.reshape(view.height, view.width).astype(np.float32)


def _hidden_by(view: CameraView, xyz: np.ndarray, wall) -> np.ndarray:
    if wall is None:
        return np.zeros(len(xyz), bool)
    uv, z = view.project_pinhole(xyz)
    d = _depth_map(view, wall)
    u = np.clip(np.rint(uv[:, 0]).astype(int), 0, view.width - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(int), 0, view.height - 1)
    return z > d[v, u] + 0.01


def _part_file(path, views, xyz, albedo, wall, accept_hidden_in, rng):
    """A depth part's observation file: every point in every view that has it inside; a view whose occlusion
    the part cannot test (``accept_hidden_in``) records what its pixel shows (the wall) where hidden."""
    P, V, R, C = [], [], [], []
    for k, view in enumerate(views):
        uv, z = view.project_pinhole(xyz)
        inside = (z > 0) & view.inside(uv, margin=2.0)
        hidden = _hidden_by(view, xyz, wall)
        if view.name not in accept_hidden_in:
            inside &= ~hidden                              # the part's own z-buffer removes these
        idx = np.flatnonzero(inside)
        # the wall: the ground's material in shade (15 % darker; a very different colour the robust weights
        # would take out on their own, a similar one biases the gain)
        colour = np.where(hidden[idx, None], 0.85 * albedo[idx], albedo[idx])
        g = np.exp(TRUE_LOG_GAIN[view.name])
        P.append(idx)
        V.append(np.full(len(idx), k))
        R.append(np.full(len(idx), 0.3))
        C.append((colour * g * np.exp(rng.normal(0.0, NOISE, (len(idx), 1)))).astype(np.float32))
    obs = RadiometricObservations(np.concatenate(P), np.concatenate(V), np.concatenate(R), np.concatenate(C))
    save_observations(path, obs, views, points_enu_m=xyz)


def _block(tmp_path, wall, seed=0):
    rng = np.random.default_rng(seed)
    a = [_view(f"a{i}", e) for i, e in enumerate((-60.0, -45.0, -30.0, -15.0))]
    b = [_view(f"b{i}", e) for i, e in enumerate((35.0, 50.0, 65.0, 80.0))]
    # part A: ground points of its maps (east up to 18 m, where its images end; the wall at 20-22 m is in none
    # of them), observed in its images and its partner b0, which sees those east of ~14 m behind the wall
    ea, na = np.meshgrid(np.arange(-90.0, 18.01, 1.0), np.arange(-20.0, 20.01, 1.0))
    xa = np.c_[ea.ravel(), na.ravel(), np.zeros(ea.size)]
    _part_file(tmp_path / "a.npz", a + [b[0]], xa, rng.uniform(60, 160, (len(xa), 3)), wall, {"b0"}, rng)
    # part B: ground points east of the wall, in its images and its partner a3 (which sees them, unhidden)
    eb, nb = np.meshgrid(np.arange(23.0, 110.01, 1.0), np.arange(-20.0, 20.01, 1.0))
    xb = np.c_[eb.ravel(), nb.ravel(), np.zeros(eb.size)]
    _part_file(tmp_path / "b.npz", b + [a[3]], xb, rng.uniform(60, 160, (len(xb), 3)), wall, set(), rng)
    maps = {v.name: (v.scaled(0.5), _depth_map(v.scaled(0.5), wall)) for v in a + b}
    return [tmp_path / "a.npz", tmp_path / "b.npz"], maps


def _gain_error_percent(result) -> dict:
    names = sorted(TRUE_LOG_GAIN)
    est = np.array([np.mean(result["images"][n][:3]) for n in names])
    true = np.array([TRUE_LOG_GAIN[n] for n in names])
    err = 100 * ((est - est.mean()) - (true - true.mean()))
    return dict(zip(names, err))


def test_partner_behind_another_parts_occluder_is_dropped(tmp_path):
    files, maps = _block(tmp_path, WALL)
    before = solve_block(files, vignetting=False)                                  # the depth parts' test only
    after = solve_block(files, vignetting=False, depth_map_of=lambda n: maps.get(n))
    missing = solve_block(files, vignetting=False, depth_map_of=lambda n: None if n == "b0" else maps.get(n))
    eb, ea, em = _gain_error_percent(before), _gain_error_percent(after), _gain_error_percent(missing)
    occ = after["occlusion"]
    print(f"b0 gain - truth: {eb['b0']:.3f} % before, {ea['b0']:.3f} % after ({occ['hidden']} of "
          f"{occ['tested']} observations hidden); max over images after {max(abs(x) for x in ea.values()):.3f} %")
    assert abs(eb["b0"]) > 1.0                         # the wall's colour biases the partner's gain
    assert max(abs(x) for x in ea.values()) < 0.15     # dropped: every gain within 0.15 % of the truth
    assert occ["hidden"] > 50 and occ["views_with_map"] == 8 and occ["views_without_map"] == 0
    # b0 without its map: today's rule for it (nothing of its observations dropped), so the bias stays
    assert missing["occlusion"]["views_without_map"] == 1 and abs(em["b0"] - eb["b0"]) < 1e-6


def test_nothing_occluded_leaves_the_solve_unchanged(tmp_path):
    files, maps = _block(tmp_path, None)
    before = solve_block(files, vignetting=False)
    after = solve_block(files, vignetting=False, depth_map_of=lambda n: maps.get(n))
    assert after["occlusion"]["hidden"] == 0 and after["occlusion"]["tested"] == after["observations"]
    assert after["observations"] == before["observations"] and after["images"] == before["images"]
