"""Combination of forward and backward filter passes into one smoothed solution (fixed-interval
smoother on the two independent estimates, as RTKLIB's 'combined' mode)."""

from __future__ import annotations

import numpy as np

from .rtk_filter import STATUS_FIX, STATUS_FLOAT, STATUS_NONE, FilterOutput

FIX_CONFLICT_M = 0.05   # two fixed solutions further apart than this disagree on an integer
# in a conflict, a pass fixed without a break for this many epochs, and this many times longer than the other,
# is believed: a fresh filter's first fixes (the backward pass's start) are the usual wrong ones
TRUSTED_RUN_EPOCHS = 10
TRUSTED_RUN_FACTOR = 3


def _fixed_run_lengths(status: np.ndarray, backward: bool) -> np.ndarray:
    """Epochs each epoch's fix has lasted without a break, counted in the pass's own direction."""
    run = np.zeros(len(status), dtype=np.int64)
    order = range(len(status) - 1, -1, -1) if backward else range(len(status))
    prev = 0
    for e in order:
        prev = prev + 1 if status[e] == STATUS_FIX else 0
        run[e] = prev
    return run


def _lone_fix(status: np.ndarray) -> np.ndarray:
    """Fixed epochs whose neighbours in the pass (both, where they exist) are not fixed."""
    fixed = status == STATUS_FIX
    before = np.concatenate([[False], fixed[:-1]])
    after = np.concatenate([fixed[1:], [False]])
    return fixed & ~before & ~after


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


def combine(fwd: FilterOutput, bwd: FilterOutput) -> tuple[FilterOutput, np.ndarray]:
    """Per epoch: the better-quality pass where qualities differ (except a lone fix, below); the
    covariance-weighted mean of two float passes; the plain mean (covariance not reduced) of two fixed
    passes. Two fixed passes that disagree by more than 5 cm hold a wrong integer between them: the one
    fixed without a break for at least 10 epochs and 3 times longer than the other is kept, else the epoch
    is downgraded to float. A fix alone in its pass (its neighbours there not fixed) against a float of the
    other pass gives the float. Returns the combined output and a per-epoch conflict flag (set whichever
    way the conflict went)."""
    n = len(fwd.status)
    out = FilterOutput(fwd.status.copy(), fwd.position_ecef_m.copy(), fwd.covariance_ecef_m2.copy(), fwd.n_sats.copy(),
                       fwd.ratio.copy(), fwd.residuals_m.copy(), fwd.n_fixed_amb.copy())
    conflict = np.zeros(n, dtype=bool)
    rf, rb = _rank(fwd.status), _rank(bwd.status)
    take_b = rb < rf
    # a pass's lone fix (float on both sides in that pass) where the other pass is float is not taken: on the
    # u-blox walk these were the combined solution's only fixes the carrier phase contradicts (docs/gnss.md)
    take_b &= ~(_lone_fix(bwd.status) & (fwd.status == STATUS_FLOAT))
    take_b |= _lone_fix(fwd.status) & (bwd.status == STATUS_FLOAT)
    for name in ("status", "position_ecef_m", "covariance_ecef_m2", "n_sats", "ratio", "residuals_m", "n_fixed_amb"):
        getattr(out, name)[take_b] = getattr(bwd, name)[take_b]
    if fwd.float_position_ecef_m is not None and bwd.float_position_ecef_m is not None:
        out.float_position_ecef_m, out.float_covariance_ecef_m2 = _combined_float(fwd, bwd)
    both = np.nonzero((rf == rb) & (fwd.status != STATUS_NONE))[0]
    run_f, run_b = _fixed_run_lengths(fwd.status, False), _fixed_run_lengths(bwd.status, True)
    xf, xb = fwd.position_ecef_m[both], bwd.position_ecef_m[both]
    qf, qb = fwd.covariance_ecef_m2[both], bwd.covariance_ecef_m2[both]
    x_mean, q_mean = _weighted_mean(xf, qf, xb, qb)
    for k, e in enumerate(both):
        q = q_mean[k]
        if not np.isfinite(q).all():
            continue      # a covariance that does not invert: the epoch keeps the pass chosen above
        if fwd.status[e] == STATUS_FIX:
            # two fixed passes with the same integers are the same function of this epoch's data, not two
            # independent estimates: average them without shrinking the covariance
            out.position_ecef_m[e] = 0.5 * (xf[k] + xb[k])
            out.covariance_ecef_m2[e] = 0.5 * (qf[k] + qb[k])
        else:
            out.position_ecef_m[e] = x_mean[k]
            out.covariance_ecef_m2[e] = q
        out.ratio[e] = max(fwd.ratio[e], bwd.ratio[e])
        out.n_sats[e] = max(fwd.n_sats[e], bwd.n_sats[e])
        if fwd.status[e] == STATUS_FIX and np.linalg.norm(xf[k] - xb[k]) > FIX_CONFLICT_M:
            conflict[e] = True
            longer, shorter = max(run_f[e], run_b[e]), min(run_f[e], run_b[e])
            if longer >= TRUSTED_RUN_EPOCHS and longer >= TRUSTED_RUN_FACTOR * shorter:
                src = fwd if run_f[e] > run_b[e] else bwd
                out.position_ecef_m[e] = src.position_ecef_m[e]
                out.covariance_ecef_m2[e] = src.covariance_ecef_m2[e]
                out.ratio[e], out.n_sats[e] = src.ratio[e], src.n_sats[e]
                out.residuals_m[e], out.n_fixed_amb[e] = src.residuals_m[e], src.n_fixed_amb[e]
            else:
                out.status[e] = STATUS_FLOAT
                out.covariance_ecef_m2[e] = q + np.outer(xf[k] - xb[k], xf[k] - xb[k]) / 4.0
    return out, conflict
