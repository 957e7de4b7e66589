"""A simulated survey laid out the way a DJI RTK aircraft writes its flight (``georef simulate
--aircraft dji-rtk``).

``simulate_site`` first makes the usual survey with a gimbal-stabilised camera (``camera_mount =
"gimbal"``) and exposure-time triggers (DJI's MRK times are exposure times: delay 0); this module then
rewrites it:

    DJI_<yyyymmddHHMM>_<nnn>_Georef/      one folder per flight (battery), as on the aircraft's card
        DJI_<yyyymmddHHMMSS>_<iiii>_V.JPG    photos, XMP drone-dji tags: RtkFlag 50, RtkStd*, camera
                                             position (GpsLatitude / GpsLongtitude / AbsoluteAltitude,
                                             WGS84 ellipsoidal height), gimbal and flight angles, speeds
        DJI_<...>_Timestamp.MRK              per exposure: GPS week/seconds, antenna -> camera offset
                                             N/E/V (mm), the real-time RTK camera position, sigmas, Q 50
        DJI_<...>_PPKRAW.bin                 the aircraft's raw GNSS log: RTCM 3 MSM7 with ephemerides
    base/   the base station (one file, or split in two at the flights' boundary with ``flights=2``)
    gcp/    points.csv and gcp_list.txt (image names as in the flight folders)
    truth/  as for any simulated survey, plus dji_names.json (truth image name -> DJI photo name)

No ``rover/``, ``nav/`` or ``events.csv``: the flight folder carries all of it. The real-time
positions in the MRK and the XMP are the true camera centres plus a session error common to the flight (the
network RTK's or the RTK base's error, ``DJI_RTK_SESSION_SIGMA_M``, which the aircraft does not state; drawn per
flight from its own random stream, so the per-exposure noise is the same with or without it) plus independent noise
of the stated RTK sigmas. The session errors drawn are in truth/dji_names.json.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np

from ..gnss.gnss_time import gps_time_s_to_week_tow
from .flight import antenna_to_camera_enu, gps_time_to_utc

DJI_RTK_SIGMA_M = (0.010, 0.010, 0.015)      # the real-time RTK fix's sigmas (north, east, up)
# the error common to one flight's real-time RTK positions (north, east, up; 1 sigma): an NTRIP network's or an RTK
# base's position error, unstated by the aircraft. An assumption: a survey-grade RTK specification's 1 cm / 1.5 cm
DJI_RTK_SESSION_SIGMA_M = (0.010, 0.010, 0.015)
# the error of the aircraft's per-unit factory calibration written as DewarpData (1 sigma): relative focal
# length and principal point (px). A modelling assumption (docs/dji.md), not a measured DJI figure.
FACTORY_CALIBRATION_ERROR = {"f_rel": 3e-4, "pp_px": 0.3}
XMP_NAMESPACE = b"http://ns.adobe.com/xap/1.0/\x00"


def xmp_packet(tags: dict[str, str]) -> bytes:
    """An XMP packet with the given ``drone-dji:`` tags as attributes, as DJI writes them."""
    attrs = "\n    ".join(f'drone-dji:{k}="{v}"' for k, v in tags.items())
    text = ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
            '<x:xmpmeta xmlns:x="adobe:ns:meta/">\n <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
            '  <rdf:Description rdf:about="" xmlns:tiff="http://ns.adobe.com/tiff/1.0/"\n'
            '    xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/"\n'
            f'    tiff:Make="DJI"\n    {attrs}>\n  </rdf:Description>\n </rdf:RDF>\n</x:xmpmeta>\n'
            '<?xpacket end="w"?>')
    return text.encode("utf-8")


def insert_xmp(jpeg_path: Path, packet: bytes) -> None:
    """Insert an XMP APP1 segment right after a JPEG's SOI marker."""
    data = jpeg_path.read_bytes()
    if data[:2] != b"\xff\xd8":
        raise ValueError(f"{jpeg_path}: not a JPEG")
    body = XMP_NAMESPACE + packet
    if len(body) + 2 > 65535:
        raise ValueError("XMP packet too long for one APP1 segment")
    seg = b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body
    jpeg_path.write_bytes(data[:2] + seg + data[2:])


