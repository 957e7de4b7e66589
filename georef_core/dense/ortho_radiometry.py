"""Radiometric compensation between the images of an orthophoto: per-image exposure gains and per-camera
vignetting, estimated from ground points seen by several images.

Model (per colour channel c): an image k of camera m records a ground point P at normalised radius rho
(distance to the principal point / half the image diagonal) as

    I_k,c(P) = g_k,c * V_m,c(rho) * L_c(P),      log V_m,c(rho) = b1 rho^2 + b2 rho^4 + b3 rho^6  (V(0) = 1)

with L the ground's radiance (Lambertian: the same from every view). For a point seen by views k and j the
radiance cancels in the difference of logs:

    log I_k - log I_j = (a_k - a_j) + f_m(k)(rho_k) - f_m(j)(rho_j),      a = log g

which is linear in the unknowns (one a per image, ``degree`` b per camera, per channel). Samples: a lattice
of measured DSM cells (``n_samples``, the ENU points of the DSM) projected into every view that sees them
(same z-buffer visibility test as the orthophoto), colours read bilinearly from the image blurred by a
Gaussian of ``blur_px`` (a small misregistration on texture then costs little); channels clipped in the
image (< 8 or > 247) are left out. Pairs: each observation with up to 5 following observations of the same
point. Robust least squares: iteratively reweighted on the mean of the three channels' log differences
(Cauchy weights, scale 1.4826 MAD of the residuals), then one solve per channel with the final weights;
with a prior a_k ~ N(0, prior_sigma^2) and the mean of the a_k held at 0 (so the block keeps its overall
exposure and does not drift), b ~ N(0, 1). Images without observations keep g = 1.

Applying it: a pixel's colour is divided by g_k,c V_m,c(rho) before it is mosaicked
(:meth:`RadiometryModel.correction`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass
class RadiometryModel:
    log_gain: np.ndarray  # (n_views, 3) natural log of each image's gain per channel (R, G, B)
    camera_of_view: np.ndarray  # (n_views,) camera index of each view
    vignetting_coef: np.ndarray  # (n_cameras, 3, degree): log V(rho) = sum_j b_j rho^(2 j)
    observations: np.ndarray  # (n_views,) observations used per view
    n_points: int  # ground points seen by 2+ views
    residual_nmad: float  # robust scatter of the log differences (G channel): the noise of one pair

    @property
    def gains(self) -> np.ndarray:
        return np.exp(self.log_gain)

    def vignetting(self, camera: int, rho: np.ndarray) -> np.ndarray:
        """V(rho) per channel, (n, 3)."""
        r2 = np.asarray(rho, np.float64) ** 2
        powers = np.stack([r2 ** (j + 1) for j in range(self.vignetting_coef.shape[2])], 1)  # (n, degree)
        return np.exp(powers @ self.vignetting_coef[camera].T)

    def correction(self, k: int, rho: np.ndarray) -> np.ndarray:
        """(n, 3) float32 factors that take view k's colours at radius rho to the common radiometry."""
        f = self.vignetting(int(self.camera_of_view[k]), rho) * self.gains[k][None, :]
        return (1.0 / f).astype(np.float32)

    def summary(self) -> dict:
        g = self.gains.mean(axis=1)
        corner = [float(self.vignetting(m, np.array([1.0])).mean()) for m in range(len(self.vignetting_coef))]
        return {"gain_min": float(g.min()), "gain_max": float(g.max()),
                "gain_rms_percent": float(100 * np.sqrt(np.mean(np.log(g) ** 2))),
                "vignetting_at_corner": corner, "points": int(self.n_points),
                "pair_nmad_percent": float(100 * self.residual_nmad)}


def camera_index(views) -> np.ndarray:
    """One index per distinct camera (same full image size and intrinsics) of the views."""
    keys, out = {}, []
    for v in views:
        s = v.full_width / v.width
        key = (v.full_width, v.full_height, round(float(v.K[0, 0] * s), 1), round(float(v.K[0, 2] * s), 1),
               round(float(v.K[1, 2] * s), 1))
        out.append(keys.setdefault(key, len(keys)))
    return np.asarray(out, np.int64)


def normalised_radius(view, uv: np.ndarray) -> np.ndarray:
    """Distance of pixels to the principal point over half the image diagonal."""
    cx, cy = float(view.K[0, 2]), float(view.K[1, 2])
    return np.hypot(uv[:, 0] - cx, uv[:, 1] - cy) / (0.5 * np.hypot(view.width, view.height))


@dataclass
class RadiometricObservations:
    point: np.ndarray  # (n,) ground point index
    view: np.ndarray  # (n,) view index
    rho: np.ndarray  # (n,) normalised radius in the view
    rgb: np.ndarray  # (n, 3) float32 colour (R, G, B)


def observe(views, points_enu: np.ndarray, visible, blur_px: float = 1.5) -> RadiometricObservations:
    """Colours of the ground points in every view that sees them. ``visible(k, uv, z) -> bool mask`` is the
    orthophoto's occlusion test of view k; images are read one at a time (``views[k].read_image()``)."""
    P, V, R, C = [], [], [], []
    for k, v in enumerate(views):
        uv, z = v.project_distorted(points_enu)
        inside = (z > 0) & v.inside(uv, margin=2.0)
        idx = np.nonzero(inside)[0]
        if len(idx) == 0:
            continue
        ok = visible(k, uv[idx], z[idx])
        idx = idx[ok]
        if len(idx) == 0:
            continue
        img = v.read_image()
        if blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur_px)
        n, cols = len(idx), 4096          # remap wants maps under 32767 a side: fold the list into rows
        m = np.zeros((-(-n // cols) * cols, 2), np.float32)
        m[:n] = uv[idx]
        m = m.reshape(-1, cols, 2)
        rgb = cv2.remap(img, m[..., 0].copy(), m[..., 1].copy(), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)[:n, ::-1].astype(np.float32)
        P.append(idx)
        V.append(np.full(len(idx), k))
        R.append(normalised_radius(v, uv[idx]))
        C.append(rgb)
    if not P:
        return RadiometricObservations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3), np.float32))
    return RadiometricObservations(np.concatenate(P), np.concatenate(V), np.concatenate(R), np.concatenate(C))


