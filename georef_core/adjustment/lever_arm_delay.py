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

Several flights (docs/georeferencing.md, "Several flights"): with ``flight`` (the flight, or offset group,
0..F-1 of each position) and ``offset_prior_cov_m2`` (3F, 3F), a common 3-D offset ``o_f`` of each flight's
GNSS positions (measured minus true) is estimated with that zero-mean prior, ``C_i = A_i - o_f + R_i L +
v_i dt``, as in the bundle adjustment. Mode (b): the similarity's translation and the offsets' mean are
told apart only by the prior (the result's absolute position is then only as good as the prior says:
its covariance carries it); the flights' differences are measured. Mode (a): the horizontal offsets are
told apart from the lever arm by the heading changes of the lines (the lever arm turns with the camera,
the offset does not); the vertical offset and the lever arm's camera-z (a nadir camera) only by the
prior, so the lever arm z's sigma grows to the offsets' vertical prior. The GNSS variance factor scales
the GNSS weights, not the prior.
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
    residual_enu_m: np.ndarray    # (K, 3) C - (A + R L + v dt) (A - o_flight where the offsets are modelled)
    outlier: np.ndarray           # (K,) bool
    sigma0: float
    similarity: tuple[float, np.ndarray, np.ndarray] | None = None  # (scale, R, t) for mode (b)
    # per-flight GNSS offsets, where modelled: (F, 3) ENU values, their (3F, 3F) covariance, and in mode (b) the
    # cross-covariance (p, 3F) of the similarity's parameters (names, without the offsets) with them
    flight_offset_enu_m: np.ndarray | None = None
    flight_offset_cov_m2: np.ndarray | None = None
    param_offset_cov: np.ndarray | None = None

    def sigma(self, name: str) -> float:
        return float(np.sqrt(self.cov[self.names.index(name), self.names.index(name)])) if name in self.names else 0.0


def _whiten(cov):
    inv = np.linalg.inv(cov)
    return np.transpose(np.linalg.cholesky(inv), (0, 2, 1))


def _huber(norm, k=2.5):
    w = np.ones_like(norm)
    w[norm > k] = k / norm[norm > k]
    return w


def _offset_prior(flight, offset_prior_cov_m2, K: int):
    """(F, whitener of the offsets' prior (3F, 3F), one-hot (K, F) of each position's flight), or (0, None, None)."""
    if flight is None or offset_prior_cov_m2 is None:
        return 0, None, None
    flight = np.asarray(flight, int)
    if flight.shape != (K,):
        raise ValueError(f"flight: one flight index per GNSS position ({K}), got {flight.shape}")
    F = int(flight.max()) + 1 if K else 0
    P = np.asarray(offset_prior_cov_m2, float)
    if P.shape != (3 * F, 3 * F):
        raise ValueError(f"offset_prior_cov_m2: ({3 * F}, {3 * F}) for {F} flights, got {P.shape}")
    Wp = np.linalg.cholesky(np.linalg.inv(P)).T           # |Wp o|^2 = o^T P^-1 o
    return F, Wp, np.eye(F)[flight]


def _offset_names(F: int) -> list[str]:
    return [f"flight{f + 1}.offset_{a}" for f in range(F) for a in "enu"]


