"""The noise-model arithmetic: the block/Toeplitz variance of a weighted sum equals the brute-force double
sum over cells; defaults and dense_summary.json are read as documented."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.volumes.uncertainty import (DEFAULT_SIGMA_Z_M, NoiseModel, correlated_sum_sigma,
                                             smoothed_profile_sigma)


def _brute(w_cells, cell, sigma, L):
    ii, jj = np.nonzero(np.ones_like(w_cells))
    x, y, w = jj * cell, ii * cell, w_cells[ii, jj] * cell * cell
    d2 = (x[:, None] - x[None, :]) ** 2 + (y[:, None] - y[None, :]) ** 2
    rho = (d2 == 0).astype(float) if L == 0 else np.exp(-d2 / L ** 2)
    return sigma * np.sqrt(w @ rho @ w)


@pytest.mark.parametrize("L", [0.0, 0.3, 1.5])
def test_block_sum_matches_brute_force(L):
    rng = np.random.default_rng(1)
    cell = 0.1
    w = (rng.uniform(size=(24, 30)) > 0.2).astype(float) * rng.uniform(0.5, 1.0, size=(24, 30))
    exact = _brute(w, cell, 0.05, L)
    s1 = correlated_sum_sigma(w * cell * cell, 1, cell, -cell, 0.05, L, exact=True)
    assert s1 == pytest.approx(exact, rel=1e-9)
    # blocks of 3 x 3 cells: exact when the weight is uniform within each block
    wb = np.kron(rng.uniform(0.2, 1.0, size=(8, 10)), np.ones((3, 3)))
    exact_b = _brute(wb, cell, 0.05, L)
    coarse = wb.reshape(8, 3, 10, 3).sum(axis=(1, 3)) * cell * cell
    assert correlated_sum_sigma(coarse, 3, cell, -cell, 0.05, L, exact=True) == pytest.approx(exact_b, rel=1e-9)


def test_merged_blocks_are_close_to_exact():
    """The default merges blocks up to about L/2 when the correlation is long: within 2 % of the exact sum
    on a disc of 240 x 240 cells."""
    cell, L = 0.05, 2.0
    yy, xx = np.mgrid[0:240, 0:240]
    w = (np.hypot(xx - 119.5, yy - 119.5) < 110).astype(float) * cell * cell
    exact = correlated_sum_sigma(w, 1, cell, -cell, 0.05, L, exact=True)
    fast = correlated_sum_sigma(w, 1, cell, -cell, 0.05, L)
    assert fast == pytest.approx(exact, rel=0.02)


def test_smoothed_profile_sigma_limits():
    # independent samples: the running median of n samples reduces sigma by about sqrt(pi/2 / n)
    s = smoothed_profile_sigma(0.05, 0.0, 0.1, 1.0)
    assert s == pytest.approx(0.05 * np.sqrt(np.pi / 2 / 11), rel=1e-9)
    # correlation much longer than the window: no reduction (capped at sigma_z)
    assert smoothed_profile_sigma(0.05, 50.0, 0.1, 1.0) == pytest.approx(0.05)


def test_noise_model_sources(tmp_path):
    dsm = tmp_path / "dsm.tif"
    m = NoiseModel.for_dsm(dsm)
    assert m.sigma_z_m == DEFAULT_SIGMA_Z_M and m.sources["sigma_z_m"].startswith("default")
    (tmp_path / "dense_summary.json").write_text(json.dumps({"dsm_vertical_rmse_m": 0.031, "dsm_height_bias_m": -0.012}))
    m = NoiseModel.for_dsm(dsm, correlation_length_m=2.0)
    assert (m.sigma_z_m, m.height_bias_m, m.correlation_length_m) == (0.031, -0.012, 2.0)
    assert m.sources["sigma_z_m"] == "dense_summary.json: dsm_vertical_rmse_m"
    assert m.sources["correlation_length_m"] == "given"
    assert NoiseModel.from_dict(m.to_dict()) == m