def _pairs(point: np.ndarray, max_offset: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Observation index pairs (i, j) of the same point: each observation with up to ``max_offset`` of the
    following observations of its point (all pairs of points seen up to 6 times)."""
    order = np.argsort(point, kind="stable")
    p = point[order]
    a, b = [], []
    for d in range(1, max_offset + 1):
        same = np.nonzero(p[:-d] == p[d:])[0]
        a.append(order[same])
        b.append(order[same + d])
    return np.concatenate(a), np.concatenate(b)


def estimate_radiometry(obs: RadiometricObservations, n_views: int, camera_of_view: np.ndarray, degree: int = 3,
                        prior_sigma: float = 0.3, iterations: int = 5, vignetting: bool = True) -> RadiometryModel:
    """Robust least-squares gains and vignetting (module docstring)."""
    n_cam = int(camera_of_view.max()) + 1 if len(camera_of_view) else 1
    deg = degree if vignetting else 0
    log_gain = np.zeros((n_views, 3))
    coef = np.zeros((n_cam, 3, degree))
    counts = np.zeros(n_views, np.int64)
    ia, ib = _pairs(obs.point) if len(obs.point) else (np.zeros(0, np.int64), np.zeros(0, np.int64))
    n_points = int(len(np.unique(obs.point[ia]))) if len(ia) else 0
    nmad = float("nan")
    if len(ia) < 10:
        return RadiometryModel(log_gain, camera_of_view, coef, counts, n_points, nmad)
    va, vb = obs.view[ia], obs.view[ib]
    ca, cb = camera_of_view[va], camera_of_view[vb]
    n_unk = n_views + n_cam * deg
    # each row of the design has 2 + 2 deg entries: +1 at a_va, -1 at a_vb, rho_a^2j at b_{ca,j}, -rho_b^2j
    # at b_{cb,j}; the normal equations are accumulated entry pair by entry pair (bincount)
    cols = [va, vb] + [n_views + ca * deg + j for j in range(deg)] + [n_views + cb * deg + j for j in range(deg)]
    vals = ([np.ones(len(ia)), -np.ones(len(ia))] + [obs.rho[ia] ** (2 * (j + 1)) for j in range(deg)]
            + [-(obs.rho[ib] ** (2 * (j + 1))) for j in range(deg)])
    prior = np.zeros(n_unk)
    prior[:n_views] = 1.0 / prior_sigma ** 2
    prior[n_views:] = 1.0
    mean_row = np.zeros(n_unk)
    mean_row[:n_views] = 1.0 / n_views
    fixed = np.diag(prior) + 1e6 * np.outer(mean_row, mean_row)

    def normal(w, y):
        N = np.zeros(n_unk * n_unk)
        rhs = np.zeros(n_unk)
        for p_, (cp, vp) in enumerate(zip(cols, vals)):
            wv = w * vp
            rhs += np.bincount(cp, wv * y, minlength=n_unk)
            for cq, vq in zip(cols[p_:], vals[p_:]):
                t = np.bincount(cp * n_unk + cq, wv * vq, minlength=n_unk * n_unk)
                N += t
                if cq is not cp:
                    N += t.reshape(n_unk, n_unk).T.ravel()
        return N.reshape(n_unk, n_unk), rhs

    def predict(x):
        return sum(v * x[c] for c, v in zip(cols, vals))

    ga, gb = obs.rgb[ia], obs.rgb[ib]
    good = np.all((ga >= 8) & (ga <= 247) & (gb >= 8) & (gb <= 247), axis=1)
    Y = np.log(np.maximum(ga, 1.0)) - np.log(np.maximum(gb, 1.0))  # (pairs, 3)
    # robust weights from the channels' mean (iteratively reweighted), then one solve per channel with them
    y = Y.mean(axis=1)
    w = good.astype(np.float64)
    for _ in range(iterations):
        N, rhs = normal(w, y)
        x = np.linalg.solve(N + fixed, rhs)
        r = y - predict(x)
        s = 1.4826 * np.median(np.abs(r[good])) + 1e-6
        w = good / (1.0 + (r / (3.0 * s)) ** 2)
    nmad = float(s)
    N, _ = normal(w, y)
    for c in range(3):
        rhs = sum(np.bincount(cp, w * vp * Y[:, c], minlength=n_unk) for cp, vp in zip(cols, vals))
        x = np.linalg.solve(N + fixed, rhs)
        log_gain[:, c] = x[:n_views]
        if deg:
            coef[:, c, :] = x[n_views:].reshape(n_cam, deg)
    counts = np.bincount(np.concatenate([va, vb]), minlength=n_views)
    return RadiometryModel(log_gain, camera_of_view, coef, counts, n_points, nmad)


def sample_points(have: np.ndarray, enu: np.ndarray, n_samples: int) -> np.ndarray:
    """ENU points of a regular lattice of measured DSM cells, about ``n_samples`` of them."""
    n_have = int(have.sum())
    if n_have == 0:
        return np.zeros((0, 3))
    step = max(1, int(np.ceil(np.sqrt(n_have / max(1, n_samples)))))
    sub = have[::step, ::step]
    return enu[::step, ::step][sub]
