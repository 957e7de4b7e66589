"""Writers of the ground truth of a simulated survey (the ``truth/`` folder) and of the survey inputs
that are not images (``gcp/points.csv``, ``events.csv``).

truth/ holds:

* ``trajectory.csv``: antenna-phase-centre knots of the true trajectory (time, ECEF position and
  velocity, local ENU, project CRS, body yaw/pitch/roll, ``R_cam_to_enu`` as r00..r22);
  :meth:`georef_core.sim.flight.Trajectory.from_csv` rebuilds the interpolators from it.
* ``camera_poses.json``: per image, trigger and exposure times, camera centre (ECEF, ENU, project
  CRS), attitude (camera to ECEF / ENU / project-grid axes), antenna state at the trigger.
* ``intrinsics.json``, ``lever_arm_delay.json``, ``targets.csv``, ``stockpiles.geojson``,
  ``dsm.tif`` (float32 GeoTIFF of ellipsoidal heights in the project CRS), ``site.json``.
* with machines on the site (``SiteOptions.machines``): ``machines.geojson`` (their blocks) and ``dtm.tif``
  (the bare earth, machines left out, on the grid of ``dsm.tif``).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from ..gnss.gnss_time import gps_time_s_to_week_tow
from .flight import (R_CAM_TO_BODY, CameraEvent, FlightOptions, FlightPlan, Trajectory, antenna_to_camera_enu,
                     gps_time_to_utc)

LEVER_DELAY_CONVENTION = (
    "lever_arm_cam_m: vector from the GNSS antenna phase centre to the camera projection centre, in the camera "
    "frame (x right, y down in the image, z along the optical axis). exposure_gps_time_s = trigger_gps_time_s + "
    "delay_s. Truth: C = apc(t_exposure) + R_cam_to_world(t_exposure) @ lever_arm_cam_m. First-order model used "
    "by georeferencing: C ~= apc(t_trigger) + R_cam_to_world @ lever_arm_cam_m + v_apc(t_trigger) * delay_s.")


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def _is_flat(x) -> bool:
    """Scalars, or a list of scalars, or a matrix (list of lists of scalars): printed on one line."""
    if isinstance(x, list):
        return all(not isinstance(v, (dict, list)) or (isinstance(v, list) and all(not isinstance(w, (dict, list)) for w in v))
                   for v in x)
    return not isinstance(x, dict)


def _format_json(x, level: int = 0) -> str:
    pad = " " * (level + 1)
    if isinstance(x, dict):
        if not x:
            return "{}"
        items = [f"{pad}{json.dumps(k)}: {_format_json(v, level + 1)}" for k, v in x.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * level + "}"
    if isinstance(x, list) and not _is_flat(x):
        items = [f"{pad}{_format_json(v, level + 1)}" for v in x]
        return "[\n" + ",\n".join(items) + "\n" + " " * level + "]"
    return json.dumps(x)


def write_json(path, obj) -> None:
    """JSON with one line per key and number lists / matrices kept on one line (full float precision)."""
    Path(path).write_text(_format_json(_jsonable(obj)) + "\n")


def _antenna_to_camera_enu(trajectory: Trajectory, t: float, lever: np.ndarray, flight: FlightOptions | None):
    if flight is not None and flight.camera_mount == "gimbal":
        return antenna_to_camera_enu(trajectory, t, flight)
    return trajectory.R_cam_to_enu(t) @ lever


def camera_poses(trajectory: Trajectory, events: list[CameraEvent], lever_arm_cam_m, delay_s: float,
                 flight: FlightOptions | None = None) -> list[dict]:
    """Per-image truth poses (see module doc); with a gimbal ``flight`` the antenna -> camera vector of each
    exposure is the mount's (``flight.antenna_to_camera_enu``), recorded as ``antenna_to_camera_ned_m``."""
    frame = trajectory.frame
    lever = np.asarray(lever_arm_cam_m, dtype=float)
    out = []
    for e in events:
        te, tt = e.exposure_gps_time_s, e.trigger_gps_time_s
        R = trajectory.R_cam_to_enu(te)
        offset = _antenna_to_camera_enu(trajectory, te, lever, flight)
        c_enu = trajectory.position_enu(te) + offset
        c_ecef = frame.enu_to_ecef(c_enu)
        c_grid = frame.ecef_to_grid(c_ecef)
        p_trig = trajectory.position_ecef(tt)
        v_trig = trajectory.velocity_ecef(tt)
        R_ecef = frame.R_enu_to_ecef @ R
        model = p_trig + frame.R_enu_to_ecef @ offset + v_trig * delay_s
        R_grid = frame.R_enu_to_grid_axes(float(c_grid[0]), float(c_grid[1]), float(c_grid[2])) @ R
        utc = gps_time_to_utc(te)
        week, tow = gps_time_s_to_week_tow(tt)
        out.append({
            "name": e.name, "index": e.index, "line": e.line,
            "trigger_gps_time_s": tt, "exposure_gps_time_s": te,
            "trigger_gps_week": week, "trigger_tow_s": tow,
            "exposure_utc": utc.isoformat(timespec="microseconds") + "Z",
            "camera_centre_ecef_m": c_ecef, "camera_centre_enu_m": c_enu,
            "camera_centre_crs_m": c_grid, "camera_velocity_enu_m_s": trajectory.velocity_enu(te),
            "R_cam_to_ecef": R_ecef, "R_cam_to_enu": R, "R_cam_to_crs_grid": R_grid,
            "yaw_pitch_roll_deg": trajectory.yaw_pitch_roll_deg(te),
            "antenna_ecef_at_trigger_m": p_trig, "antenna_velocity_ecef_at_trigger_m_s": v_trig,
            "antenna_ecef_at_exposure_m": trajectory.position_ecef(te),
            "first_order_model_error_m": float(np.linalg.norm(model - c_ecef)),
            "antenna_to_camera_ned_m": np.array([offset[1], offset[0], -offset[2]]),
        })
    return out


