"""MLAMBDA integer least squares: exhaustive search on small problems, RTKLIB demo5's lambda()
(through pyrtklib5), invariance under unimodular transformations, edge cases, partial fixing, timing."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest

from georef_core.gnss.lambda_search import (
    LambdaResult,
    SearchLimitError,
    ltdl_decompose,
    mlambda_search,
    partial_fix_subset,
    ratio_test_passes,
)

WAVELENGTHS_M = (0.190293672798365, 0.244210213424568)  # GPS L1, L2


def dd_float_problem(rng, n_sats, n_freq=2, n_epochs=5, dt_s=30.0, sigma_phase_m=0.003, sigma_code_m=0.3,
                     offset=1_000_000):
    """Simulated short-baseline double-difference float solution: (float ambiguities, covariance, truth).

    Unknowns: baseline (3, with a 3 m prior) and one DD ambiguity per satellite pair and frequency;
    DD phase and code of ``n_epochs`` epochs with slowly moving satellites, DD correlation included.
    """
    az = rng.uniform(0.0, 2 * np.pi, n_sats)
    el = rng.uniform(np.radians(15), np.radians(85), n_sats)
    rate = rng.normal(size=(n_sats, 2)) * np.radians(0.5) / 60.0
    nd = n_sats - 1
    n = nd * n_freq
    normal = np.zeros((3 + n, 3 + n))
    normal[:3, :3] += np.eye(3) / 3.0**2
    c_inv = np.linalg.inv(np.eye(nd) + 1.0)
    for k in range(n_epochs):
        a = az + rate[:, 0] * k * dt_s
        e = el + rate[:, 1] * k * dt_s
        los = np.stack([np.cos(e) * np.sin(a), np.cos(e) * np.cos(a), np.sin(e)], axis=1)
        g = -(los[1:] - los[0])
        for f in range(n_freq):
            phase = np.zeros((nd, 3 + n))
            phase[:, :3] = g
            phase[:, 3 + f * nd:3 + (f + 1) * nd] = np.eye(nd) * WAVELENGTHS_M[f]
            code = np.zeros((nd, 3 + n))
            code[:, :3] = g
            normal += phase.T @ c_inv @ phase / (2 * sigma_phase_m**2)
            normal += code.T @ c_inv @ code / (2 * sigma_code_m**2)
    q = np.linalg.inv(normal)[3:, 3:]
    q = 0.5 * (q + q.T)
    truth = rng.integers(-offset, offset, n).astype(float) if offset else np.zeros(n)
    return truth + np.linalg.cholesky(q) @ rng.normal(size=n), q, truth


def geometry_covariance(rng, n, pos_sigma_m=0.15, amb_sigma_cyc=0.05):
    """Correlated covariance (cycles^2) from a random DD geometry: J P J^T / lambda^2 + noise."""
    los = rng.normal(size=(n + 1, 3))
    los /= np.linalg.norm(los, axis=1)[:, None]
    j = (los[1:] - los[0]) / WAVELENGTHS_M[0]
    a = rng.normal(size=(3, 3)) * pos_sigma_m
    return j @ (a @ a.T) @ j.T + amb_sigma_cyc**2 * (np.eye(n) + 1.0)


def exhaustive_best(a, q, radius2):
    """All integer vectors with squared norm <= radius2, by brute force over the bounding box."""
    q_inv = np.linalg.inv(q)
    half = np.sqrt(radius2 * np.diag(q))
    ranges = [np.arange(np.ceil(ai - hi), np.floor(ai + hi) + 1) for ai, hi in zip(a, half)]
    assert np.prod([len(r) for r in ranges]) < 3_000_000, "box too large for the brute force"
    grid = np.array(list(itertools.product(*ranges)), dtype=float)
    d = grid - a
    norms = np.einsum("ij,jk,ik->i", d, q_inv, d)
    order = np.argsort(norms)
    keep = order[norms[order] <= radius2]
    return grid[keep].astype(np.int64), norms[keep]


# ---------------------------------------------------------------------------------------------------
# exhaustive search


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_matches_exhaustive_search(n):
    rng = np.random.default_rng(100 + n)
    tested = 0
    while tested < 25:
        q = geometry_covariance(rng, n)
        a = rng.normal(size=n) * 5.0
        res = mlambda_search(a, q, 2)
        # brute force over the box holding every integer vector with a norm up to our second-best:
        # it must find nothing better, and the two best must be ours
        radius2 = res.squared_norms[1] * (1 + 1e-9) + 1e-12
        if np.prod(2 * np.sqrt(radius2 * np.diag(q)) + 1) > 2_000_000:
            continue  # too large a box for a brute force: draw another problem
        grid, norms = exhaustive_best(a, q, radius2)
        assert len(grid) >= 2
        np.testing.assert_array_equal(res.candidates, grid[:2])
        np.testing.assert_allclose(res.squared_norms, norms[:2], rtol=1e-9)
        assert res.ratio == pytest.approx(norms[1] / norms[0])
        tested += 1


def test_more_candidates_match_exhaustive_search():
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = geometry_covariance(rng, 4)
        a = rng.normal(size=4) * 3.0
        res = mlambda_search(a, q, 6)
        grid, norms = exhaustive_best(a, q, res.squared_norms[-1] * (1 + 1e-9) + 1e-12)
        np.testing.assert_array_equal(res.candidates, grid[:6])
        np.testing.assert_allclose(res.squared_norms, norms[:6], rtol=1e-9)
        assert np.all(np.diff(res.squared_norms) >= 0)


@pytest.mark.parametrize("ordering", ["sorted", "min-pivot", "none"])
def test_orderings_give_the_same_solution(ordering):
    rng = np.random.default_rng(11)
    for n_sats in (3, 6, 9, 12):
        a, q, _ = dd_float_problem(rng, n_sats, n_epochs=2)
        ref = mlambda_search(a, q, 3, ordering="sorted")
        res = mlambda_search(a, q, 3, ordering=ordering)
        np.testing.assert_array_equal(res.candidates, ref.candidates)
        np.testing.assert_allclose(res.squared_norms, ref.squared_norms, rtol=1e-9)


def test_recovers_the_true_integers_of_a_strong_float_solution():
    rng = np.random.default_rng(3)
    for n_sats in (5, 8, 11):
        a, q, truth = dd_float_problem(rng, n_sats, n_epochs=10)
        res = mlambda_search(a, q, 2)
        np.testing.assert_array_equal(res.best, truth.astype(np.int64))
        assert res.ratio > 3.0


# ---------------------------------------------------------------------------------------------------
# RTKLIB demo5 lambda()


def _rtklib_lambda(p, a, q, m=2):
    n = len(a)
    fa, qa = p.Arr1Ddouble(n), p.Arr1Ddouble(n * n)
    for i, v in enumerate(a):
        fa[i] = float(v)
    for i, v in enumerate(np.asarray(q).T.ravel()):  # column-major
        qa[i] = float(v)
    f, s = p.Arr1Ddouble(n * m), p.Arr1Ddouble(m)
    info = getattr(p, "lambda")(n, m, fa, qa, f, s)
    cands = np.rint(np.array(list(f)).reshape(m, n)).astype(np.int64)
    return info, cands, np.array(list(s))


def test_matches_rtklib_lambda():
    p = pytest.importorskip("pyrtklib5")
    rng = np.random.default_rng(2024)
    compared = 0
    for n_sats in (2, 3, 4, 6, 9, 11, 16):
        for k in range(12):
            a, q, truth = dd_float_problem(rng, n_sats, n_epochs=(1, 2, 5)[k % 3])
            a = a - truth + rng.integers(-50, 50, len(a))  # RTKLIB works on the raw values
            info, cands, norms = _rtklib_lambda(p, a, q)
            if info != 0:  # RTKLIB gives up after 10000 search loops
                continue
            res = mlambda_search(a, q, 2)
            np.testing.assert_array_equal(res.candidates, cands)
            np.testing.assert_allclose(res.squared_norms, norms, rtol=1e-8)
            compared += 1
    assert compared >= 70


# ---------------------------------------------------------------------------------------------------
# structure: LTDL, invariance, edge cases


def test_ltdl_with_minimum_pivoting():
    rng = np.random.default_rng(5)
    for n in (1, 2, 5, 12):
        q = geometry_covariance(rng, n) if n > 1 else np.array([[0.3]])
        for pivot in (True, False):
            lmat, d, perm = ltdl_decompose(q, pivot=pivot)
            np.testing.assert_allclose(q[np.ix_(perm, perm)], lmat.T @ np.diag(d) @ lmat, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(np.diag(lmat), 1.0)
            assert np.all(np.triu(lmat, 1) == 0)
            assert np.all(d > 0)
        lmat, d, perm = ltdl_decompose(q, pivot=True)
        assert d[-1] == pytest.approx(np.min(np.diag(q)))  # the first pivot is the smallest variance


def test_invariant_under_unimodular_transformation():
    """Searching (Z^T a, Z^T Q Z) gives Z^T times the solutions of (a, Q), with the same norms."""
    rng = np.random.default_rng(8)
    for n in (3, 5, 8):
        q = geometry_covariance(rng, n)
        a = rng.normal(size=n) * 4.0
        z = np.eye(n, dtype=np.int64)
        for _ in range(n):  # random product of integer Gauss transformations and swaps
            i, j = rng.choice(n, 2, replace=False)
            z[:, j] += rng.choice([-1, 1]) * z[:, i]
            if rng.random() < 0.3:
                z[:, [i, j]] = z[:, [j, i]]
        assert abs(round(np.linalg.det(z))) == 1
        ref = mlambda_search(a, q, 3)
        res = mlambda_search(z.T @ a, z.T @ q @ z, 3)
        np.testing.assert_array_equal(res.candidates, ref.candidates @ z)
        # Z^T Q Z is formed with rounding errors of order |Z|^2 |Q| eps
        np.testing.assert_allclose(res.squared_norms, ref.squared_norms, rtol=1e-6)


def test_identity_covariance_is_rounding():
    a = np.array([0.2, -1.45, 3.9, 10.01])
    res = mlambda_search(a, np.eye(4), 3)
    np.testing.assert_array_equal(res.candidates[0], [0, -1, 4, 10])
    # next best: move the coordinate whose fraction is nearest one half (-1.45 -> -2), then 0.2 -> 1
    np.testing.assert_array_equal(res.candidates[1], [0, -2, 4, 10])
    np.testing.assert_array_equal(res.candidates[2], [1, -1, 4, 10])
    r0 = 0.2**2 + 0.45**2 + 0.1**2 + 0.01**2
    np.testing.assert_allclose(res.squared_norms, [r0, r0 - 0.45**2 + 0.55**2, r0 - 0.2**2 + 0.8**2])


def test_diagonal_covariance_already_decorrelated():
    var = np.array([0.01, 0.5, 2.0])
    a = np.array([2.3, -0.6, 7.4])
    res = mlambda_search(a, np.diag(var), 2)
    np.testing.assert_array_equal(res.best, [2, -1, 7])
    alt = [(0.7**2 - 0.3**2) / 0.01, (0.6**2 - 0.4**2) / 0.5, (0.6**2 - 0.4**2) / 2.0]
    best = np.sum((a - [2, -1, 7]) ** 2 / var)
    assert res.squared_norms[1] == pytest.approx(best + min(alt))
    np.testing.assert_array_equal(res.candidates[1], [2, -1, 8])


def test_integer_float_vector_has_zero_norm_and_infinite_ratio():
    q = geometry_covariance(np.random.default_rng(1), 4)
    res = mlambda_search(np.array([3.0, -2.0, 0.0, 17.0]), q, 2)
    np.testing.assert_array_equal(res.best, [3, -2, 0, 17])
    assert res.squared_norms[0] == 0.0
    assert res.ratio == np.inf and ratio_test_passes(res, 3.0)


def test_large_ambiguities_keep_their_precision():
    rng = np.random.default_rng(4)
    a, q, truth = dd_float_problem(rng, 7, offset=0)
    big = rng.integers(-10**8, 10**8, len(a))  # float64 keeps ~1e-8 cycles at 1e8
    ref = mlambda_search(a, q, 2)
    res = mlambda_search(a + big, q, 2)
    np.testing.assert_array_equal(res.candidates, ref.candidates + big)
    np.testing.assert_allclose(res.squared_norms, ref.squared_norms, rtol=1e-5)


def test_single_ambiguity():
    res = mlambda_search(np.array([4.3]), np.array([[0.04]]), 3)
    np.testing.assert_array_equal(res.candidates[:, 0], [4, 5, 3])
    np.testing.assert_allclose(res.squared_norms, np.array([0.3, 0.7, 1.3]) ** 2 / 0.04)
    assert isinstance(res, LambdaResult)
    assert res.candidates.dtype == np.int64 and res.candidates.shape == (3, 1)


def test_bad_input_raises_clear_errors():
    q = np.array([[1.0, 2.0], [2.0, 1.0]])  # indefinite
    with pytest.raises(ValueError, match="positive definite"):
        mlambda_search(np.zeros(2), q)
    with pytest.raises(ValueError, match="positive definite"):
        mlambda_search(np.zeros(2), np.array([[1.0, 1.0], [1.0, 1.0]]))  # singular
    with pytest.raises(ValueError, match="positive definite"):
        ltdl_decompose(q, pivot=True)
    with pytest.raises(ValueError, match="symmetric"):
        mlambda_search(np.zeros(2), np.array([[1.0, 0.5], [0.1, 1.0]]))
    with pytest.raises(ValueError, match="NaN"):
        mlambda_search(np.array([np.nan, 0.0]), np.eye(2))
    with pytest.raises(ValueError, match="shape"):
        mlambda_search(np.zeros(3), np.eye(2))
    with pytest.raises(ValueError, match="non-empty"):
        mlambda_search(np.zeros(0), np.zeros((0, 0)))
    with pytest.raises(ValueError, match="n_candidates"):
        mlambda_search(np.zeros(2), np.eye(2), 0)


def test_search_limit():
    a, q, _ = dd_float_problem(np.random.default_rng(9), 11, n_epochs=1)
    with pytest.raises(SearchLimitError):
        mlambda_search(a, q, 2, max_nodes=3)


def test_ratio_test():
    res = LambdaResult(np.zeros((2, 3), dtype=np.int64), np.array([1.0, 3.5]), 3.5)
    assert ratio_test_passes(res, 3.0)
    assert not ratio_test_passes(res, 4.0)
    with pytest.raises(ValueError):
        ratio_test_passes(LambdaResult(np.zeros((1, 3), dtype=np.int64), np.array([1.0]), np.inf), 3.0)


# ---------------------------------------------------------------------------------------------------
# partial ambiguity resolution


def _problem_with_weak_members(rng, n_good=6, weak=(2, 5)):
    """Precise ambiguities near integers plus a few hopeless ones (variance 1 cycle^2, fraction 0.5)."""
    n = n_good + len(weak)
    q = geometry_covariance(rng, n, pos_sigma_m=0.002, amb_sigma_cyc=0.02)
    truth = rng.integers(-100, 100, n)
    a = truth + np.linalg.cholesky(q) @ rng.normal(size=n) * 0.5
    for w in weak:
        q[w, :] *= 20.0
        q[:, w] *= 20.0
        a[w] = truth[w] + 0.5
    return a, q, truth


def test_partial_fix_drops_the_worst_first_until_the_ratio_passes():
    rng = np.random.default_rng(21)
    a, q, truth = _problem_with_weak_members(rng)
    full = mlambda_search(a, q, 2)
    assert not ratio_test_passes(full, 3.0)
    elevation = np.full(len(a), 0.8)
    elevation[5] = 0.10  # lowest: dropped first
    elevation[2] = 0.15
    elevation[0] = 0.20
    res = partial_fix_subset(a, q, elevation, 3.0, 4)
    assert res.fixed
    np.testing.assert_array_equal(res.dropped, [5, 2])
    np.testing.assert_array_equal(res.kept, [0, 1, 3, 4, 6, 7])
    np.testing.assert_array_equal(res.fixed_ambiguities(), truth[res.kept])
    # ordering by variance (largest dropped first) finds the same subset
    by_var = partial_fix_subset(a, q, -np.diag(q), 3.0, 4)
    assert by_var.fixed and set(by_var.dropped.tolist()) == {2, 5}


def test_partial_fix_passes_at_once_and_respects_min_ambiguities():
    rng = np.random.default_rng(22)
    a, q, truth = dd_float_problem(rng, 8, n_epochs=10)
    res = partial_fix_subset(a, q, np.arange(len(a)), 3.0, 4)
    assert res.fixed and res.dropped.size == 0
    np.testing.assert_array_equal(res.fixed_ambiguities(), truth.astype(np.int64))

    a, q, _ = _problem_with_weak_members(np.random.default_rng(23))
    res = partial_fix_subset(a, q, np.zeros(len(a)), 3.0, len(a))  # no drop allowed
    assert not res.fixed and res.dropped.size == 0 and res.kept.size == len(a)
    assert res.fixed_ambiguities().size == 0
    res = partial_fix_subset(a, q, np.zeros(len(a)), 1e9, 5)  # never passes
    assert not res.fixed and res.kept.size == 5
    np.testing.assert_array_equal(res.dropped, [0, 1, 2])  # ties: lower index first


# ---------------------------------------------------------------------------------------------------
# timing


def _best_time(fn, repeats):
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def test_timing_realistic_problems():
    """Dual-frequency DD float solutions: 11 satellites (n = 20) and 21 satellites (n = 40)."""
    rng = np.random.default_rng(31)
    lines = []
    for n_sats, n_epochs in ((11, 10), (11, 1), (21, 10)):
        times = []
        for _ in range(5):
            a, q, truth = dd_float_problem(rng, n_sats, n_epochs=n_epochs)
            res = mlambda_search(a, q, 2)
            if n_epochs > 1:
                np.testing.assert_array_equal(res.best, truth.astype(np.int64))
            times.append(_best_time(lambda: mlambda_search(a, q, 2), 7))
        lines.append(f"n={len(a)} ({n_epochs} epochs): median {np.median(times) * 1e3:.2f} ms, "
                     f"max {np.max(times) * 1e3:.2f} ms")
        assert np.median(times) < 0.1  # generous: a loaded CI machine must not fail on timing
    print("\nmlambda_search timing: " + "; ".join(lines))


def test_full_size_reduction_gives_the_same_solution(monkeypatch):
    """Forcing the (normally rare) size reduction of L changes nothing in the result."""
    import georef_core.gnss.lambda_search as ls

    rng = np.random.default_rng(12)
    problems = [dd_float_problem(rng, n_sats, n_epochs=ep) for n_sats, ep in ((4, 1), (8, 2), (11, 1), (16, 5))]
    refs = [mlambda_search(a, q, 3) for a, q, _ in problems]
    monkeypatch.setattr(ls, "_GROWTH_LIMIT", 0.0)
    monkeypatch.setattr(ls, "_GROWTH_LIMIT_LOOP", 0.0)
    for (a, q, _), ref in zip(problems, refs):
        res = mlambda_search(a, q, 3)
        np.testing.assert_array_equal(res.candidates, ref.candidates)
        np.testing.assert_allclose(res.squared_norms, ref.squared_norms, rtol=1e-9)
