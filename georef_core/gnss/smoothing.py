"""Combination of forward and backward filter passes into one smoothed solution (fixed-interval
smoother on the two independent estimates, as RTKLIB's 'combined' mode)."""

from __future__ import annotations

import numpy as np

from .fix_witness import PhaseArbiter, contradicted_fixes, float_back
from .rtk_filter import STATUS_FIX, STATUS_NONE, FilterOutput


def _weighted_mean(xf: np.ndarray, qf: np.ndarray, xb: np.ndarray, qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Covariance-weighted mean of two independent estimates, row by row: (x (N, 3), q (N, 3, 3)); NaN in
    the rows whose covariances do not invert."""
    try:
        return _weighted_mean_rows(xf, qf, xb, qb)
    except np.linalg.LinAlgError:      # a singular row: the others one by one
        x, q = np.full(xf.shape, np.nan), np.full(qf.shape, np.nan)
        for k in range(len(xf)):
            try:
                xk, qk = _weighted_mean_rows(xf[k:k + 1], qf[k:k + 1], xb[k:k + 1], qb[k:k + 1])
            except np.linalg.LinAlgError:
                continue
            x[k], q[k] = xk[0], qk[0]
        return x, q


def _weighted_mean_rows(xf, qf, xb, qb):
    wf, wb = np.linalg.inv(qf), np.linalg.inv(qb)
    q = np.linalg.inv(wf + wb)
    return (q @ (wf @ xf[..., None] + wb @ xb[..., None]))[..., 0], q


def _combined_float(fwd: FilterOutput, bwd: FilterOutput) -> tuple[np.ndarray, np.ndarray]:
    """The two passes' float solutions combined per epoch (covariance-weighted mean where both exist, else
    the one that does): what an epoch falls back to when its combined fix is refused (fix_continuity)."""
    xf, xb = fwd.float_position_ecef_m, bwd.float_position_ecef_m
    qf, qb = fwd.float_covariance_ecef_m2, bwd.float_covariance_ecef_m2
    has_f = np.isfinite(xf).all(axis=1) & np.isfinite(qf).all(axis=(1, 2))
    has_b = np.isfinite(xb).all(axis=1) & np.isfinite(qb).all(axis=(1, 2))
    x = np.where(has_f[:, None], xf, xb).copy()
    q = np.where(has_f[:, None, None], qf, qb).copy()
    both = np.nonzero(has_f & has_b)[0]
    if len(both):
        xm, qm = _weighted_mean(xf[both], qf[both], xb[both], qb[both])
        ok = np.isfinite(xm).all(axis=1)
        x[both[ok]], q[both[ok]] = xm[ok], qm[ok]
    return x, q


def _rank(status: np.ndarray) -> np.ndarray:
    """Lower is better: fix 1 < float 2 < single 5; none is worst."""
    return np.where(status == STATUS_NONE, 99, status)


def combine(fwd: FilterOutput, bwd: FilterOutput, arbiter: PhaseArbiter | None = None) -> tuple[FilterOutput, np.ndarray]:
    """Per epoch: the better-quality pass where qualities differ; the covariance-weighted mean of two float
    passes; the covariance-weighted mean (covariance not reduced) of two fixed passes. First each pass's fixes that the
    other contradicts are given back their float (fix_witness.contradicted_fixes): two fixed passes more
    than 5 cm apart hold a wrong integer between them; the carrier phase against the epochs both fix alike
    (the arbiter) keeps one where it can tell, else both are refused and the epoch is the weighted mean of
    the two floats; a fix alone in its pass against a float of the other is refused. Returns the combined
    output and a per-epoch conflict flag (both passes fixed, more than 5 cm apart)."""
    refuse_f, refuse_b, conflict = contradicted_fixes(fwd, bwd, arbiter)
    fwd, bwd = float_back(fwd, refuse_f), float_back(bwd, refuse_b)
    out = FilterOutput(fwd.status.copy(), fwd.position_ecef_m.copy(), fwd.covariance_ecef_m2.copy(), fwd.n_sats.copy(),
                       fwd.ratio.copy(), fwd.residuals_m.copy(), fwd.n_fixed_amb.copy())
    rf, rb = _rank(fwd.status), _rank(bwd.status)
    take_b = rb < rf
    for name in ("status", "position_ecef_m", "covariance_ecef_m2", "n_sats", "ratio", "residuals_m", "n_fixed_amb"):
        getattr(out, name)[take_b] = getattr(bwd, name)[take_b]
    if fwd.float_position_ecef_m is not None and bwd.float_position_ecef_m is not None:
        out.float_position_ecef_m, out.float_covariance_ecef_m2 = _combined_float(fwd, bwd)
    both = np.nonzero((rf == rb) & (fwd.status != STATUS_NONE))[0]
    xf, xb = fwd.position_ecef_m[both], bwd.position_ecef_m[both]
    qf, qb = fwd.covariance_ecef_m2[both], bwd.covariance_ecef_m2[both]
    x_mean, q_mean = _weighted_mean(xf, qf, xb, qb)
    for k, e in enumerate(both):
        q = q_mean[k]
        if not np.isfinite(q).all():
            continue      # a covariance that does not invert: the epoch keeps the pass chosen above
        if fwd.status[e] == STATUS_FIX:
            # two fixed passes with the same integers are (without dynamics) the same function of this epoch's
            # data, not two independent estimates: the covariance-weighted mean (the plain mean when the two
            # are alike; in static mode, or a fresh pass's first fixes beside a long one, the better one
            # counts most), its covariance the better pass's, not shrunk
            out.position_ecef_m[e] = x_mean[k]
            better = qf[k] if np.trace(qf[k]) <= np.trace(qb[k]) else qb[k]
            out.covariance_ecef_m2[e] = better
        else:
            out.position_ecef_m[e] = x_mean[k]
            out.covariance_ecef_m2[e] = q
        out.ratio[e] = max(fwd.ratio[e], bwd.ratio[e])
        out.n_sats[e] = max(fwd.n_sats[e], bwd.n_sats[e])
    return out, conflict
