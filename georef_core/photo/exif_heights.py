"""Navigation-grade EXIF GPS heights checked against the block, and the block levelled when they drift.

A consumer drone's (or camera's) EXIF altitude is often barometric and drifts during a flight (tens of
metres over a battery are common). On a serpentine flight a height drift in time is nearly inseparable from
a tilt of the block about the along-track axis: an adjustment that trusts the heights at their stated sigma
fits the drift with a tilt (observed: 43 degrees on a 75-photo block whose EXIF heights drift by ~110 m).

The check (``check_exif_heights``), before the adjustment, on the SfM block and the EXIF positions:

1. a 7-parameter similarity of the SfM camera centres onto the EXIF positions: the tilt it implies (the
   angle of the cameras' mean optical axis from nadir) and the vertical variance factor of its residuals
   against the stated vertical sigma;
2. the same block levelled (with horizontal rotation, scale and position from the EXIF positions, a 2-D
   similarity) on one of:

   * the cameras' **recorded gimbal attitude** (DJI XMP ``GimbalPitchDegree`` / ``GimbalYawDegree``), where
     the photos carry one: each camera's optical axis is expected at its recorded pitch in the vertical
     plane of its recorded yaw; the rotation that best takes the SfM axes onto them (Wahba's problem, least
     squares over the unit vectors) levels the block, its yaw left free (a compass offset common to the
     photos changes nothing; the yaw comes from the EXIF positions). 1 sigma: ``GIMBAL_SIGMA_DEG`` (an
     assumption for the gimbal's horizon and the camera's mounting, not a measured figure) scaled by the
     geometry of the look directions, with the axes' own scatter about the recorded ones. Only where that
     sigma is no worse than the nadir assumption's: the recorded directions of a block whose cameras all
     look one way do not fix the tilt about that direction (the block's free yaw takes it), and the block is
     then not levelled. The recorded yaw, not only the pitch, is needed: on a serpentine the look
     directions are pairwise opposite, and pitch alone with each camera's heading free leaves the tilt about
     the lines' direction undetermined, the very tilt a drift mimics;
   * otherwise the assumption that the cameras' mean optical axis is nadir, 1 sigma ``NADIR_SIGMA_DEG`` (a
     mapping flight with a nadir gimbal or a nadir-fixed camera; an assumption, not a measured figure) -
     unless the SfM optical axes show an oblique or mixed oblique + nadir block: their RMS angle from their
     mean direction above ``OBLIQUE_AXIS_RMS_DEG`` (a nadir block's axes scatter by the body's attitude, a
     few degrees; cameras pitched 30 degrees forward on a serpentine by ~30). Such a block is levelled on
     its mean axis all the same, on the stated assumption that its look directions balance (a serpentine
     with a forward-looking camera, a multi-direction oblique pattern), and the warning says so: obliques
     that look mostly one way break it by up to their scatter (left unlevelled, a significant drift tilts
     the block by tens of degrees, 70 on the test block: the worse outcome);
   * checked, where the sparse cloud is given, against the ground (``ground_plane``): an earthworks site is
     broadly level (assumed: mean slope over the block under ``SITE_SLOPE_MAX_DEG``), so in the frame levelled on
     the mean axis the cloud's robust plane should tilt by no more than that plus the level's error. Cameras all
     looking one way (a fixed forward-tilted camera, no gimbal XMP) scatter like a nadir block's and are levelled
     their tilt wrong on the mean axis; the ground then tilts by that much. Where the ground's tilt exceeds
     ``SITE_SLOPE_MAX_DEG`` + ``GROUND_CHECK_Z`` x (the level's sigma and the plane's jackknife sigma combined),
     the block is levelled on the ground plane instead (``level_method`` ``ground-plane``, 1 sigma half the slope
     bound), and the text says so, naming the tilt;
3. the EXIF heights minus the block's heights (the levelled block's; the 7-parameter similarity's where
   the block is not levelled, which sees only the part of a drift a tilt cannot take) regressed on time,
   **per flight** (``flight``: the adjustment's flights, ``steps.georef.image_flights``: DJI flight folders
   or a gap between photos): one joint least-squares fit with an offset and a rate per flight and one
   residual variance (the same receiver on every flight; short flights borrow the others' degrees of
   freedom), and an F-test of all the rates being zero (one flight: the rate's two-sided t-test, F = t^2).
   Each flight's barometer is zeroed at its own take-off, so each has its own drift and its own level. The
   heights are called inconsistent with the block when the rates are significant (p < ``DRIFT_P_VALUE``,
   fixed in advance) and some flight's drift over that flight exceeds their stated vertical sigma (so the
   adjustment's weighting of them is wrong).

When they are inconsistent and the block is levelled, the heights given to the adjustment are those of the
levelled block placed at the EXIF heights' level: each flight's fitted level at its own mean time (the
drift removed), averaged over the photos (one flight: its offset). One level for the whole block, not each
flight's own: the SfM block is rigid, so flights placed at levels that differ by metres would be a step
the adjustment could only take up by tilting the block across flights that cover different parts of the
site; the flights' levels are reported. The heights are weighted at the larger of their stated sigma and
the robust scatter (1.4826 MAD) left after the drift; the horizontal positions (the same receiver) at the
larger of their stated sigma and the robust scatter of the levelled block's horizontal residuals. The EXIF
heights' own scatter would otherwise tilt a small block by several degrees again (metres of noise over lines
tens of metres apart); the block comes out level to the levelling's sigma, with horizontal position and scale
still from EXIF.
"""