def estimate_lever_arm_delay(R_cam_to_enu, centres_enu_m, antenna_enu_m, velocity_enu_m_s, cov_enu_m2,
                             estimate_lever: bool = True, lever_arm_cam_m=None, estimate_delay: bool = True,
                             delay_s: float = 0.0, flight=None, offset_prior_cov_m2=None) -> LeverDelayFit:
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
    n_main = len(names)
    F, Wp, onehot = _offset_prior(flight, offset_prior_cov_m2, K)
    blocks = []
    if estimate_lever:
        blocks.append(R)
    if estimate_delay:
        blocks.append(v[:, :, None])
    if F:   # y = R L + v dt - o_flight
        blocks.append(-np.einsum("kf,ij->kifj", onehot, np.eye(3)).reshape(K, 3, 3 * F))
        names = names + _offset_names(F)
    A = np.concatenate(blocks, axis=2)  # (K, 3, p)
    known = np.zeros((K, 3))
    if not estimate_lever:
        known += np.einsum("kij,j->ki", R, lever0)
    if not estimate_delay:
        known += v * delay_s
    yy = y - known
    U = _whiten(np.asarray(cov_enu_m2, float))
    w = np.ones(K)
    s0 = 1.0
    Np = np.zeros((len(names), len(names)))
    if F:
        Np[n_main:, n_main:] = Wp.T @ Wp
    for _ in range(6):
        # the GNSS weights scaled by the variance factor (of the previous round; with no prior the solution does
        # not depend on it), the offsets' prior as it is
        g = np.sqrt(w) / (s0 if F else 1.0)
        Aw = np.einsum("kij,kjl->kil", U, A) * g[:, None, None]
        yw = np.einsum("kij,kj->ki", U, yy) * g[:, None]
        Am, ym = Aw.reshape(-1, len(names)), yw.reshape(-1)
        x = np.linalg.solve(Am.T @ Am + Np, Am.T @ ym)
        r = yy - np.einsum("kij,j->ki", A, x)
        nr = np.linalg.norm(np.einsum("kij,kj->ki", U, r), axis=1) / np.sqrt(3)
        w_used = w
        s0 = np.sqrt(np.sum(w * nr ** 2 * 3) / max(3 * K - n_main, 1))
        w = _huber(nr / max(s0, 1e-9))
    Aw = np.einsum("kij,kjl->kil", U, A) * np.sqrt(w_used)[:, None, None]
    Ng = Aw.reshape(-1, len(names)).T @ Aw.reshape(-1, len(names))
    cov = np.linalg.inv(Ng / s0 ** 2 + Np) if F else np.linalg.inv(Ng) * s0 ** 2
    lever = x[:3] if estimate_lever else lever0
    delay = float(x[3 if estimate_lever else 0]) if estimate_delay else delay_s
    fo = {}
    if F:
        fo = {"flight_offset_enu_m": x[n_main:].reshape(F, 3).copy(), "flight_offset_cov_m2": cov[n_main:, n_main:].copy()}
    return LeverDelayFit(lever, delay, cov, names, r, nr / max(s0, 1e-9) > 4.0, float(s0), **fo)


