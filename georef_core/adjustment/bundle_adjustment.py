"""GNSS-aided bundle adjustment with lever arm, trigger delay and ground control (Daakir et al. 2015,
eq. 6, solved jointly with the tie points as the paper's conclusion proposes).

Unknowns, all in the local ENU frame of the project (metres, radians, seconds):

* per camera: attitude (``R_cam_to_enu``, updated by a small rotation on the left) and centre ``C_i``;
* the intrinsics of each camera (``camera_model``: f, cx, cy, k1, k2, k3, p1, p2, or the fisheye's f, cx,
  cy, k1..k4; which are free is a choice): one set shared by all images, or one per camera group
  (``camera_group``: several cameras, sizes or focal lengths in one block);
* the lever arm ``L`` (camera frame) and the trigger delay ``dt``;
* for a rolling-shutter camera, the readout time ``tau`` (first to last image row): row ``v`` of image i
  is exposed at ``(v / H - 0.5) tau`` from the trigger (the middle row's time), when the camera has moved
  by ``V_i (v / H - 0.5) tau`` (``V_i`` its velocity, from the GNSS at the trigger; the rotation during
  the readout is neglected);
* the tie points and the control points ``X_p``.

Observations, each group with its own a-priori sigma and a variance component estimated from its
residuals (so the posterior covariances are "honest"):

* image measurements of tie and control points (pixels);
* GNSS antenna positions at the camera triggers ``A_i`` with their PPK covariance:
  ``C_i = A_i + R_i L + v_i dt`` (v_i the antenna velocity at the trigger);
* surveyed control point coordinates with their covariance.

Optionally (``gnss_flight`` and ``flight_offset_prior_cov_m2``), a common 3-D offset ``o_f`` of the GNSS
camera positions of each flight f (battery; measured minus true), ``C_i = A_i - o_f + R_i L + v_i dt``, with a prior of zero
mean and the given covariance over the stacked offsets (a part shared by every flight, e.g. an
unsurveyed base position, plus a part of each flight's own: its ambiguity set, an RTK network's offset).
The per-epoch PPK sigmas describe the epoch-to-epoch noise only; without the offsets the adjustment
would average N correlated positions as if independent and report covariances that are too small.
Control points estimate the offsets; without them the prior is propagated into every covariance.

Solved by Levenberg-Marquardt on the normal equations with the points eliminated (Schur complement;
the reduced camera system is dense and small). Robustness by iteratively reweighted least squares
(Huber) on each image measurement and each GNSS epoch; observations whose normalised residual stays
large are flagged as outliers. Posterior covariance of cameras, intrinsics, lever arm and delay is the
inverse of the reduced system after the variance components have been applied.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from ..errors import ProcessingError
from .camera_model import param_names, project_camera_points

_INTR_STEP = np.array([1e-2, 1e-2, 1e-2, 1e-6, 1e-6, 1e-6, 1e-7, 1e-7])


def skew(v: np.ndarray) -> np.ndarray:
    """(n, 3) -> (n, 3, 3) cross-product matrices."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


@dataclass
class BundleProblem:
    R_cam_to_enu: np.ndarray          # (N, 3, 3)
    centre_enu_m: np.ndarray          # (N, 3)
    intrinsics: np.ndarray            # (8,) see camera_model, or (G, 8): one row per camera group
    points_enu_m: np.ndarray          # (P, 3) tie points followed by control/check points
    obs_camera: np.ndarray            # (M,) camera index of each image measurement
    obs_point: np.ndarray             # (M,) point index
    obs_uv_px: np.ndarray             # (M, 2) OpenCV pixel convention
    obs_sigma_px: np.ndarray          # (M,) a-priori sigma per measurement
    obs_group: np.ndarray             # (M,) 0 tie point, 1 control/check point measurement
    gnss_camera: np.ndarray = field(default_factory=lambda: np.zeros(0, int))   # (K,)
    antenna_enu_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    antenna_velocity_enu_m_s: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    antenna_cov_enu_m2: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    lever_arm_cam_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    delay_s: float = 0.0
    control_point: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # (Q,) point index
    control_enu_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    control_cov_enu_m2: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    # a-priori lever arm (e.g. tape-measured) used as a weighted observation when the lever arm is estimated
    lever_arm_prior_cam_m: np.ndarray | None = None
    lever_arm_prior_sigma_m: np.ndarray | None = None
    # a-priori intrinsics (8,) or (G, 8) (e.g. a DJI aircraft's per-unit factory calibration, DewarpData) used
    # as weighted observations of the free intrinsics; sigma of the same shape, infinite where there is no prior
    intrinsics_prior: np.ndarray | None = None
    intrinsics_prior_sigma: np.ndarray | None = None
    fisheye: bool = False             # projection of ``intrinsics`` (see camera_model)
    # rolling shutter (module docstring): the cameras' velocities (N, 3), the image height and the readout
    # time (each a float, or (G,) per camera group); None / 0: a global shutter (every row exposed at the
    # trigger). Images of a global-shutter camera in a mixed block carry a zero velocity.
    camera_velocity_enu_m_s: np.ndarray | None = None
    image_height_px: float | np.ndarray = 0.0
    readout_s: float | np.ndarray = 0.0
    # several cameras: the camera group (row of ``intrinsics``) of each image (N,); None: all group 0
    camera_group: np.ndarray | None = None
    # per-flight GNSS offsets (module docstring): the flight (0..F-1) of each GNSS position (K,), the
    # prior covariance of the stacked offsets (3F, 3F; ENU, m^2, about zero) and their current values (F, 3);
    # None: no offsets (every GNSS position independent)
    gnss_flight: np.ndarray | None = None
    flight_offset_prior_cov_m2: np.ndarray | None = None
    flight_offset_enu_m: np.ndarray | None = None
    # variance-component groups of the GNSS positions (K,) (e.g. 0 RTK fixed, 1 float / single): each group gets
    # its own a-posteriori variance factor (sigma0 "gnss_group_<g>", times the common "gnss" one); None: one factor
    gnss_variance_group: np.ndarray | None = None

    @property
    def n_flights(self) -> int:
        """Number of modelled per-flight GNSS offsets (0: not modelled)."""
        if self.gnss_flight is None or self.flight_offset_prior_cov_m2 is None or len(self.gnss_camera) == 0:
            return 0
        return int(np.max(self.gnss_flight)) + 1

    def offsets(self) -> np.ndarray:
        """(F, 3) the current per-flight offsets (zeros where not yet set)."""
        F = self.n_flights
        if self.flight_offset_enu_m is None or np.shape(self.flight_offset_enu_m) != (F, 3):
            return np.zeros((F, 3))
        return np.asarray(self.flight_offset_enu_m, float)

    @property
    def n_groups(self) -> int:
        return int(np.asarray(self.intrinsics).reshape(-1, 8).shape[0])

    def group_of_camera(self) -> np.ndarray:
        return np.zeros(len(self.centre_enu_m), int) if self.camera_group is None else np.asarray(self.camera_group, int)

    def group_of_obs(self) -> np.ndarray:
        return self.group_of_camera()[self.obs_camera]

    def per_obs(self, values) -> np.ndarray | float:
        """A per-group value for each image measurement: a float stays a float; one camera's (8,)
        intrinsics stay (8,); (G,) values become (M,), (G, 8) intrinsics (M, 8)."""
        v = np.asarray(values, float)
        if v.ndim == 0:
            return float(v)
        G = self.n_groups
        if G == 1:
            return float(v.reshape(-1)[0]) if v.size == 1 else v.reshape(-1)
        grp = self.group_of_obs()
        return v[grp] if v.shape == (G,) else v.reshape(G, -1)[grp]

    @property
    def rolling_shutter(self) -> bool:
        return self.camera_velocity_enu_m_s is not None and bool(np.all(np.asarray(self.image_height_px) > 0))

    def row_offset_s_per_readout(self) -> np.ndarray:
        """(M,) time of each image measurement's row from the trigger, in units of the readout time."""
        return row_offset_per_readout(self.obs_uv_px[:, 1], self.per_obs(self.image_height_px))