def _flight_of_events(events, n_flights: int) -> list[int]:
    """Flight (0-based) of every event: the lines split in ``n_flights`` consecutive groups."""
    lines = sorted({e.line for e in events})
    per = math.ceil(len(lines) / n_flights)
    flight_of_line = {ln: min(k // per, n_flights - 1) for k, ln in enumerate(lines)}
    return [flight_of_line[e.line] for e in events]


def write_dji_flights(result, n_flights: int = 1, seed: int = 0, rtk_session_error: bool = True) -> dict:
    """Rewrite the survey of ``result`` (a ``SimulationResult`` made with a gimbal camera and GNSS) into
    DJI flight folders (module docstring). Returns a summary of what was written. ``rtk_session_error``: False
    leaves the RTK positions without the per-flight session error (truth plus independent noise only)."""
    from ..gnss.input_files import load_navigation
    from ..gnss.rinex_obs import read_rinex_obs
    from ..gnss.rtcm3_writer import encode_rtcm3_stream
    from .truth import write_json

    out = Path(result.out_dir)
    o = result.options
    if result.gnss is None:
        raise ValueError("a DJI RTK flight needs the simulated GNSS (no --no-gnss)")
    if o.flight.camera_mount != "gimbal":
        raise ValueError("a DJI RTK flight is simulated with a gimbal camera (camera_mount='gimbal')")
    if n_flights < 1:
        raise ValueError("at least one flight")
    traj, frame, events = result.trajectory, result.site.frame, result.events
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 909]))
    rover_files = sorted((out / "rover").iterdir())
    rover = read_rinex_obs(next(p for p in rover_files if p.name.startswith("rover")))
    nav_paths = sorted((out / "nav").iterdir())
    nav = load_navigation(nav_paths)
    flight_of = _flight_of_events(events, n_flights)
    n_flights = max(flight_of) + 1
    t_first = [min(e.exposure_gps_time_s for e, f in zip(events, flight_of) if f == k) for k in range(n_flights)]
    t_last = [max(e.exposure_gps_time_s for e, f in zip(events, flight_of) if f == k) for k in range(n_flights)]
    # each flight's log: from the start (or the previous flight's last photo + 1 s) to its last photo + 1 s
    # (or the end), so the logs of consecutive flights are apart by the time between their photos
    log_start = [rover.gps_time_s[0]] + [t_last[k - 1] + 1.0 for k in range(1, n_flights)]
    log_end = [t_first[k + 1] - 1.0 for k in range(n_flights - 1)] + [rover.gps_time_s[-1]]
    names: dict[str, str] = {}
    folders = []
    sig = np.asarray(DJI_RTK_SIGMA_M)
    session_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 910]))
    session_neu = session_rng.standard_normal((n_flights, 3)) * np.asarray(DJI_RTK_SESSION_SIGMA_M) \
        * float(bool(rtk_session_error))
    dewarp = _factory_calibration_text(result.camera, rng, gps_time_to_utc(events[0].exposure_gps_time_s))
    for k in range(n_flights):
        utc0 = gps_time_to_utc(t_first[k])
        stem = f"DJI_{utc0:%Y%m%d%H%M}_{k + 1:03d}"
        folder = out / f"{stem}_Georef"
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        folders.append(folder)
        sel = (rover.gps_time_s >= log_start[k] - 1e-6) & (rover.gps_time_s <= log_end[k] + 1e-6)
        part = _subset_epochs(rover, sel)
        stream = encode_rtcm3_stream(part, nav, msm=7, receiver_type="DJI simulated RTK")
        (folder / f"{stem}_PPKRAW.bin").write_bytes(stream)
        mrk_lines = []
        idx = 0
        for e, f in zip(events, flight_of):
            if f != k:
                continue
            idx += 1
            te = e.exposure_gps_time_s
            off_enu = antenna_to_camera_enu(traj, te, o.flight)
            cam_enu = traj.position_enu(te) + off_enu
            noisy = cam_enu + rng.standard_normal(3) * sig[[1, 0, 2]] + session_neu[k][[1, 0, 2]]
            lat, lon, h = _enu_to_llh_deg(frame, noisy)
            week, sow = gps_time_s_to_week_tow(te)
            n_mm, e_mm, v_mm = (int(round(1000 * v)) for v in (off_enu[1], off_enu[0], -off_enu[2]))
            mrk_lines.append(f"{idx}\t{sow:.6f}\t[{week}]\t{n_mm:6d},N\t{e_mm:6d},E\t{v_mm:6d},V\t{lat:.8f},Lat\t"
                             f"{lon:.8f},Lon\t{h:.3f},Ellh\t{sig[0]:.6f}, {sig[1]:.6f}, {sig[2]:.6f}\t50,Q")
            new_name = f"DJI_{gps_time_to_utc(te):%Y%m%d%H%M%S}_{idx:04d}_V.JPG"
            src = out / "images" / e.name
            if src.is_file():
                dst = folder / new_name
                shutil.move(str(src), dst)
                tags = _xmp_tags(traj, te, lat, lon, h, sig, result.camera)
                tags["DewarpData"], tags["DewarpFlag"] = dewarp, "0"
                insert_xmp(dst, xmp_packet(tags))
            names[e.name] = new_name
        (folder / f"{stem}_Timestamp.MRK").write_text("\n".join(mrk_lines) + "\n")
    _split_base(out / "base", log_end[0] + 0.5 if n_flights > 1 else None)
    _rename_in_gcp_list(out / "gcp" / "gcp_list.txt", names)
    for name in ("rover", "nav", "images"):
        shutil.rmtree(out / name, ignore_errors=True)
    (out / "events.csv").unlink(missing_ok=True)
    meta_path = out / "survey.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    meta.pop("takeoff_antenna_ecef_m", None)
    meta["aircraft"] = "dji-rtk (simulated)"
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    write_json(out / "truth" / "dji_names.json", {"names": names, "flights": [f.name for f in folders],
                                                 "rtk_sigma_neu_m": list(DJI_RTK_SIGMA_M),
                                                 "rtk_session_sigma_neu_m": list(DJI_RTK_SESSION_SIGMA_M)
                                                 if rtk_session_error else [0.0, 0.0, 0.0],
                                                 "rtk_session_error_neu_m": session_neu.round(5).tolist()})
    return {"flights": [f.name for f in folders], "photos": len(names)}


