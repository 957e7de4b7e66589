"""Triangulation of ground points from their image measurements with known cameras, and blunder
detection (a measurement that does not triangulate with the others)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera_model import project_camera_points, undistort_pixels


@dataclass
class Triangulated:
    xyz_enu_m: np.ndarray
    residual_px: np.ndarray      # (n, 2) per measurement
    cov_enu_m2: np.ndarray       # from the image noise only
    n_used: int
    max_angle_deg: float         # widest intersection angle


def _camera_of(intr, cam_idx):
    """The intrinsics of each measurement: ``intr`` is one camera's (8,) or each camera's (N, 8) (several
    cameras in the block), indexed like the rotations and centres."""
    intr = np.asarray(intr, float)
    return intr[np.asarray(cam_idx, int)] if intr.ndim == 2 else intr


def _ray_directions(uv_px, cam_idx, R_cam_to_enu, intr, fisheye=False):
    xy = undistort_pixels(np.asarray(uv_px, float), _camera_of(intr, cam_idx), fisheye=fisheye)
    d_cam = np.column_stack([xy, np.ones(len(xy))])
    d = np.einsum("nij,nj->ni", R_cam_to_enu[cam_idx], d_cam)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def triangulate(uv_px, cam_idx, R_cam_to_enu, centres, intr, sigma_px: float = 1.0, iterations: int = 5,
                fisheye: bool = False, centre_shift_enu_m=None) -> Triangulated:
    """Least-squares intersection of the rays (midpoint), refined by Gauss-Newton on the reprojection.
    ``intr`` and ``fisheye``: the camera (see camera_model; (8,), or (N, 8) one row per camera of
    ``R_cam_to_enu``). ``centre_shift_enu_m`` (n, 3): where each
    measurement's camera was at the exposure of its row, from ``centres`` (a rolling shutter; None: 0)."""
    uv_px = np.asarray(uv_px, float)
    cam_idx = np.asarray(cam_idx, int)
    origins = centres[cam_idx] + (0.0 if centre_shift_enu_m is None else np.asarray(centre_shift_enu_m, float))
    d = _ray_directions(uv_px, cam_idx, R_cam_to_enu, intr, fisheye)
    intr = _camera_of(intr, cam_idx)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for oi, di in zip(origins, d):
        P = np.eye(3) - np.outer(di, di)
        A += P
        b += P @ oi
    X = np.linalg.lstsq(A, b, rcond=None)[0]
    Rw2c = np.transpose(R_cam_to_enu[cam_idx], (0, 2, 1))
    N = np.eye(3)
    for _ in range(iterations):
        pc = np.einsum("nij,nj->ni", Rw2c, X[None] - origins)
        uv = project_camera_points(pc, intr, fisheye)
        J = np.zeros((len(uv_px), 2, 3))
        h = 1e-5
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            pp = np.einsum("nij,nj->ni", Rw2c, (X + e)[None] - origins)
            pm = np.einsum("nij,nj->ni", Rw2c, (X - e)[None] - origins)
            J[:, :, k] = (project_camera_points(pp, intr, fisheye) - project_camera_points(pm, intr, fisheye)) / (2 * h)
        Jm = J.reshape(-1, 3)
        r = (uv - uv_px).reshape(-1)
        N = Jm.T @ Jm
        dx = -np.linalg.lstsq(N, Jm.T @ r, rcond=None)[0]
        X = X + dx
        if np.linalg.norm(dx) < 1e-7:
            break
    pc = np.einsum("nij,nj->ni", Rw2c, X[None] - origins)
    res = project_camera_points(pc, intr, fisheye) - uv_px
    cos = np.clip(d @ d.T, -1, 1)
    ang = float(np.degrees(np.arccos(cos.min()))) if len(d) > 1 else 0.0
    try:
        cov = np.linalg.inv(N) * sigma_px ** 2
    except np.linalg.LinAlgError:
        cov = np.full((3, 3), np.inf)
    return Triangulated(X, res, cov, len(uv_px), ang)


@dataclass
class BlunderReport:
    point: str
    image: str
    residual_px: float           # distance of the measurement from the projection of the point
    others_rms_px: float         # reprojection RMS of the point's other measurements without it
    message: str


def find_blunders(name: str, images: list[str], uv_px, cam_idx, R_cam_to_enu, centres, intr,
                  threshold_px: float = 5.0, fisheye: bool = False) -> tuple[list[int], list[BlunderReport]]:
    """Measurements of one point that do not triangulate with the others. With three or more
    measurements each is left out in turn: a measurement whose leave-one-out prediction misses by more
    than ``threshold_px`` while the others agree among themselves is a blunder (removed one at a time,
    worst first). With two measurements a failed intersection is reported but cannot be attributed.
    Returns the indices of the measurements to keep and the reports."""
    keep = list(range(len(images)))
    reports: list[BlunderReport] = []
    uv_px = np.asarray(uv_px, float)
    cam_idx = np.asarray(cam_idx, int)
    while len(keep) >= 3:
        full = triangulate(uv_px[keep], cam_idx[keep], R_cam_to_enu, centres, intr, fisheye=fisheye)
        if np.max(np.linalg.norm(full.residual_px, axis=1)) <= threshold_px:
            break
        best = None
        for j in range(len(keep)):
            rest = keep[:j] + keep[j + 1:]
            t = triangulate(uv_px[rest], cam_idx[rest], R_cam_to_enu, centres, intr, fisheye=fisheye)
            others = float(np.sqrt(np.mean(np.sum(t.residual_px ** 2, 1))))
            i = keep[j]
            pc = R_cam_to_enu[cam_idx[i]].T @ (t.xyz_enu_m - centres[cam_idx[i]])
            miss = float(np.linalg.norm(project_camera_points(pc[None], _camera_of(intr, [cam_idx[i]]), fisheye)[0]
                                        - uv_px[i])) if pc[2] > 0 else np.inf
            if best is None or others < best[1]:
                best = (j, others, miss)
        j, others, miss = best
        if others > threshold_px:
            break  # leaving one out does not make the rest agree: not a single blunder
        i = keep[j]
        reports.append(BlunderReport(name, images[i], miss, others,
                                     f"point {name}: the measurement in {images[i]} does not triangulate with the "
                                     f"point's other {len(keep) - 1} measurements (off by {miss:.1f} px, the others "
                                     f"agree to {others:.2f} px); it was left out"))
        keep.pop(j)
    if len(keep) == 2:
        t = triangulate(uv_px[keep], cam_idx[keep], R_cam_to_enu, centres, intr, fisheye=fisheye)
        if np.max(np.linalg.norm(t.residual_px, axis=1)) > threshold_px:
            reports.append(BlunderReport(name, ", ".join(images[i] for i in keep), float(np.max(np.linalg.norm(t.residual_px, axis=1))),
                                         float("nan"), f"point {name}: its two measurements ({images[keep[0]]}, "
                                         f"{images[keep[1]]}) do not intersect; one of them is wrong"))
    return keep, reports