@dataclass
class BundleOptions:
    free_intrinsics: np.ndarray = field(default_factory=lambda: np.ones(8, bool))  # (8,) or (G, 8) per camera
    estimate_lever_arm: bool = True
    estimate_delay: bool = True
    estimate_readout: bool = False   # rolling shutter: estimate the readout time (needs camera velocities)
    max_iterations: int = 40
    huber_k: float = 2.5          # in units of the normalised residual
    outlier_k: float = 4.0        # flagged beyond this many sigma (after convergence)
    variance_components: bool = True
    min_gnss_sigma_m: float = 0.005  # floor added in quadrature to the PPK sigma (timing, interpolation)
    tolerance: float = 1e-6       # relative cost decrease to stop
    initial_variances: dict | None = None  # variance factors to start from (e.g. from a previous adjustment)
    cov_points: tuple = ()        # further point indices (e.g. tie points) whose posterior covariance to return


@dataclass
class BundleResult:
    problem: BundleProblem         # holds the adjusted values
    iterations: int
    converged: bool
    rms_reprojection_px: float
    sigma0: dict                   # a-posteriori variance factors per group (1 = a-priori sigma was right)
    global_names: list[str]        # names of the free global parameters
    global_values: np.ndarray
    global_cov: np.ndarray         # covariance of the free global parameters
    camera_cov: np.ndarray         # (N, 6, 6): rotation (rad, world axes) and centre (m)
    obs_outlier: np.ndarray        # (M,) bool
    gnss_outlier: np.ndarray       # (K,) bool
    gnss_residual_enu_m: np.ndarray  # (K, 3) C - (A + R L + v dt) (+ o_flight where modelled)
    obs_residual_px: np.ndarray    # (M, 2)
    point_cov_enu_m2: dict = field(default_factory=dict)  # point index -> (3, 3) for control points
    # per-flight GNSS offsets, where modelled: values (F, 3), their covariance (3F, 3F) and each camera
    # centre's covariance with them (N, 3, 3F)
    flight_offset_enu_m: np.ndarray | None = None
    flight_offset_cov_m2: np.ndarray | None = None
    camera_flight_cov_m2: np.ndarray | None = None
    # each camera's covariance with the free global parameters (N, 6, G): rotation (rad, world axes) and centre
    # (m) rows, ``global_names`` columns; what a point triangulated afterwards needs to carry the globals' share
    # (e.g. the focal length's) of its error (georef's check-point tables)
    camera_global_cov: np.ndarray | None = None

    @property
    def global_sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.global_cov))

    def global_correlation(self) -> np.ndarray:
        s = self.global_sigma
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.global_cov / np.outer(s, s)

    def value(self, name: str) -> tuple[float, float]:
        i = self.global_names.index(name)
        return float(self.global_values[i]), float(self.global_sigma[i])


