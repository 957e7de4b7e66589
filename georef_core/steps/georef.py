"""Step: georeferencing of a survey's photos (`georef georef SURVEY_DIR --out OUT_DIR`).

1. PPK of the drone's GNSS (``OUT_DIR/ppk``, reused when present) -> antenna position, velocity and
   covariance at each camera trigger.
2. SfM with pycolmap (``OUT_DIR/sfm``, reused when present and made with the same options).
3. The images are tied to their triggers (events.csv names, else the receiver's event records in the
   order of the images' EXIF times).
4. Adjustment in one of three modes (Daakir et al. 2015):
   ``joint`` (c) bundle adjustment of tie points, GNSS camera positions with their covariances, lever
   arm, delay, self-calibration and control points together; ``gcp`` (a) orientation from control
   points, then lever arm + delay from the GNSS positions; ``similarity`` (b) a 7-parameter similarity +
   delay from the GNSS positions with a known lever arm, no control.
5. Control points' image measurements are screened for blunders; check points are triangulated and
   compared with their surveyed coordinates (residual table), control points by leave-one-out.
6. Outputs: ``oriented_images.json``, ``residuals.json/.csv``, ``control_loo.json/.csv``,
   ``lever_arm_delay.json``, ``georef_summary.json``, ``sparse_points.ply``, ``plots/``.
"""

from __future__ import annotations

import csv
import json
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from ..adjustment import camera_model as cm
from ..adjustment.bundle_adjustment import (BundleOptions, BundleProblem, adjust, flight_offset_prior_cov,
                                            rolling_shutter_shift)
from ..adjustment.control_points import ControlData, load_control, point_sigma_enu_cov, points_to_enu
from ..adjustment.lever_arm_delay import estimate_lever_arm_delay, fit_similarity_delay, similarity_centre_cov
from ..adjustment.residual_table import ResidualRow, ResidualTable
from ..adjustment.triangulation import find_blunders, triangulate
from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn
from ..project_frame import ProjectFrame, utm_epsg_for
from .exif_triggers import exif_trigger_times
from .georef_options import (FACTORY_CALIBRATION_CHOICES, IMAGE_SUFFIXES, MODE_ALIASES, MODES,  # noqa: F401
                             SFM_MODELS, GeorefOptions, georef_options_from_dict, validate_flight_options,
                             validate_shutter_options)


# Weights of a factory calibration used as a prior (GeorefOptions.factory_calibration = "prior"): focal
# length 0.05 % (a per-unit calibration drifts with temperature and focus), principal point 1 px of the
# calibrated image, distortion loosely (the block determines it well). An assumption stated in
# docs/dji.md, not a measured figure of DJI units.
FACTORY_CALIBRATION_SIGMA = {"f_rel": 5e-4, "pp_px": 1.0, "k": 0.02, "p": 0.002}


def factory_calibration(image_path: Path, width_px: int, height_px: int) -> tuple[np.ndarray, str] | None:
    """The 8 intrinsics (f, cx, cy, k1, k2, k3, p1, p2; OpenCV pixels of this image) of a DJI photo's
    DewarpData, scaled when the photo is smaller than the calibrated sensor (CalibratedOpticalCenterX is
    half the calibrated width), and a description; None when the photo has none."""
    from ..photo.dji_xmp import read_dji_xmp

    x = read_dji_xmp(image_path)
    if x is None or x.dewarp is None:
        return None
    d = x.dewarp
    cal_w = 2.0 * x.calibrated_optical_center_x_px if x.calibrated_optical_center_x_px else float(width_px)
    k = width_px / cal_w
    # DJI's centre is width/2 with the pixel corner at 0; OpenCV's pixel centres are whole numbers
    cx = (cal_w / 2.0 + d.cx_offset_px) * k - 0.5
    cal_h = 2.0 * x.calibrated_optical_center_y_px if x.calibrated_optical_center_y_px else height_px / k
    cy = (cal_h / 2.0 + d.cy_offset_px) * k - 0.5
    f = 0.5 * (d.fx_px + d.fy_px) * k
    when = f" of {d.calibration_date}" if d.calibration_date else ""
    return np.array([f, cx, cy, d.k1, d.k2, d.k3, d.p1, d.p2]), f"DewarpData{when} in {image_path.name}"