def write_dsm(path, site, resolution_m: float, bounds_site: tuple[float, float, float, float],
              bare_earth: bool = False) -> dict:
    """Truth DSM (surface sampled at cell centres), float32 GeoTIFF in the project CRS, ellipsoidal heights;
    ``bare_earth``: the truth DTM instead (``Site.bare_earth``: the machines left out).

    The grid is aligned on multiples of the resolution in project-CRS coordinates."""
    import rasterio
    from affine import Affine

    f = site.frame
    r = float(resolution_m)
    xmin, ymin, xmax, ymax = bounds_site
    e_min = math.floor((f.origin_e + xmin) / r) * r
    n_max = math.ceil((f.origin_n + ymax) / r) * r
    e_max = math.ceil((f.origin_e + xmax) / r) * r
    n_min = math.floor((f.origin_n + ymin) / r) * r
    width = int(round((e_max - e_min) / r))
    height = int(round((n_max - n_min) / r))
    x0 = e_min - f.origin_e + 0.5 * r
    y_top = n_max - f.origin_n - 0.5 * r
    z = site.surface_grid(x0, y_top - (height - 1) * r, width, height, r,
                          fn=site.bare_earth if bare_earth else None)[::-1].astype(np.float32)
    profile = {
        "driver": "GTiff", "width": width, "height": height, "count": 1, "dtype": "float32",
        "crs": f"EPSG:{f.epsg}", "transform": Affine(r, 0.0, e_min, 0.0, -r, n_max),
        "compress": "deflate", "predictor": 3, "tiled": True, "blockxsize": 256, "blockysize": 256,
    }
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)
        ds.update_tags(AREA_OR_POINT="Area", VERTICAL="WGS84 ellipsoidal height, metres",
                       SOURCE="georef_core.sim truth " + ("bare earth (no machines)" if bare_earth else "surface")
                       + " sampled at cell centres")
        ds.set_band_description(1, "ellipsoidal height (m)")
    return {"file": Path(path).name, "resolution_m": r, "width": width, "height": height,
            "bounds_crs": [e_min, n_min, e_max, n_max], "epsg": f.epsg}