class _Layout:
    def __init__(self, prob: BundleProblem, opt: BundleOptions):
        G = prob.n_groups
        free = np.asarray(opt.free_intrinsics, bool)
        self.intr_free = np.tile(free.reshape(-1, 8), (G // len(free.reshape(-1, 8)), 1)) \
            if free.reshape(-1, 8).shape[0] != G else free.reshape(G, 8).copy()
        # column of each (group, parameter) among the global unknowns, -1 where held (group-major order)
        self.intr_cols = -np.ones((G, 8), int)
        self.intr_cols[self.intr_free] = np.arange(int(self.intr_free.sum()))
        pn = param_names(prob.fisheye)
        names = [pn[k] if G == 1 else f"cam{g + 1}.{pn[k]}" for g, k in zip(*np.nonzero(self.intr_free))]
        self.n_intr = len(names)
        self.lever = opt.estimate_lever_arm and len(prob.gnss_camera) > 0
        self.delay = opt.estimate_delay and len(prob.gnss_camera) > 0
        self.lever_col = len(names)
        if self.lever:
            names += ["lever_x", "lever_y", "lever_z"]
        self.delay_col = len(names)
        if self.delay:
            names += ["delay"]
        # the readout of each camera group whose images move (rolling-shutter groups with GNSS velocities)
        self.readout_cols = -np.ones(G, int)
        if opt.estimate_readout and prob.rolling_shutter:
            moving = np.linalg.norm(np.asarray(prob.camera_velocity_enu_m_s, float), axis=1) > 0
            for g in range(G):
                if np.any(moving & (prob.group_of_camera() == g)):
                    self.readout_cols[g] = len(names)
                    names += ["readout" if G == 1 else f"cam{g + 1}.readout"]
        self.readout = bool(np.any(self.readout_cols >= 0))
        # per-flight GNSS offsets (E, N, U of each flight)
        self.n_flights = prob.n_flights
        self.flight_col = len(names)
        for f in range(self.n_flights):
            names += [f"flight{f + 1}.offset_e", f"flight{f + 1}.offset_n", f"flight{f + 1}.offset_u"]
        self.names = names
        self.n_global = len(names)
        self.n_cam = len(prob.centre_enu_m)
        self.cam0 = self.n_global
        self.nx = self.n_global + 6 * self.n_cam
        self.n_pts = len(prob.points_enu_m)


def flight_offset_prior_cov(n_flights: int, common_sigma_enu_m, flight_sigma_enu_m) -> np.ndarray:
    """(3F, 3F) prior covariance of F stacked per-flight GNSS offsets (E, N, U each): a part shared by every
    flight (``common_sigma_enu_m``, e.g. the base position's sigma when the base is not surveyed) plus an
    independent part of each flight's own (``flight_sigma_enu_m``: its ambiguity set, an RTK network offset),
    one (3,) for every flight or (F, 3), one row per flight (e.g. from each flight's RTK quality)."""
    common = np.diag(np.asarray(common_sigma_enu_m, float) ** 2 * np.ones(3))
    own_sd = np.asarray(flight_sigma_enu_m, float)
    own_sd = np.broadcast_to(own_sd.reshape(-1, 3) if own_sd.size == 3 * n_flights and own_sd.ndim == 2
                             else own_sd * np.ones(3), (n_flights, 3))
    own = np.zeros((3 * n_flights, 3 * n_flights))
    own[np.diag_indices(3 * n_flights)] = own_sd.reshape(-1) ** 2
    return np.kron(np.ones((n_flights, n_flights)), common) + own


def row_offset_per_readout(v_px: np.ndarray, image_height_px: float) -> np.ndarray:
    """Time of image row(s) ``v_px`` from the image's time (its middle row's), in units of the readout time."""
    return np.asarray(v_px, float) / image_height_px - 0.5


def rolling_shutter_shift(velocity_enu_m_s: np.ndarray, v_px: np.ndarray, image_height_px: float,
                          readout_s: float) -> np.ndarray:
    """(n, 3) where the camera was, from its centre, when each measurement's row was exposed: velocity (n, 3)
    x the row's time (the rolling-shutter model of the module docstring)."""
    return np.asarray(velocity_enu_m_s, float) * (readout_s * row_offset_per_readout(v_px, image_height_px))[:, None]


def _row_shift(prob: BundleProblem, readout_s) -> np.ndarray | float:
    """(M, 3) displacement of each measurement's camera centre at its row's exposure (rolling shutter), or 0."""
    if not prob.rolling_shutter:
        return 0.0
    return rolling_shutter_shift(prob.camera_velocity_enu_m_s[prob.obs_camera], prob.obs_uv_px[:, 1],
                                 prob.per_obs(prob.image_height_px), prob.per_obs(readout_s))


def _reprojection(prob: BundleProblem, intr=None, R=None, C=None, X=None, readout=None):
    R = prob.R_cam_to_enu if R is None else R
    C = prob.centre_enu_m if C is None else C
    X = prob.points_enu_m if X is None else X
    intr = prob.intrinsics if intr is None else intr
    readout = prob.readout_s if readout is None else readout
    Rw2c = np.transpose(R[prob.obs_camera], (0, 2, 1))
    d = X[prob.obs_point] - C[prob.obs_camera] - _row_shift(prob, readout)
    p = np.einsum("mij,mj->mi", Rw2c, d)
    return project_camera_points(p, prob.per_obs(intr), prob.fisheye), p, d, Rw2c


def _gnss_residual(prob: BundleProblem, R=None, C=None, lever=None, delay=None, offsets=None):
    R = prob.R_cam_to_enu if R is None else R
    C = prob.centre_enu_m if C is None else C
    lever = prob.lever_arm_cam_m if lever is None else lever
    delay = prob.delay_s if delay is None else delay
    i = prob.gnss_camera
    a = np.einsum("kij,j->ki", R[i], lever)
    g = C[i] - prob.antenna_enu_m - a - prob.antenna_velocity_enu_m_s * delay
    if prob.n_flights:
        g = g + (prob.offsets() if offsets is None else offsets)[np.asarray(prob.gnss_flight, int)]
    return g, a


def _jacobi_scaled(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, diag(s) S diag(s)) with s = 1/sqrt(diag S): the columns of the reduced normal matrix span ten
    orders of magnitude (k3 against a focal length in pixels), which unscaled would lose the
    ill-determined directions (lever arm z against f) to rounding."""
    d = np.diag(S)
    s = 1.0 / np.sqrt(np.where(d > 0, d, 1.0))
    return s, S * s[:, None] * s[None, :]


def _solve_scaled(S: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    s, Ss = _jacobi_scaled(S)
    try:
        y = np.linalg.solve(Ss, rhs * s)
    except np.linalg.LinAlgError:
        y = np.linalg.lstsq(Ss, rhs * s, rcond=None)[0]
    return y * s


def _inverse_scaled(S: np.ndarray) -> np.ndarray:
    s, Ss = _jacobi_scaled(S)
    try:
        inv = np.linalg.inv(Ss)
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(Ss)
    return inv * s[:, None] * s[None, :]


def _whiteners(cov: np.ndarray) -> np.ndarray:
    """Upper factors U with U^T U = cov^-1, (n, 3, 3)."""
    if len(cov) == 0:
        return np.zeros((0, 3, 3))
    inv = np.linalg.inv(cov)
    Lc = np.linalg.cholesky(inv)
    return np.transpose(Lc, (0, 2, 1))


class BundleAdjuster:
    def __init__(self, problem: BundleProblem, options: BundleOptions | None = None):
        self.prob = problem
        self.opt = options or BundleOptions()
        self.lay = _Layout(problem, self.opt)
        p = problem
        if len(p.gnss_camera) + len(p.control_point) == 0:
            raise ProcessingError("the adjustment needs GNSS camera positions or control points to define its datum")
        if len(p.gnss_camera) == 0 and len(p.control_point) < 3:
            raise ProcessingError(f"without GNSS camera positions at least 3 control points are needed "
                                  f"(have {len(p.control_point)})")
        gcov = np.asarray(p.antenna_cov_enu_m2, float).copy()
        if len(gcov):
            gcov = gcov + np.eye(3) * self.opt.min_gnss_sigma_m ** 2
        self.gnss_cov_apriori = gcov
        self.var = {"image": 1.0, "gnss": 1.0, "control": 1.0}
        K = len(p.gnss_camera)
        vg = p.gnss_variance_group
        self.gnss_vgroup = np.zeros(K, int) if vg is None else np.asarray(vg, int).reshape(-1)
        if len(self.gnss_vgroup) != K:
            raise ProcessingError(f"gnss_variance_group has {len(self.gnss_vgroup)} entries for {K} GNSS positions")
        self.var_gnss_group = np.ones(int(self.gnss_vgroup.max()) + 1 if K else 1)
        if self.opt.initial_variances:
            init = dict(self.opt.initial_variances)
            for g in range(len(self.var_gnss_group)):
                self.var_gnss_group[g] = init.pop(f"gnss_group_{g}", 1.0)
            self.var.update({k: v for k, v in init.items() if not k.startswith("gnss_group_")})
        self.w_obs = np.ones(len(p.obs_camera))
        self.w_gnss = np.ones(len(p.gnss_camera))
        self.w_ctl = np.ones(len(p.control_point))
        # whitener of the per-flight offsets' prior: W^T W = prior covariance^-1
        self.flight_W = None
        if self.lay.n_flights:
            F = self.lay.n_flights
            cov = np.asarray(p.flight_offset_prior_cov_m2, float)
            if cov.shape != (3 * F, 3 * F):
                raise ProcessingError(f"the per-flight GNSS offsets' prior covariance is {cov.shape}, expected "
                                      f"({3 * F}, {3 * F}) for {F} flight(s)")
            try:
                self.flight_W = np.linalg.cholesky(np.linalg.inv(cov)).T
            except np.linalg.LinAlgError:
                raise ProcessingError("the per-flight GNSS offsets' prior covariance is not positive definite "
                                      "(a zero sigma? leave the offsets out instead)") from None
            p.flight_offset_enu_m = p.offsets().copy()

    # ----------------------------------------------------------------------------------- residuals
    def _normalised(self, state=None):
        p = self.prob
        R, C, X, intr, lever, delay, readout, off = state if state is not None else (
            p.R_cam_to_enu, p.centre_enu_m, p.points_enu_m, p.intrinsics, p.lever_arm_cam_m, p.delay_s, p.readout_s,
            p.offsets())
        uv, *_ = _reprojection(p, intr, R, C, X, readout)
        r_obs = (uv - p.obs_uv_px) / (p.obs_sigma_px * np.sqrt(self.var["image"]))[:, None]
        Ug = _whiteners(self._gnss_cov())
        g, _ = _gnss_residual(p, R, C, lever, delay, off)
        r_g = np.einsum("kij,kj->ki", Ug, g)
        Uc = _whiteners(p.control_cov_enu_m2 * self.var["control"])
        r_c = np.einsum("qij,qj->qi", Uc, X[p.control_point] - p.control_enu_m)
        self._r_prior = np.concatenate([self._lever_prior_residual(lever), self._intrinsics_prior_residual(intr),
                                        self._flight_prior_residual(off)])
        return r_obs, r_g, r_c

    def _gnss_cov(self) -> np.ndarray:
        """The GNSS positions' covariances with their variance factors (common and per variance group)."""
        f = self.var["gnss"] * self.var_gnss_group[self.gnss_vgroup]
        return self.gnss_cov_apriori * f[:, None, None]

    def _flight_prior_residual(self, off) -> np.ndarray:
        if self.flight_W is None:
            return np.zeros(0)
        return self.flight_W @ np.asarray(off, float).reshape(-1)

    def _lever_prior_residual(self, lever) -> np.ndarray:
        p = self.prob
        if not self.lay.lever or p.lever_arm_prior_cam_m is None:
            return np.zeros(0)
        return (np.asarray(lever) - p.lever_arm_prior_cam_m) / np.asarray(p.lever_arm_prior_sigma_m, float)

    def _prior_arrays(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The intrinsics prior and its sigma as (G, 8) (a single (8,) prior applies to every group)."""
        p = self.prob
        if p.intrinsics_prior is None or p.intrinsics_prior_sigma is None:
            return None
        G = p.n_groups
        val = np.asarray(p.intrinsics_prior, float).reshape(-1, 8)
        sig = np.asarray(p.intrinsics_prior_sigma, float).reshape(-1, 8)
        return np.broadcast_to(val, (G, 8)), np.broadcast_to(sig, (G, 8))

    def _intrinsics_prior_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """(columns among the global parameters, flat (group * 8 + parameter) indices) of the free
        intrinsics with a prior."""
        pr = self._prior_arrays()
        if pr is None:
            return np.zeros(0, int), np.zeros(0, int)
        sig = pr[1]
        ok = self.lay.intr_free & np.isfinite(sig) & (sig > 0)
        flat = np.flatnonzero(ok.reshape(-1))
        return self.lay.intr_cols.reshape(-1)[flat], flat

    def _intrinsics_prior_residual(self, intr) -> np.ndarray:
        cols, k = self._intrinsics_prior_columns()
        if not len(k):
            return np.zeros(0)
        val, sig = self._prior_arrays()
        I = np.asarray(intr, float).reshape(-1)
        if len(I) == 8 and self.prob.n_groups > 1:
            I = np.tile(I, self.prob.n_groups)
        return (I[k] - val.reshape(-1)[k]) / sig.reshape(-1)[k]

    def _cost(self, r_obs, r_g, r_c) -> float:
        return float(np.sum(self.w_obs * np.sum(r_obs ** 2, 1)) + np.sum(self.w_gnss * np.sum(r_g ** 2, 1))
                     + np.sum(self.w_ctl * np.sum(r_c ** 2, 1)) + np.sum(self._r_prior ** 2))

    @staticmethod
    def _huber(norm: np.ndarray, k: float) -> np.ndarray:
        w = np.ones_like(norm)
        big = norm > k
        w[big] = k / norm[big]
        return w

    # ----------------------------------------------------------------------------------- Jacobian
    def _linearise(self):
        p, lay = self.prob, self.lay
        M = len(p.obs_camera)
        uv, pc, d, Rw2c = _reprojection(p)
        sig = p.obs_sigma_px * np.sqrt(self.var["image"])
        r_obs = (uv - p.obs_uv_px) / sig[:, None]
        sw = np.sqrt(self.w_obs) / sig  # row scale for the Jacobian
        # d(uv)/d(p_cam) and d(uv)/d(intrinsics), central differences, vectorised over observations
        intr_obs = p.per_obs(p.intrinsics)            # (8,) one camera, or (M, 8) each measurement's camera
        Jp = np.empty((M, 2, 3))
        h = 1e-6 * np.maximum(np.abs(pc[:, 2]), 1e-3)
        for k in range(3):
            dp = np.zeros_like(pc)
            dp[:, k] = h
            Jp[:, :, k] = (project_camera_points(pc + dp, intr_obs, p.fisheye)
                            - project_camera_points(pc - dp, intr_obs, p.fisheye)) / (2 * h)[:, None]
        JX = np.einsum("mij,mjk->mik", Jp, Rw2c)
        Jrot = np.einsum("mij,mjk->mik", JX, skew(d))
        JX *= sw[:, None, None]
        Jrot *= sw[:, None, None]
        rows_r = (np.sqrt(self.w_obs)[:, None] * r_obs).reshape(-1)

        # sparse assembly of the x-part (global + cameras) and the point blocks
        rows, cols, vals = [], [], []
        obs_rows = np.arange(M)[:, None] * 2 + np.arange(2)[None, :]  # (M, 2)
        grp = p.group_of_obs()
        for k in np.flatnonzero(lay.intr_free.any(axis=0)):   # each measurement's own camera's columns
            col = lay.intr_cols[grp, k]
            m = col >= 0
            if not m.any():
                continue
            e = np.zeros(8)
            e[k] = _INTR_STEP[k]
            io = intr_obs[m] if np.ndim(intr_obs) == 2 else intr_obs
            dk = (project_camera_points(pc[m], io + e, p.fisheye)
                  - project_camera_points(pc[m], io - e, p.fisheye)) / (2 * _INTR_STEP[k]) * sw[m, None]
            rows.append(obs_rows[m].reshape(-1))
            cols.append(np.repeat(col[m], 2))
            vals.append(dk.reshape(-1))
        if lay.readout:  # d(uv)/d(readout) = -d(uv)/dX . V_i (v / H - 0.5), the readout of the image's camera
            col = lay.readout_cols[grp]
            m = col >= 0
            dr = -np.einsum("mij,mj->mi", JX[m], p.camera_velocity_enu_m_s[p.obs_camera[m]]
                            * p.row_offset_s_per_readout()[m, None])
            rows.append(obs_rows[m].reshape(-1))
            cols.append(np.repeat(col[m], 2))
            vals.append(dr.reshape(-1))
        cam_cols = lay.cam0 + 6 * p.obs_camera
        rows.append(np.repeat(obs_rows[:, :, None], 6, 2).reshape(-1))
        cols.append((cam_cols[:, None, None] + np.arange(6)[None, None, :]).repeat(2, 1).reshape(-1))
        vals.append(np.concatenate([Jrot, -JX], axis=2).reshape(-1))
        n_rows = 2 * M
        r_all = [rows_r]

        # GNSS rows
        K = len(p.gnss_camera)
        Ug = _whiteners(self._gnss_cov())
        if K:
            g, a = _gnss_residual(p)
            sqw = np.sqrt(self.w_gnss)[:, None, None]
            U = Ug * sqw
            r_all.append(np.einsum("kij,kj->ki", U, g).reshape(-1))
            g_rows = n_rows + np.arange(K)[:, None] * 3 + np.arange(3)[None, :]
            ccols = lay.cam0 + 6 * p.gnss_camera
            blk = np.concatenate([np.einsum("kij,kjl->kil", U, skew(a)), U], axis=2)  # rot, centre
            rows.append(np.repeat(g_rows[:, :, None], 6, 2).reshape(-1))
            cols.append((ccols[:, None, None] + np.arange(6)[None, None, :]).repeat(3, 1).reshape(-1))
            vals.append(blk.reshape(-1))
            if lay.lever:
                JL = -np.einsum("kij,kjl->kil", U, p.R_cam_to_enu[p.gnss_camera])
                rows.append(np.repeat(g_rows[:, :, None], 3, 2).reshape(-1))
                cols.append(np.broadcast_to(lay.lever_col + np.arange(3), (K, 3, 3)).reshape(-1))
                vals.append(JL.reshape(-1))
            if lay.delay:
                Jd = -np.einsum("kij,kj->ki", U, p.antenna_velocity_enu_m_s)
                rows.append(g_rows.reshape(-1))
                cols.append(np.full(3 * K, lay.delay_col))
                vals.append(Jd.reshape(-1))
            if lay.n_flights:   # d(residual)/d(offset of the position's flight) = U
                fcol = lay.flight_col + 3 * np.asarray(p.gnss_flight, int)
                rows.append(np.repeat(g_rows[:, :, None], 3, 2).reshape(-1))
                cols.append(np.broadcast_to((fcol[:, None] + np.arange(3))[:, None, :], (K, 3, 3)).reshape(-1))
                vals.append(U.reshape(-1))
            n_rows += 3 * K
        if self.flight_W is not None:
            nf = 3 * lay.n_flights
            r_all.append(self._flight_prior_residual(p.offsets()))
            rows.append(np.repeat(n_rows + np.arange(nf), nf))
            cols.append(np.tile(lay.flight_col + np.arange(nf), nf))
            vals.append(self.flight_W.reshape(-1))
            n_rows += nf
        rp = self._lever_prior_residual(p.lever_arm_cam_m)
        if len(rp):
            r_all.append(rp)
            rows.append(n_rows + np.arange(3))
            cols.append(lay.lever_col + np.arange(3))
            vals.append(1.0 / np.asarray(p.lever_arm_prior_sigma_m, float))
            n_rows += 3
        ri = self._intrinsics_prior_residual(p.intrinsics)
        if len(ri):
            cols_i, k_i = self._intrinsics_prior_columns()
            r_all.append(ri)
            rows.append(n_rows + np.arange(len(ri)))
            cols.append(cols_i)
            vals.append(1.0 / self._prior_arrays()[1].reshape(-1)[k_i])
            n_rows += len(ri)
        Jx = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_rows + 3 * len(p.control_point), lay.nx))

        # point part: per-observation 2x3 blocks (JX) and control priors
        Q = len(p.control_point)
        Uc = _whiteners(p.control_cov_enu_m2 * self.var["control"])
        prow = np.repeat(obs_rows[:, :, None], 3, 2).reshape(-1)
        pcol = (3 * p.obs_point[:, None, None] + np.arange(3)[None, None, :]).repeat(2, 1).reshape(-1)
        pval = JX.reshape(-1)
        if Q:
            Ucw = Uc * np.sqrt(self.w_ctl)[:, None, None]
            Xc = p.points_enu_m[p.control_point]
            r_all.append(np.einsum("qij,qj->qi", Ucw, Xc - p.control_enu_m).reshape(-1))
            c_rows = n_rows + np.arange(Q)[:, None] * 3 + np.arange(3)[None, :]
            prow = np.concatenate([prow, np.repeat(c_rows[:, :, None], 3, 2).reshape(-1)])
            pcol = np.concatenate([pcol, (3 * p.control_point[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1).reshape(-1)])
            pval = np.concatenate([pval, Ucw.reshape(-1)])
            n_rows += 3 * Q
        Jpts = sp.csr_matrix((pval, (prow, pcol)), shape=(n_rows, 3 * lay.n_pts))
        # D blocks
        D = np.zeros((lay.n_pts, 3, 3))
        np.add.at(D, p.obs_point, np.einsum("mki,mkj->mij", JX, JX))
        if Q:
            np.add.at(D, p.control_point, np.einsum("qki,qkj->qij", Ucw, Ucw))
        r = np.concatenate(r_all)
        return Jx, Jpts, D, r

    # ----------------------------------------------------------------------------------- solve
    def _solve_step(self, Jx, Jpts, D, r, lam: float):
        lay = self.lay
        A = (Jx.T @ Jx).toarray()
        B = (Jx.T @ Jpts).tocsr()
        bx = Jx.T @ r
        bp = Jpts.T @ r
        A_d = A + lam * np.diag(np.maximum(np.diag(A), 1e-9))
        Dd = D + lam * np.maximum(np.einsum("pii->pi", D), 1e-9)[:, :, None] * np.eye(3)[None]
        Dd = Dd + np.eye(3)[None] * 1e-12
        Dinv = np.linalg.inv(Dd)
        Dinv_sp = sp.bsr_matrix((Dinv, np.arange(lay.n_pts), np.arange(lay.n_pts + 1)), shape=(3 * lay.n_pts, 3 * lay.n_pts)).tocsr()
        BD = B @ Dinv_sp
        S = A_d - (BD @ B.T).toarray()
        rhs = -(bx - BD @ bp)
        dx = _solve_scaled(S, rhs)
        dp = Dinv_sp @ (-bp - B.T @ dx)
        return dx, dp, S, Dinv, B

    def _apply(self, dx, dp):
        p, lay = self.prob, self.lay
        shape = np.shape(p.intrinsics)
        intr = np.asarray(p.intrinsics, float).reshape(-1, 8).copy()
        intr[lay.intr_free] += dx[:lay.n_intr]
        intr = intr.reshape(shape)
        lever = p.lever_arm_cam_m.copy()
        if lay.lever:
            lever += dx[lay.lever_col:lay.lever_col + 3]
        delay = p.delay_s + (dx[lay.delay_col] if lay.delay else 0.0)
        readout = p.readout_s
        if lay.readout:
            if np.ndim(p.readout_s) == 0:
                readout = float(p.readout_s) + float(dx[lay.readout_cols[0]])
            else:
                readout = np.asarray(p.readout_s, float).copy()
                for g, c in enumerate(lay.readout_cols):
                    if c >= 0:
                        readout[g] += dx[c]
        off = p.offsets()
        if lay.n_flights:
            off = off + dx[lay.flight_col:lay.flight_col + 3 * lay.n_flights].reshape(-1, 3)
        cam = dx[lay.cam0:].reshape(-1, 6)
        R = Rotation.from_rotvec(cam[:, :3]).as_matrix() @ p.R_cam_to_enu
        C = p.centre_enu_m + cam[:, 3:]
        X = p.points_enu_m + dp.reshape(-1, 3)
        return R, C, X, intr, lever, float(delay), (float(readout) if np.ndim(readout) == 0 else readout), off

    def _commit(self, state):
        p = self.prob
        (p.R_cam_to_enu, p.centre_enu_m, p.points_enu_m, p.intrinsics, p.lever_arm_cam_m, p.delay_s, p.readout_s,
         off) = state
        if self.lay.n_flights:
            p.flight_offset_enu_m = off

    def _reweight(self):
        r_obs, r_g, r_c = self._normalised()
        k = self.opt.huber_k
        self.w_obs = self._huber(np.linalg.norm(r_obs, axis=1) / np.sqrt(2), k)
        self.w_gnss = self._huber(np.linalg.norm(r_g, axis=1) / np.sqrt(3), k) if len(r_g) else self.w_gnss
        self.w_ctl = self._huber(np.linalg.norm(r_c, axis=1) / np.sqrt(3), k) if len(r_c) else self.w_ctl

    def _iterate(self, max_iter: int) -> tuple[int, bool]:
        lam = 1e-4
        cost = self._cost(*self._normalised())
        it = 0
        converged = False
        while it < max_iter:
            it += 1
            Jx, Jpts, D, r = self._linearise()
            dx, dp, *_ = self._solve_step(Jx, Jpts, D, r, lam)
            state = self._apply(dx, dp)
            new_cost = self._cost(*self._normalised(state))
            if new_cost < cost:
                self._commit(state)
                rel = (cost - new_cost) / max(cost, 1e-12)
                cost = new_cost
                lam = max(lam / 5, 1e-9)
                if rel < self.opt.tolerance:
                    converged = True
                    break
            else:
                lam *= 10
                if lam > 1e6:
                    converged = True  # no further decrease possible
                    break
        return it, converged

    def run(self) -> BundleResult:
        opt = self.opt
        iters, converged = self._iterate(opt.max_iterations)
        # rounds of robust reweighting and variance-component estimation, each followed by re-solving
        for k in range(3):
            if opt.variance_components and k > 0:
                self._variance_components()
            self._reweight()
            i2, converged = self._iterate(opt.max_iterations)
            iters += i2
        return self._result(iters, converged)

    # ----------------------------------------------------------------------------------- statistics
    def _covariances(self):
        Jx, Jpts, D, r = self._linearise()
        _, _, S, Dinv, B = self._solve_step(Jx, Jpts, D, r, 0.0)
        return _inverse_scaled(S), Dinv, B

    def _variance_components(self):
        """Group variance factors from the residuals and the groups' redundancy numbers."""
        p, lay = self.prob, self.lay
        r_obs, r_g, r_c = self._normalised()
        Sinv, Dinv, B = self._covariances()
        K, Q = len(p.gnss_camera), len(p.control_point)
        n_obs = 2 * len(p.obs_camera)
        # hat-matrix traces of the GNSS and control rows (their parameters' marginal covariances are known)
        h_g = 0.0
        if K:
            Ug = _whiteners(self._gnss_cov()) * np.sqrt(self.w_gnss)[:, None, None]
            h_k = np.zeros(K)
            _, a = _gnss_residual(p)
            for k in range(K):
                i = p.gnss_camera[k]
                cols = list(range(lay.cam0 + 6 * i, lay.cam0 + 6 * i + 6))
                J = np.concatenate([Ug[k] @ skew(a[k][None])[0], Ug[k]], axis=1)
                if lay.lever:
                    cols += list(range(lay.lever_col, lay.lever_col + 3))
                    J = np.concatenate([J, -Ug[k] @ p.R_cam_to_enu[i]], axis=1)
                if lay.delay:
                    cols.append(lay.delay_col)
                    J = np.concatenate([J, -(Ug[k] @ p.antenna_velocity_enu_m_s[k])[:, None]], axis=1)
                if lay.n_flights:
                    f0 = lay.flight_col + 3 * int(p.gnss_flight[k])
                    cols += list(range(f0, f0 + 3))
                    J = np.concatenate([J, Ug[k]], axis=1)
                h_k[k] = float(np.trace(J @ Sinv[np.ix_(cols, cols)] @ J.T))
            h_g = float(h_k.sum())
        h_c = 0.0
        if Q:
            Uc = _whiteners(p.control_cov_enu_m2 * self.var["control"]) * np.sqrt(self.w_ctl)[:, None, None]
            Bd = B.toarray() if B.shape[1] <= 3 * 2000 else None
            for q in range(Q):
                j = p.control_point[q]
                Cp = self._point_cov(j, Sinv, Dinv, B, Bd)
                h_c += float(np.trace(Uc[q] @ Cp @ Uc[q].T))
        u = lay.nx + 3 * lay.n_pts
        h_o = max(u - h_g - h_c, 0.0)
        red_o = max(n_obs - h_o, 1.0)
        red_g = max(3 * K - h_g, 1.0)
        red_c = max(3 * Q - h_c, 1.0)
        s_o = float(np.sum(self.w_obs * np.sum(r_obs ** 2, 1))) / red_o
        self.var["image"] *= s_o
        if K and len(self.var_gnss_group) > 1:   # one factor per variance group, from its own redundancy
            q = self.w_gnss * np.sum(r_g ** 2, 1)
            for g in range(len(self.var_gnss_group)):
                m = self.gnss_vgroup == g
                if m.any():
                    self.var_gnss_group[g] *= float(q[m].sum()) / max(3 * int(m.sum()) - float(h_k[m].sum()), 1.0)
        elif K:
            self.var["gnss"] *= float(np.sum(self.w_gnss * np.sum(r_g ** 2, 1))) / red_g
        if Q and red_c > 2.0:
            # few control points carry little information on their own variance: only update when
            # they have a real redundancy
            self.var["control"] *= float(np.sum(self.w_ctl * np.sum(r_c ** 2, 1))) / red_c

    @staticmethod
    def _point_cov(j, Sinv, Dinv, B, Bd=None) -> np.ndarray:
        Bj = (Bd[:, 3 * j:3 * j + 3] if Bd is not None else B[:, 3 * j:3 * j + 3].toarray())
        Dj = Dinv[j]
        return Dj + Dj @ Bj.T @ Sinv @ Bj @ Dj

    def _result(self, iters: int, converged: bool) -> BundleResult:
        p, lay = self.prob, self.lay
        Sinv, Dinv, B = self._covariances()
        r_obs, r_g, r_c = self._normalised()
        uv, *_ = _reprojection(p)
        res_px = uv - p.obs_uv_px
        k_out = self.opt.outlier_k
        obs_out = np.linalg.norm(r_obs, axis=1) / np.sqrt(2) > k_out
        gnss_out = np.linalg.norm(r_g, axis=1) / np.sqrt(3) > k_out if len(r_g) else np.zeros(0, bool)
        ok = ~obs_out
        rms = float(np.sqrt(np.mean(np.sum(res_px[ok] ** 2, 1)))) if ok.any() else float("nan")
        readouts = np.broadcast_to(np.asarray(p.readout_s, float).reshape(-1), (p.n_groups,))
        g_vals = np.concatenate([np.asarray(p.intrinsics, float).reshape(-1, 8)[lay.intr_free],
                                 p.lever_arm_cam_m if lay.lever else [],
                                 [p.delay_s] if lay.delay else [],
                                 readouts[lay.readout_cols >= 0], p.offsets().reshape(-1)])
        G = lay.n_global
        cam_cov = np.stack([Sinv[lay.cam0 + 6 * i: lay.cam0 + 6 * i + 6, lay.cam0 + 6 * i: lay.cam0 + 6 * i + 6]
                            for i in range(lay.n_cam)])
        g, _ = _gnss_residual(p)
        pcov = {int(j): self._point_cov(int(j), Sinv, Dinv, B)
                for j in list(p.control_point) + list(self.opt.cov_points)}
        sig0 = {k: float(np.sqrt(v)) for k, v in self.var.items()}
        if len(self.var_gnss_group) > 1:
            sig0.update({f"gnss_group_{g}": float(np.sqrt(v)) for g, v in enumerate(self.var_gnss_group)})
        fl = {}
        if lay.n_flights:
            fc = slice(lay.flight_col, lay.flight_col + 3 * lay.n_flights)
            fl = {"flight_offset_enu_m": p.offsets().copy(), "flight_offset_cov_m2": Sinv[fc, fc].copy(),
                  "camera_flight_cov_m2": np.stack([Sinv[lay.cam0 + 6 * i + 3: lay.cam0 + 6 * i + 6, fc]
                                                    for i in range(lay.n_cam)])}
        cam_glob = np.stack([Sinv[lay.cam0 + 6 * i: lay.cam0 + 6 * i + 6, :G] for i in range(lay.n_cam)]) \
            if lay.n_cam else np.zeros((0, 6, G))
        return BundleResult(**fl, problem=p, iterations=iters, converged=converged, rms_reprojection_px=rms, sigma0=sig0,
                            global_names=list(lay.names), global_values=g_vals, global_cov=Sinv[:G, :G].copy(),
                            camera_cov=cam_cov, camera_global_cov=cam_glob, obs_outlier=obs_out, gnss_outlier=gnss_out, gnss_residual_enu_m=g,
                            obs_residual_px=res_px, point_cov_enu_m2=pcov)


def adjust(problem: BundleProblem, options: BundleOptions | None = None) -> BundleResult:
    """Run the adjustment in place on ``problem`` and return the statistics.

    Staged: the block is first brought onto its datum (GNSS positions, control points) with the camera
    intrinsics held, then everything is freed. Straight from SfM the datum misfit is large and the
    intrinsics are the least determined unknowns (focal length against flying height); solving for all
    at once lets Levenberg-Marquardt crawl along that valley instead of closing the misfit."""
    opt = options or BundleOptions()
    if opt.initial_variances is None and np.any(opt.free_intrinsics):
        first = replace(opt, free_intrinsics=np.zeros_like(np.asarray(opt.free_intrinsics, bool)),
                        estimate_readout=False, variance_components=False, max_iterations=30)
        BundleAdjuster(problem, first)._iterate(first.max_iterations)
    return BundleAdjuster(problem, opt).run()