def fit_similarity_delay(model_centres, model_R_cam_to_model, antenna_enu_m, velocity_enu_m_s, cov_enu_m2,
                         lever_arm_cam_m, estimate_delay: bool = True, initial=None, flight=None,
                         offset_prior_cov_m2=None) -> LeverDelayFit:
    """Similarity (s, R, t) taking the SfM model to ENU, plus the delay, from GNSS with a known lever arm:
    ``s R c_i + t = A_i + (R R_i) L + v_i dt`` (``A_i - o_flight`` where the per-flight offsets are modelled:
    module docstring)."""
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
    F, Wp, onehot = _offset_prior(flight, offset_prior_cov_m2, K)
    off = np.zeros((F, 3))
    nx = npar + 3 * F
    Np = np.zeros((nx, nx))
    if F:
        Np[npar:, npar:] = Wp.T @ Wp
        J_off = np.einsum("kf,ij->kifj", onehot, np.eye(3)).reshape(K, 3, 3 * F)   # d r / d o = +I

    def resid(x, off=off):
        s = np.exp(x[0])
        Rs = Rotation.from_rotvec(x[1:4]).as_matrix()
        r = s * c @ Rs.T + x[4:7] - A - np.einsum("ij,kjl,l->ki", Rs, Rm, L) - v * (x[7] if estimate_delay else 0.0)
        return r + off[np.asarray(flight, int)] if F else r

    w = np.ones(K)
    s0 = 1.0
    for it in range(30):
        r = resid(x, off)
        J = np.zeros((K, 3, nx))
        for k in range(npar):
            e = np.zeros(8)
            e[k] = 1e-7
            J[:, :, k] = (resid(x + e, off) - resid(x - e, off)) / 2e-7
        if F:
            J[:, :, npar:] = J_off
        g = np.sqrt(w) / (s0 if F else 1.0)       # the variance factor weights the GNSS, not the prior
        Jw = np.einsum("kij,kjl->kil", U, J) * g[:, None, None]
        rw = np.einsum("kij,kj->ki", U, r) * g[:, None]
        Jm, rm = Jw.reshape(-1, nx), rw.reshape(-1)
        N = Jm.T @ Jm
        rhs = Jm.T @ rm
        if F:
            rhs = rhs + Np[:, npar:] @ off.reshape(-1)
        dx = -np.linalg.solve(N + Np, rhs)
        x[:npar] += dx[:npar]
        if F:
            off = off + dx[npar:].reshape(F, 3)
        nr = np.linalg.norm(np.einsum("kij,kj->ki", U, resid(x, off)), axis=1) / np.sqrt(3)
        s0_used = s0
        s0 = np.sqrt(np.sum(w * nr ** 2 * 3) / max(3 * K - npar, 1))
        w = _huber(nr / max(s0, 1e-9))
        if np.max(np.abs(dx)) < 1e-10 and it > 3:
            break
    if F:   # the GNSS part of the last normal matrix at the final variance factor, plus the prior
        cov = np.linalg.inv(N * s0_used ** 2 / s0 ** 2 + Np)
    else:
        cov = np.linalg.inv(N) * s0 ** 2
    r = resid(x, off)
    names = ["log_scale", "rot_x", "rot_y", "rot_z", "tx", "ty", "tz"] + (["delay"] if estimate_delay else [])
    fo = {}
    if F:
        fo = {"flight_offset_enu_m": off.copy(), "flight_offset_cov_m2": cov[npar:, npar:].copy(),
              "param_offset_cov": cov[:npar, npar:].copy()}
        names = names + _offset_names(F)
    return LeverDelayFit(L, float(x[7]) if estimate_delay else 0.0, cov, names, r, nr / max(s0, 1e-9) > 4.0, float(s0),
                         similarity=(float(np.exp(x[0])), Rotation.from_rotvec(x[1:4]).as_matrix(), x[4:7].copy()),
                         **fo)


def similarity_centre_cov(fit: LeverDelayFit, model_centres) -> tuple[np.ndarray, np.ndarray | None]:
    """Mode (b): the covariance (N, 3, 3) of the camera centres ``s R c + t`` that the similarity's
    uncertainty gives (linear propagation of ``fit.cov`` over log-scale, rotation vector and translation),
    and, where the per-flight offsets were modelled, each centre's covariance with them (N, 3, 3F)."""
    if fit.similarity is None:
        raise ValueError("not a similarity fit")
    s, Rs, t = fit.similarity
    c = np.asarray(model_centres, float)
    rv = Rotation.from_matrix(Rs).as_rotvec()
    x0 = np.concatenate([[np.log(s)], rv, t])

    def centres(x):
        return np.exp(x[0]) * c @ Rotation.from_rotvec(x[1:4]).as_matrix().T + x[4:7]

    J = np.zeros((len(c), 3, 7))
    for k in range(7):
        e = np.zeros(7)
        e[k] = 1e-7
        J[:, :, k] = (centres(x0 + e) - centres(x0 - e)) / 2e-7
    cov = np.einsum("nik,kl,njl->nij", J, fit.cov[:7, :7], J)
    cross = None
    if fit.param_offset_cov is not None:
        cross = np.einsum("nik,kf->nif", J, fit.param_offset_cov[:7])
    return cov, cross