def stockpiles_geojson(site) -> dict:
    f = site.frame
    feats = []
    for p in site.piles:
        poly = p.footprint_polygon(256)
        zb = p.base_height(poly[:, 0], poly[:, 1])
        ring = [[float(x + f.origin_e), float(y + f.origin_n), float(z)] for (x, y), z in zip(poly, zb)]
        ring.append(ring[0])
        _, k = f.grid_factors(p.cx + f.origin_e, p.cy + f.origin_n)
        props = p.to_dict()
        props["centre_crs_m"] = [p.cx + f.origin_e, p.cy + f.origin_n, float(p.surface(p.cx, p.cy))]
        props["base_plane"]["equation"] = "z = z0_m + dz_dx*(E - centre_E) + dz_dy*(N - centre_N)  (project CRS)"
        props["scale_factor"] = float(k)
        props["volume_ground_m3"] = p.volume / float(k) ** 2
        props["volume_note"] = ("volume_m3: analytic volume above the base plane in project-CRS units (grid m^2 x "
                                "ellipsoidal m), what integrating the DSM gives; volume_ground_m3 = volume_m3 / k^2")
        props["polygon_note"] = "toe outline (256-gon for circular toes), z = base plane height"
        feats.append({"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": [ring]}})
    return {"type": "FeatureCollection", "name": "stockpiles",
            "crs": {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{f.epsg}"}},
            "features": feats}


def write_targets_csv(path, site) -> None:
    f = site.frame
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "role", "easting_m", "northing_m", "ellipsoidal_height_m", "x_ecef_m", "y_ecef_m", "z_ecef_m",
                    "lat_deg", "lon_deg", "size_m", "rotation_deg", "x_site_m", "y_site_m"])
        for t in site.targets:
            e, n = t.x + f.origin_e, t.y + f.origin_n
            ecef = f.grid_to_ecef(e, n, t.z)
            lat, lon = f.grid_to_latlon_rad(e, n)
            w.writerow([t.name, t.role, f"{e:.4f}", f"{n:.4f}", f"{t.z:.4f}", f"{ecef[0]:.4f}", f"{ecef[1]:.4f}",
                        f"{ecef[2]:.4f}", f"{math.degrees(float(lat)):.10f}", f"{math.degrees(float(lon)):.10f}",
                        f"{t.size_m:.3f}", f"{math.degrees(t.rotation_rad):.3f}", f"{t.x:.4f}", f"{t.y:.4f}"])