from __future__ import annotations

import math

import numpy as np

from .align import fit_similarity

NADIR_SIGMA_DEG = 3.0     # assumed 1 sigma of the block's mean optical axis from nadir (mapping flight)
DRIFT_P_VALUE = 0.01      # significance level of the height drift's test (fixed in advance)
# assumed 1 sigma of a recorded gimbal attitude (DJI XMP) against the camera's optical axis in the level frame:
# the aircraft's horizon estimate and the camera's mounting on the gimbal (DJI states no figure)
GIMBAL_SIGMA_DEG = 1.0
# without recorded attitudes: the SfM optical axes' RMS angle from their mean direction above this is an oblique
# or mixed oblique + nadir block (a nadir block's axes: the body's attitude, a few degrees; measured in the docs)
OBLIQUE_AXIS_RMS_DEG = 10.0
# the ground check of a level taken without recorded attitudes (cameras all looking one way look like a nadir block):
# assumed bound on an earthworks site's mean ground slope over the photographed block (an assumption, not measured:
# platforms, haul roads and stockpile yards are graded to a few percent; Caliterra's real block: 5.1 deg, docs)
SITE_SLOPE_MAX_DEG = 10.0
GROUND_CHECK_Z = 2.326    # one-sided 1 % quantile of the normal: the same 0.01 level as the drift's test
# what a levelled block's level rests on, per level_method (the warning and the georef summary's accuracy text)
LEVEL_BASIS = {"gimbal": "the cameras' recorded gimbal attitudes",
               "nadir": "the assumption that the cameras' mean optical axis is nadir",
               "balanced-oblique": "the assumption that the look directions of this oblique or mixed block balance "
                                   "(their mean axis nadir)",
               "ground-plane": "the sparse cloud's ground plane, the site taken as broadly level (its mean slope under "
                               f"{SITE_SLOPE_MAX_DEG:g} deg): the cameras' mean axis, off nadir, was contradicted by the "
                               "ground"}
MIN_GIMBAL_PHOTOS = 6     # recorded attitudes are used where at least this many registered photos carry one


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


def axis_rms_deg(axis: np.ndarray) -> float:
    """The optical axes' RMS angle from their mean direction, degrees (any frame: rotation-invariant)."""
    A = np.asarray(axis, float).reshape(-1, 3)
    A = A / np.linalg.norm(A, axis=1, keepdims=True)
    m = A.mean(axis=0)
    m /= np.linalg.norm(m)
    return math.degrees(math.sqrt(float(np.mean(np.arccos(np.clip(A @ m, -1.0, 1.0)) ** 2))))


def gimbal_axis_enu(pitch_deg, yaw_deg) -> np.ndarray:
    """Unit optical axes (N, 3, ENU) of recorded gimbal attitudes: DJI's NED pitch (-90 looking straight down,
    the axis' elevation) and yaw (degrees from true north, clockwise)."""
    p, y = np.radians(np.asarray(pitch_deg, float)), np.radians(np.asarray(yaw_deg, float))
    return np.column_stack([np.cos(p) * np.sin(y), np.cos(p) * np.cos(y), np.sin(p)])


