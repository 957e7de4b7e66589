"""Doming: the block's systematic bending, estimated and reported with its significance.

A nadir block whose lens distortion is wrong (held at a wrong calibration, or self-calibrated where the
radial distortion trades with the block's curvature: one flying height, parallel lines, weak camera
positions) bends like a bowl or a dome: the tie points agree with each other, the check points may be
few, and the DSM is off by a smooth quadratic surface across the block (James & Robson 2014).

What is measured here: a quadratic surface fitted to height differences over the block,

    dz(u, v) = a + b u + c v + d u^2 [+ e u v + f v^2]

with (u, v) the block's principal axes (u along its longest extent) centred on the block, weighted by
the stated sigmas of the differences. The differences are

* ``camera positions``: the adjusted camera centres minus their GNSS / photo positions (the adjustment's
  GNSS residuals, vertical): how far the photogrammetric block bends the cameras away from where the
  receiver put them;
* ``check points`` (six or more): triangulated minus surveyed heights.

The figure reported is the height of the block's centre above its edges, ``X = -(d L_u^2 + f L_v^2)``
with ``L_u``, ``L_v`` the half-extents of the points along the axes (``X > 0``: a dome, the centre high;
``X < 0``: a bowl). Its sigma comes from the fit's covariance scaled by the residuals' own scatter (the
a-posteriori variance factor, so wrong a-priori sigmas do not make it significant), and its significance
from Student's t with the fit's degrees of freedom: ``significant`` when the two-sided p-value is below
``DOMING_P_VALUE`` (a test level fixed in advance, not a threshold tuned on data). Where the points do
not span the minor axis (one or two flight lines: ``v^2`` is then the constant again) only ``u^2`` is
fitted, and ``u v`` when it is determined (on two lines, a slope of its own for each line): a term is
kept when what the other terms cannot explain of it has an RMS above 0.1 on the axes scaled to [-1, 1].
The summary says which terms were fitted.
"""

from __future__ import annotations

import math

import numpy as np

DOMING_P_VALUE = 0.01        # two-sided test level of "significant" (about 2.6 sigma for many points)
MIN_POINTS = 6


def _t_two_sided_p(t: float, dof: int) -> float:
    from scipy import stats

    return float(2.0 * stats.t.sf(abs(t), dof))


def fit_doming(xy_m: np.ndarray, dz_m: np.ndarray, sigma_m: np.ndarray | None = None, what: str = "") -> dict | None:
    """Fit the bowl to height differences ``dz_m`` (n,) at horizontal positions ``xy_m`` (n, 2) with a-priori
    sigmas ``sigma_m`` (n,; default equal weights). Returns a dict (``doming_m``, ``sigma_m``, ``t``,
    ``p_value``, ``significant``, ``terms``, ``extent_m``, ...) or None with fewer than ``MIN_POINTS``
    points or when the fit has no degree of freedom left."""
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    dz = np.asarray(dz_m, float).reshape(-1)
    sig = np.ones(len(dz)) if sigma_m is None else np.asarray(sigma_m, float).reshape(-1)
    ok = np.all(np.isfinite(xy), axis=1) & np.isfinite(dz) & np.isfinite(sig) & (sig > 0)
    xy, dz, sig = xy[ok], dz[ok], sig[ok]
    n = len(dz)
    if n < MIN_POINTS:
        return None
    centre = xy.mean(axis=0)
    _, _, vt = np.linalg.svd(xy - centre, full_matrices=False)
    axes = vt if vt.shape[0] == 2 else np.eye(2)
    uv = (xy - centre) @ axes.T
    L = np.maximum(np.max(np.abs(uv), axis=0), 1e-6)
    s = uv / L                                           # scaled to [-1, 1] along each axis
    cols = {"1": np.ones(n), "u": s[:, 0], "v": s[:, 1], "u2": s[:, 0] ** 2, "uv": s[:, 0] * s[:, 1],
            "v2": s[:, 1] ** 2}
    terms = ["1", "u", "v", "u2"]
    for extra in ("v2", "uv"):   # only where the points determine them: not explained by the other terms
        A = np.column_stack([cols[t] for t in terms])
        rest = cols[extra] - A @ np.linalg.lstsq(A, cols[extra], rcond=None)[0]
        if float(np.sqrt(np.mean(rest ** 2))) > 0.1 and n - len(terms) - 1 >= 2:
            terms.append(extra)
    A = np.column_stack([cols[t] for t in terms])
    sv = np.linalg.svd(A / np.linalg.norm(A, axis=0), compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:                            # e.g. every point on one line: no curvature known
        terms.remove("v")
        A = np.column_stack([cols[t] for t in terms])
    p = len(terms)
    dof = n - p
    if dof < 1:
        return None
    w = 1.0 / sig ** 2
    N = A.T @ (A * w[:, None])
    Ninv = np.linalg.pinv(N)
    coef = Ninv @ (A.T @ (w * dz))
    res = dz - A @ coef
    s0_2 = float(np.sum(w * res ** 2) / dof)            # a-posteriori variance factor
    cov = Ninv * s0_2
    g = np.zeros(p)                                      # X = -(d + f) in the scaled axes: centre minus edges
    for t in ("u2", "v2"):
        if t in terms:
            g[terms.index(t)] = -1.0
    X = float(g @ coef)
    sX = float(math.sqrt(max(g @ cov @ g, 0.0)))
    t_stat = X / sX if sX > 0 else float("inf")
    pval = _t_two_sided_p(t_stat, dof) if np.isfinite(t_stat) else 0.0
    out = {
        "from": what, "n": int(n), "terms": terms, "dof": int(dof),
        "doming_m": round(X, 5), "sigma_m": round(sX, 5), "t": round(t_stat, 3), "p_value": float(f"{pval:.3g}"),
        "significant": bool(pval < DOMING_P_VALUE), "test_level": DOMING_P_VALUE,
        "extent_m": [round(2 * float(L[0]), 2), round(2 * float(L[1]), 2)],
        "axis_u_enu": [round(float(v), 4) for v in axes[0]],
        "residual_rms_m": round(float(np.sqrt(np.mean(res ** 2))), 5),
        "sigma0": round(math.sqrt(s0_2), 3),
        "meaning": "height of the block's centre above its edges from a quadratic fit (positive: a dome, "
                   "negative: a bowl)",
    }
    return out


def describe(d: dict) -> str:
    """'doming: X mm over the block (sigma Y mm, t, p)' for the summary and the warnings."""
    shape = "dome" if d["doming_m"] > 0 else "bowl"
    return (f"doming: {1000 * d['doming_m']:+.1f} mm over the block ({d['extent_m'][0]:.0f} x {d['extent_m'][1]:.0f} m; "
            f"sigma {1000 * d['sigma_m']:.1f} mm, t = {d['t']:.1f}, p = {d['p_value']:.2g}; from {d['n']} "
            f"{d['from']}){': a significant ' + shape if d['significant'] else ': not significant'}")
