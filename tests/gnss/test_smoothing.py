"""The covariance-weighted mean behind the combined (forward + backward) solution: equal to the textbook
formula row by row, and a row whose covariance does not invert leaves the others combined."""

from __future__ import annotations

import numpy as np

from georef_core.gnss.smoothing import _weighted_mean


def _spd(rng, n):
    a = rng.normal(size=(n, 3, 3))
    return a @ a.transpose(0, 2, 1) * 1e-4 + np.eye(3) * 1e-6


def test_weighted_mean_matches_the_formula_and_survives_a_singular_row():
    rng = np.random.default_rng(4)
    n = 6
    xf, xb = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    qf, qb = _spd(rng, n), _spd(rng, n)
    x, q = _weighted_mean(xf, qf, xb, qb)
    for k in range(n):
        wf, wb = np.linalg.inv(qf[k]), np.linalg.inv(qb[k])
        qk = np.linalg.inv(wf + wb)
        assert np.allclose(q[k], qk, rtol=1e-12, atol=0)
        assert np.allclose(x[k], qk @ (wf @ xf[k] + wb @ xb[k]), rtol=1e-12, atol=1e-15)
        # the mean lies between the two estimates in the metric of each: closer to the more certain one
        assert np.trace(q[k]) < min(np.trace(qf[k]), np.trace(qb[k]))
    qf_bad = qf.copy()
    qf_bad[2] = 0.0                       # a pass without a covariance at one epoch
    x2, q2 = _weighted_mean(xf, qf_bad, xb, qb)
    assert np.isnan(x2[2]).all() and np.isnan(q2[2]).all()
    keep = np.arange(n) != 2
    assert np.allclose(x2[keep], x[keep]) and np.allclose(q2[keep], q[keep])
