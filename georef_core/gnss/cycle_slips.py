"""Cycle-slip detection on one receiver's carrier phases, as flags 'a slip happened between the previous
observation of this signal and this epoch' (slip_into[e, s, b]). Detectors: loss-of-lock indicator,
geometry-free phase combination jump (two bands), and phase change versus integrated Doppler."""

from __future__ import annotations

import warnings

import numpy as np


def lli_slips(lli: np.ndarray, phase_cyc: np.ndarray | None = None) -> np.ndarray:
    """LLI bit 0 = lost lock since the previous epoch. With the phases (same shape), also every change of
    bit 1 (half-cycle ambiguity unresolved) between consecutive observations of a signal: the receiver
    shifts the phase by half a cycle when it resolves the ambiguity (u-blox), so either transition breaks
    the phase arc (as in RTKLIB)."""
    slips = (lli & 1).astype(bool)
    if phase_cyc is not None:
        slips |= half_cycle_transitions(lli, ~np.isnan(phase_cyc))
    return slips


def half_cycle_transitions(lli: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(E, ...) bool: LLI bit 1 differs from the signal's previous valid observation (axis 0)."""
    half = (lli & 2).astype(bool)
    flat_valid = valid.reshape(valid.shape[0], -1)
    flat_half = half.reshape(half.shape[0], -1)
    prev = _previous_valid_index(flat_valid)
    out = np.zeros(flat_valid.shape, dtype=bool)
    e_i, c_i = np.nonzero(flat_valid & (prev >= 0))
    out[e_i, c_i] = flat_half[e_i, c_i] != flat_half[prev[e_i, c_i], c_i]
    return out.reshape(valid.shape)


def _previous_valid_index(valid: np.ndarray) -> np.ndarray:
    """For each epoch and column, the index of the previous epoch where valid, else -1 (axis 0)."""
    idx = np.where(valid, np.arange(valid.shape[0])[:, None], -1)
    prev = np.maximum.accumulate(idx, axis=0)
    out = np.full_like(prev, -1)
    out[1:] = prev[:-1]
    return out


def geometry_free_slips(phase_cyc: np.ndarray, lam: np.ndarray, threshold_m: float) -> np.ndarray:
    """Jump of L1 - L2 (m) between consecutive observations of a satellite beyond threshold_m.
    phase_cyc (E, S, F); lam (S, F). Flags both bands (the combination cannot tell which slipped)."""
    n_e, n_s, n_f = phase_cyc.shape
    out = np.zeros((n_e, n_s, n_f), dtype=bool)
    if n_f < 2 or threshold_m <= 0:
        return out
    gf = phase_cyc[..., 0] * lam[None, :, 0] - phase_cyc[..., 1] * lam[None, :, 1]
    valid = ~np.isnan(gf)
    prev = _previous_valid_index(valid)
    e_i, s_i = np.nonzero(valid & (prev >= 0))
    jump = np.abs(gf[e_i, s_i] - gf[prev[e_i, s_i], s_i]) > threshold_m
    out[e_i[jump], s_i[jump], :2] = True
    return out


def doppler_slips(phase_cyc: np.ndarray, doppler_hz: np.ndarray, time_s: np.ndarray, threshold_cyc: float) -> np.ndarray:
    """|delta phase + mean Doppler * dt| beyond threshold after removing the epoch's median over satellites
    (the receiver clock drift is common to all). RINEX sign convention: phase grows as Doppler is negative."""
    n_e, n_s, n_f = phase_cyc.shape
    out = np.zeros(phase_cyc.shape, dtype=bool)
    if threshold_cyc <= 0 or n_e < 2:
        return out
    for b in range(n_f):
        ph, dp = phase_cyc[..., b], doppler_hz[..., b]
        valid = ~np.isnan(ph) & ~np.isnan(dp)
        prev = _previous_valid_index(valid)
        d = np.full((n_e, n_s), np.nan)
        e_i, s_i = np.nonzero(valid & (prev >= 0))
        p_i = prev[e_i, s_i]
        dt = time_s[e_i] - time_s[p_i]
        d[e_i, s_i] = (ph[e_i, s_i] - ph[p_i, s_i]) + 0.5 * (dp[e_i, s_i] + dp[p_i, s_i]) * dt
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # epochs without any pair: all-NaN rows
            med = np.nanmedian(d, axis=1, keepdims=True)
        res = np.abs(d - med)
        out[..., b] = np.nan_to_num(res, nan=0.0) > threshold_cyc
    return out
