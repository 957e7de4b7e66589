"""Similarity (7-parameter Helmert) fit between two point sets, e.g. SfM camera centres to known ones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Similarity:
    scale: float
    R: np.ndarray  # 3x3
    t: np.ndarray  # 3

    def apply(self, xyz) -> np.ndarray:
        return self.scale * np.asarray(xyz, dtype=float) @ self.R.T + self.t


def fit_similarity(src, dst) -> tuple[Similarity, np.ndarray]:
    """Least-squares s, R, t with dst ~= s R src + t (Umeyama 1991). Returns it and the residuals dst - fit
    (N, 3). Needs at least 3 non-collinear points."""
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError("need at least 3 matching points")
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    u, sv, vt = np.linalg.svd(b.T @ a / len(src))
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[2] = -1.0
    R = u @ np.diag(d) @ vt
    var_src = float(np.mean(np.sum(a * a, axis=1)))
    s = float(np.sum(sv * d) / var_src)
    sim = Similarity(scale=s, R=R, t=md - s * R @ ms)
    return sim, dst - sim.apply(src)