def level_on_recorded_axes(axis_model: np.ndarray, axis_expected_enu: np.ndarray) -> dict:
    """The rotation (model frame -> ENU) that best takes the unit optical axes ``axis_model`` (N, 3) onto the
    recorded ones ``axis_expected_enu`` (Wahba's problem: least squares over the unit vectors, solved by SVD), its
    yaw free, and how well it fixes the level: ``up_model`` (the model-frame direction it takes to the vertical),
    ``residual_rms_deg`` (the axes' scatter about the recorded ones, per component), ``geometry_factor`` (the
    weakest tilt direction's 1 sigma per unit angular sigma of one camera, times sqrt(N): 1 for a nadir block,
    about 1/cos of the off-nadir angle for pairwise opposite look directions, infinite for one look direction)
    and ``random_sigma_deg`` (the tilt's 1 sigma from the residual scatter)."""
    a = np.asarray(axis_model, float).reshape(-1, 3)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    e = np.asarray(axis_expected_enu, float).reshape(-1, 3)
    e = e / np.linalg.norm(e, axis=1, keepdims=True)
    m = len(a)
    U, _, Vt = np.linalg.svd(e.T @ a)
    R = U @ np.diag([1.0, 1.0, float(np.linalg.det(U @ Vt))]) @ Vt
    b = a @ R.T
    res = b - e
    s_ang = math.sqrt(float(np.sum(res ** 2)) / max(1, 2 * m - 3))
    # information of a small rotation w (ENU) from the axes: d(R a) = w x b, each axis fixing the 2 components of w
    # across itself; the tilt's (w_E, w_N) with the yaw w_U free: the Schur complement
    N = m * np.eye(3) - b.T @ b
    Ntt, ntz, nzz = N[:2, :2], N[:2, 2], float(N[2, 2])
    S = Ntt - np.outer(ntz, ntz) / nzz if nzz > 1e-9 * m else Ntt
    lam = np.linalg.eigvalsh(S)
    inv_max = math.inf if lam[0] <= 1e-9 * m else 1.0 / float(lam[0])
    return {"R_model_to_enu": R, "up_model": R.T @ np.array([0.0, 0.0, 1.0]),
            "residual_rms_deg": math.degrees(s_ang), "geometry_factor": math.sqrt(m * inv_max),
            "random_sigma_deg": math.degrees(s_ang * math.sqrt(inv_max))}