def load_calibration(path) -> dict:
    """Lever arm (with its sigma), delay, camera intrinsics and, for a rolling-shutter camera whose readout
    the run modelled, the readout time of an earlier run (its OUT_DIR or its georef_summary.json): what a
    calibration flight hands to the production flights."""
    p = Path(path)
    summary_path = p / "georef_summary.json" if p.is_dir() else p
    try:
        s = json.loads(summary_path.read_text())
        lad = s["lever_arm_delay"]
        intr = [float(v) for v in s["intrinsics"]["values"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputFileError(summary_path, f"not a georeferencing summary with a lever arm and intrinsics ({exc})") from None
    sig = lad.get("lever_arm_sigma_m")
    shutter = s.get("rolling_shutter") or {}
    readout = shutter.get("readout_s") if shutter.get("modelled") else None
    return {"lever_arm_cam_m": tuple(float(v) for v in lad["lever_arm_cam_m"]),
            "lever_arm_sigma_m": float(max(max(sig), 0.002)) if sig else None,
            "delay_s": float(lad["delay_s"]), "intrinsics": tuple(intr), "camera_model": s.get("camera_model", "brown"),
            "readout_s": None if readout is None else float(readout), "source": str(summary_path)}


def _image_names(image_dir: Path) -> list[str]:
    if not image_dir.is_dir():
        raise InputFileError(image_dir, "the survey has no images/ folder")
    names = sorted(p.name for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise InputFileError(image_dir, "no JPEG/TIFF images found")
    return names


def _shutter_flag(first_image: Path, option: bool | None, readout_s: float | None) -> dict:
    from ..photo.camera_shutter import rolling_shutter_of
    from ..photo.images import read_image_info

    model = read_image_info(first_image, warn=False).model
    if option is not None:
        rolling, source = option, "given by the user"
    elif readout_s is not None and readout_s > 0:
        rolling, source = True, "a readout time given by the user"
    else:
        rolling, source = rolling_shutter_of(model)
    return {"camera_model": model, "rolling_shutter": rolling, "source": source, "modelled": False}


READOUT_CORRELATION_WARNING = 0.4  # above it the estimated readout is called weakly determined (docs)


def _shutter_outcomes(shutters: list[dict], adj: "_Adjusted", opts: GeorefOptions, image_dir: Path,
                      warnings: list) -> None:
    """Each camera group's ``_shutter_outcome``."""
    for g, shutter in enumerate(shutters):
        _shutter_outcome(shutter, adj, opts, image_dir, warnings, g)


def _shutter_outcome(shutter: dict, adj: "_Adjusted", opts: GeorefOptions, image_dir: Path, warnings: list,
                     group: int = 0) -> None:
    """Record in ``shutter`` whether the adjustment modelled the rolling shutter of camera ``group`` (and the
    readout time it used), or warn where a rolling-shutter camera could not be modelled."""
    if not shutter["rolling_shutter"]:
        return
    if adj.camera_velocity_enu_m_s is not None:
        readout, sigma = float(adj.readout_s[group]), adj.readout_sigma_s[group]
        shutter.update(modelled=True, readout_s=round(readout, 6),
                       readout_sigma_s=None if sigma is None else round(sigma, 6),
                       readout_source="given" if opts.readout_s is not None else "estimated")
        names = adj.correlations.get("names", [])
        key = "readout" if len(adj.readout_s) == 1 else f"cam{group + 1}.readout"
        if key in names:
            row = np.abs(np.asarray(adj.correlations["matrix"], float)[names.index(key)])
            others = [(float(r), n) for r, n in zip(row, names) if n != key and np.isfinite(r)]
            if others:
                rho, name = max(others)
                shutter["readout_strongest_correlation"] = {"with": name, "abs_rho": round(rho, 3)}
                if rho > READOUT_CORRELATION_WARNING:
                    warnings.append(
                        f"{image_dir}: the rolling-shutter readout ({1000 * readout:.1f} ms) is correlated "
                        f"{rho:.2f} with {name}: this block separates them weakly (few lines; on such blocks the "
                        f"estimate was found tens of ms off with a sigma of a few ms), so its sigma is optimistic; "
                        f"hold the readout with --readout-ms or a calibration flight's (--calibration)")
        return
    why = "mode 'similarity' does not adjust the images" if opts.mode == "similarity" else \
        "it needs the camera velocities from the GNSS at the triggers, and there are none"
    warnings.append(f"{image_dir}: the camera ({shutter['camera_model'] or 'unknown model'}: {shutter['source']}) "
                    f"has a rolling shutter, which is not modelled here ({why}): its along-track skew (readout time "
                    f"x speed, several cm at survey speeds) stays in the residuals; use mode 'joint' with GNSS, fly "
                    f"slower or use a mechanical/global-shutter camera")


# ------------------------------------------------------------------------------------------- GNSS at images

@dataclass
class ImageGnss:
    """Antenna state at the trigger of each image that has one (ECEF)."""
    names: list[str]
    trigger_gps_time_s: np.ndarray
    position_ecef_m: np.ndarray
    velocity_ecef_m_s: np.ndarray
    sd_ecef_m: np.ndarray
    status: np.ndarray
    source: str
    warnings: list[str] = field(default_factory=list)
    cov_ecef_m2: np.ndarray | None = None     # (N, 3, 3) full covariance where known (else sd_ecef_m, diagonal)
    from_photos: bool = False                 # positions read from the photos (XMP RTK / EXIF GPS), not PPK
    kind: str = ""                            # photo positions: "rtk" or "exif-gps" (photo_positions.py)
    gimbal_deg: np.ndarray | None = None      # photo positions: (N, 2) recorded gimbal pitch, yaw (deg; NaN: none)
    heights_from_takeoff: bool = False        # photo positions: heights from a barometer zeroed at take-off (DJI XMP)


def _read_ppk_events(path: Path) -> dict[str, np.ndarray]:
    with open(path) as f:
        rows = list(csv.DictReader(f))
    g = lambda k: np.array([float(r[k]) for r in rows])  # noqa: E731
    return {"t": g("gps_time_s"), "status": g("status").astype(int),
            "pos": np.column_stack([g("x_ecef_m"), g("y_ecef_m"), g("z_ecef_m")]),
            "vel": np.column_stack([g("vx_ecef_m_s"), g("vy_ecef_m_s"), g("vz_ecef_m_s")]),
            "sd": np.column_stack([g("sd_x_m"), g("sd_y_m"), g("sd_z_m")])}


def _survey_events(path: Path) -> dict[str, float]:
    """image name -> trigger GPS time from a survey events.csv (columns image, trigger_gps_time_s)."""
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if not rows or "image" not in rows[0] or not any(k in rows[0] for k in ("trigger_gps_time_s", "gps_time_s")):
        raise InputFileError(path, "events.csv needs the columns image and trigger_gps_time_s")
    key = "trigger_gps_time_s" if "trigger_gps_time_s" in rows[0] else "gps_time_s"
    return {r["image"]: float(r[key]) for r in rows}


def _ppk_summary(out: Path) -> dict:
    """OUT_DIR/ppk/summary.json, {} when there is none (or it cannot be read)."""
    try:
        s = json.loads((out / "ppk" / "summary.json").read_text())
    except (OSError, ValueError):
        return {}
    return s if isinstance(s, dict) else {}


def _ppk_exif_offset(out: Path) -> float | None:
    """The EXIF clock offset the PPK of OUT_DIR/ppk took its trigger times with (ppk/summary.json), None when
    its triggers did not come from EXIF times."""
    v = _ppk_summary(out).get("exif_time_offset_s")
    return None if v is None else float(v)


def match_images_to_events(image_dir: Path, image_names: list[str], ppk_events_csv: Path,
                           times: dict[str, float] | None = None, times_source: str = "",
                           ev_csv: Path | None = None) -> ImageGnss:
    """Tie images to the PPK states at their triggers: ``times`` (image -> trigger GPS time) when given,
    else the survey's trigger table ``ev_csv`` (events.csv, or the one made from a DJI MRK), else the
    rover's event records in the order of the images' EXIF times."""
    ev = _read_ppk_events(ppk_events_csv)
    warnings: list[str] = []
    if times is not None or (ev_csv is not None and ev_csv.is_file()):
        if times is None:
            times = _survey_events(ev_csv)
            times_source = ev_csv.name
        names, idx = [], []
        for name in image_names:
            if name not in times:
                warnings.append(f"{name}: no trigger time in {times_source}; the image is used without GNSS")
                continue
            k = int(np.argmin(np.abs(ev["t"] - times[name])))
            if abs(ev["t"][k] - times[name]) > 1e-3:
                warnings.append(f"{name}: its trigger time has no PPK event; the image is used without GNSS")
                continue
            names.append(name)
            idx.append(k)
        source = f"{times_source} (image names) matched to the PPK events"
    else:
        from ..photo.images import read_image_info

        infos = []
        for name in image_names:
            info = read_image_info(image_dir / name)
            t = info.time_original
            infos.append(((t.timestamp() if t.tzinfo else t.replace(tzinfo=None).timestamp()) if t else None, name))
        if len(ev["t"]) != len(image_names):
            raise InputFileError(image_dir, f"{len(image_names)} images but {len(ev['t'])} camera events in "
                                 f"the rover's log and no events.csv to say which is which; give events.csv "
                                 f"(image, trigger_gps_time_s)")
        if any(t is None for t, _ in infos):
            order = list(image_names)
            warnings.append("images without EXIF time: events matched in file-name order")
        else:
            order = [n for _, n in sorted(infos)]
        names, idx = order, list(range(len(order)))
        source = "rover event records, in the order of the images' EXIF times"
    idx = np.asarray(idx, int)
    return ImageGnss(names, ev["t"][idx], ev["pos"][idx], ev["vel"][idx], ev["sd"][idx], ev["status"][idx], source,
                     warnings)


def _photo_position_gnss(image_dir: Path, image_names: list[str], meta: dict, opts: GeorefOptions,
                         warnings: list) -> ImageGnss | None:
    """Camera positions from the photos themselves (DJI RTK XMP, else EXIF GPS) when the survey has no raw
    GNSS: the camera centres are observed directly, so the lever arm is held at zero and no delay is
    estimated (photo_positions.py)."""
    from ..photo.photo_positions import read_photo_positions

    pp = read_photo_positions(image_dir, image_names, str(meta.get("photo_heights", "ellipsoidal")))
    if pp is None:
        return None
    warnings += pp.warnings
    n = len(pp.names)
    sd = np.sqrt(np.abs(np.einsum("kii->ki", pp.cov_ecef_m2)))
    gnss = ImageGnss(pp.names, pp.time_gps_s, pp.position_ecef_m, np.zeros((n, 3)), sd, pp.status, pp.source,
                     cov_ecef_m2=pp.cov_ecef_m2, from_photos=True, kind=str(pp.kind), gimbal_deg=pp.gimbal_deg,
                     heights_from_takeoff=pp.heights_from_takeoff)
    if opts.lever_arm_cam_m is None:
        opts.lever_arm_cam_m = (0.0, 0.0, 0.0)
        opts.estimate_lever_arm = False
    opts.estimate_delay = False
    opts.delay_s = 0.0
    if pp.kind == "exif-gps":
        warnings.append("camera positions from the photos' navigation-grade EXIF GPS (metre level): without control "
                        "points the survey's absolute position is only as good as these positions (see "
                        "absolute_accuracy in the summary); its shape does not depend on them, but its level does: "
                        "heights that drift tilt the block, and a tilted block tilts the DSM and changes volumes, "
                        "unless it is levelled (exif_heights in the summary) or tied by control points")
    return gnss


def _exif_heights(rec, gnss: ImageGnss, gnss_enu: dict, warnings: list, flights: dict | None = None) -> dict | None:
    """EXIF GPS heights checked against the SfM block (photo/exif_heights.py), per flight (``flights``: image ->
    flight, the adjustment's, ``image_flights``); where they drift and the block can be levelled (on the photos'
    recorded gimbal attitudes, else on the nadir-axis assumption unless the axes show an oblique block; without
    attitudes checked against the sparse cloud's ground plane, ``rec.points_xyz``, and levelled on it where the mean
    axis is contradicted: cameras all looking one way), the
    heights given to the adjustment (``gnss_enu``, in place) are the levelled block's at one level from the EXIF
    heights (each flight's at its first photo for heights from a barometer zeroed at take-off, DJI XMP
    RelativeAltitude, else at its mean time; averaged over the photos), and the horizontal sigmas are raised to the positions' scatter, so that the block is levelled instead
    of tilted by the drift."""
    from ..photo.exif_heights import check_exif_heights
    from ..photo.photo_positions import EXIF_GPS_SIGMA_M

    by_name = rec.image_by_name()
    names = [n for n in gnss.names if n in gnss_enu and n in by_name]
    if len(names) < 6:
        return None
    t_of = dict(zip(gnss.names, np.asarray(gnss.trigger_gps_time_s, float)))
    t = np.array([t_of[n] for n in names])
    source = "EXIF times"
    if not np.all(np.isfinite(t)) or len(np.unique(t)) < len(t) // 2:
        t, source = np.array([sorted(names).index(n) for n in names], float), "photo order (no usable EXIF times)"
    C = np.array([by_name[n].centre for n in names])
    A = np.array([by_name[n].R_cam_from_world[2] for n in names])     # the optical axis (camera +z) in the model
    X = np.array([gnss_enu[n][0] for n in names])
    fl = np.array([(flights or {}).get(n, 0) for n in names], int)
    gim = np.full((len(names), 2), np.nan)
    if gnss.gimbal_deg is not None:
        g_of = dict(zip(gnss.names, np.asarray(gnss.gimbal_deg, float).reshape(-1, 2)))
        gim = np.array([g_of.get(n, (np.nan, np.nan)) for n in names], float).reshape(-1, 2)
    out = check_exif_heights(C, A, X, t, EXIF_GPS_SIGMA_M[1], source, sigma_h_m=EXIF_GPS_SIGMA_M[0], flight=fl,
                             gimbal_pitch_deg=gim[:, 0], gimbal_yaw_deg=gim[:, 1],
                             level_at="start" if gnss.heights_from_takeoff else "mean",
                             points_sfm=getattr(rec, "points_xyz", None))
    if out.get("inconsistent") and not out.get("levelled"):
        warnings.append(out["text"])
    if out.get("levelled"):
        h, sig = out.pop("height_enu_m"), float(out["sigma_v_m"])
        sig_h = float(out["sigma_h_m"])
        for k, n in enumerate(names):
            enu, vel, cov, st, tt = gnss_enu[n]
            enu, cov = np.array(enu, float), np.array(cov, float)
            enu[2] = h[k]
            cov[2, :], cov[:, 2] = 0.0, 0.0
            cov[2, 2] = sig ** 2
            if sig_h > EXIF_GPS_SIGMA_M[0]:
                cov[:2, :2] *= (sig_h / EXIF_GPS_SIGMA_M[0]) ** 2
            gnss_enu[n] = (enu, vel, cov, st, tt)
        warnings.append(out["text"])
    return out


def image_flights(gnss: ImageGnss, offsets_csv: Path | None, gap_s: float) -> tuple[dict[str, int], str]:
    """The flight (0, 1, ... in time order) of each image with a GNSS position, and how it was found: the
    flight folders of a DJI survey (``camera_offsets.csv`` -> flight, one per Timestamp.MRK), else a gap of
    more than ``gap_s`` seconds between consecutive trigger times (a battery swap)."""
    from .survey_inputs import read_camera_flights

    names = list(gnss.names)
    t = np.asarray(gnss.trigger_gps_time_s, float)
    if offsets_csv is not None and Path(offsets_csv).is_file():
        rows = read_camera_flights(offsets_csv)
        if names and all(rows.get(n) is not None for n in names):
            raw = {n: rows[n] for n in names}
            order = sorted(set(raw.values()), key=lambda k: min(t[i] for i, n in enumerate(names) if raw[n] == k))
            return {n: order.index(raw[n]) for n in names}, f"flight folders ({Path(offsets_csv).name})"
    if not names:
        return {}, "no GNSS positions"
    if not np.all(np.isfinite(t)):
        return {n: 0 for n in names}, "one flight (trigger times unknown)"
    order = np.argsort(t, kind="stable")
    new_flight = np.r_[False, np.diff(t[order]) > gap_s]
    flight = np.cumsum(new_flight)
    return {names[i]: int(f) for i, f in zip(order, flight)}, f"gaps of more than {gap_s:g} s between photos"


FIXED_STATUS = 1    # a fixed solution: PPK status 1, DJI RtkFlag 50 (photo_positions.STATUS_OF_RTK_FLAG)
# a time without exposures after which a not-fixed stretch is taken as a new one (its bias re-drawn): measured, the lag
# at which a real float error's drifting part has lost half its correlation (45-67 s on the car it was chosen on,
# 26-60 s on two checks; bench/float_error_correlation.py, docs/georeferencing.md "The float-stretch gap, measured")
FLOAT_STRETCH_GAP_S = 60.0


def _stretches(members: list[str], exposures: dict, gap_s: float) -> dict[str, int]:
    """The not-fixed stretch (0, 1, ...) of each not-fixed exposure among ``members`` (one flight): consecutive
    not-fixed exposures in time order (insertion order where a time is missing) are one stretch until a fixed
    exposure or more than ``gap_s`` seconds without an exposure."""
    t = np.array([float(exposures[n][3]) if len(exposures[n]) > 3 else np.nan for n in members])
    order = np.argsort(t, kind="stable") if np.all(np.isfinite(t)) else np.arange(len(members))
    out, k, prev_t, open_ = {}, -1, None, False
    for i in order:
        n = members[i]
        if int(exposures[n][1]) == FIXED_STATUS:
            open_ = False
        else:
            if not open_ or (prev_t is not None and np.isfinite(t[i]) and t[i] - prev_t > gap_s):
                k += 1
            out[n], open_ = k, True
        prev_t = t[i]
    return out


def flight_offset_groups(exposures: dict, flight_sigma_enu_m,
                         stretch_gap_s: float = FLOAT_STRETCH_GAP_S) -> tuple[dict[str, int], list[dict]]:
    """The per-flight offsets' groups and their own prior sigmas from the positions' quality (docs/dji.md, "The
    per-flight prior from the RTK quality"). ``exposures``: image -> (flight, status, per-exposure sigma E/N/U, m:
    the PPK's, or the photo's RtkStd[, trigger time s]). Each flight's fixed exposures (status 1) form one group;
    its other exposures (float, single point) one group per stretch (``_stretches``: contiguous in time, ended by
    a fixed exposure or a gap of more than ``stretch_gap_s``): a float or single-point solution's error is a bias
    drifting over minutes, re-drawn when the solution re-converges, not the epoch-to-epoch noise a fixed one's sigma
    describes. Each group's sigma, per axis, is the larger of ``flight_sigma_enu_m`` and the median of its
    exposures' sigmas. Returns image -> group (flight order, fixed first, then the stretches in time order) and one
    row per group."""
    default = np.asarray(flight_sigma_enu_m, float).reshape(3)
    key = {}
    for f in sorted({int(v[0]) for v in exposures.values()}):
        members = [n for n, v in exposures.items() if int(v[0]) == f]
        stretch = _stretches(members, exposures, stretch_gap_s)
        key.update({n: (f, 0, -1) if n not in stretch else (f, 1, stretch[n]) for n in members})
    keys = sorted(set(key.values()))
    group_of = {n: keys.index(key[n]) for n in exposures}
    n_stretches = {f: sum(1 for k in keys if k[0] == f and k[1]) for f, _, _ in keys}
    rows = []
    for g, (f, not_fixed, stretch) in enumerate(keys):
        members = [n for n in exposures if group_of[n] == g]
        med = np.median(np.array([np.asarray(exposures[n][2], float).reshape(3) for n in members]), axis=0)
        row = {"flight": f + 1, "quality": "not fixed" if not_fixed else "fixed",
               "status": sorted({int(exposures[n][1]) for n in members}), "images": len(members),
               "median_position_sigma_enu_m": med.round(4).tolist(),
               "sigma_enu_m": np.maximum(default, med).round(4).tolist()}
        if not_fixed and n_stretches[f] > 1:
            row["stretch"] = stretch + 1
        rows.append(row)
    return group_of, rows


def flight_offset_prior(opts: GeorefOptions, gnss: ImageGnss | None, n_flights: int,
                        base_position: dict | None, exposures: dict | None = None) -> dict | None:
    """The prior of the per-flight GNSS offsets (docs/georeferencing.md, "Several flights"), or None where they
    are not modelled: PPK or RTK camera positions, ``opts.flight_offsets`` on, or auto with two or more flights,
    a base position that is not surveyed, exposures that are not fixed, or RTK-tagged photos. Common part (every
    flight): the base position's sigma from the PPK summary where it states one (not surveyed), else 0; each
    flight's own part: ``opts.flight_offset_sigma_m`` (horizontal, vertical), raised per group of exposures by their
    quality (``flight_offset_groups``) where ``exposures`` (image -> flight, status, sigma E/N/U[, time s]) is
    given."""
    if opts.flight_offsets == "off" or gnss is None or n_flights < 1:
        return None
    if gnss.from_photos and gnss.kind != "rtk":      # metre-level EXIF GPS: its own sigma dwarfs any offset
        return None
    common = np.zeros(3)
    common_source = "surveyed base (no common part)"
    if gnss.from_photos:
        common_source = ("RTK-tagged photos: the RTK session's error (network or base) is each flight's own part, "
                         "no common part")
    elif base_position and base_position.get("sigma_enu_m") is not None:
        common = np.asarray(base_position["sigma_enu_m"], float).reshape(3)
        common_source = f"base position not surveyed ({base_position.get('source')}): its sigma"
    h, v = (float(x) for x in opts.flight_offset_sigma_m)
    own = np.array([h, h, v])
    group_of, groups = flight_offset_groups(exposures, own) if exposures else (None, None)
    not_fixed = bool(groups) and any(g["quality"] != "fixed" for g in groups)
    # RTK-tagged photos share their session's error (the NTRIP network's or the RTK base's), which their RtkStd
    # does not state: auto models it for one fixed flight too (docs/dji.md, "The RTK session's error")
    rtk_session = bool(gnss.from_photos and gnss.kind == "rtk")
    if opts.flight_offsets == "auto" and n_flights < 2 and not np.any(common > 0) and not not_fixed \
            and not rtk_session:
        return None
    if not np.any(common > 0) and not np.any(own > 0):
        return None                                # a zero prior: nothing to model
    if np.any(common + own <= 0):
        raise ProcessingError(f"flight_offset_sigma_m {opts.flight_offset_sigma_m}: a zero sigma with no base-position "
                              "sigma to add to it leaves an axis without a prior; give positive sigmas or "
                              "flight_offsets off")
    out = {"common_sigma_enu_m": common.round(4).tolist(), "flight_sigma_enu_m": own.round(4).tolist(),
           "common_source": common_source,
           "flight_source": "flight_offset_sigma_m (an assumption: a survey-grade RTK specification, 1 cm + 1 ppm "
                            "horizontally, 1.5 cm + 1 ppm vertically)"}
    if groups:
        out.update(group_of_image=group_of, groups=groups,
                   flight_source=out["flight_source"] + "; per group of a flight's exposures (fixed / each not-fixed "
                   "stretch) the larger of it and the median of the exposures' own sigmas (" +
                   ("the photos' RtkStd" if gnss.from_photos else "the PPK's") + ")")
    return out


def _offset_groups_of(flight_prior: dict, gn: list[str]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The per-flight offsets of the GNSS positions ``gn``: the offset (0..F-1, among those present) of each
    position, the offsets' prior covariance (3F, 3F) and the groups present (flight_offset_prior's)."""
    key = flight_prior.get("group_of_image") or flight_prior["flights"]
    present = sorted({key[n] for n in gn})
    groups = flight_prior.get("groups")
    own = np.array([groups[g]["sigma_enu_m"] for g in present]) if groups else flight_prior["flight_sigma_enu_m"]
    return (np.array([present.index(key[n]) for n in gn], int),
            flight_offset_prior_cov(len(present), flight_prior["common_sigma_enu_m"], own), present)


def _absolute_accuracy(gnss: ImageGnss | None, adj: "_Adjusted", control: ControlData, gnss_enu: dict,
                       base_position: dict | None = None) -> dict:
    """What the result's absolute position rests on, in words and figures, for the summary (and the UI).
    ``base_position``: the PPK summary's base_position (its source and sigma): PPK camera positions are
    relative to the base, so all of them, and the survey with them, share the base position's error."""
    used = list(adj.stats.get("control_points_used") or [])
    n_cp = len(used)
    basis, text = [], []
    if n_cp:
        h, v = np.median([control.points[n].sigma_m for n in used if n in control.points], axis=0) \
            if any(n in control.points for n in used) else (float("nan"), float("nan"))
        basis.append({"kind": "control points", "n": n_cp, "sigma_m": [float(h), float(v)]})
        text.append(f"{n_cp} control point(s) surveyed to {100 * h:.0f} cm horizontally / {100 * v:.0f} cm vertically")
    used_gnss = [gnss_enu[r["image"]][2] for r in adj.gnss_rows if r["image"] in gnss_enu]
    if gnss is not None and used_gnss:
        cov = np.array(used_gnss)
        sh = float(np.median(np.sqrt(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]))))
        sv = float(np.median(np.sqrt(cov[:, 2, 2])))
        kind = "photo positions" if gnss.from_photos else "PPK camera positions"
        basis.append({"kind": kind, "source": gnss.source, "n": len(used_gnss),
                      "median_sigma_m": {"horizontal": round(sh, 4), "vertical": round(sv, 4)}})
        text.append(f"{len(used_gnss)} {kind} ({gnss.source}; stated sigma {_metres(sh)} horizontally, "
                    f"{_metres(sv)} vertically, median per photo)")
    base_sigma = None
    if gnss is not None and not gnss.from_photos and used_gnss and base_position:
        base_sigma = base_position.get("sigma_enu_m")
        basis.append({"kind": "base position", "source": base_position.get("source"), "sigma_enu_m": base_sigma})
        text.append("the base position they are relative to: " + str(base_position.get("text") or
                                                                    base_position.get("source")))
    fo = adj.stats.get("flight_offsets") if adj.stats.get("mode") != "gcp" else None   # gcp: lever arm, delay only
    if fo:
        csig = np.sqrt(np.einsum("nii->ni", np.asarray(adj.centre_cov_enu_m2, float)))
        ch, cv = float(np.median(np.hypot(csig[:, 0], csig[:, 1]) / np.sqrt(2))), float(np.median(csig[:, 2]))
        basis.append({"kind": "per-flight GNSS offsets", "flights": len({r["flight"] for r in fo["flights"]}),
                      "offsets_modelled": len(fo["flights"]), "prior": fo["prior"],
                      "estimated_by": fo["estimated_by"],
                      "offsets": [{k: r[k] for k in ("flight", "offset_enu_m", "sigma_enu_m")} for r in fo["flights"]],
                      "camera_centre_median_sigma_m": {"horizontal": round(ch, 4), "vertical": round(cv, 4)}})
    if not basis:
        return {"basis": [], "text": "no absolute reference"}
    lead = "the survey's absolute position rests on " + " and ".join(text)
    if fo:
        sd = np.array([r["sigma_enu_m"] for r in fo["flights"]])
        n_fl = len({r["flight"] for r in fo["flights"]})
        lead += (f". Each of the {n_fl} flight(s) is given a common offset of its GNSS positions (prior "
                 f"{_metres(float(np.hypot(*fo['prior']['flight_sigma_enu_m'][:2]) / np.sqrt(2)))} horizontally, "
                 f"{_metres(fo['prior']['flight_sigma_enu_m'][2])} vertically per flight"
                 + (", plus the base position's sigma common to all" if any(fo["prior"]["common_sigma_enu_m"]) else "")
                 + "".join(f"; flight {r['flight']}'s {r['images']} exposures not fixed ("
                           + (f"stretch {r['stretch']}; " if r.get("stretch") else "") + f"status {r['status']}) have "
                           f"their own offset, prior {_metres(float(np.hypot(*r['prior_sigma_enu_m'][:2]) / np.sqrt(2)))} "
                           f"horizontally, {_metres(r['prior_sigma_enu_m'][2])} vertically (from their own sigmas)"
                           for r in fo["flights"] if r.get("quality") == "not fixed")
                 + f"), estimated by {fo['estimated_by'].split(':')[0]}: offsets known to "
                 f"{_metres(float(np.median(np.hypot(sd[:, 0], sd[:, 1]) / np.sqrt(2))))} horizontally, "
                 f"{_metres(float(np.median(sd[:, 2])))} vertically; the camera centres' stated sigmas include it "
                 f"(median {_metres(ch)} horizontally, {_metres(cv)} vertically)")
    if base_sigma is not None:
        e, n, u = (float(v) for v in base_sigma)
        lead += (f". The base position is uncertain by {_metres(float(np.hypot(e, n)))} horizontally and "
                 f"{_metres(u)} vertically (1 sigma): every PPK camera position shares that error, so the PPK "
                 "sigmas above describe the survey's shape, not its absolute position"
                 + ("; the control points tie it to the ground" if n_cp else
                    ": with no control point the whole survey is shifted by the base position's error. Give the "
                    "base's surveyed position (--base-pos) or a control point"))
    if not n_cp and gnss is not None and gnss.from_photos:
        lead += (": no control point ties it to the ground, so its absolute accuracy is that of the photo positions "
                 "at their stated sigma, and worse on the ground where the block is small (its tilt rests on the "
                 "photos' height differences: a tilt error moves the ground by the flying height times the angle); "
                 "check points, where given, measure it")
    return {"basis": basis, "text": lead}


def _metres(v: float) -> str:
    return f"{v:.1f} m" if v >= 1.0 else f"{100 * v:.1f} cm"


def _apply_camera_offsets(gnss: ImageGnss, offsets_ned_m: dict[str, np.ndarray], opts: GeorefOptions,
                          warnings: list) -> None:
    """Move each antenna position at an exposure to the camera centre with the aircraft's own per-exposure
    antenna -> camera offset (a DJI MRK's N/E/V, already rotated by the aircraft and gimbal attitude), and
    hold the lever arm at zero: a gimbal camera has no fixed lever arm in the body frame to estimate."""
    from ..gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic

    moved = 0
    for k, name in enumerate(gnss.names):
        d = offsets_ned_m.get(name)
        if d is None or not np.all(np.isfinite(gnss.position_ecef_m[k])):
            continue
        lat, lon, _ = ecef_to_geodetic(gnss.position_ecef_m[k])
        enu = np.array([d[1], d[0], -d[2]])
        gnss.position_ecef_m[k] = gnss.position_ecef_m[k] + ecef_to_enu_rotation(lat, lon).T @ enu
        moved += 1
    gnss.source += "; camera centres from the MRK's per-exposure antenna-to-camera offsets"
    if opts.lever_arm_cam_m is None:
        opts.lever_arm_cam_m = (0.0, 0.0, 0.0)
        opts.estimate_lever_arm = False
        warnings.append(f"{moved} camera centre(s) placed with the aircraft's per-exposure antenna-to-camera offsets "
                        "(DJI MRK, gimbal camera): no lever arm estimated")
    else:
        warnings.append("a lever arm was given although the MRK offsets already place the camera centres: the given "
                        "lever arm is applied on top of them")


# ------------------------------------------------------------------------------------------- roles

def apply_roles(control: ControlData, control_opt: str | None, check_opt: str | None) -> None:
    names = set(control.points)
    if control_opt:
        if control_opt == "all":
            sel = names
        elif control_opt == "none":
            sel = set()
        else:
            sel = {s.strip() for s in control_opt.split(",") if s.strip()}
            unknown = sel - names
            if unknown:
                raise InputFileError("--control", f"unknown point(s): {', '.join(sorted(unknown))}")
        for n, p in control.points.items():
            p.role = "control" if n in sel else "check"
    if check_opt:
        sel = {s.strip() for s in check_opt.split(",") if s.strip()}
        unknown = sel - names
        if unknown:
            raise InputFileError("--check", f"unknown point(s): {', '.join(sorted(unknown))}")
        for n in sel:
            control.points[n].role = "check"


# ------------------------------------------------------------------------------------------- the step

def _project_frame(opts: GeorefOptions, meta: dict, control: ControlData, gnss: ImageGnss | None) -> ProjectFrame:
    from ..gnss.frames import ecef_to_geodetic

    epsg = opts.project_epsg
    if epsg is None and str(meta.get("project_crs", "")).upper().startswith("EPSG:"):
        epsg = int(str(meta["project_crs"]).split(":")[1])
    if gnss is not None and len(gnss.names):
        llh = ecef_to_geodetic(gnss.position_ecef_m.mean(axis=0))
    elif control.points:
        from pyproj import CRS, Transformer

        p = next(iter(control.points.values()))
        tr = Transformer.from_crs(CRS.from_user_input(p.crs), "EPSG:4326", always_xy=True)
        xy = np.array([q.xyz_crs[:2] for q in control.points.values()]).mean(axis=0)
        lon, lat = tr.transform(xy[0], xy[1])
        llh = np.array([np.radians(lat), np.radians(lon), np.mean([q.xyz_crs[2] for q in control.points.values()])])
    else:
        raise ProcessingError("neither GNSS camera positions nor ground control points: nothing to georeference with")
    lat, lon, h = float(np.degrees(llh[0])), float(np.degrees(llh[1])), float(llh[2])
    if epsg is None:
        epsg = utm_epsg_for(lat, lon)
    from pyproj import Transformer

    e, n = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(lon, lat)
    return ProjectFrame(epsg=int(epsg), origin_e=round(float(e), 1), origin_n=round(float(n), 1), h_ref=round(h, 1))


def run_georef(survey_dir, out_dir, options: GeorefOptions | None = None, progress: ProgressFn | None = None) -> dict:
    from ..photo.sfm import SfmOptions, run_sfm, sfm_inputs_key
    from .gnss_solve import gnss_inputs_key, read_survey_json, run_survey_gnss, trigger_table_key, trigger_times_key

    if isinstance(options, dict):
        opts = georef_options_from_dict(options)  # validated there
    else:
        opts = replace(options) if options is not None else GeorefOptions()   # the run's own copy
        validate_shutter_options(opts)
        validate_flight_options(opts)
    if opts.mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}")
    survey_dir, out = Path(survey_dir), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    warnings: list[str] = []
    report = progress or (lambda *a: None)
    meta = read_survey_json(survey_dir)
    from .survey_inputs import read_camera_offsets, survey_inputs

    found = survey_inputs(survey_dir, out)
    warnings += found.warnings
    image_dir = found.image_dir
    image_names = _image_names(image_dir)

    # ---- control points
    gcp_dir = survey_dir / "gcp"
    points_csv = gcp_dir / "points.csv" if (gcp_dir / "points.csv").is_file() else None
    gcp_list = gcp_dir / "gcp_list.txt" if (gcp_dir / "gcp_list.txt").is_file() else None
    control = load_control(points_csv, gcp_list, opts.points_crs or meta.get("points_crs"))
    for p in control.points.values():
        p.sigma_m = tuple(opts.gcp_sigma_m)
    apply_roles(control, opts.control, opts.check)
    target_refinement = None
    if opts.refine_targets and control.measurements:
        from ..adjustment.target_refinement import refine_measurements

        n_ref, n_keep = refine_measurements(image_dir, control.measurements)
        target_refinement = {"refined": n_ref, "kept_as_clicked": n_keep}
    missing_imgs = sorted({m.image for m in control.measurements} - set(image_names))
    if missing_imgs:
        warnings.append(f"{gcp_list}: measurements in images that are not in images/: {', '.join(missing_imgs)} (ignored)")

    # ---- GNSS
    t0 = time.perf_counter()
    gnss = None
    if found.rover_files or (survey_dir / "rover").is_dir():   # a rover/ without a log: the GNSS step says so
        report("gnss", 0, 1)
        ev_csv = out / "ppk" / "events.csv"
        times, times_source = None, ""
        gnss_options = dict(opts.gnss_options)
        # trigger times from the photos' EXIF times are a GNSS-step setting (exif_time_offset_s): the platform's
        # gnss step made ppk/ with them and the run's GNSS options; this step reads them (the command line's
        # --exif-time-offset runs the same GNSS step here, with the command's GNSS options)
        gnss_offset = _ppk_exif_offset(out)
        offset = gnss_offset if opts.ppk_from_gnss_step else opts.exif_time_offset_s
        if offset is not None:
            times, w = exif_trigger_times(image_dir, image_names, offset)
            warnings += w
            times_source = f"EXIF times {offset:+.3f} s"
            gnss_options["exif_time_offset_s"] = offset
        def same_triggers() -> bool:
            """An earlier PPK is reused only when it was made for the same trigger times (the same source: EXIF
            times with the same offset, or not; the same times: their hash, recorded by the GNSS step) from the
            same GNSS files with the same GNSS options (gnss_solve.gnss_inputs_key)."""
            if gnss_options.get("events_csv"):
                key = trigger_table_key(gnss_options["events_csv"])
            elif times is not None:
                key = trigger_times_key(times.values())
            else:
                key = trigger_table_key(found.events_csv)
            prev = _ppk_summary(out)
            return (gnss_offset == offset and prev.get("triggers_sha256") == key
                    and prev.get("inputs_sha256") == gnss_inputs_key(found, gnss_options))

        if not opts.ppk_from_gnss_step and not (opts.reuse and ev_csv.is_file() and same_triggers()):
            run_survey_gnss(survey_dir, out, gnss_options, found=found)
        if ev_csv.is_file():
            gnss = match_images_to_events(image_dir, image_names, ev_csv, times, times_source, found.events_csv)
            warnings += gnss.warnings
            if found.camera_offsets_csv is not None and times is None:
                _apply_camera_offsets(gnss, read_camera_offsets(found.camera_offsets_csv), opts, warnings)
        else:
            warnings.append("the PPK solution has no camera events: images are not tied to GNSS positions")
        report("gnss", 1, 1)
    if gnss is None and not found.rover_files:
        gnss = _photo_position_gnss(image_dir, image_names, meta, opts, warnings)
    timings["gnss_s"] = time.perf_counter() - t0
    if opts.mode in ("joint", "similarity") and gnss is None:
        if opts.mode == "similarity":
            raise ProcessingError("mode 'similarity' needs GNSS camera positions (rover/ + events)")
        warnings.append("no GNSS: the joint adjustment uses the control points only")
    if opts.mode == "similarity" and opts.lever_arm_cam_m is None:
        raise ProcessingError("mode 'similarity' needs a known lever arm (--lever-arm X,Y,Z in the camera frame)")
    frame = _project_frame(opts, meta, control, gnss)

    gnss_enu = {}
    if gnss is not None:
        enu = frame.ecef_to_enu(gnss.position_ecef_m)
        vel = gnss.velocity_ecef_m_s @ frame.R_ecef_to_enu.T
        if gnss.cov_ecef_m2 is not None:
            cov = np.einsum("ij,kjm,lm->kil", frame.R_ecef_to_enu, gnss.cov_ecef_m2, frame.R_ecef_to_enu)
        else:
            cov = np.einsum("ij,kj,lj->kil", frame.R_ecef_to_enu, gnss.sd_ecef_m ** 2, frame.R_ecef_to_enu)
        for k, name in enumerate(gnss.names):
            if gnss.status[k] == 0:
                warnings.append(f"{name}: no PPK solution at its trigger; used without GNSS")
                continue
            gnss_enu[name] = (enu[k], vel[k], cov[k], int(gnss.status[k]), float(gnss.trigger_gps_time_s[k]))
    # the flights (batteries) of the GNSS positions and the prior of their common offsets
    flight_prior, flights = None, {}
    if gnss is not None and gnss_enu:
        flights, flights_source = image_flights(gnss, found.camera_offsets_csv, opts.flight_gap_s)
        flights = {n: f for n, f in flights.items() if n in gnss_enu}
        exposures = {n: (f, gnss_enu[n][3], np.sqrt(np.abs(np.diag(gnss_enu[n][2]))), gnss_enu[n][4])
                     for n, f in flights.items()}
        flight_prior = flight_offset_prior(opts, gnss, len(set(flights.values())),
                                           _ppk_summary(out).get("base_position"), exposures)
        if flight_prior is not None:
            flight_prior.update(flights=flights, flights_from=flights_source)

    # ---- SfM
    t0 = time.perf_counter()
    sfm_model = SFM_MODELS.get(opts.camera_model)
    if sfm_model is None:
        raise ValueError(f"camera model must be one of {tuple(SFM_MODELS)}")
    positions = {n: tuple(float(v) for v in gnss_enu[n][0]) for n in gnss_enu} or None
    sfm_opts = SfmOptions(camera_model=sfm_model, refine_principal_point=opts.camera_model == "brown",
                          num_threads=opts.num_threads, positions=positions)
    sfm_dir = out / "sfm"
    rec = None
    if opts.reuse and (sfm_dir / "sfm_summary.json").is_file():
        prev = json.loads((sfm_dir / "sfm_summary.json").read_text())
        # reused only when made from the same photos with the same options (sfm.sfm_inputs_key)
        if prev.get("inputs_key") == sfm_inputs_key(image_dir, sfm_opts) and (sfm_dir / "sparse" / "0").is_dir():
            from ..photo import colmap_api

            rec = colmap_api.read_model(sfm_dir / "sparse" / "0")
    sfm_reused = rec is not None
    if rec is None:
        import warnings as _warnings

        with _warnings.catch_warnings():   # the left-out photos are reported below, from the SfM summary
            _warnings.filterwarnings("ignore", message=r".*: left out: ")
            res = run_sfm(image_dir, sfm_dir, sfm_opts, progress=progress)
        rec = res.reconstruction
    timings["sfm_s"] = time.perf_counter() - t0
    sfm_summary = json.loads((sfm_dir / "sfm_summary.json").read_text()) if (sfm_dir / "sfm_summary.json").is_file() else {}
    left_out = sfm_summary.get("left_out") or []
    warnings += [lo["reason"] for lo in left_out]
    if rec is None or rec.num_registered < 3:
        raise ProcessingError(f"structure from motion registered {0 if rec is None else rec.num_registered} of "
                              f"{len(image_names)} images: the images do not overlap enough")
    unregistered = sorted(set(image_names) - {im.name for im in rec.images.values()} - {lo["image"] for lo in left_out})
    if unregistered:
        warnings.append(f"{len(unregistered)} image(s) not registered by SfM: {', '.join(unregistered[:10])}"
                        + (" ..." if len(unregistered) > 10 else ""))
    cameras = _camera_groups(rec, image_dir)
    exif_heights = (_exif_heights(rec, gnss, gnss_enu, warnings, flights) if gnss is not None and gnss.kind == "exif-gps"
                    else None)
    shutters = [_shutter_flag(image_dir / c["first_image"], opts.rolling_shutter, opts.readout_s) for c in cameras]

    t0 = time.perf_counter()
    report("adjustment", 0, 1)
    result = _adjust(opts, frame, rec, control, gnss_enu, warnings,
                     rolling=[bool(sh["rolling_shutter"]) for sh in shutters], image_dir=image_dir,
                     flight_prior=flight_prior)
    result.heights_from_block = bool(exif_heights and exif_heights.get("levelled"))
    _shutter_outcomes(shutters, result, opts, image_dir, warnings)
    timings["adjustment_s"] = time.perf_counter() - t0
    report("adjustment", 1, 1)

    t0 = time.perf_counter()
    summary = _write_outputs(out, image_dir, opts, frame, rec, control, result, gnss, warnings, cameras)
    summary["images"]["left_out"] = left_out
    summary["sfm"]["reused"] = sfm_reused   # an earlier model of the same photos and options (sfm_inputs_key)
    summary["absolute_accuracy"] = _absolute_accuracy(gnss, result, control, gnss_enu,
                                                      _ppk_summary(out).get("base_position"))
    summary["inputs"] = found.summary()
    summary["target_refinement"] = target_refinement
    if exif_heights is not None:
        summary["exif_heights"] = exif_heights
        if exif_heights.get("levelled") and isinstance(summary["absolute_accuracy"], dict):
            summary["absolute_accuracy"]["text"] += (
                f"; the photos' heights drift, so the block's level rests instead on {exif_heights['level_basis']} "
                f"(tilt sigma {exif_heights['level_sigma_deg']:g} deg; exif_heights)")
        elif exif_heights.get("inconsistent") and isinstance(summary["absolute_accuracy"], dict):
            summary["absolute_accuracy"]["text"] += (
                "; the photos' heights drift and the block could not be levelled (exif_heights): its tilt rests on "
                "the drifting heights")
    summary["rolling_shutter"] = dict(shutters[0])
    if len(shutters) > 1:
        summary["rolling_shutter"]["cameras"] = shutters
    timings["outputs_s"] = time.perf_counter() - t0
    summary["timings_s"] = {k: round(v, 2) for k, v in timings.items()}
    (out / "georef_summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def _camera_groups(rec, image_dir: Path) -> list[dict]:
    """The SfM's cameras in camera-id order (the adjustment's camera groups): id, size, COLMAP model, the
    registered images and a label from the first image's EXIF (make, model, focal length)."""
    from ..photo.images import read_image_info

    out = []
    for cid in sorted(rec.cameras):
        c = rec.cameras[cid]
        imgs = sorted(im.name for im in rec.images.values() if im.camera_id == cid)
        if not imgs:
            continue
        info = read_image_info(image_dir / imgs[0], warn=False)
        cam = " ".join(v for v in (info.make, info.model) if v) or "unknown camera"
        focal = f"{info.focal_length_mm:g} mm" if info.focal_length_mm else "no EXIF focal length"
        out.append({"colmap_camera_id": int(cid), "width": int(c.width), "height": int(c.height),
                    "label": f"{cam}, {c.width} x {c.height} px, {focal}", "first_image": imgs[0],
                    "n_images": len(imgs)})
    return out


# ------------------------------------------------------------------------------------------- adjustment

@dataclass
class _Adjusted:
    names: list[str]                 # registered image names, camera order
    R_cam_to_enu: np.ndarray
    centre_enu_m: np.ndarray
    centre_cov_enu_m2: np.ndarray
    intrinsics: np.ndarray           # (G, 8): one row per camera group
    intrinsics_sigma: list           # per camera group: parameter name -> sigma
    lever_arm_cam_m: np.ndarray
    lever_arm_sigma_m: np.ndarray | None
    delay_s: float
    delay_sigma_s: float | None
    correlations: dict
    points_enu_m: np.ndarray
    points_rgb: np.ndarray
    gnss_rows: list[dict]            # per image with GNSS: residual ENU, outlier flag, time
    blunders: list[dict]
    used_measurements: dict          # point -> list of (image, uv)
    stats: dict
    rerun: object = None             # callable(control_names) -> (R, C, intr, readout_s) for leave-one-out
    fisheye: bool = False            # projection of ``intrinsics`` (camera_model)
    camera_group: np.ndarray | None = None   # (N,) camera group (row of intrinsics) of each image
    # rolling shutter, where modelled: each camera's velocity (at its trigger; zero for the images of a
    # global-shutter camera), each group's image height and readout
    camera_velocity_enu_m_s: np.ndarray | None = None
    image_height_px: np.ndarray = field(default_factory=lambda: np.zeros(1))
    readout_s: np.ndarray = field(default_factory=lambda: np.zeros(1))
    readout_sigma_s: list = field(default_factory=lambda: [None])
    doming: dict | None = None       # the block's bending against the camera positions (doming.py)
    heights_from_block: bool = False  # the camera heights were the levelled SfM block's (exif_heights.py)
    # per-flight GNSS offsets, where modelled: their covariance (3F, 3F) and each camera centre's with them
    flight_offset_cov_m2: np.ndarray | None = None
    camera_flight_cov_m2: np.ndarray | None = None
    # the adjustment's free global parameters (intrinsics, lever arm, delay, ...): names, covariance (G, G) and
    # each camera's covariance with them (N, 6, G), for the check points' share of their errors
    # (globals_point_cov); None where no bundle adjustment ran (similarity)
    global_names: list | None = None
    global_cov: np.ndarray | None = None
    camera_global_cov: np.ndarray | None = None

    def camera_intrinsics(self, intr: np.ndarray | None = None) -> np.ndarray:
        """(N, 8) each image's intrinsics (its group's row of ``intr``, default the adjusted ones)."""
        intr = self.intrinsics if intr is None else intr
        return np.asarray(intr, float).reshape(-1, 8)[self.camera_group]

    def centre_shift_enu_m(self, cam_idx: np.ndarray, uv_px: np.ndarray, readout_s=None):
        """(n, 3) where each measurement's camera was at its row's exposure, from the camera centre; None
        for a global shutter (bundle_adjustment's rolling-shutter model)."""
        if self.camera_velocity_enu_m_s is None:
            return None
        g = self.camera_group[cam_idx]
        readout = np.asarray(self.readout_s if readout_s is None else readout_s, float).reshape(-1)
        return rolling_shutter_shift(self.camera_velocity_enu_m_s[cam_idx], uv_px[:, 1], self.image_height_px[g],
                                     readout[g])


def _intrinsics_sigmas(res, G: int, fisheye: bool) -> list[dict]:
    """Per camera group: parameter name -> sigma of the free intrinsics (names 'f', ... with one camera,
    'cam2.f', ... with several)."""
    out: list[dict] = [{} for _ in range(G)]
    pn = cm.param_names(fisheye)
    for n in res.global_names:
        g, _, k = n.rpartition(".")
        if k not in pn or (G == 1) != (g == ""):
            continue
        out[int(g[3:]) - 1 if g else 0][k] = res.value(n)[1]
    return out


def _initial_similarity(rec, names, gnss_enu, lever, control: ControlData, control_enu: dict, im_idx, intr,
                        fisheye: bool = False):
    from ..photo.align import fit_similarity

    by_name = rec.image_by_name()
    with_gnss = [n for n in names if n in gnss_enu]
    if len(with_gnss) >= 3:
        src = np.array([by_name[n].centre for n in with_gnss])
        dst = np.array([gnss_enu[n][0] for n in with_gnss])
        sim, _ = fit_similarity(src, dst)
        # include the lever arm once the rotation is known
        if np.any(lever):
            dst2 = dst + np.array([sim.R @ by_name[n].R_cam_from_world.T @ lever for n in with_gnss])
            sim, _ = fit_similarity(src, dst2)
        return sim
    # control points triangulated in the model frame
    R_model = np.array([by_name[n].R_cam_from_world.T for n in names])
    C_model = np.array([by_name[n].centre for n in names])
    src, dst = [], []
    for pname, p in control.points.items():
        if p.role != "control":
            continue
        ms = [m for m in control.measurements_of(pname) if m.image in im_idx]
        if len(ms) < 2:
            continue
        uv, cams = np.array([m.uv_px for m in ms]), np.array([im_idx[m.image] for m in ms])
        keep, _ = find_blunders(pname, [m.image for m in ms], uv, cams, R_model, C_model, intr,
                                fisheye=fisheye)  # (reported later)
        if len(keep) < 2:
            continue
        t = triangulate(uv[keep], cams[keep], R_model, C_model, intr, fisheye=fisheye)
        src.append(t.xyz_enu_m)
        dst.append(control_enu[pname])
    if len(src) < 3:
        raise ProcessingError(f"{len(src)} control points are measured in two or more images; at least 3 are needed "
                              f"without GNSS camera positions")
    sim, _ = fit_similarity(np.array(src), np.array(dst))
    return sim


def select_tie_points(xyz_enu_m: np.ndarray, track_length: np.ndarray, max_points: int, cells: int = 40) -> np.ndarray:
    """Indices of at most ``max_points`` points spread over a cells x cells horizontal grid, taking the
    longest tracks of each cell first (round robin over the cells), points seen in 2 images last."""
    n = len(xyz_enu_m)
    if n <= max_points:
        return np.arange(n)
    xy = xyz_enu_m[:, :2]
    lo, hi = np.percentile(xy, 1, axis=0), np.percentile(xy, 99, axis=0)
    ij = np.clip(((xy - lo) / np.maximum(hi - lo, 1e-9) * cells).astype(int), 0, cells - 1)
    cell = ij[:, 0] * cells + ij[:, 1]
    # rank of each point inside its cell by decreasing track length
    order = np.lexsort((-track_length, cell))
    first = np.r_[0, np.flatnonzero(np.diff(cell[order])) + 1]
    rank = np.arange(n) - np.repeat(first, np.diff(np.r_[first, n]))
    key = rank + np.where(track_length[order] < 3, n, 0)
    return np.sort(order[np.argsort(key, kind="stable")[:max_points]])


CONTROL_SIGMA0_P = 0.001   # a control variance factor above its chi-square quantile at this level is flagged


def control_accuracy_warning(sigma0: dict, n_control: int) -> str | None:
    """A warning when the control points' a-posteriori variance factor says their coordinates (or their
    identification in the images) are much worse than the survey accuracy they are weighted with, else None.
    The factor's square is a chi-square over its redundancy divided by it; the redundancy is at most 3 per point
    and less where the points also fix the datum, so the quantile is taken with n_control degrees of freedom
    (the larger threshold: a factor above it is beyond chance whatever the redundancy between n and 3n)."""
    s = sigma0.get("control") if isinstance(sigma0, dict) else None
    if s is None or n_control < 1 or not np.isfinite(s):
        return None
    from scipy.stats import chi2

    limit = float(np.sqrt(chi2.ppf(1.0 - CONTROL_SIGMA0_P, n_control) / n_control))
    if s <= limit:
        return None
    return (f"the control points fit the block {s:.1f} times worse than their stated survey accuracy (variance "
            f"factor sigma0 {s:.2f}, above {limit:.2f}, the {100 * (1 - CONTROL_SIGMA0_P):.1f} % bound for "
            f"{n_control} point(s)): their coordinates are less accurate than assumed (e.g. hand-held GPS instead of "
            "a survey), or some are misidentified in the images; the stated accuracy of the result rests on them, "
            "so check them (the residual table names each)")


def _adjust(opts: GeorefOptions, frame: ProjectFrame, rec, control: ControlData, gnss_enu: dict, warnings: list,
            rolling: bool | list = False, image_dir: Path | None = None, flight_prior: dict | None = None) -> _Adjusted:
    # the camera groups: the SfM's cameras of the registered images, in camera-id order (camera 1 is the
    # largest group); every image has its group's intrinsics
    images = sorted(rec.images.values(), key=lambda im: im.name)
    names = [im.name for im in images]
    cam_ids = sorted({im.camera_id for im in images})
    cams = [rec.cameras[c] for c in cam_ids]
    G = len(cams)
    cam_group = np.array([cam_ids.index(im.camera_id) for im in images], int)
    rolling_g = list(rolling) if isinstance(rolling, (list, tuple)) else [bool(rolling)] * G
    fisheye = cm.is_fisheye(opts.camera_model)
    for cam in cams:
        if fisheye != (cam.model in cm.COLMAP_FISHEYE_MODELS):
            raise ProcessingError(f"the structure from motion used the COLMAP camera {cam.model}, which does not match "
                                  f"the camera model {opts.camera_model!r}; re-run with --rerun")
    # the SfM's own cameras go with its poses (the starting orientation and the blunder screening on them); a
    # calibrated camera (fixed_intrinsics) is what the adjustment holds
    intr_sfm = np.array([cm.from_colmap(c.model, c.params) for c in cams])          # (G, 8)
    intr0 = intr_sfm.copy()
    held = np.zeros(G, bool)                   # groups held at a calibration
    prior = None
    if opts.factory_calibration != "ignore" and not fisheye and image_dir is not None:
        pv, ps, src = np.zeros((G, 8)), np.full((G, 8), np.inf), []
        for g, cam in enumerate(cams):
            if g == 0 and opts.fixed_intrinsics is not None:
                continue
            first = names[int(np.flatnonzero(cam_group == g)[0])]
            fc = factory_calibration(image_dir / first, cam.width, cam.height)
            if fc is None:
                continue
            label = fc[1] if G == 1 else f"camera {g + 1}: {fc[1]}"
            if opts.factory_calibration == "fixed":
                intr0[g], held[g] = fc[0], True
                warnings.append(f"camera held at its factory calibration ({label})")
            else:
                sg = FACTORY_CALIBRATION_SIGMA
                pv[g] = fc[0]
                ps[g] = [sg["f_rel"] * fc[0][0], sg["pp_px"], sg["pp_px"], sg["k"], sg["k"], sg["k"], sg["p"], sg["p"]]
                src.append(label)
        if src:
            prior = (pv, ps, "; ".join(src))
    if opts.fixed_intrinsics is not None:
        if len(opts.fixed_intrinsics) != 8:
            raise ProcessingError(f"fixed intrinsics need 8 values: {', '.join(cm.param_names(fisheye)[:7 if fisheye else 8])}"
                                  f"{', 0' if fisheye else ''} (OpenCV pixels)")
        intr0[0], held[0] = np.asarray(opts.fixed_intrinsics, float), True
        if G > 1:
            warnings.append(f"the given calibration holds camera 1 ({cams[0].width} x {cams[0].height} px); the "
                            f"other {G - 1} camera(s) are self-calibrated")
    intr_sfm_cam = intr_sfm[cam_group]         # (N, 8) each image's SfM camera
    im_idx = {n: i for i, n in enumerate(names)}
    id_to_idx = {im.image_id: i for i, im in enumerate(images)}
    lever0 = np.asarray(opts.lever_arm_cam_m, float) if opts.lever_arm_cam_m is not None else np.zeros(3)
    ctl_points = list(control.points.values())
    control_enu = dict(zip([p.name for p in ctl_points], points_to_enu(ctl_points, frame))) if ctl_points else {}

    # rolling shutter: modelled where the images are adjusted and the GNSS gives each camera's velocity
    # (images without GNSS, or of a global-shutter camera, keep a zero velocity: their rows are taken as
    # exposed at once)
    cam_vel = None
    if any(rolling_g) and gnss_enu and opts.mode in ("joint", "gcp"):
        cam_vel = np.array([gnss_enu[n][1] if n in gnss_enu and rolling_g[cam_group[i]] else np.zeros(3)
                            for i, n in enumerate(names)], float)
    estimate_readout = cam_vel is not None and opts.readout_s is None
    readout0 = np.array([float(opts.readout_s) if opts.readout_s is not None and rolling_g[g] else 0.0
                         for g in range(G)])
    heights = np.array([float(c.height) for c in cams])

    sim = _initial_similarity(rec, names, gnss_enu, lever0, control, control_enu, im_idx, intr_sfm_cam, fisheye)
    R0 = np.array([sim.R @ im.R_cam_from_world.T for im in images])
    C0 = np.array([sim.apply(im.centre[None])[0] for im in images])

    # blunders among the control/check point measurements (on the initial orientation)
    blunders, used = [], {}
    for pname in control.points:
        ms = [m for m in control.measurements_of(pname) if m.image in im_idx]
        if not ms:
            continue
        keep, reps = find_blunders(pname, [m.image for m in ms], np.array([m.uv_px for m in ms]),
                                   np.array([im_idx[m.image] for m in ms]), R0, C0, intr_sfm_cam, opts.blunder_threshold_px,
                                   fisheye=fisheye)
        for r in reps:
            blunders.append({"point": r.point, "image": r.image, "residual_px": round(r.residual_px, 2), "message": r.message})
            warnings.append(r.message)
        used[pname] = [(ms[i].image, ms[i].uv_px) for i in keep]

    # tie points: a spatially even subset, longest tracks first in each cell
    pts = rec.points_xyz
    order = select_tie_points(sim.apply(pts), rec.points_track_length, opts.max_tie_points)
    keep_pt = np.zeros(len(pts), bool)
    keep_pt[order] = True
    new_index = -np.ones(len(pts), int)
    new_index[keep_pt] = np.arange(keep_pt.sum())
    sel = keep_pt[rec.obs_point_index] & np.isin(rec.obs_image_id, list(id_to_idx))
    tie_cam = np.array([id_to_idx[i] for i in rec.obs_image_id[sel]], int)
    tie_pt = new_index[rec.obs_point_index[sel]]
    tie_uv = rec.obs_xy_px[sel] - 0.5
    tie_xyz = sim.apply(pts[keep_pt])
    rgb = rec.points_rgb[keep_pt]

    def build(control_names: set[str], use_gnss: bool, start=None) -> tuple[BundleProblem, list[str], list[str]]:
        """Problem with the tie points, the GCPs measured in >= 2 images (control ones with priors);
        ``start`` = (R, C, tie points, intrinsics, lever arm, delay, readout) warm-starts it."""
        n_tie = len(tie_xyz)
        Rs, Cs, Ps, Is, Ls, Ds, Ts = start if start is not None else (R0, C0, tie_xyz, intr0, lever0,
                                                                       float(opts.delay_s), readout0)
        gcp_names = [n for n in used if len(used[n]) >= 2 and n in control_names]
        g_xyz, g_cam, g_pt, g_uv = [], [], [], []
        for k, n in enumerate(gcp_names):
            ms = used[n]
            t = triangulate(np.array([m[1] for m in ms]), np.array([im_idx[m[0]] for m in ms]), Rs, Cs,
                            np.asarray(Is).reshape(-1, 8)[cam_group], fisheye=fisheye)
            g_xyz.append(t.xyz_enu_m)
            for img, uv in ms:
                g_cam.append(im_idx[img])
                g_pt.append(n_tie + k)
                g_uv.append(uv)
        P = np.vstack([Ps, np.array(g_xyz).reshape(-1, 3)])
        obs_cam = np.concatenate([tie_cam, np.array(g_cam, int)])
        obs_pt = np.concatenate([tie_pt, np.array(g_pt, int)])
        obs_uv = np.vstack([tie_uv, np.array(g_uv).reshape(-1, 2)])
        sig = np.concatenate([np.full(len(tie_cam), opts.sigma_px), np.full(len(g_cam), opts.gcp_sigma_px)])
        grp = np.concatenate([np.zeros(len(tie_cam), int), np.ones(len(g_cam), int)])
        gn = [n for n in names if n in gnss_enu] if use_gnss else []
        prob = BundleProblem(R_cam_to_enu=Rs.copy(), centre_enu_m=Cs.copy(), intrinsics=Is.copy(), points_enu_m=P,
                             obs_camera=obs_cam, obs_point=obs_pt, obs_uv_px=obs_uv, obs_sigma_px=sig, obs_group=grp,
                             gnss_camera=np.array([im_idx[n] for n in gn], int),
                             antenna_enu_m=np.array([gnss_enu[n][0] for n in gn]).reshape(-1, 3),
                             antenna_velocity_enu_m_s=np.array([gnss_enu[n][1] for n in gn]).reshape(-1, 3),
                             antenna_cov_enu_m2=np.array([gnss_enu[n][2] for n in gn]).reshape(-1, 3, 3),
                             lever_arm_cam_m=np.array(Ls, float), delay_s=float(Ds),
                             control_point=np.arange(n_tie, n_tie + len(gcp_names), dtype=int),
                             control_enu_m=np.array([control_enu[n] for n in gcp_names]).reshape(-1, 3),
                             control_cov_enu_m2=point_sigma_enu_cov([control.points[n] for n in gcp_names]),
                             fisheye=fisheye, camera_velocity_enu_m_s=cam_vel, camera_group=cam_group,
                             image_height_px=heights, readout_s=np.asarray(Ts, float).copy())
        if opts.lever_arm_cam_m is not None and opts.lever_arm_sigma_m is not None:
            prob.lever_arm_prior_cam_m = lever0.copy()
            prob.lever_arm_prior_sigma_m = np.full(3, float(opts.lever_arm_sigma_m))
        if prior is not None:
            prob.intrinsics_prior, prob.intrinsics_prior_sigma = prior[0].copy(), prior[1].copy()
        if flight_prior is not None and gn:   # a common offset per flight (flight_offset_prior)
            prob.gnss_flight, prob.flight_offset_prior_cov_m2, _ = _offset_groups_of(flight_prior, gn)
        return prob, gn, gcp_names

    free = np.tile(cm.free_mask(opts.camera_model), (G, 1))
    free[held] = False
    est_lever = opts.estimate_lever_arm if opts.estimate_lever_arm is not None else \
        (opts.lever_arm_cam_m is None or opts.lever_arm_sigma_m is not None)
    control_names = {n for n, p in control.points.items() if p.role == "control"}
    lever_sigma = None
    delay_sigma = None
    flight_cov = cam_flight_cov = None
    glob: tuple = (None, None, None)     # the bundle adjustment's globals: names, covariance, cameras' with them
    correlations: dict = {}
    gnss_rows: list[dict] = []
    stats: dict = {"mode": opts.mode}
    if prior is not None:
        g0 = int(np.flatnonzero(np.isfinite(prior[1][:, 0]))[0])
        stats["factory_calibration"] = {"source": prior[2], "used_as": "prior",
                                        "sigma": dict(zip(cm.param_names(fisheye), prior[1][g0].round(6).tolist()))}
    elif opts.factory_calibration == "fixed" and held.any():
        stats["factory_calibration"] = {"used_as": "fixed"}

    def run_ba(control_set, use_gnss, with_lever, with_delay, start=None, variances=None):
        prob, gn, gcps = build(control_set, use_gnss, start)
        bo = BundleOptions(free_intrinsics=free, estimate_lever_arm=with_lever, estimate_delay=with_delay,
                           estimate_readout=estimate_readout)
        if variances is not None:  # a warm re-run keeps the variance factors of the full adjustment
            bo.variance_components = False
            bo.initial_variances = dict(variances)
        return adjust(prob, bo), gn, gcps

    if opts.mode == "joint":
        res, gn, gcps = run_ba(control_names, True, est_lever and bool(gnss_enu), opts.estimate_delay and bool(gnss_enu))
        prob = res.problem
        lever, delay = prob.lever_arm_cam_m, prob.delay_s
        if "lever_x" in res.global_names:
            lever_sigma = np.array([res.value(k)[1] for k in ("lever_x", "lever_y", "lever_z")])
        if "delay" in res.global_names:
            delay_sigma = res.value("delay")[1]
        corr = res.global_correlation()
        correlations = {"names": res.global_names, "matrix": np.round(corr, 3).tolist()}
        for k, n in enumerate(gn):
            gnss_rows.append({"image": n, "gps_time_s": gnss_enu[n][4], "status": gnss_enu[n][3],
                              "residual_enu_m": res.gnss_residual_enu_m[k].round(5).tolist(),
                              "sigma_u_m": round(float(np.sqrt(gnss_enu[n][2][2, 2] + 0.005 ** 2)), 5),
                              "outlier": bool(res.gnss_outlier[k])})
        stats.update({"iterations": res.iterations, "converged": res.converged,
                      "rms_reprojection_px": round(res.rms_reprojection_px, 3), "sigma0": res.sigma0,
                      "tie_observation_outliers": int(res.obs_outlier.sum()), "gnss_outliers": int(res.gnss_outlier.sum()),
                      "control_points_used": gcps})
        w = control_accuracy_warning(res.sigma0, len(gcps) if gcps else 0)
        if w:
            warnings.append(w)
        if res.flight_offset_enu_m is not None:
            flight_cov, cam_flight_cov = res.flight_offset_cov_m2, res.camera_flight_cov_m2
            stats["flight_offsets"] = _flight_offsets_summary(
                flight_prior, gn, res, "the control points" if gcps else "nothing: no control point, the prior is "
                "propagated into the covariances (only the flights' differences are measured, by the tie points)")
        intr = prob.intrinsics
        isig = _intrinsics_sigmas(res, G, fisheye)
        glob = (res.global_names, res.global_cov, res.camera_global_cov)
        R, C = prob.R_cam_to_enu, prob.centre_enu_m
        ccov = res.camera_cov[:, 3:, 3:]
        P, prgb = prob.points_enu_m[:len(tie_xyz)], rgb
    elif opts.mode == "gcp":
        res, _, gcps = run_ba(control_names, False, False, False)
        if len(gcps) < 3:
            raise ProcessingError(f"mode 'gcp' needs at least 3 control points measured in two or more images "
                                  f"(have {len(gcps)})")
        prob = res.problem
        R, C, intr = prob.R_cam_to_enu, prob.centre_enu_m, prob.intrinsics
        gn = [n for n in names if n in gnss_enu]
        if len(gn) < 3:
            raise ProcessingError("mode 'gcp' estimates the lever arm and delay from GNSS camera positions: none found")
        k_idx = [im_idx[n] for n in gn]
        cov = np.array([gnss_enu[n][2] for n in gn]) + res.camera_cov[k_idx][:, 3:, 3:] + np.eye(3) * 1e-6
        fl, fl_cov = (None, None) if flight_prior is None else _offset_groups_of(flight_prior, gn)[:2]
        fit = estimate_lever_arm_delay(R[k_idx], C[k_idx], np.array([gnss_enu[n][0] for n in gn]),
                                       np.array([gnss_enu[n][1] for n in gn]), cov, estimate_lever=est_lever,
                                       lever_arm_cam_m=lever0, estimate_delay=opts.estimate_delay, delay_s=opts.delay_s,
                                       flight=fl, offset_prior_cov_m2=fl_cov)
        if fit.flight_offset_enu_m is not None:   # they move the lever arm and delay only (the cameras: control)
            stats["flight_offsets"] = _flight_offsets_summary(
                flight_prior, gn, fit, "the control points' camera orientations (the offsets enter the lever arm and "
                "delay only; the vertical offsets and the lever arm's camera z are told apart by the prior alone)")
            if est_lever:
                warnings.append("mode 'gcp' with per-flight GNSS offsets: the lever arm's component along the camera "
                                "axis cannot be told from the flights' vertical GNSS offsets (a nadir camera); its "
                                "sigma includes their prior (lever_arm_delay.json)")
        lever, delay = fit.lever_arm_cam_m, fit.delay_s
        if est_lever:
            lever_sigma = np.array([fit.sigma(k) for k in ("lever_x", "lever_y", "lever_z")])
        if opts.estimate_delay:
            delay_sigma = fit.sigma("delay")
        s = np.sqrt(np.diag(fit.cov))
        correlations = {"names": fit.names, "matrix": np.round(fit.cov / np.outer(s, s), 3).tolist()}
        for k, n in enumerate(gn):
            gnss_rows.append({"image": n, "gps_time_s": gnss_enu[n][4], "status": gnss_enu[n][3],
                              "residual_enu_m": (-fit.residual_enu_m[k]).round(4).tolist(), "outlier": bool(fit.outlier[k])})
        stats.update({"rms_reprojection_px": round(res.rms_reprojection_px, 3), "sigma0": res.sigma0,
                      "lever_delay_sigma0": fit.sigma0, "control_points_used": gcps,
                      "gnss_outliers": int(fit.outlier.sum())})
        w = control_accuracy_warning(res.sigma0, len(gcps))
        if w:
            warnings.append(w)
        isig = _intrinsics_sigmas(res, G, fisheye)
        glob = (res.global_names, res.global_cov, res.camera_global_cov)
        ccov = res.camera_cov[:, 3:, 3:]
        P, prgb = prob.points_enu_m[:len(tie_xyz)], rgb
    else:  # similarity
        by_name = rec.image_by_name()
        gn = [n for n in names if n in gnss_enu]
        fl, fl_cov = (None, None) if flight_prior is None else _offset_groups_of(flight_prior, gn)[:2]
        fit = fit_similarity_delay(np.array([by_name[n].centre for n in gn]),
                                   np.array([by_name[n].R_cam_from_world.T for n in gn]),
                                   np.array([gnss_enu[n][0] for n in gn]), np.array([gnss_enu[n][1] for n in gn]),
                                   np.array([gnss_enu[n][2] for n in gn]) + np.eye(3) * 1e-5, lever0,
                                   estimate_delay=opts.estimate_delay, flight=fl, offset_prior_cov_m2=fl_cov)
        s, Rs, t = fit.similarity
        R = np.array([Rs @ im.R_cam_from_world.T for im in images])
        C = np.array([s * Rs @ im.centre + t for im in images])
        intr = intr0
        lever, delay = lever0, fit.delay_s
        if opts.estimate_delay:
            delay_sigma = fit.sigma("delay")
        isig = [{} for _ in range(G)]
        sd = np.sqrt(np.diag(fit.cov))
        correlations = {"names": fit.names, "matrix": np.round(fit.cov / np.outer(sd, sd), 3).tolist()}
        for k, n in enumerate(gn):
            gnss_rows.append({"image": n, "gps_time_s": gnss_enu[n][4], "status": gnss_enu[n][3],
                              "residual_enu_m": (-fit.residual_enu_m[k]).round(4).tolist(), "outlier": bool(fit.outlier[k])})
        stats.update({"scale": s, "sigma0": fit.sigma0, "gnss_outliers": int(fit.outlier.sum())})
        ccov = np.repeat((np.mean([np.trace(gnss_enu[n][2]) for n in gn]) / 3 * fit.sigma0 ** 2 * np.eye(3))[None], len(names), 0)
        if fit.flight_offset_enu_m is not None:
            # the similarity's own uncertainty, which now holds the offsets' (its translation and their mean are
            # told apart by their prior only), added to each centre; the check points get their share
            sim_cov, cam_flight_cov = similarity_centre_cov(fit, np.array([im.centre for im in images]))
            ccov = ccov + sim_cov
            flight_cov = fit.flight_offset_cov_m2
            stats["flight_offsets"] = _flight_offsets_summary(
                flight_prior, gn, fit, "nothing: the similarity's translation and the offsets' mean are told apart by "
                "the prior only, which is propagated into the covariances (the flights' differences are measured)")
        P, prgb = s * pts @ Rs.T + t, rec.points_rgb

    final = (res.problem, res.sigma0) if opts.mode in ("joint", "gcp") else None

    def rerun(control_set: set[str]):
        fp, s0 = final
        start = (fp.R_cam_to_enu, fp.centre_enu_m, fp.points_enu_m[:len(tie_xyz)], fp.intrinsics, fp.lever_arm_cam_m,
                 fp.delay_s, fp.readout_s)
        var = {k: v ** 2 for k, v in s0.items()}
        if opts.mode == "joint":
            r, _, _ = run_ba(control_set, True, est_lever and bool(gnss_enu), opts.estimate_delay and bool(gnss_enu),
                             start, var)
        elif opts.mode == "gcp":
            r, _, g = run_ba(control_set, False, False, False, start, var)
            if len(g) < 3:
                return None
        else:
            return None
        return r.problem.R_cam_to_enu, r.problem.centre_enu_m, r.problem.intrinsics, r.problem.readout_s

    readout, readout_sigma = readout0, [None] * G
    if final is not None:
        readout = np.asarray(final[0].readout_s, float).reshape(-1)
        for g in range(G):
            key = "readout" if G == 1 else f"cam{g + 1}.readout"
            if key in res.global_names:
                readout_sigma[g] = res.value(key)[1]
    return _Adjusted(names=names, R_cam_to_enu=R, centre_enu_m=C, centre_cov_enu_m2=ccov,
                     intrinsics=np.asarray(intr, float).reshape(G, 8), intrinsics_sigma=isig,
                     lever_arm_cam_m=np.asarray(lever, float), lever_arm_sigma_m=lever_sigma,
                     delay_s=float(delay), delay_sigma_s=delay_sigma, correlations=correlations, points_enu_m=P,
                     points_rgb=prgb, gnss_rows=gnss_rows, blunders=blunders, used_measurements=used, stats=stats,
                     rerun=rerun, fisheye=fisheye, camera_group=cam_group, camera_velocity_enu_m_s=cam_vel,
                     image_height_px=heights, readout_s=np.asarray(readout, float).reshape(G),
                     readout_sigma_s=readout_sigma, flight_offset_cov_m2=flight_cov, camera_flight_cov_m2=cam_flight_cov,
                     global_names=glob[0], global_cov=glob[1], camera_global_cov=glob[2])


def _flight_offsets_summary(flight_prior: dict, gn: list[str], res, estimated_by: str) -> dict:
    """The summary's flight_offsets: the model, its prior, and per offset (a flight, or its fixed / not-fixed
    exposures where the prior follows the positions' quality) the images, the estimated offset (E, N, U) and its
    sigma. ``res``: anything with ``flight_offset_enu_m`` and ``flight_offset_cov_m2``."""
    key = flight_prior.get("group_of_image") or flight_prior["flights"]
    present = sorted({key[n] for n in gn})
    groups = flight_prior.get("groups")
    sd = np.sqrt(np.abs(np.diag(res.flight_offset_cov_m2))).reshape(-1, 3)
    rows = []
    for k, g in enumerate(present):
        imgs = [n for n in gn if key[n] == g]
        row = {"flight": groups[g]["flight"] if groups else int(g) + 1, "images": len(imgs), "first_image": imgs[0],
               "last_image": imgs[-1], "offset_enu_m": np.asarray(res.flight_offset_enu_m)[k].round(4).tolist(),
               "sigma_enu_m": sd[k].round(4).tolist()}
        if groups:
            row.update({"quality": groups[g]["quality"], "status": groups[g]["status"],
                        "median_position_sigma_enu_m": groups[g]["median_position_sigma_enu_m"],
                        "prior_sigma_enu_m": groups[g]["sigma_enu_m"]})
            if groups[g].get("stretch"):
                row["stretch"] = groups[g]["stretch"]
        rows.append(row)
    return {"model": "C = A(trigger) - o_flight + R L + v dt (o_flight: the error common to the flight's GNSS "
                     "positions, measured minus true, E/N/U)",
            "flights_from": flight_prior["flights_from"],
            "prior": {k: flight_prior[k] for k in ("common_sigma_enu_m", "common_source", "flight_sigma_enu_m",
                                                   "flight_source")},
            "estimated_by": estimated_by,
            "flights": rows}


def _doming(adj: _Adjusted, control: ControlData, frame: ProjectFrame, checks: ResidualTable, warnings: list) -> dict:
    """The block's bending (adjustment/doming.py) from the adjusted camera centres against their GNSS /
    photo positions and, with six or more, from the check points; a warning when significant."""
    from ..adjustment.doming import describe, fit_doming

    out: dict = {"camera_positions": None, "check_points": None}
    idx = {n: i for i, n in enumerate(adj.names)}
    rows = [r for r in adj.gnss_rows if not r["outlier"] and r["image"] in idx and r.get("sigma_u_m")]
    if rows:
        xy = np.array([adj.centre_enu_m[idx[r["image"]], :2] for r in rows])
        out["camera_positions"] = fit_doming(xy, [r["residual_enu_m"][2] for r in rows],
                                             [r["sigma_u_m"] for r in rows], "camera positions (adjusted - GNSS)")
    pts = [r for r in checks.rows if r.name in control.points]
    if len(pts) >= 6:
        enu = dict(zip([r.name for r in pts], points_to_enu([control.points[r.name] for r in pts], frame)))
        out["check_points"] = fit_doming(np.array([enu[r.name][:2] for r in pts]), [r.dz_m for r in pts],
                                         None, "check points (triangulated - surveyed)")
    if out["camera_positions"] and adj.heights_from_block:   # not an independent check: no warning from it
        out["camera_positions"]["note"] = ("against camera heights taken from the levelled SfM block (the EXIF heights "
                                           "drift: exif_heights), not independent ones: it compares the adjusted block with "
                                           "the SfM block's own shape")
    texts = [describe(d) + (" (against heights from the levelled block: not a check)" if d.get("note") else "")
             for d in (out["camera_positions"], out["check_points"]) if d]
    out["text"] = "; ".join(texts) if texts else "doming: not estimated (fewer than 6 camera positions or check points)"
    for d in (out["camera_positions"], out["check_points"]):
        if d and d["significant"] and not d.get("note"):
            warnings.append(f"{describe(d)}: the block is bent; its DSM carries a bowl of about this size. Causes: a "
                            "wrong or held lens distortion, a self-calibration on one flying height with weak camera "
                            "positions. Remedies: a calibrated camera, oblique images or cross lines, control points "
                            "spread over the block (docs/georeferencing.md, Doming)")
    return out


# ------------------------------------------------------------------------------------------- outputs

def _residual_row(name, role, est_enu, cov_enu, frame: ProjectFrame, control: ControlData, n_img, note="") -> ResidualRow:
    from pyproj import CRS, Transformer

    p = control.points[name]
    est_grid = frame.enu_to_grid(est_enu)
    crs = CRS.from_user_input(p.crs)
    if crs.to_epsg() == frame.epsg:
        surveyed = p.xyz_crs
    else:
        tr = Transformer.from_crs(crs, f"EPSG:{frame.epsg}", always_xy=True)
        e, n = tr.transform(p.xyz_crs[0], p.xyz_crs[1])
        surveyed = np.array([e, n, p.xyz_crs[2]])
    d = est_grid - surveyed
    sig = tuple(float(v) for v in np.sqrt(np.abs(np.diag(cov_enu)))) if cov_enu is not None else None
    return ResidualRow(name, role, float(d[0]), float(d[1]), float(d[2]), float(np.linalg.norm(d)), n_img, sig, note)


def flight_offset_point_cov(camera_flight_cov_m2: np.ndarray, flight_offset_cov_m2: np.ndarray) -> np.ndarray:
    """(3, 3) the part of a triangulated point's covariance that the per-flight GNSS offsets' uncertainty puts
    there: each observing camera's centre moves with the offsets by M_i = Cov(C_i, o) Cov(o)^-1, a point
    moves with its cameras' mean shift, so it carries (mean M_i) Cov(o) (mean M_i)^T (linear propagation)."""
    Co = np.asarray(flight_offset_cov_m2, float)
    M = np.mean(np.asarray(camera_flight_cov_m2, float), axis=0) @ np.linalg.pinv(Co)
    return M @ Co @ M.T


def globals_point_cov(adj: _Adjusted, uv_px: np.ndarray, cams: np.ndarray, R: np.ndarray, C: np.ndarray,
                      intr: np.ndarray, readout_s=None) -> np.ndarray | None:
    """(3, 3) the part of a triangulated point's covariance that the adjustment's global parameters put there
    (intrinsics, lever arm, delay; not the per-flight offsets, which flight_offset_point_cov carries), or None
    where the adjustment gave no globals. Linear propagation as for the flight offsets: each observing camera
    moves with the globals g by M_i = Cov(cam_i, g) Cov(g)^-1, so the point moves by V = dX/dg (the intrinsics
    changed and its cameras moved by M_i, at once; central differences of the triangulation) and carries
    V Cov(g) V^T. In a nadir block at one height the focal length is set by its prior and moves every point
    along the axis by -(df/f) x the flying height, which the image noise alone does not state."""
    from scipy.spatial.transform import Rotation

    names, cov, cam_cov = adj.global_names, adj.global_cov, adj.camera_global_cov
    if not names or cov is None or cam_cov is None:
        return None
    pn = list(cm.param_names(adj.fisheye))
    sel, where = [], []                  # global column; (group, intrinsic index) or None for lever / delay
    for k, n in enumerate(names):
        g, _, key = n.rpartition(".")
        if key in pn and (g == "" or g.startswith("cam")):
            sel.append(k)
            where.append((int(g[3:]) - 1 if g else 0, pn.index(key)))
        elif n.startswith("lever_") or n == "delay":
            sel.append(k)
            where.append(None)
    if not sel:
        return None
    Cg = cov[np.ix_(sel, sel)]
    sd = np.sqrt(np.clip(np.diag(Cg), 0.0, None))
    if not np.all(np.isfinite(sd)) or not np.any(sd > 0):
        return None
    used = np.unique(cams)
    M = cam_cov[used][:, :, sel] @ np.linalg.pinv(Cg)            # (n, 6, k) cameras' move per unit of each global
    intr = np.asarray(intr, float).reshape(-1, 8)
    shift = adj.centre_shift_enu_m(cams, uv_px, readout_s)
    V = np.zeros((3, len(sel)))
    for j, w in enumerate(where):
        if sd[j] <= 0:
            continue
        x = []
        for h in (sd[j], -sd[j]):
            Rh, Ch, ih = R.copy(), C.copy(), intr.copy()
            Rh[used] = Rotation.from_rotvec(M[:, :3, j] * h).as_matrix() @ R[used]
            Ch[used] = C[used] + M[:, 3:, j] * h
            if w is not None:
                ih[w] += h
            x.append(triangulate(uv_px, cams, Rh, Ch, adj.camera_intrinsics(ih), fisheye=adj.fisheye,
                                 centre_shift_enu_m=shift).xyz_enu_m)
        V[:, j] = (x[0] - x[1]) / (2.0 * sd[j])
    return V @ Cg @ V.T


def _check_table(adj: _Adjusted, frame, control: ControlData, roles=("check",), R=None, C=None, intr=None,
                 kind="check points", readout_s: float | None = None) -> ResidualTable:
    R = adj.R_cam_to_enu if R is None else R
    C = adj.centre_enu_m if C is None else C
    intr = adj.intrinsics if intr is None else intr
    idx = {n: i for i, n in enumerate(adj.names)}
    table = ResidualTable(kind, f"EPSG:{frame.epsg} (E, N, ellipsoidal h)")
    for name, p in sorted(control.points.items()):
        if p.role not in roles:
            continue
        ms = [m for m in adj.used_measurements.get(name, []) if m[0] in idx]
        if len(ms) < 2:
            continue
        uv, cams = np.array([m[1] for m in ms]), np.array([idx[m[0]] for m in ms])
        t = triangulate(uv, cams, R, C, adj.camera_intrinsics(intr), fisheye=adj.fisheye,
                        centre_shift_enu_m=adj.centre_shift_enu_m(cams, uv, readout_s))
        cov = t.cov_enu_m2
        if cov is not None and adj.camera_flight_cov_m2 is not None:
            cov = cov + flight_offset_point_cov(adj.camera_flight_cov_m2[np.unique(cams)], adj.flight_offset_cov_m2)
        g_cov = globals_point_cov(adj, uv, cams, R, C, intr, readout_s) if cov is not None else None
        if g_cov is not None:
            cov = cov + g_cov
        table.rows.append(_residual_row(name, p.role, t.xyz_enu_m, cov, frame, control, len(ms)))
    return table


def _write_outputs(out: Path, image_dir: Path, opts: GeorefOptions, frame: ProjectFrame, rec, control: ControlData,
                   adj: _Adjusted, gnss, warnings: list, cameras: list[dict] | None = None) -> dict:
    from ..photo.oriented_images import OrientedCamera, OrientedImage, OrientedImages

    # oriented images: one camera per camera group (ids 1, 2, ...)
    rolling = adj.camera_velocity_enu_m_s is not None  # the readout modelled: the dense step needs it too
    cameras = cameras or _camera_groups(rec, image_dir)
    oriented_cams = {}
    for g, c in enumerate(cameras):
        model, params = cm.to_colmap(adj.intrinsics[g], adj.fisheye)
        oriented_cams[g + 1] = OrientedCamera(model, c["width"], c["height"], params,
                                              float(adj.readout_s[g]) if rolling else 0.0)
    oi = OrientedImages(frame=frame, image_dir=Path(os.path.abspath(image_dir)),
                        cameras=oriented_cams,
                        images=[OrientedImage(n, int(adj.camera_group[i]) + 1, adj.R_cam_to_enu[i], adj.centre_enu_m[i],
                                              np.sqrt(np.abs(np.diag(adj.centre_cov_enu_m2[i]))),
                                              adj.camera_velocity_enu_m_s[i] if rolling else None)
                                for i, n in enumerate(adj.names)],
                        sparse_xyz_enu_m=adj.points_enu_m, sparse_rgb=adj.points_rgb,
                        extra={"source": f"georef {opts.mode} adjustment"})
    oi.write(out / "oriented_images.json")
    _write_ply(out / "sparse_points.ply", frame.enu_to_grid(adj.points_enu_m) - np.array([frame.origin_e, frame.origin_n, 0.0]),
               adj.points_rgb, comment=f"project CRS EPSG:{frame.epsg}, offsets from E0={frame.origin_e} N0={frame.origin_n}")

    # check points and leave-one-out
    checks = _check_table(adj, frame, control)
    checks.write(out / "residuals.json", out / "residuals.csv")
    loo = ResidualTable("control points, leave-one-out", checks.crs)
    controls = sorted(n for n, p in control.points.items() if p.role == "control")
    if opts.leave_one_out and controls and opts.mode in ("joint", "gcp"):
        for name in controls:
            r = adj.rerun(set(controls) - {name})
            if r is None:
                continue
            R, C, intr, readout = r
            control.points[name].role = "loo"
            t = _check_table(adj, frame, control, roles=("loo",), R=R, C=C, intr=intr, readout_s=readout)
            control.points[name].role = "control"
            for row in t.rows:
                row.role = "control (left out)"
                loo.rows.append(row)
        loo.write(out / "control_loo.json", out / "control_loo.csv")
    fit_table = _check_table(adj, frame, control, roles=("control",), kind="control points (in the adjustment)")
    adj.doming = _doming(adj, control, frame, checks, warnings)

    lever = {"lever_arm_cam_m": adj.lever_arm_cam_m.round(5).tolist(),
             "lever_arm_sigma_m": None if adj.lever_arm_sigma_m is None else adj.lever_arm_sigma_m.round(5).tolist(),
             "delay_s": round(adj.delay_s, 6), "delay_sigma_s": None if adj.delay_sigma_s is None else round(adj.delay_sigma_s, 6),
             "estimated": {"lever_arm": adj.lever_arm_sigma_m is not None, "delay": adj.delay_sigma_s is not None},
             "model": "C = A(trigger) + R_cam_to_enu @ lever_arm + v(trigger) * delay",
             "correlations": adj.correlations}
    if rolling:  # the readout, with the lever arm and delay: what a calibration flight hands on
        rs0 = adj.readout_sigma_s[0]
        lever.update({"readout_s": round(float(adj.readout_s[0]), 6),
                      "readout_sigma_s": None if rs0 is None else round(rs0, 6),
                      "rolling_shutter_model": "row v seen from C + v(trigger) * (v / image height - 0.5) * readout"})
        lever["estimated"]["readout"] = rs0 is not None
        if len(adj.readout_s) > 1:
            lever["readout_s_per_camera"] = [round(float(v), 6) for v in adj.readout_s]
    (out / "lever_arm_delay.json").write_text(json.dumps(lever, indent=1))
    (out / "gnss_residuals.json").write_text(json.dumps(adj.gnss_rows, indent=1))

    plots = []
    try:
        from ..adjustment.plots import plot_check_residuals, plot_gnss_residuals

        (out / "plots").mkdir(exist_ok=True)
        plots.append(str(plot_check_residuals(out / "plots" / "check_residuals.png", checks, loo, control, frame)))
        if adj.gnss_rows:
            plots.append(str(plot_gnss_residuals(out / "plots" / "gnss_residuals.png", adj.gnss_rows)))
    except ImportError as exc:  # matplotlib missing: the numbers are still written
        warnings.append(f"plots not drawn ({exc})")

    summary = {
        "mode": opts.mode, "camera_model": opts.camera_model, "project_frame": frame.to_dict(),
        "images": {"total": len(_image_names(image_dir)), "registered": len(adj.names),
                   "with_gnss": len(adj.gnss_rows)},
        "gnss_source": gnss.source if gnss is not None else None,
        "sfm": {"mean_reprojection_error_px": rec.mean_reprojection_error_px, "points": int(len(rec.points_xyz))},
        "adjustment": adj.stats,
        "cameras": [{"id": g + 1, **{k: v for k, v in c.items() if k != "first_image"},
                     "values": adj.intrinsics[g].round(7).tolist(),
                     "sigma": {k: float(v) for k, v in adj.intrinsics_sigma[g].items()}} for g, c in enumerate(cameras)],
        "doming": adj.doming,
        "intrinsics": {"names": list(cm.param_names(adj.fisheye)), "values": adj.intrinsics[0].round(7).tolist(),
                       "sigma": {k: float(v) for k, v in adj.intrinsics_sigma[0].items()},
                       "camera": 1 if len(cameras) == 1 else f"camera 1 of {len(cameras)} (see cameras)",
                       "projection": "fisheye" if adj.fisheye else "perspective",
                       "convention": "OpenCV pixels (top-left pixel centre = 0, 0); " + (
                           "OpenCV fisheye: radius f theta (1 + k1 theta^2 + ... + k4 theta^8)" if adj.fisheye else
                           "Brown distortion on normalised coordinates")},
        "lever_arm_delay": lever,
        "check_points": checks.to_dict(), "control_points_fit": fit_table.to_dict(),
        "control_leave_one_out": loo.to_dict() if loo.rows else None,
        "blunders": adj.blunders, "warnings": warnings, "plots": plots,
        "outputs": {k: v for k, v in {"oriented_images": "oriented_images.json", "residuals_json": "residuals.json",
                                                  "residuals_csv": "residuals.csv", "lever_arm_delay": "lever_arm_delay.json",
                                                  "sparse_points": "sparse_points.ply"}.items()},
        "options": {k: v for k, v in asdict(opts).items() if k != "gnss_options"},
    }
    return summary


def _write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray, comment: str = "") -> None:
    header = ("ply\nformat binary_little_endian 1.0\n" + (f"comment {comment}\n" if comment else "")
              + f"element vertex {len(xyz)}\nproperty double x\nproperty double y\nproperty double z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    rec = np.zeros(len(xyz), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rec["r"], rec["g"], rec["b"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(rec.tobytes())


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The georef step as the contract runs it (specs.GEOREF): the PPK is the gnss step's, read as it is."""
    return run_georef(workspace.survey_dir, workspace.out_dir, {**dict(options or {}), "ppk_from_gnss_step": True},
                      progress)
