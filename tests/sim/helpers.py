"""Test helpers: sub-pixel X-corner (checker target centre) location and a similarity fit."""

from __future__ import annotations

import numpy as np


def refine_xcorner(img: np.ndarray, guess, radius: float, iterations: int = 30):
    """Centre of a 2x2 checker (saddle point) near ``guess`` (u, v), OpenCV pixel convention.

    Every image gradient inside the window is orthogonal to the vector from the corner to its pixel
    (the edges pass through the corner), so the corner solves sum(w g g^T) q = sum(w g g^T p)."""
    q = np.asarray(guess, dtype=float).copy()
    h, w = img.shape
    r = int(np.ceil(radius)) + 2
    for _ in range(iterations):
        cu, cv = int(round(q[0])), int(round(q[1]))
        if cu - r - 1 < 0 or cv - r - 1 < 0 or cu + r + 2 > w or cv + r + 2 > h:
            return None
        p = img[cv - r - 1:cv + r + 2, cu - r - 1:cu + r + 2]
        gx = 0.5 * (p[1:-1, 2:] - p[1:-1, :-2])
        gy = 0.5 * (p[2:, 1:-1] - p[:-2, 1:-1])
        vv, uu = np.mgrid[cv - r:cv + r + 1, cu - r:cu + r + 1].astype(float)
        wt = np.exp(-((uu - q[0]) ** 2 + (vv - q[1]) ** 2) / (2 * (radius / 2) ** 2))
        a11 = np.sum(wt * gx * gx)
        a12 = np.sum(wt * gx * gy)
        a22 = np.sum(wt * gy * gy)
        b1 = np.sum(wt * (gx * gx * uu + gx * gy * vv))
        b2 = np.sum(wt * (gx * gy * uu + gy * gy * vv))
        det = a11 * a22 - a12 * a12
        if det <= 1e-9:
            return None
        qn = np.array([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det])
        done = np.linalg.norm(qn - q) < 1e-4
        q = qn
        if done:
            break
    return q


def similarity_fit(src: np.ndarray, dst: np.ndarray):
    """Umeyama: scale s, rotation R, translation t minimising |dst - (s R src + t)|."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    u, sig, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.eye(3)
    d[2, 2] = np.sign(np.linalg.det(u @ vt))
    rot = u @ d @ vt
    s = np.trace(np.diag(sig) @ d) / a.var(0).sum()
    return s, rot, md - s * rot @ ms