def ground_plane(points: np.ndarray, above: np.ndarray, up: np.ndarray, max_points: int = 20000) -> dict | None:
    """A robust plane through the sparse cloud ``points`` (M, 3; any frame), its normal turned towards the cameras
    ``above`` (N, 3), and its tilt from the direction ``up`` (unit, same frame) with that tilt's 1 sigma.

    The plane: total least squares (SVD) on the points left after trimming, five times, those farther from the
    plane than 2.5 robust sigmas (1.4826 MAD of the orthogonal distances): stockpiles, machines and false matches
    are not ground. Its sigma: a delete-one-cell jackknife over a 4 x 4 grid of the points' horizontal extent (the
    ground's relief is spatially correlated, so the points' formal sigma would be far too small). ``tilt_deg``: the
    normal's angle from ``up``; ``tilt_sigma_deg``: the jackknife's RMS of that angle's change (both components);
    ``normal``; ``n_points`` / ``n_inliers``; None with fewer than 30 points."""
    P = np.asarray(points, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 30:
        return None
    if len(P) > max_points:      # a fixed subsample: the same answer on every run
        P = P[np.random.default_rng(0).choice(len(P), max_points, replace=False)]
    up = np.asarray(up, float) / np.linalg.norm(up)

    def fit(Q):
        c = Q.mean(axis=0)
        n = np.linalg.svd(Q - c, full_matrices=False)[2][2]
        return c, n

    keep = np.ones(len(P), bool)
    for _ in range(5):
        c, nrm = fit(P[keep])
        r = (P - c) @ nrm
        mad = float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        new_keep = np.abs(r - np.median(r[keep])) < 2.5 * max(1.4826 * mad, 1e-9)
        if new_keep.sum() < 30 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    Q = P[keep]
    c, nrm = fit(Q)
    if float((np.asarray(above, float).reshape(-1, 3).mean(axis=0) - c) @ nrm) < 0:
        nrm = -nrm

    def tilt_vec(n):
        """The normal's small-angle offset from ``up`` in two fixed directions across it (radians)."""
        return np.array([n @ e1, n @ e2]) / max(float(n @ up), 1e-9)

    e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    # the grid on the plane's own in-plane axes
    u, v = (Q - c) @ np.cross(nrm, e2), (Q - c) @ np.cross(e1, nrm)
    iu = np.clip(((u - u.min()) / max(np.ptp(u), 1e-9) * 4).astype(int), 0, 3)
    iv = np.clip(((v - v.min()) / max(np.ptp(v), 1e-9) * 4).astype(int), 0, 3)
    cell = iu * 4 + iv
    cells = [k for k in np.unique(cell) if np.sum(cell == k) >= 3]
    sigma = math.nan
    if len(cells) >= 3:
        tv = []
        for k in cells:
            sel = cell != k
            _, nk = fit(Q[sel])
            tv.append(tilt_vec(nk if nk @ nrm > 0 else -nk))
        tv = np.array(tv)
        g = len(tv)
        sigma = math.degrees(math.sqrt((g - 1) / g * float(np.sum((tv - tv.mean(axis=0)) ** 2))))
    tilt = math.degrees(math.acos(float(np.clip(nrm @ up, -1.0, 1.0))))
    return {"tilt_deg": tilt, "tilt_sigma_deg": sigma, "normal": nrm, "n_points": int(len(P)),
            "n_inliers": int(keep.sum())}


def _drift_fit(d: np.ndarray, t: np.ndarray, flight: np.ndarray) -> dict | None:
    """Offset + rate per flight (one joint least-squares fit, one residual variance) of ``d`` on ``t``, and the
    F-test of all the rates being zero; None when there are no degrees of freedom left."""
    n = len(d)
    labels = sorted(set(flight.tolist()))
    cols_off, cols_rate, rows = [], [], []
    for f in labels:
        sel = flight == f
        tm = float(t[sel].mean())
        cols_off.append(sel.astype(float))
        rows.append({"sel": sel, "t_mean": tm, "t_first": float(t[sel].min()), "rate_col": None})
        if sel.sum() >= 3 and np.ptp(t[sel]) > 0:
            rows[-1]["rate_col"] = len(cols_rate)
            cols_rate.append(np.where(sel, t - tm, 0.0))
    k = len(cols_rate)
    dof = n - len(cols_off) - k
    if k == 0 or dof < 1:
        return None
    G0 = np.column_stack(cols_off)
    G = np.column_stack(cols_off + cols_rate)
    coef, *_ = np.linalg.lstsq(G, d, rcond=None)
    e = d - G @ coef
    rss1 = float(np.sum(e ** 2))
    c0, *_ = np.linalg.lstsq(G0, d, rcond=None)
    rss0 = float(np.sum((d - G0 @ c0) ** 2))
    s_e = math.sqrt(rss1 / dof)
    from scipy import stats

    if rss1 > 0:
        F = (rss0 - rss1) / k / (rss1 / dof)
        p = float(stats.f.sf(F, k, dof))
    else:
        F, p = math.inf, 0.0
    out_rows = []
    for j, (f, r) in enumerate(zip(labels, rows)):
        sel = r["sel"]
        dur = float(np.ptp(t[sel]))
        row = {"flight": int(f) + 1, "n": int(sel.sum()), "duration_min": round(dur / 60, 2),
               "level_m": float(coef[j]), "rate_m_s": 0.0, "rate_sigma_m_s": None,
               "first_minus_mean_s": r["t_first"] - r["t_mean"]}
        if r["rate_col"] is not None:
            sxx = float(np.sum((t[sel] - r["t_mean"]) ** 2))
            row["rate_m_s"] = float(coef[len(labels) + r["rate_col"]])
            row["rate_sigma_m_s"] = s_e / math.sqrt(sxx)
        row["duration_s"] = dur
        out_rows.append(row)
    return {"rows": out_rows, "residual": e, "s_e": s_e, "F": F, "k": k, "dof": dof, "p": p}


def check_exif_heights(centre_sfm: np.ndarray, axis_sfm: np.ndarray, exif_enu_m: np.ndarray, time_s: np.ndarray,
                       sigma_v_m: float, time_source: str = "EXIF times", sigma_h_m: float | None = None,
                       flight: np.ndarray | None = None, gimbal_pitch_deg: np.ndarray | None = None,
                       gimbal_yaw_deg: np.ndarray | None = None, level_at: str = "mean",
                       points_sfm: np.ndarray | None = None) -> dict:
    """The check above. ``centre_sfm`` / ``axis_sfm``: (N, 3) camera centres and optical axes (unit, +z of
    the camera) in the SfM frame; ``exif_enu_m`` (N, 3) the EXIF positions in local ENU; ``time_s`` (N,)
    exposure times (any origin); ``sigma_v_m`` their stated vertical sigma; ``flight`` (N,) each photo's flight
    (any labels; None: one flight); ``gimbal_pitch_deg`` / ``gimbal_yaw_deg`` (N,) the recorded gimbal attitude
    (DJI XMP; NaN where a photo has none); ``level_at`` where each flight's level is taken: ``"mean"`` its mean
    time (least scatter; a drift with no known zero, e.g. a camera's own GPS), ``"start"`` its first photo (heights
    relative to a barometer zeroed at take-off, DJI XMP ``RelativeAltitude``: the drift starts from zero there);
    ``points_sfm`` (M, 3) the sparse cloud in the SfM frame, for the ground check of a level taken without recorded
    attitudes (None: no check).
    Returns a dict (the summary's ``exif_heights``) with ``inconsistent``
    (the drift), ``levelled``, the statistics, and when levelled ``height_enu_m`` (N,) and ``sigma_v_m`` to give
    the adjustment, ``level_sigma_deg``, ``assumption`` and a ``text``."""
    C = np.asarray(centre_sfm, float).reshape(-1, 3)
    A = np.asarray(axis_sfm, float).reshape(-1, 3)
    X = np.asarray(exif_enu_m, float).reshape(-1, 3)
    t = np.asarray(time_s, float).reshape(-1)
    n = len(C)
    if level_at not in ("mean", "start"):
        raise ValueError(f"level_at must be 'mean' or 'start', not {level_at!r}")
    for name, v in (("flight", flight), ("gimbal_pitch_deg", gimbal_pitch_deg), ("gimbal_yaw_deg", gimbal_yaw_deg)):
        if v is not None and np.asarray(v).size != n:
            raise ValueError(f"{name}: {np.asarray(v).size} values for {n} photos")
    if flight is None:
        fl = np.zeros(n, int)
    else:
        _, fl = np.unique(np.asarray(flight).reshape(-1), return_inverse=True)
    if n < 6 or not np.all(np.isfinite(t)) or np.ptp(t) <= 0:
        return {"inconsistent": False, "levelled": False,
                "text": f"EXIF heights: not checked ({n} photos with positions and times; 6 with distinct times needed)"}
    # 1. the 7-parameter similarity onto the EXIF positions
    sim7, res7 = fit_similarity(C, X)
    A_unit = A / np.linalg.norm(A, axis=1, keepdims=True)
    mean_axis = A_unit.mean(axis=0)
    axis7 = sim7.R @ mean_axis
    tilt7 = _tilt_deg(axis7)
    dof7 = max(1, n - 3)   # the vertical residuals' share of the 7 parameters' 3N - 7 degrees of freedom, roughly
    vf7 = float(np.sum(res7[:, 2] ** 2) / sigma_v_m ** 2 / dof7)
    axis_scatter_deg = math.degrees(float(np.sqrt(np.mean(np.sum((A_unit - mean_axis) ** 2, axis=1))))) / math.sqrt(n)
    rms_axis = axis_rms_deg(A_unit)
    # 2. how the block is levelled: on the recorded gimbal attitudes, else on a nadir mean axis, else not at all
    pitch = np.full(n, np.nan) if gimbal_pitch_deg is None else np.asarray(gimbal_pitch_deg, float).reshape(-1)
    yaw = np.full(n, np.nan) if gimbal_yaw_deg is None else np.asarray(gimbal_yaw_deg, float).reshape(-1)
    rec = np.isfinite(pitch) & np.isfinite(yaw)
    up7, method, level_sigma, not_levelled_why, gim = None, None, None, None, None
    if rec.sum() >= MIN_GIMBAL_PHOTOS:
        gim = level_on_recorded_axes(A_unit[rec] @ sim7.R.T, gimbal_axis_enu(pitch[rec], yaw[rec]))
        level_sigma = math.hypot(GIMBAL_SIGMA_DEG * gim["geometry_factor"], gim["random_sigma_deg"])
        if level_sigma <= NADIR_SIGMA_DEG:
            up7, method = gim["up_model"], "gimbal"
        else:
            gf = gim["geometry_factor"]
            not_levelled_why = (f"the recorded gimbal attitudes of {int(rec.sum())} photos fix the block's level only to "
                                f"{level_sigma:.1f} deg (1 sigma; their look directions' geometry "
                                f"{'x ' + format(gf, '.1f') if math.isfinite(gf) else 'leaves a tilt free'}: every camera "
                                f"looking one way fixes no tilt about that direction; the SfM axes "
                                f"{gim['residual_rms_deg']:.1f} deg RMS from the recorded ones), worse than the "
                                f"{NADIR_SIGMA_DEG:g} deg of the nadir assumption")
    else:
        # on the mean axis; an oblique or mixed block with no recorded attitude too, on the stated assumption that
        # its look directions balance (a serpentine with a forward-looking camera, a five-direction oblique
        # pattern: their mean is nadir up to the body's attitude). Left unlevelled, a significant drift tilts the
        # block by tens of degrees (70 deg on the test's block); obliques looking mostly one way break the
        # assumption by up to their scatter, which the warning states
        up7, method = -axis7, ("balanced-oblique" if rms_axis > OBLIQUE_AXIS_RMS_DEG else "nadir")
        level_sigma = math.hypot(NADIR_SIGMA_DEG, axis_scatter_deg)
    # the ground check: in the frame levelled so far, the sparse cloud's robust plane should be about as level as an
    # earthworks site is (mean slope under SITE_SLOPE_MAX_DEG); without recorded attitudes a ground tilted beyond that
    # plus GROUND_CHECK_Z x the level's and the fit's sigma says the mean axis is not nadir (cameras all looking one
    # way, whose axes scatter like a nadir block's), and the block is levelled on the ground plane instead
    ground = None
    if up7 is not None and points_sfm is not None:
        u7 = up7 / np.linalg.norm(up7)
        gp = ground_plane(np.asarray(points_sfm, float).reshape(-1, 3) @ sim7.R.T, C @ sim7.R.T, u7)
        if gp is not None:
            s_g = gp["tilt_sigma_deg"]
            bound = SITE_SLOPE_MAX_DEG + GROUND_CHECK_Z * math.hypot(level_sigma, s_g if math.isfinite(s_g) else 0.0)
            ground = {"tilt_deg": round(gp["tilt_deg"], 2),
                      "tilt_sigma_deg": round(s_g, 2) if math.isfinite(s_g) else None,
                      "threshold_deg": round(bound, 2), "points": gp["n_points"], "inliers": gp["n_inliers"],
                      "of_level": method, "level_rejected": False}
            if method in ("nadir", "balanced-oblique") and math.isfinite(s_g) and gp["tilt_deg"] > bound:
                ground["level_rejected"] = True
                up7, method = gp["normal"], "ground-plane"
                level_sigma = math.hypot(SITE_SLOPE_MAX_DEG / 2, s_g)
    if up7 is not None:
        R_lev = _rotation_onto(up7, np.array([0.0, 0.0, 1.0])) @ sim7.R
        P = sim7.scale * C @ R_lev.T
        ph, xh = P[:, :2] - P[:, :2].mean(axis=0), X[:, :2] - X[:, :2].mean(axis=0)
        zp, zx = ph[:, 0] + 1j * ph[:, 1], xh[:, 0] + 1j * xh[:, 1]
        w = np.vdot(zp, zx) / np.vdot(zp, zp)              # complex scale x rotation (least squares)
        s2, yaw_b = abs(w), float(np.angle(w))
        eh = xh - np.column_stack([(w * zp).real, (w * zp).imag])      # horizontal residuals of the levelled block
        Rz = np.array([[math.cos(yaw_b), -math.sin(yaw_b), 0], [math.sin(yaw_b), math.cos(yaw_b), 0], [0, 0, 1.0]])
        z_block = s2 * sim7.scale * (C @ (Rz @ R_lev).T)[:, 2]
    else:
        z_block = X[:, 2] - res7[:, 2]      # the block fitted to the heights (tilt and all)
        eh = None
    # 3. the EXIF heights minus the block's, on time: offset + rate per flight, F-test of the rates
    d = X[:, 2] - z_block
    fit = _drift_fit(d, t, fl)
    if fit is None:
        return {"inconsistent": False, "levelled": False, "n": n,
                "text": f"EXIF heights: not checked ({n} photos in {len(set(fl.tolist()))} flights: no degrees of "
                        "freedom left for an offset and a rate per flight)"}
    rows, e, s_e, p = fit["rows"], fit["residual"], fit["s_e"], fit["p"]
    for r in rows:
        if level_at == "start":
            r["level_m"] += r["rate_m_s"] * r["first_minus_mean_s"]
        r["drift_m"] = r["rate_m_s"] * r["duration_s"]
        r["drift_sigma_m"] = None if r["rate_sigma_m_s"] is None else r["rate_sigma_m_s"] * r["duration_s"]
    worst = max(rows, key=lambda r: abs(r["drift_m"]))
    multi = len(rows) > 1
    duration_s = float(np.ptp(t))
    drift_m = worst["drift_m"]
    inconsistent = bool(p < DRIFT_P_VALUE and abs(drift_m) > sigma_v_m)
    t_stat = worst["rate_m_s"] / worst["rate_sigma_m_s"] if worst["rate_sigma_m_s"] else math.inf
    out = {"inconsistent": inconsistent, "levelled": False, "n": n, "time_source": time_source,
           "similarity_tilt_deg": round(tilt7, 2), "vertical_variance_factor": round(vf7, 2),
           "stated_sigma_v_m": sigma_v_m, "axis_rms_deg": round(rms_axis, 2),
           "drift_m": round(drift_m, 2), "duration_min": round((worst["duration_s"] if multi else duration_s) / 60, 2),
           "drift_sigma_m": round(worst["drift_sigma_m"] or 0.0, 2),
           "t": round(t_stat, 2) if math.isfinite(t_stat) else None, "p_value": float(f"{p:.3g}"),
           "residual_sd_after_drift_m": round(s_e, 2), "p_level": DRIFT_P_VALUE,
           "drift_against": "the levelled block" if up7 is not None else "the block fitted to the heights (not levelled)",
           "level_at": ("each flight's first photo (heights from a barometer zeroed at take-off)" if level_at == "start"
                        else "each flight's mean time")}
    if multi:
        out.update(n_flights=len(rows), F=round(fit["F"], 2) if math.isfinite(fit["F"]) else None,
                   test=f"F-test of {fit['k']} per-flight rates ({fit['dof']} residual degrees of freedom)")
    out["flights"] = [{"flight": r["flight"], "n": r["n"], "duration_min": r["duration_min"],
                       "drift_m": round(r["drift_m"], 2),
                       "drift_sigma_m": None if r["drift_sigma_m"] is None else round(r["drift_sigma_m"], 2),
                       "level_m": round(r["level_m"], 2)} for r in rows]
    if ground is not None:
        out["ground"] = ground
    if gim is not None:
        out["gimbal"] = {"photos": int(rec.sum()), "residual_rms_deg": round(gim["residual_rms_deg"], 2),
                         "geometry_factor": round(gim["geometry_factor"], 2) if math.isfinite(gim["geometry_factor"])
                         else None, "level_sigma_deg": round(level_sigma, 2) if math.isfinite(level_sigma) else None}
    if multi:
        per = "; ".join(f"flight {r['flight']} {r['drift_m']:+.1f} m over {r['duration_s'] / 60:.1f} min"
                        for r in rows)
        stat = (f"drift per flight ({time_source}): {per}; F = {fit['F']:.1f} on ({fit['k']}, {fit['dof']}) "
                f"degrees of freedom, p = {p:.2g}")
    else:
        stat = (f"drift {drift_m:+.1f} m over {duration_s / 60:.1f} min ({time_source}; sigma "
                f"{(worst['drift_sigma_m'] or 0.0):.1f} m, t = {t_stat:.1f}, p = {p:.2g})")
    if not inconsistent:
        lev = f"a similarity onto them tilts it {tilt7:.1f} deg from a nadir mean axis"
        if method == "gimbal":
            lev += f"; the recorded gimbal attitudes would level it to {level_sigma:.1f} deg"
        elif up7 is None:
            lev = f"a similarity onto them; {not_levelled_why}"
        if method == "ground-plane":
            lev += (f"; on the cameras' mean axis the sparse cloud's ground would tilt {ground['tilt_deg']:.1f} deg: "
                    "cameras looking one way, the drift tested against the ground-levelled block")
        out["text"] = (f"EXIF heights consistent with the block at their stated {sigma_v_m:g} m: {stat}; the block is "
                       f"levelled by them ({lev})")
        return out
    if up7 is None:
        out["text"] = (f"EXIF heights inconsistent with the block ({stat}; against the block fitted to them, so only "
                       f"the part of the drift a tilt cannot take is seen): held at their stated {sigma_v_m:g} m they "
                       f"tilt it. The block is NOT levelled: {not_levelled_why}. The heights keep their stated weights "
                       f"and the block's tilt, the DSM's slope and volumes rest on them: control points or RTK/PPK "
                       f"positions are needed")
        out["not_levelled"] = not_levelled_why
        return out
    mad = float(np.median(np.abs(e - np.median(e))))
    sigma_new = max(sigma_v_m, 1.4826 * mad)
    if sigma_h_m is not None:   # the same receiver's horizontal sigma: raised to its robust scatter where larger
        eh_c = eh.reshape(-1)
        sigma_h_new = max(sigma_h_m, 1.4826 * float(np.median(np.abs(eh_c - np.median(eh_c)))))
        out["sigma_h_m"] = round(sigma_h_new, 2)
    level_m = float(sum(r["level_m"] * r["n"] for r in rows) / n)     # one level for the rigid block
    at = "first photo" if level_at == "start" else "mean time"
    if method == "gimbal":
        assumption = (f"the cameras' recorded gimbal attitudes (XMP pitch and yaw of {int(rec.sum())} photos, 1 sigma "
                      f"{GIMBAL_SIGMA_DEG:g} deg assumed, x {gim['geometry_factor']:.2f} for their look directions; "
                      f"the SfM axes scatter {gim['residual_rms_deg']:.2f} deg about them)")
        how = f"on {LEVEL_BASIS[method]}"
    elif method == "balanced-oblique":
        assumption = (f"an oblique or mixed block (its optical axes scatter {rms_axis:.1f} deg RMS about their mean, "
                      f"more than {OBLIQUE_AXIS_RMS_DEG:g} deg) with no gimbal attitude recorded: its look directions "
                      f"taken to balance, so that their mean axis is nadir (1 sigma {NADIR_SIGMA_DEG:g} deg; "
                      f"{axis_scatter_deg:.2f} deg from the axes' scatter); obliques looking mostly one way would "
                      f"leave the block tilted by up to {rms_axis:.0f} deg")
        how = (f"on {LEVEL_BASIS[method]}, its axes scattering {rms_axis:.1f} deg with no gimbal attitude recorded "
               f"(obliques looking mostly one way would leave it tilted by up to that much)")
    elif method == "ground-plane":
        why = (f"levelled on the cameras' mean axis (axes scatter {rms_axis:.1f} deg RMS, no gimbal attitude recorded) "
               f"the sparse cloud's ground plane tilts {ground['tilt_deg']:.1f} deg (jackknife sigma "
               f"{ground['tilt_sigma_deg']:.1f} deg), beyond the {ground['threshold_deg']:.1f} deg a site mean slope of "
               f"{SITE_SLOPE_MAX_DEG:g} deg and that level's error allow: cameras all looking one way (e.g. a fixed "
               f"forward-tilted camera) would be levelled about {ground['tilt_deg']:.0f} deg wrong on their mean axis")
        assumption = (f"{why}; the ground plane taken as level instead (1 sigma {level_sigma:.1f} deg: the "
                      f"{SITE_SLOPE_MAX_DEG:g} deg slope bound taken as 2 sigma, with the fit's): a site that really "
                      f"slopes leaves the block tilted by its mean slope")
        how = (f"on {LEVEL_BASIS[method]} ({why}; a site that really slopes leaves the block tilted by its mean "
               f"slope)")
    else:
        assumption = (f"the cameras' mean optical axis is nadir (1 sigma {NADIR_SIGMA_DEG:g} deg, an assumption for a "
                      f"mapping flight; {axis_scatter_deg:.2f} deg from the axes' scatter)")
        how = f"on {LEVEL_BASIS[method]}"
    out.update(levelled=True, level_method=method, level_basis=LEVEL_BASIS[method], height_enu_m=z_block + level_m, sigma_v_m=round(sigma_new, 2),
               level_sigma_deg=round(level_sigma, 2), assumption=assumption)
    if multi:
        lv = [r["level_m"] for r in rows]
        out["flight_levels_spread_m"] = round(max(lv) - min(lv), 2)
    hz = f" (weighted at {out['sigma_h_m']:g} m, their scatter about the levelled block)" if "sigma_h_m" in out else ""
    flights_txt = (f"each flight's drift is removed and the block placed at the flights' mean level (each at its {at}; "
                   f"their levels differ by {out['flight_levels_spread_m']:.1f} m; one level for the rigid block)"
                   if multi else
                   f"the heights' drift is removed (rate {rows[0]['rate_m_s'] * 60:+.2f} m/min) and only their level "
                   f"at the flight's {at} is kept")
    out["text"] = (f"EXIF heights inconsistent with the block ({stat}): held at their stated {sigma_v_m:g} m they "
                   f"would tilt it {tilt7:.1f} deg. The block is levelled instead {how} (tilt sigma "
                   f"{level_sigma:.1f} deg); {flights_txt} (weighted at {sigma_new:.1f} m); horizontal position "
                   f"and scale still from the EXIF GPS{hz}. Volumes and the DSM's slope rest on that levelling: "
                   f"control points or RTK/PPK positions remove it")
    return out
