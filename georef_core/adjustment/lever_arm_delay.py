"""Lever arm and trigger delay outside the bundle adjustment (Daakir et al. 2015, eqs. 3 and 4).

Camera centre from GNSS: ``C_i = A_i + R_i L + v_i dt`` with ``A_i`` the antenna at the trigger,
``R_i`` camera-to-ENU attitude, ``L`` the lever arm in the camera frame, ``v_i`` the antenna velocity and
``dt`` the delay between trigger and exposure.

* mode (a): the cameras are oriented by control points; ``L`` and ``dt`` are the weighted least-squares
  solution of the linear equations above (``estimate_lever_arm_delay``);
* mode (b): the cameras come from a free SfM model; a 7-parameter similarity (model -> ENU) and ``dt``
  are estimated from the antenna positions with the lever arm known (``fit_similarity_delay``).

Both are robust (Huber reweighting) and flag GNSS epochs whose normalised residual exceeds 4 sigma;
their covariances are scaled by the a-posteriori variance factor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import ProcessingError


@dataclass
class LeverDelayFit:
    lever_arm_cam_m: np.ndarray
    delay_s: float
    cov: np.ndarray               # covariance of the estimated parameters (names below)
    names: list[str]
    residual_enu_m: np.ndarray    # (K, 3) C - (A + R L + v dt)
    outlier: np.ndarray           # (K,) bool
    sigma0: float
    similarity: tuple[float, np.ndarray, np.ndarray] | None = None  # (scale, R, t) for mode (b)

    def sigma(self, name: str) -> float:
        return float(np.sqrt(self.cov[self.names.index(name), self.names.index(name)])) if name in self.names else 0.0


def _whiten(cov):
    inv = np.linalg.inv(cov)
    return np.transpose(np.linalg.cholesky(inv), (0, 2, 1))


def _huber(norm, k=2.5):
    w = np.ones_like(norm)
    w[norm > k] = k / norm[norm > k]
    return w


def estimate_lever_arm_delay(R_cam_to_enu, centres_enu_m, antenna_enu_m, velocity_enu_m_s, cov_enu_m2,
                             estimate_lever: bool = True, lever_arm_cam_m=None, estimate_delay: bool = True,
                             delay_s: float = 0.0) -> LeverDelayFit:
    R = np.asarray(R_cam_to_enu, float)
    y = np.asarray(centres_enu_m, float) - np.asarray(antenna_enu_m, float)
    v = np.asarray(velocity_enu_m_s, float)
    K = len(y)
    lever0 = np.zeros(3) if lever_arm_cam_m is None else np.asarray(lever_arm_cam_m, float)
    names = (["lever_x", "lever_y", "lever_z"] if estimate_lever else []) + (["delay"] if estimate_delay else [])
    if not names:
        raise ValueError("nothing to estimate")
    if 3 * K < len(names) + 3:
        raise ProcessingError(f"{K} camera positions are too few to estimate the lever arm and delay")
    blocks = []
    if estimate_lever:
        blocks.append(R)
    if estimate_delay:
        blocks.append(v[:, :, None])
    A = np.concatenate(blocks, axis=2)  # (K, 3, p)
    known = np.zeros((K, 3))
    if not estimate_lever:
        known += np.einsum("kij,j->ki", R, lever0)
    if not estimate_delay:
        known += v * delay_s
    yy = y - known
    U = _whiten(np.asarray(cov_enu_m2, float))
    w = np.ones(K)
    for _ in range(6):
        Aw = np.einsum("kij,kjl->kil", U, A) * np.sqrt(w)[:, None, None]
        yw = np.einsum("kij,kj->ki", U, yy) * np.sqrt(w)[:, None]
        Am, ym = Aw.reshape(-1, len(names)), yw.reshape(-1)
        N = Am.T @ Am
        x = np.linalg.solve(N, Am.T @ ym)
        r = yy - np.einsum("kij,j->ki", A, x)
        nr = np.linalg.norm(np.einsum("kij,kj->ki", U, r), axis=1) / np.sqrt(3)
        s0 = np.sqrt(np.sum(w * nr ** 2 * 3) / max(3 * K - len(names), 1))
        w = _huber(nr / max(s0, 1e-9))
    cov = np.linalg.inv(N) * s0 ** 2
    lever = x[:3] if estimate_lever else lever0
    delay = float(x[-1]) if estimate_delay else delay_s
    return LeverDelayFit(lever, delay, cov, names, r, nr / max(s0, 1e-9) > 4.0, float(s0))


def fit_similarity_delay(model_centres, model_R_cam_to_model, antenna_enu_m, velocity_enu_m_s, cov_enu_m2,
                         lever_arm_cam_m, estimate_delay: bool = True, initial=None) -> LeverDelayFit:
    """Similarity (s, R, t) taking the SfM model to ENU, plus the delay, from GNSS with a known lever arm:
    ``s R c_i + t = A_i + (R R_i) L + v_i dt``."""
    from ..photo.align import fit_similarity

    c = np.asarray(model_centres, float)
    Rm = np.asarray(model_R_cam_to_model, float)
    A = np.asarray(antenna_enu_m, float)
    v = np.asarray(velocity_enu_m_s, float)
    L = np.asarray(lever_arm_cam_m, float)
    K = len(c)
    if K < 3:
        raise ProcessingError("a similarity needs at least 3 camera positions")
    if initial is None:
        sim, _ = fit_similarity(c, A)
        x = np.concatenate([[np.log(sim.scale)], Rotation.from_matrix(sim.R).as_rotvec(), sim.t, [0.0]])
    else:
        s, Rs, t = initial
        x = np.concatenate([[np.log(s)], Rotation.from_matrix(Rs).as_rotvec(), t, [0.0]])
    U = _whiten(np.asarray(cov_enu_m2, float))
    npar = 8 if estimate_delay else 7

    def resid(x):
        s = np.exp(x[0])
        Rs = Rotation.from_rotvec(x[1:4]).as_matrix()
        r = s * c @ Rs.T + x[4:7] - A - np.einsum("ij,kjl,l->ki", Rs, Rm, L) - v * (x[7] if estimate_delay else 0.0)
        return r

    w = np.ones(K)
    s0 = 1.0
    for it in range(30):
        r = resid(x)
        J = np.zeros((K, 3, npar))
        for k in range(npar):
            e = np.zeros(8)
            e[k] = 1e-7
            J[:, :, k] = (resid(x + e) - resid(x - e)) / 2e-7
        Jw = np.einsum("kij,kjl->kil", U, J) * np.sqrt(w)[:, None, None]
        rw = np.einsum("kij,kj->ki", U, r) * np.sqrt(w)[:, None]
        Jm, rm = Jw.reshape(-1, npar), rw.reshape(-1)
        N = Jm.T @ Jm
        dx = -np.linalg.solve(N, Jm.T @ rm)
        x[:npar] += dx
        nr = np.linalg.norm(np.einsum("kij,kj->ki", U, resid(x)), axis=1) / np.sqrt(3)
        s0 = np.sqrt(np.sum(w * nr ** 2 * 3) / max(3 * K - npar, 1))
        w = _huber(nr / max(s0, 1e-9))
        if np.max(np.abs(dx)) < 1e-10 and it > 3:
            break
    cov = np.linalg.inv(N) * s0 ** 2
    r = resid(x)
    names = ["log_scale", "rot_x", "rot_y", "rot_z", "tx", "ty", "tz"] + (["delay"] if estimate_delay else [])
    return LeverDelayFit(L, float(x[7]) if estimate_delay else 0.0, cov, names, r, nr / max(s0, 1e-9) > 4.0, float(s0),
                         similarity=(float(np.exp(x[0])), Rotation.from_rotvec(x[1:4]).as_matrix(), x[4:7].copy()))