def write_gcp_points(folder, site, noise_m: tuple[float, float] = (0.0, 0.0), seed: int = 0) -> Path:
    """``gcp/points.csv`` (name, E, N, h, role) and ``gcp/README.md``; optional survey noise (sigma h, v)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    f = site.frame
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 606]))
    path = folder / "points.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "easting_m", "northing_m", "ellipsoidal_height_m", "role"])
        for t in site.targets:
            dn = rng.standard_normal(3) * np.array([noise_m[0], noise_m[0], noise_m[1]])
            w.writerow([t.name, f"{t.x + f.origin_e + dn[0]:.4f}", f"{t.y + f.origin_n + dn[1]:.4f}",
                        f"{t.z + dn[2]:.4f}", t.role])
    n_ctl = sum(t.role == "control" for t in site.targets)
    (folder / "README.md").write_text(
        f"# Ground control points\n\n`points.csv`: centres of the square 2x2 black/white checker targets, "
        f"project CRS EPSG:{f.epsg} (easting, northing in metres) and WGS84 ellipsoidal heights (m).\n\n"
        f"`role`: `control` ({n_ctl} targets: the work-area corners and centre first) are meant as GCPs for the "
        f"adjustment; `check` ({len(site.targets) - n_ctl}) are independent check points, not to be used in it.\n\n"
        f"Survey noise added to these coordinates: sigma {noise_m[0]} m horizontal, {noise_m[1]} m vertical "
        f"(truth without noise: `../truth/targets.csv`).\n")
    return path


def write_events_csv(path, events: list[CameraEvent]) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "trigger_gps_time_s", "gps_week", "tow_s"])
        for e in events:
            week, tow = gps_time_s_to_week_tow(e.trigger_gps_time_s)
            w.writerow([e.name, f"{e.trigger_gps_time_s:.7f}", week, f"{tow:.7f}"])


def write_truth(truth_dir, site, plan: FlightPlan, trajectory: Trajectory, events: list[CameraEvent], camera,
                flight: FlightOptions, dsm_resolution_m: float, dsm_bounds_site, extra: dict | None = None) -> dict:
    """Write every truth file; returns a dict of what was written."""
    d = Path(truth_dir)
    d.mkdir(parents=True, exist_ok=True)
    trajectory.to_csv(d / "trajectory.csv")
    poses = camera_poses(trajectory, events, flight.lever_arm_cam_m, flight.trigger_delay_s, flight)
    write_json(d / "camera_poses.json", {
        "frames": {
            "ecef": "WGS84 ECEF (EPSG:4978), metres",
            "enu": "local east/north/up tangent frame at the site origin: ecef = origin_ecef + R_ecef_to_enu^T @ enu",
            "crs": f"project CRS EPSG:{site.frame.epsg} easting/northing + WGS84 ellipsoidal height",
            "camera": "x right, y down in the image, z along the optical axis (OpenCV / COLMAP)",
            "R_cam_to_crs_grid": "camera axes to (grid east, grid north, up) at the camera (meridian convergence "
                                 "and the vertical's tilt included; projection scale not a rotation)",
            "yaw_pitch_roll_deg": "body FRD w.r.t. local NED at the site origin, ZYX (heading from true north)",
        },
        "site_frame": site.frame.to_dict(),
        "lever_arm_cam_m": list(flight.lever_arm_cam_m), "delay_s": flight.trigger_delay_s,
        "images": poses,
    })
    write_json(d / "intrinsics.json", camera.to_dict())
    write_json(d / "lever_arm_delay.json", {
        "lever_arm_cam_m": list(flight.lever_arm_cam_m), "delay_s": flight.trigger_delay_s,
        "convention": LEVER_DELAY_CONVENTION,
        "R_cam_to_body": R_CAM_TO_BODY, "body_frame": "FRD (x forward, y right, z down)",
        "lever_arm_body_m": (R_CAM_TO_BODY @ np.asarray(flight.lever_arm_cam_m)).tolist(),
    })
    write_targets_csv(d / "targets.csv", site)
    write_json(d / "stockpiles.geojson", stockpiles_geojson(site))
    dsm = write_dsm(d / "dsm.tif", site, dsm_resolution_m, dsm_bounds_site)
    if site.machines:
        from .machines import machines_geojson

        write_json(d / "machines.geojson", machines_geojson(site))
        write_dsm(d / "dtm.tif", site, dsm_resolution_m, dsm_bounds_site, bare_earth=True)
    desc = site.to_dict()
    desc["flight_plan"] = {
        "line_bearing_deg": plan.line_bearing_deg, "line_spacing_m": plan.line_spacing_m,
        "trigger_spacing_m": plan.trigger_spacing_m, "footprint_m_across_along": plan.footprint_m,
        "takeoff_site_xy_m": plan.takeoff_xy, "takeoff_ground_h_m": plan.takeoff_ground_h,
        "antenna_h_on_lines_m": plan.flight_h, "lines": plan.lines,
    }
    desc["trajectory"] = {"t_start_gps_s": trajectory.t_start, "t_end_gps_s": trajectory.t_end, **trajectory.info}
    desc["dsm"] = dsm
    if extra:
        desc.update(extra)
    write_json(d / "site.json", desc)
    return {"dsm": dsm, "n_images": len(events)}


def write_gcp_image_measurements(path, site, trajectory: Trajectory, events: list[CameraEvent], camera,
                                 lever_arm_cam_m, noise_px: float = 0.3, seed: int = 0, border_px: float = 8.0,
                                 flight: FlightOptions | None = None, camera_of: dict | None = None) -> int:
    """``gcp/gcp_list.txt``: where a surveyor would have clicked each target in each image, in OpenDroneMap's
    format (first line the CRS, then ``E N h x y image name``; pixel (0, 0) is the centre of the top-left
    pixel). Positions are the true projections (through a rolling shutter where the camera has one) plus ``noise_px`` (sigma per axis) of clicking noise;
    targets closer than ``border_px`` to the image edge are left out; ``camera_of`` (image name -> camera)
    where the images were taken with several cameras. Returns the number of lines."""
    f = site.frame
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 808]))
    lever = np.asarray(lever_arm_cam_m, dtype=float)
    targets = site.targets
    if not targets:
        return 0
    t_enu = np.array([f.site_to_enu(t.x, t.y, t.z) for t in targets])
    lines = [f"EPSG:{f.epsg}"]
    default_camera = camera
    for e in events:
        camera = (camera_of or {}).get(e.name, default_camera)
        te = e.exposure_gps_time_s
        R = trajectory.R_cam_to_enu(te)
        c = trajectory.position_enu(te) + _antenna_to_camera_enu(trajectory, te, lever, flight)
        px = camera.project_world_moving(t_enu, c, R, trajectory.velocity_enu(te))
        for t, uv in zip(targets, px):
            if not np.all(np.isfinite(uv)):
                continue
            if not (border_px <= uv[0] <= camera.width - 1 - border_px and border_px <= uv[1] <= camera.height - 1 - border_px):
                continue
            u, v = uv + rng.standard_normal(2) * noise_px
            lines.append(f"{t.x + f.origin_e:.4f} {t.y + f.origin_n:.4f} {t.z:.4f} {u:.2f} {v:.2f} {e.name} {t.name}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("\n".join(lines) + "\n")
    return len(lines) - 1