def _factory_calibration_text(camera, rng, when) -> str:
    """DewarpData of the simulated unit: the true camera with a factory calibration error drawn once
    (FACTORY_CALIBRATION_ERROR), in DJI's layout (principal point as an offset from width/2, height/2 with
    the pixel corner at 0; coefficients k1, k2, p1, p2, k3)."""
    err = FACTORY_CALIBRATION_ERROR
    scale = 1.0 + rng.standard_normal() * err["f_rel"]
    dx, dy = rng.standard_normal(2) * err["pp_px"]
    cx_off = camera.cx + 0.5 - camera.width / 2.0 + dx
    cy_off = camera.cy + 0.5 - camera.height / 2.0 + dy
    vals = [camera.fx * scale, camera.fy * scale, cx_off, cy_off, camera.k1, camera.k2, camera.p1, camera.p2, camera.k3]
    return f"{when:%Y-%m-%d};" + ",".join(f"{v:.12f}" for v in vals)


def _enu_to_llh_deg(frame, enu: np.ndarray) -> tuple[float, float, float]:
    from ..gnss.frames import ecef_to_geodetic

    lat, lon, h = ecef_to_geodetic(frame.enu_to_ecef(enu))
    return math.degrees(float(lat)), math.degrees(float(lon)), float(h)


