"""Uncertainty of a volume (± m^3, 1 sigma and 95 %) and the DSM error model behind it.

DSM error model: the height error of a cell is e = b + n(x, y), with

* ``b`` a vertical bias common to the whole survey (``height_bias_m``: the check-point mean dz);
* ``n`` a random, spatially correlated field: standard deviation ``sigma_z_m`` per cell and
  correlation rho(d) = exp(-(d / L)^2) between cells d apart (``correlation_length_m`` L; L = 0 is
  uncorrelated cell noise). Photogrammetric DSM errors are correlated over the matching window and
  the surface smoothing (decimetres to metres), so L defaults to 1 m.

A volume is a linear functional of the heights, V = sum_i u_i z_i (u_i: cell area x coverage over the
polygon, minus each outline sample's weight in the base), so

    Var_noise(V) = sigma_z^2 * sum_ij u_i u_j rho(d_ij),

computed on the coverage summed over square blocks of ``block`` cells (grid at most 512 blocks a
side). The Gaussian correlation is separable, so the double sum is trace(U^T R_y U R_x) with Toeplitz
matrices of the mean block-to-block correlation (exact averages over the cells of two blocks; for
L << block it reduces to the per-cell sum of independent errors).

The components reported (1 sigma, m^3), combined in quadrature:

* ``dsm_noise_m3``: the random field above through the surface and (linear outline bases) the base;
* ``base_m3``: the base's own error where not in the above: percentile bases (lowest/highest) take
  A x sigma_s x sqrt(1 + z_p^2), sigma_s the noise left after the running median along the outline
  and z_p the normal quantile of the percentile (the noise pushes a low percentile down); an
  imported or locked base takes A x its sigma (or the random field of another DSM);
* ``height_bias_m3``: |b| x A where the base is independent of the DSM (elevation, surface, locked);
  an outline base moves with the DSM, so a vertical bias cancels and this term is 0;
* ``base_model_m3``: the spread (standard deviation) of the nets of the three outline interpolators
  mean, plane and TIN: how well the outline defines the ground (0 for elevation/surface/locked);
* ``nodata_fill_m3``: filled area x sigma_z (a floor for the interpolation of holes).

``ci95_m3`` = 1.96 sigma.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

DEFAULT_SIGMA_Z_M = 0.05
DEFAULT_HEIGHT_BIAS_M = 0.02
DEFAULT_CORRELATION_LENGTH_M = 1.0
Z95 = 1.959963984540054
MAX_COARSE = 512


@dataclass
class NoiseModel:
    """Error model of one DSM (see the module docstring); ``sources`` says where each value came from."""

    sigma_z_m: float = DEFAULT_SIGMA_Z_M
    height_bias_m: float = DEFAULT_HEIGHT_BIAS_M
    correlation_length_m: float = DEFAULT_CORRELATION_LENGTH_M
    sources: dict = field(default_factory=dict)
    # horizontal reach of the surface smoothing (matching window + cell; dense_summary.json): a toe raises
    # the DSM this far out, so outline bases sample the ground beyond it. None: unknown (1.5 cells used)
    smoothing_radius_m: float | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "NoiseModel":
        r = d.get("smoothing_radius_m")
        return cls(float(d["sigma_z_m"]), float(d["height_bias_m"]), float(d["correlation_length_m"]),
                   dict(d.get("sources", {})), float(r) if r is not None else None)

    @classmethod
    def for_dsm(cls, dsm_path, sigma_z_m: float | None = None, height_bias_m: float | None = None,
                correlation_length_m: float | None = None) -> "NoiseModel":
        """Given values first, then ``dense_summary.json`` (a DTM: ``dtm_summary.json``) next to the DSM (keys ``dsm_vertical_rmse_m``,
        ``dsm_height_bias_m`` or ``check_height_bias_m``, ``dsm_error_correlation_length_m``), then the
        defaults (5 cm, 2 cm, 1 m)."""
        summary = {}
        sp = Path(dsm_path).with_name("dense_summary.json")
        if not sp.exists() and Path(dsm_path).with_name("dtm_summary.json").exists():
            sp = Path(dsm_path).with_name("dtm_summary.json")  # a DTM: the dtm step carries the DSM's error model
        if sp.exists():
            try:
                summary = json.loads(sp.read_text())
            except (OSError, json.JSONDecodeError):
                summary = {}
        src = {}

        def pick(given, keys, default, name):
            if given is not None:
                src[name] = "given"
                return float(given)
            for k in keys:
                v = summary.get(k) if isinstance(summary, dict) else None
                if isinstance(v, (int, float)) and math.isfinite(v):
                    src[name] = f"{sp.name}: {k}"
                    return float(v)
            src[name] = "default" + ("" if sp.exists() else " (no dense_summary.json next to the DSM)")
            return default

        s = pick(sigma_z_m, ("dsm_vertical_rmse_m",), DEFAULT_SIGMA_Z_M, "sigma_z_m")
        b = pick(height_bias_m, ("dsm_height_bias_m", "check_height_bias_m"), DEFAULT_HEIGHT_BIAS_M, "height_bias_m")
        L = pick(correlation_length_m, ("dsm_error_correlation_length_m",), DEFAULT_CORRELATION_LENGTH_M,
                 "correlation_length_m")
        if s < 0 or L < 0:
            raise ValueError("DSM sigma and correlation length must be >= 0")
        r = summary.get("dsm_smoothing_radius_m") if isinstance(summary, dict) else None
        if isinstance(r, (int, float)) and math.isfinite(r) and r >= 0:
            src["smoothing_radius_m"] = f"{sp.name}: dsm_smoothing_radius_m"
            return cls(s, b, L, src, float(r))
        return cls(s, b, L, src)


def block_size_for(nrows: int, ncols: int) -> int:
    """Coarse block (cells a side) so the weight grid has at most MAX_COARSE blocks a side."""
    return max(1, -(-max(nrows, ncols) // MAX_COARSE))


def _block_correlation_1d(n: int, block: int, cell_m: float, L: float) -> np.ndarray:
    """Mean correlation, along one axis, between the cells of two blocks ``l`` blocks apart, l = 0..n-1."""
    m = np.arange(-(block - 1), block)
    tri = (block - np.abs(m)) / float(block * block)
    lag = np.arange(n)[:, None] * block + m[None, :]
    if L <= 0:
        rho = (lag == 0).astype(float)
    else:
        rho = np.exp(-((lag * cell_m / L) ** 2))
    return rho @ tri


@lru_cache(maxsize=16)
def _toeplitz_correlation(n: int, block: int, cell_m: float, L: float) -> np.ndarray:
    from scipy.linalg import toeplitz

    r = toeplitz(_block_correlation_1d(n, block, cell_m, L))
    r.setflags(write=False)
    return r


def _block_sum(U: np.ndarray, k: int) -> np.ndarray:
    ny, nx = -(-U.shape[0] // k) * k, -(-U.shape[1] // k) * k
    P = np.zeros((ny, nx))
    P[:U.shape[0], :U.shape[1]] = U
    return P.reshape(ny // k, k, nx // k, k).sum(axis=(1, 3))


def _correlated_quadratic(U: np.ndarray, block: int, dx_m: float, dy_m: float, L: float) -> float:
    """sum_IJ U_I U_J rho~(I - J) (separable): banded 1-D convolutions when the correlation dies within a few
    blocks, dense Toeplitz products otherwise."""
    from scipy.ndimage import convolve1d

    out = U
    for axis, cell in ((1, dx_m), (0, dy_m)):
        n = U.shape[axis]
        r = _block_correlation_1d(n, block, cell, L)
        k = int(np.flatnonzero(r > 1e-12 * r[0])[-1]) + 1  # lags that matter
        if k < n // 4:
            kern = np.concatenate([r[1:k][::-1], r[:k]])
            out = convolve1d(out, kern, axis=axis, mode="constant", cval=0.0)
        else:
            R = _toeplitz_correlation(n, block, cell, L)
            out = out @ R if axis == 1 else R @ out
    return float(np.sum(U * out))


def correlated_sum_sigma(weights_m2: np.ndarray, block: int, dx_m: float, dy_m: float, sigma_z_m: float,
                         correlation_length_m: float, exact: bool = False) -> float:
    """1-sigma of sum_I U_I e_I for the coarse weight grid U (m^2 per block of ``block`` cells, rows = y)
    under the model. Unless ``exact``, blocks are merged up to about L/2 (keeping at least 32 a side):
    the correlation barely changes across such a block (< 3 % between two neighbours' centres)."""
    if sigma_z_m == 0 or not np.any(weights_m2):
        return 0.0
    rows = np.flatnonzero(np.any(weights_m2 != 0, axis=1))
    cols = np.flatnonzero(np.any(weights_m2 != 0, axis=0))
    U = weights_m2[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
    L = correlation_length_m
    if not exact and L > 0:
        k = int(0.5 * L / (block * max(abs(dx_m), abs(dy_m))))
        k = min(k, max(1, min(U.shape) // 32))
        if k > 1:
            U, block = _block_sum(U, k), block * k
    q = _correlated_quadratic(U, block, abs(dx_m), abs(dy_m), L)
    return sigma_z_m * math.sqrt(max(q, 0.0))


def smoothed_profile_sigma(sigma_z_m: float, L: float, spacing_m: float, window_m: float) -> float:
    """Noise left on an outline profile after a running median over ``window_m``: the noise of the
    window mean under the correlation model, times sqrt(pi/2) (median of Gaussian samples), at most
    sigma_z."""
    n = max(2 * max(int(round(0.5 * window_m / spacing_m)), 1) + 1, 1)
    d = (np.arange(n)[:, None] - np.arange(n)[None, :]) * spacing_m
    rho = (d == 0).astype(float) if L <= 0 else np.exp(-((d / L) ** 2))
    s_mean = sigma_z_m * math.sqrt(rho.sum()) / n
    return min(sigma_z_m, s_mean * math.sqrt(math.pi / 2))


def normal_quantile(p: float) -> float:
    from scipy.special import ndtri

    return float(ndtri(p))


def combine(components: dict) -> dict:
    """1-sigma (quadrature sum of the components) and the 95 % half-width."""
    s = math.sqrt(sum(v * v for v in components.values()))
    return {"sigma_m3": s, "ci95_m3": Z95 * s}
