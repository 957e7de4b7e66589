"""The frame camera model of the adjustment: pinhole with Brown distortion, one focal length.

Pixels follow OpenCV (centre of the top-left pixel at (0, 0)); COLMAP's pixels are 0.5 larger. The
parameter vector is ``f, cx, cy, k1, k2, k3, p1, p2`` (pixels; distortion on normalised coordinates),
whatever the model; a model only decides which of them the adjustment may change:

* ``radial``: f, cx, cy, k1, k2 (k3, p1, p2 held at zero)
* ``brown``: all eight (radial k1..k3 + decentring p1, p2, the OpenCV/Brown model)
* ``fisheye`` is handled by COLMAP's SfM only; the adjustment refuses it with a clear message.
"""

from __future__ import annotations

import numpy as np

PARAM_NAMES = ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
MODEL_FREE = {
    "radial": ("f", "cx", "cy", "k1", "k2"),
    "brown": PARAM_NAMES,
}


def free_mask(model: str, fix_principal_point: bool = False) -> np.ndarray:
    if model not in MODEL_FREE:
        raise ValueError(f"camera model {model!r} is not supported by the adjustment (choose radial or brown)")
    names = set(MODEL_FREE[model])
    if fix_principal_point:
        names -= {"cx", "cy"}
    return np.array([n in names for n in PARAM_NAMES])


def from_colmap(model: str, params) -> np.ndarray:
    """Our 8 parameters from a COLMAP camera (model name and params, COLMAP pixel convention)."""
    p = [float(v) for v in params]
    out = np.zeros(8)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        out[0], out[1], out[2] = p[0], p[1] - 0.5, p[2] - 0.5
        if model == "SIMPLE_RADIAL":
            out[3] = p[3]
        elif model == "RADIAL":
            out[3], out[4] = p[3], p[4]
    elif model in ("PINHOLE", "OPENCV", "FULL_OPENCV"):
        out[0], out[1], out[2] = 0.5 * (p[0] + p[1]), p[2] - 0.5, p[3] - 0.5
        if model in ("OPENCV", "FULL_OPENCV"):
            out[3], out[4], out[6], out[7] = p[4], p[5], p[6], p[7]
        if model == "FULL_OPENCV":
            out[5] = p[8]
    else:
        raise ValueError(f"COLMAP camera model {model} cannot be converted to the adjustment's Brown model")
    return out


def to_colmap_opencv(params: np.ndarray) -> tuple[str, list[float]]:
    """FULL_OPENCV (COLMAP convention) parameters of our camera, for oriented_images.json."""
    f, cx, cy, k1, k2, k3, p1, p2 = [float(v) for v in params]
    return "FULL_OPENCV", [f, f, cx + 0.5, cy + 0.5, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]


def project_camera_points(p_cam: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Camera-frame points (n, 3) -> pixels (n, 2). ``params`` (8,) or (n, 8)."""
    params = np.asarray(params, dtype=float)
    if params.ndim == 1:
        f, cx, cy, k1, k2, k3, p1, p2 = params
    else:
        f, cx, cy, k1, k2, k3, p1, p2 = params.T
    z = p_cam[:, 2]
    x = p_cam[:, 0] / z
    y = p_cam[:, 1] / z
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([f * xd + cx, f * yd + cy], axis=1)


def undistort_pixels(uv: np.ndarray, params: np.ndarray, iterations: int = 10) -> np.ndarray:
    """Pixels (n, 2) -> normalised undistorted image coordinates (n, 2) by fixed-point iteration."""
    f, cx, cy, k1, k2, k3, p1, p2 = [float(v) for v in params]
    xd = (uv[:, 0] - cx) / f
    yd = (uv[:, 1] - cy) / f
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return np.stack([x, y], axis=1)
