"""Navigation-grade EXIF GPS heights checked against the block, and the block levelled when they drift.

A consumer drone's (or camera's) EXIF altitude is often barometric and drifts during a flight (tens of
metres over a battery are common). On a serpentine flight a height drift in time is nearly inseparable from
a tilt of the block about the along-track axis: an adjustment that trusts the heights at their stated sigma
fits the drift with a tilt (observed: 43 degrees on a 75-photo block whose EXIF heights drift by ~110 m).

The check (``check_exif_heights``), before the adjustment, on the SfM block and the EXIF positions:

1. a 7-parameter similarity of the SfM camera centres onto the EXIF positions: the tilt it implies (the
   angle of the cameras' mean optical axis from nadir) and the vertical variance factor of its residuals
   against the stated vertical sigma;
2. the same block levelled on a stated assumption - the cameras' mean optical axis is nadir, 1 sigma
   ``NADIR_SIGMA_DEG`` (a mapping flight with a nadir gimbal or a nadir-fixed camera; an assumption, not a
   measured figure) - with horizontal rotation, scale and position from the EXIF positions (2-D similarity);
3. the EXIF heights minus the levelled block's heights regressed on time (offset + rate): the drift rate's
   t-test (ordinary least squares, the residual scatter estimated). The heights are called inconsistent
   with the block when the drift is significant (p < ``DRIFT_P_VALUE``, fixed in advance) and the drift over
   the flight exceeds their stated vertical sigma (so the adjustment's weighting of them is wrong).

When they are inconsistent the heights given to the adjustment are those of the levelled block, placed at
the EXIF heights' level at the flight's mean time (the offset of the offset + rate fit: the drift removed,
the block's absolute height still the EXIF one), weighted at the larger of their stated sigma and the robust
scatter (1.4826 MAD) left after the drift; the horizontal positions (the same receiver) at the larger of their
stated sigma and the robust scatter of the levelled block's horizontal residuals. The EXIF heights' own scatter would otherwise tilt a small block by
several degrees again (metres of noise over lines tens of metres apart); the block comes out level to the
assumption's sigma, with horizontal position and scale still from EXIF.
"""

from __future__ import annotations

import math

import numpy as np

from .align import fit_similarity

NADIR_SIGMA_DEG = 3.0     # assumed 1 sigma of the block's mean optical axis from nadir (mapping flight)
DRIFT_P_VALUE = 0.01      # significance level of the height drift's t-test (fixed in advance)


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector a onto unit vector b (Rodrigues)."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = math.atan2(s, c)
    return np.eye(3) + math.sin(ang) * k + (1 - math.cos(ang)) * k @ k


def _tilt_deg(axis_enu: np.ndarray) -> float:
    a = axis_enu / np.linalg.norm(axis_enu)
    return math.degrees(math.acos(float(np.clip(-a[2], -1.0, 1.0))))


def block_tilt_deg(centre_enu_m: np.ndarray) -> float:
    """The angle of the camera centres' best-fitting plane (least squares in 3-D) from level, degrees."""
    c = np.asarray(centre_enu_m, float)
    _, _, vt = np.linalg.svd(c - c.mean(axis=0))
    n = vt[2]
    return math.degrees(math.acos(min(1.0, abs(float(n[2])))))


