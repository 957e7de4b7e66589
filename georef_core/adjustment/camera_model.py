"""The frame camera models of the adjustment: perspective with Brown distortion, or equidistant fisheye.

Pixels follow OpenCV (centre of the top-left pixel at (0, 0)); COLMAP's pixels are 0.5 larger. The
parameter vector always has eight entries, one focal length in pixels and the principal point first:

* perspective (``fisheye=False``): ``f, cx, cy, k1, k2, k3, p1, p2``, OpenCV's pinhole + Brown model
  on ``x = X/Z, y = Y/Z``: ``r2 = x^2 + y^2``, radial ``1 + k1 r2 + k2 r2^2 + k3 r2^3``, decentring p1, p2;
* fisheye (``fisheye=True``): ``f, cx, cy, k1, k2, k3, k4, 0``, OpenCV's fisheye model (COLMAP's
  ``OPENCV_FISHEYE``): the angle theta of the ray from the optical axis is mapped to the image radius
  ``f theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` (equidistant projection plus a
  polynomial); the last entry is unused and held at zero. Rays up to 90 degrees off the axis.

A model decides the projection and which parameters the adjustment may change:

* ``radial``: f, cx, cy, k1, k2 (k3, p1, p2 held at zero)
* ``brown``: all eight (radial k1..k3 + decentring p1, p2, the OpenCV/Brown model)
* ``fisheye``: f, cx, cy, k1..k4 (action cameras and wide-angle lenses beyond what a polynomial in r fits)
"""

from __future__ import annotations

import numpy as np