def _xmp_tags(traj, te: float, lat: float, lon: float, h: float, sig, camera) -> dict[str, str]:
    ypr = traj.yaw_pitch_roll_deg(te)
    cam = traj.R_cam_to_enu(te)
    optical = cam[:, 2]                                          # camera z axis in ENU
    gimbal_pitch = math.degrees(math.asin(max(-1.0, min(1.0, optical[2]))))
    top = -cam[:, 1]                                             # image up in ENU
    gimbal_yaw = math.degrees(math.atan2(top[0], top[1]))
    v = traj.velocity_enu(te)
    return {
        "GpsLatitude": f"{lat:.8f}", "GpsLongtitude": f"{lon:.8f}", "AbsoluteAltitude": f"{h:+.3f}",
        "RelativeAltitude": f"{h - traj.position_enu(traj.t_start)[2]:+.3f}",
        "GimbalRollDegree": "+0.00", "GimbalYawDegree": f"{(gimbal_yaw + 180.0) % 360.0 - 180.0:+.2f}",
        "GimbalPitchDegree": f"{gimbal_pitch:+.2f}",
        "FlightRollDegree": f"{ypr[2]:+.2f}", "FlightYawDegree": f"{(ypr[0] + 180.0) % 360.0 - 180.0:+.2f}",
        "FlightPitchDegree": f"{ypr[1]:+.2f}",
        "FlightXSpeed": f"{v[1]:+.2f}", "FlightYSpeed": f"{v[0]:+.2f}", "FlightZSpeed": f"{-v[2]:+.2f}",
        "CalibratedFocalLength": f"{camera.fx:.6f}",
        "CalibratedOpticalCenterX": f"{camera.width / 2.0:.6f}", "CalibratedOpticalCenterY": f"{camera.height / 2.0:.6f}",
        "RtkFlag": "50", "RtkStdLon": f"{sig[1]:.5f}", "RtkStdLat": f"{sig[0]:.5f}", "RtkStdHgt": f"{sig[2]:.5f}",
    }


def _subset_epochs(obs, sel: np.ndarray):
    from dataclasses import replace

    flags = None if obs.epoch_flags is None else obs.epoch_flags[sel]
    ev = obs.event_gps_time_s
    t = obs.gps_time_s[sel]
    ev = ev[(ev >= t[0]) & (ev <= t[-1])] if len(t) else ev[:0]
    return replace(obs, gps_time_s=t, values=obs.values[sel], lli=obs.lli[sel], ssi=obs.ssi[sel],
                   epoch_flags=flags, event_gps_time_s=ev)


def _split_base(base_dir: Path, at_gps_s: float | None) -> None:
    """With two flights, the base's RINEX file split in two at ``at_gps_s`` (a base log split by a
    restart, or hourly files): the survey must join them."""
    if at_gps_s is None:
        return
    from ..gnss.rinex_obs import read_rinex_obs, write_rinex3_obs

    files = sorted(p for p in base_dir.iterdir() if p.suffix.lower() not in (".md", ".txt"))
    src = files[0]
    obs = read_rinex_obs(src)
    first = obs.gps_time_s < at_gps_s
    for tag, sel in (("a", first), ("b", ~first)):
        write_rinex3_obs(base_dir / f"{src.stem}_{tag}{src.suffix}", _subset_epochs(obs, sel))
    src.unlink()


def _rename_in_gcp_list(path: Path, names: dict[str, str]) -> None:
    if not path.is_file():
        return
    lines = path.read_text().splitlines()
    out = [lines[0]]
    for ln in lines[1:]:
        parts = ln.split()
        if len(parts) >= 6 and parts[5] in names:
            parts[5] = names[parts[5]]
        out.append(" ".join(parts))
    path.write_text("\n".join(out) + "\n")