def check_exif_heights(centre_sfm: np.ndarray, axis_sfm: np.ndarray, exif_enu_m: np.ndarray, time_s: np.ndarray,
                       sigma_v_m: float, time_source: str = "EXIF times", sigma_h_m: float | None = None) -> dict:
    """The check above. ``centre_sfm`` / ``axis_sfm``: (N, 3) camera centres and optical axes (unit, +z of
    the camera) in the SfM frame; ``exif_enu_m`` (N, 3) the EXIF positions in local ENU; ``time_s`` (N,)
    exposure times (any origin); ``sigma_v_m`` their stated vertical sigma. Returns a dict (the summary's
    ``exif_heights``) with ``inconsistent``, the statistics, and when inconsistent ``height_enu_m`` (N,) and
    ``sigma_v_m`` to give the adjustment, ``level_sigma_deg`` and a ``text``."""
    C = np.asarray(centre_sfm, float).reshape(-1, 3)
    A = np.asarray(axis_sfm, float).reshape(-1, 3)
    X = np.asarray(exif_enu_m, float).reshape(-1, 3)
    t = np.asarray(time_s, float).reshape(-1)
    n = len(C)
    if n < 6 or not np.all(np.isfinite(t)) or np.ptp(t) <= 0:
        return {"inconsistent": False, "text": f"EXIF heights: not checked ({n} photos with positions and times; "
                                                "6 with distinct times needed)"}
    # 1. the 7-parameter similarity onto the EXIF positions
    sim7, res7 = fit_similarity(C, X)
    A_unit = A / np.linalg.norm(A, axis=1, keepdims=True)
    mean_axis = A_unit.mean(axis=0)
    axis7 = sim7.R @ mean_axis
    tilt7 = _tilt_deg(axis7)
    dof7 = max(1, n - 3)   # the vertical residuals' share of the 7 parameters' 3N - 7 degrees of freedom, roughly
    vf7 = float(np.sum(res7[:, 2] ** 2) / sigma_v_m ** 2 / dof7)
    # 2. levelled on the mean optical axis (nadir), horizontal from a 2-D similarity onto the EXIF positions
    R_lev = _rotation_onto(axis7, np.array([0.0, 0.0, -1.0])) @ sim7.R
    P = sim7.scale * C @ R_lev.T
    ph, xh = P[:, :2] - P[:, :2].mean(axis=0), X[:, :2] - X[:, :2].mean(axis=0)
    zp, zx = ph[:, 0] + 1j * ph[:, 1], xh[:, 0] + 1j * xh[:, 1]
    w = np.vdot(zp, zx) / np.vdot(zp, zp)              # complex scale x rotation (least squares)
    s2, yaw = abs(w), float(np.angle(w))
    eh = xh - np.column_stack([(w * zp).real, (w * zp).imag])      # horizontal residuals of the levelled block
    Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1.0]])
    R = Rz @ R_lev
    z_block = s2 * sim7.scale * (C @ R.T)[:, 2]
    # 3. the EXIF heights minus the levelled block's, on time: offset + rate, t-test of the rate
    d = X[:, 2] - z_block
    tm = float(t.mean())
    dt = t - tm
    G = np.column_stack([np.ones(n), dt])
    coef, *_ = np.linalg.lstsq(G, d, rcond=None)
    e = d - G @ coef
    s_e = float(np.sqrt(np.sum(e ** 2) / (n - 2)))
    se_b = s_e / math.sqrt(float(np.sum(dt ** 2)))
    rate = float(coef[1])
    t_stat = rate / se_b if se_b > 0 else math.inf
    from scipy import stats

    p = float(2 * stats.t.sf(abs(t_stat), n - 2))
    duration_s = float(np.ptp(t))
    drift_m = rate * duration_s
    inconsistent = bool(p < DRIFT_P_VALUE and abs(drift_m) > sigma_v_m)
    axis_scatter_deg = math.degrees(float(np.sqrt(np.mean(np.sum((A_unit - mean_axis) ** 2, axis=1))))) / math.sqrt(n)
    out = {"inconsistent": inconsistent, "n": n, "time_source": time_source,
           "similarity_tilt_deg": round(tilt7, 2), "vertical_variance_factor": round(vf7, 2),
           "stated_sigma_v_m": sigma_v_m,
           "drift_m": round(drift_m, 2), "duration_min": round(duration_s / 60, 2), "drift_sigma_m": round(se_b * duration_s, 2),
           "t": round(t_stat, 2) if math.isfinite(t_stat) else None, "p_value": float(f"{p:.3g}"),
           "residual_sd_after_drift_m": round(s_e, 2), "p_level": DRIFT_P_VALUE}
    stat = (f"drift {drift_m:+.1f} m over {duration_s / 60:.1f} min ({time_source}; sigma "
            f"{se_b * duration_s:.1f} m, t = {t_stat:.1f}, p = {p:.2g})")
    if not inconsistent:
        out["text"] = (f"EXIF heights consistent with the block at their stated {sigma_v_m:g} m: {stat}; the block is "
                       f"levelled by them (a similarity onto them tilts it {tilt7:.1f} deg from a nadir mean axis)")
        return out
    mad = float(np.median(np.abs(e - np.median(e))))
    sigma_new = max(sigma_v_m, 1.4826 * mad)
    if sigma_h_m is not None:   # the same receiver's horizontal sigma: raised to its robust scatter where larger
        eh_c = eh.reshape(-1)
        sigma_h_new = max(sigma_h_m, 1.4826 * float(np.median(np.abs(eh_c - np.median(eh_c)))))
        out["sigma_h_m"] = round(sigma_h_new, 2)
    level_sigma = math.hypot(NADIR_SIGMA_DEG, axis_scatter_deg)
    out.update(height_enu_m=z_block + float(coef[0]), sigma_v_m=round(sigma_new, 2),
               level_sigma_deg=round(level_sigma, 2), assumption=(
                   f"the cameras' mean optical axis is nadir (1 sigma {NADIR_SIGMA_DEG:g} deg, an assumption for a "
                   f"mapping flight; {axis_scatter_deg:.2f} deg from the axes' scatter)"))
    hz = f" (weighted at {out['sigma_h_m']:g} m, their scatter about the levelled block)" if "sigma_h_m" in out else ""
    out["text"] = (f"EXIF heights inconsistent with the block ({stat}): held at their stated {sigma_v_m:g} m they "
                   f"would tilt it {tilt7:.1f} deg. The block is levelled instead on the assumption that the cameras' "
                   f"mean optical axis is nadir (tilt sigma {level_sigma:.1f} deg); the heights' drift is removed "
                   f"(rate {rate * 60:+.2f} m/min) and only their mean level is kept (weighted at {sigma_new:.1f} m); horizontal position "
                   f"and scale still from the EXIF GPS{hz}. Volumes and the DSM's slope rest on that assumption: "
                   f"control points or RTK/PPK positions remove it")
    return out