PARAM_NAMES = ("f", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
FISHEYE_PARAM_NAMES = ("f", "cx", "cy", "k1", "k2", "k3", "k4", "unused")
MODEL_FREE = {
    "radial": ("f", "cx", "cy", "k1", "k2"),
    "brown": PARAM_NAMES,
    "fisheye": FISHEYE_PARAM_NAMES[:7],
}
COLMAP_FISHEYE_MODELS = ("SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE")


def is_fisheye(model: str) -> bool:
    """Whether an adjustment model name (radial, brown, fisheye) uses the fisheye projection."""
    return model == "fisheye"


def param_names(fisheye: bool = False) -> tuple[str, ...]:
    return FISHEYE_PARAM_NAMES if fisheye else PARAM_NAMES


def free_mask(model: str, fix_principal_point: bool = False) -> np.ndarray:
    if model not in MODEL_FREE:
        raise ValueError(f"camera model {model!r} is not supported by the adjustment (choose radial, brown or fisheye)")
    names = set(MODEL_FREE[model])
    if fix_principal_point:
        names -= {"cx", "cy"}
    return np.array([n in names for n in param_names(is_fisheye(model))])


def from_colmap(model: str, params) -> np.ndarray:
    """Our 8 parameters from a COLMAP camera (model name and params, COLMAP pixel convention); a fisheye
    model (``COLMAP_FISHEYE_MODELS``) gives the fisheye layout."""
    p = [float(v) for v in params]
    out = np.zeros(8)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        out[0], out[1], out[2] = p[0], p[1] - 0.5, p[2] - 0.5
        if model in ("SIMPLE_RADIAL", "SIMPLE_RADIAL_FISHEYE"):
            out[3] = p[3]
        elif model in ("RADIAL", "RADIAL_FISHEYE"):
            out[3], out[4] = p[3], p[4]
    elif model in ("PINHOLE", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE"):
        out[0], out[1], out[2] = 0.5 * (p[0] + p[1]), p[2] - 0.5, p[3] - 0.5
        if model == "OPENCV_FISHEYE":
            out[3:7] = p[4:8]
        elif model in ("OPENCV", "FULL_OPENCV"):
            out[3], out[4], out[6], out[7] = p[4], p[5], p[6], p[7]
        if model == "FULL_OPENCV":
            if any(abs(v) > 0 for v in p[9:12]):
                raise ValueError("COLMAP FULL_OPENCV camera with rational terms k4..k6 cannot be converted to the "
                                 "adjustment's Brown model")
            out[5] = p[8]
    else:
        raise ValueError(f"COLMAP camera model {model} cannot be converted to the adjustment's camera models")
    return out


def to_colmap(params: np.ndarray, fisheye: bool = False) -> tuple[str, list[float]]:
    """COLMAP model name and parameters (COLMAP pixel convention) of our camera, for oriented_images.json:
    FULL_OPENCV for the perspective model, OPENCV_FISHEYE for the fisheye one."""
    f, cx, cy, a, b, c, d, e = [float(v) for v in params]
    if fisheye:
        return "OPENCV_FISHEYE", [f, f, cx + 0.5, cy + 0.5, a, b, c, d]
    k1, k2, k3, p1, p2 = a, b, c, d, e
    return "FULL_OPENCV", [f, f, cx + 0.5, cy + 0.5, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]


def brown_distortion(x, y, k1, k2, k3, p1, p2, rational=(0.0, 0.0, 0.0)):
    """OpenCV's Brown distortion of normalised image coordinates x = X/Z, y = Y/Z: radial
    (1 + k1 r2 + k2 r2^2 + k3 r2^3), divided by (1 + k4 r2 + k5 r2^2 + k6 r2^3) when the rational terms
    (k4, k5, k6) are given, plus decentring p1, p2. Returns (xd, yd). The one copy of the polynomial used
    by the adjustment and the dense step."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    k4, k5, k6 = rational
    if np.any(k4) or np.any(k5) or np.any(k6):
        radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return xd, yd


def fisheye_radius(theta, k1, k2, k3, k4):
    """OpenCV's fisheye model: the angle theta (rad) of a ray from the optical axis to its normalised image
    radius theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)."""
    t2 = theta * theta
    return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def project_camera_points(p_cam: np.ndarray, params: np.ndarray, fisheye: bool = False) -> np.ndarray:
    """Camera-frame points (n, 3) -> pixels (n, 2). ``params`` (8,) or (n, 8)."""
    params = np.asarray(params, dtype=float)
    if params.ndim == 1:
        f, cx, cy, k1, k2, k3, p1, p2 = params
    else:
        f, cx, cy, k1, k2, k3, p1, p2 = params.T
    if fisheye:
        rho = np.hypot(p_cam[:, 0], p_cam[:, 1])
        theta_d = fisheye_radius(np.arctan2(rho, p_cam[:, 2]), k1, k2, k3, p1)   # k4 in the p1 slot
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(rho > 1e-12, theta_d / rho, 1.0 / np.where(p_cam[:, 2] != 0, p_cam[:, 2], 1.0))
        return np.stack([f * p_cam[:, 0] * scale + cx, f * p_cam[:, 1] * scale + cy], axis=1)
    z = p_cam[:, 2]
    xd, yd = brown_distortion(p_cam[:, 0] / z, p_cam[:, 1] / z, k1, k2, k3, p1, p2)
    return np.stack([f * xd + cx, f * yd + cy], axis=1)


def undistort_pixels(uv: np.ndarray, params: np.ndarray, iterations: int = 10, fisheye: bool = False) -> np.ndarray:
    """Pixels (n, 2) -> normalised undistorted image coordinates x = X/Z, y = Y/Z (n, 2): fixed-point
    iteration for the perspective model, Newton on the angle for the fisheye (rays beyond 90 degrees
    from the axis have no such coordinates and come back as NaN)."""
    params = np.asarray(params, float)     # (8,), or (n, 8) one camera per pixel
    f, cx, cy, k1, k2, k3, p1, p2 = params.T if params.ndim == 2 else [float(v) for v in params]
    xd = (uv[:, 0] - cx) / f
    yd = (uv[:, 1] - cy) / f
    if fisheye:
        k4 = p1
        theta_d = np.hypot(xd, yd)
        theta = theta_d.copy()
        for _ in range(2 * iterations):
            t2 = theta * theta
            g = fisheye_radius(theta, k1, k2, k3, k4) - theta_d
            dg = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + 9.0 * t2 * k4)))
            theta = theta - g / dg
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(theta_d > 1e-12, np.tan(theta) / theta_d, 1.0)
        scale = np.where((theta >= 0) & (theta < 0.5 * np.pi), scale, np.nan)
        return np.stack([xd * scale, yd * scale], axis=1)
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    return np.stack([x, y], axis=1)
