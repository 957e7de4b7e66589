"""One call that simulates a whole survey: :func:`simulate_site`.

Output folder (laid out like a user's upload, plus the truth)::

    images/        IMG_0001.JPG ... (EXIF: UTC exposure time with sub-seconds, focal length, sensor size, GPS)
    rover/         rover.obs: drone GNSS receiver, RINEX 3.04 (or rover.<yy>o, 2.11), camera time marks as events
    base/          base.obs: static base station, 1 Hz
    nav/           base.nav: multi-GNSS broadcast navigation file (shipped with the package)
    gcp/           points.csv (targets in the project CRS, role control/check) + README.md
    events.csv     trigger (GNSS time mark) gps_time_s of every image
    truth/         ground truth (see georef_core.sim.truth and georef_core.sim.survey_gnss)
    README.md

The GNSS files come from :mod:`georef_core.sim.survey_gnss` (``SimulationOptions.gnss``; None: no GNSS files).
"""

from __future__ import annotations

import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from .camera import CameraModel, CameraOptions
from .flight import (CameraEvent, FlightOptions, FlightPlan, Trajectory, antenna_to_camera_enu, gps_time_to_utc,
                     simulate_flight)
from .render import Renderer, RenderOptions, TerrainMesh, exif_bytes, exposure_gains, write_jpeg
from .site import Site, SiteOptions, build_site
from .survey_gnss import GnssOptions, SurveyGnssResult, simulate_survey_gnss
from .texture import TextureOptions, generate_texture, sun_vector_enu
from .truth import write_events_csv, write_gcp_image_measurements, write_gcp_points, write_truth

from ..progress import ProgressFn


@dataclass
class SimulationOptions:
    site: SiteOptions = field(default_factory=SiteOptions)
    flight: FlightOptions = field(default_factory=FlightOptions)
    camera: CameraOptions = field(default_factory=CameraOptions)
    texture: TextureOptions = field(default_factory=TextureOptions)
    render: RenderOptions = field(default_factory=RenderOptions)
    dsm_resolution_m: float = 0.1
    dsm_margin_m: float = 10.0  # DSM covers the work area plus this margin
    gcp_noise_m: tuple[float, float] = (0.0, 0.0)  # survey noise (sigma horizontal, vertical) in gcp/points.csv
    gcp_click_noise_px: float = 0.3  # sigma per axis of the target image measurements in gcp/gcp_list.txt
    exif_gps_noise_m: tuple[float, float] | None = (1.5, 3.0)  # navigation-grade GPS in EXIF; None: no GPS tags
    coverage_margin_m: float | None = None  # rendered world beyond the planned footprints; None: 0.15 h + 3 m
    max_texels: float = 1.2e8  # the texel is enlarged if the texture would exceed this
    workers: int = 2  # images rendered concurrently (threads)
    write_images: bool = True
    gnss: GnssOptions | None = field(default_factory=GnssOptions)  # None: no rover/, base/, nav/ files
    # a second camera (another drone, another resolution or focal length): images whose index (0-based, in
    # flight order) is 1 modulo ``second_camera_every`` are taken with it (2: every other image); truth in
    # truth/cameras.json (camera id per image) and intrinsics_camera2.json
    second_camera: CameraOptions | None = None
    second_camera_every: int = 2

    @classmethod
    def small(cls, width_px: int = 640, height_px: int = 480, **flight_kw) -> "SimulationOptions":
        """A small, fast scene (12 images of 640 x 480): two flight lines over a 36 x 16 m work area
        with two small piles and five targets."""
        site = SiteOptions(size_m=(36.0, 16.0), stockpiles=("cone", "frustum"), stockpile_scale=0.3, pit=False,
                           hillside=False, n_roads=1, road_width_m=4.0, n_targets=5, n_control=3,
                           target_size_m=1.2, target_margin_m=3.0, pad_blend_m=2.0, pad_margin_m=1.0)
        fkw = dict(height_m=40.0, speed_m_s=4.0, forward_overlap=0.75, side_overlap=0.6, extra_triggers=0,
                   static_before_s=5.0, static_after_s=5.0, hover_s=1.0)
        fkw.update(flight_kw)
        return cls(site=site, flight=FlightOptions(**fkw), camera=CameraOptions().scaled(width_px, height_px),
                   dsm_resolution_m=0.05, dsm_margin_m=4.0)


@dataclass
class SimulationResult:
    out_dir: Path
    seed: int
    options: SimulationOptions
    site: Site
    camera: CameraModel
    plan: FlightPlan
    trajectory: Trajectory
    events: list[CameraEvent]
    image_paths: list[Path]
    timings_s: dict
    generation_time_s: float
    gnss: SurveyGnssResult | None = None

    @property
    def truth_dir(self) -> Path:
        return self.out_dir / "truth"

    @property
    def n_images(self) -> int:
        return len(self.events)


class _Progress:
    def __init__(self, callback: ProgressFn | None, verbose: bool):
        self.callback = callback
        self.verbose = verbose
        self.t0 = time.perf_counter()
        self._bar = None

    def stage(self, name: str, done: int = 0, total: int = 0) -> None:
        if self.callback:
            self.callback(name, done, total)
        elif self.verbose and total == 0:
            print(f"[sim {time.perf_counter() - self.t0:6.1f} s] {name}", file=sys.stderr, flush=True)

    def images(self, total: int):
        if self.callback or not self.verbose:
            return None
        try:
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc="rendering", unit="img", file=sys.stderr)
        except ImportError:
            self._bar = None
        return self._bar

    def image_done(self, done: int, total: int) -> None:
        if self.callback:
            self.callback("render", done, total)
        elif self._bar is not None:
            self._bar.update(1)
        elif self.verbose and (done == total or done % max(1, total // 10) == 0):
            print(f"[sim {time.perf_counter() - self.t0:6.1f} s] rendered {done}/{total}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _write_readmes(out: Path, site: Site, n_images: int, flight: FlightOptions, gnss: SurveyGnssResult | None) -> None:
    if gnss is None:
        notes = {
            "rover": "GNSS rover observations: not simulated (SimulationOptions.gnss = None).",
            "base": "GNSS base-station observations: not simulated (SimulationOptions.gnss = None).",
            "nav": "Broadcast navigation file: not simulated (SimulationOptions.gnss = None).",
        }
        for name, text in notes.items():
            d = out / name
            d.mkdir(parents=True, exist_ok=True)
            (d / "README.md").write_text(f"# {name}/\n\n{text}\n")
        gnss_lines = "- `rover/`, `base/`, `nav/`: empty (no GNSS simulated)\n"
    else:
        s = gnss.summary
        gnss_lines = (
            f"- `rover/`: drone GNSS receiver ({s['receiver']['rover']}), RINEX {s['rinex_version']}, "
            f"{s['rover']['rate_hz']:g} Hz, camera trigger time marks as event records (flag 5)\n"
            f"- `base/`: base station ({s['receiver']['base']}), {s['base']['rate_hz']:g} Hz, at the position in its "
            f"RINEX header\n"
            f"- `nav/`: broadcast navigation file (GPS, GLONASS, Galileo, QZSS, BeiDou)\n\n"
            f"PPK: `{s['solve_command']}`\n\n")
    (out / "README.md").write_text(
        "# Simulated drone survey (georef_core.sim)\n\n"
        f"Seed-determined synthetic earthworks site, project CRS EPSG:{site.frame.epsg}, {n_images} images.\n\n"
        "- `images/`: JPEG images with EXIF (exposure time in UTC, focal length, focal-plane resolution, GPS)\n"
        "- `events.csv`: GNSS time marks (trigger gps_time_s) of the images; exposure = trigger + delay\n"
        "- `gcp/points.csv`: ground targets (control / check)\n"
        + gnss_lines +
        "- `truth/`: trajectory, camera poses, intrinsics, lever arm and delay, targets, stockpiles, DSM, "
        "GNSS truth (`gnss_truth.npz` / `.json`)\n\n"
        f"Lever arm (camera frame, m): {list(flight.lever_arm_cam_m)}; delay: {flight.trigger_delay_s} s.\n")


def _radiometry_truth(render: RenderOptions, events, applied_gain: dict, extra_gain: dict) -> dict:
    """truth/radiometry.json: every image's exposure gain and the cameras' vignetting (the factor an image's
    pixel carries relative to the scene's radiance = gain x vignetting(rho))."""
    return {
        "model": "pixel = gain * V(rho) * radiance (then sensor noise, 8-bit clipping, JPEG); rho = distance to "
                 "the principal point / half the image diagonal",
        "vignetting": {"V(rho)": "(1 - a rho^2 r43) / (1 + k rho^2)^2", "a": render.vignetting,
                       "r43": "(1 + (H/W)^2) / 1.5625 (1 for 4:3 images)",
                       "k": (1.0 / math.sqrt(1.0 - render.vignetting_cos4) - 1.0) if render.vignetting_cos4 > 0 else 0.0,
                       "corner_loss_cos4": render.vignetting_cos4},
        "exposure_spread": render.exposure_spread, "gain_jitter_rms": render.gain_jitter,
        "gains": {e.name: float(applied_gain.get(e.name, 1.0)) for e in events},
        "exposure_gains": {e.name: float(extra_gain[e.name]) for e in events},
    }


def _write_survey_json(out: Path, site: Site, traj, gnss: SurveyGnssResult | None) -> None:
    """``survey.json``: what the surveyor knows about the flight besides the files (project CRS, the
    surveyed take-off point for single-frequency known-start PPK, the points' CRS)."""
    import json

    doc = {"project_crs": f"EPSG:{site.frame.epsg}", "points_crs": f"EPSG:{site.frame.epsg}",
           "heights": "ellipsoidal (WGS84)"}
    if gnss is not None:
        doc["receiver"] = (gnss.summary.get("receiver") or {}).get("rover")
        doc["takeoff_antenna_ecef_m"] = [round(float(v), 4) for v in gnss.takeoff_antenna_ecef_m]
    (out / "survey.json").write_text(json.dumps(doc, indent=1) + "\n")


def simulate_site(out_dir, seed: int = 0, options: SimulationOptions | None = None,
                  progress: ProgressFn | None = None, verbose: bool = True) -> SimulationResult:
    """Simulate a survey into ``out_dir`` (created); deterministic for a given seed and options.

    ``progress(stage, done, total)`` is called for the stages (total = 0) and per rendered image; without
    it, stages are printed to stderr and a tqdm bar (if installed) shows the rendering."""
    o = options or SimulationOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pr = _Progress(progress, verbose)
    t_all = time.perf_counter()
    timings: dict[str, float] = {}

    def tick(name, t0):
        timings[name] = time.perf_counter() - t0

    t = time.perf_counter()
    pr.stage("site")
    site = build_site(o.site, seed)
    camera = CameraModel.from_options(o.camera)
    camera2 = CameraModel.from_options(o.second_camera) if o.second_camera is not None else None
    tick("site", t)

    t = time.perf_counter()
    pr.stage("flight")
    traj, events, plan = simulate_flight(site, camera, o.flight, seed)
    tick("flight", t)

    if camera2 is not None and int(o.second_camera_every) < 2:
        raise ValueError(f"second_camera_every {o.second_camera_every}: at least 2 (1 would be the second camera only)")
    camera_of = {e.name: (camera2 if camera2 is not None and e.index % int(o.second_camera_every) == 1 else camera)
                 for e in events}

    gnss = None
    if o.gnss is not None:
        t = time.perf_counter()
        pr.stage("gnss")
        gnss = simulate_survey_gnss(out, site, traj, events, o.gnss, seed)
        tick("gnss", t)

    margin = o.coverage_margin_m if o.coverage_margin_m is not None else 0.15 * o.flight.height_m + 3.0
    bounds = plan.coverage_bounds(margin)
    mesh = texture = None
    image_paths: list[Path] = []
    radiometry = None
    if o.write_images and events:
        t = time.perf_counter()
        pr.stage("mesh")
        mesh = TerrainMesh(site, bounds, o.render.mesh_step_m)
        sun = sun_vector_enu(o.texture.sun_azimuth_deg, o.texture.sun_elevation_deg)
        shadow = mesh.shadow_function(sun, o.render.threads)
        tick("mesh", t)

        t = time.perf_counter()
        pr.stage("texture")
        texel = o.texture.texel_m or max(o.flight.height_m / camera.fx, 0.012)
        area = (bounds[2] - bounds[0]) * (bounds[3] - bounds[1])
        texel = max(texel, math.sqrt(area / o.max_texels))
        texture, _facts = generate_texture(site, bounds, texel, o.texture, shadow_fn=shadow,
                                           progress=lambda m: pr.stage(m))
        tick("texture", t)

        t = time.perf_counter()
        pr.stage("render")
        img_dir = out / "images"
        img_dir.mkdir(parents=True, exist_ok=True)
        renderer = Renderer(mesh, texture, camera, o.render, seed=seed)
        renderers = {id(camera): renderer}
        if camera2 is not None:
            renderers[id(camera2)] = Renderer(mesh, texture, camera2, o.render, seed=seed)
        frame = site.frame

        # poses and EXIF GPS tags first, in this thread (pyproj transformers are not shared across threads)
        exif_rng = np.random.default_rng(np.random.SeedSequence([int(seed), 707]))
        jobs = []
        for e in events:
            te = e.exposure_gps_time_s
            R = traj.R_cam_to_enu(te)
            c = traj.position_enu(te) + antenna_to_camera_enu(traj, te, o.flight)
            gps = None
            if o.exif_gps_noise_m is not None:
                sig = np.array([o.exif_gps_noise_m[0]] * 2 + [o.exif_gps_noise_m[1]])
                g = frame.enu_to_grid(c + exif_rng.standard_normal(3) * sig)
                lat, lon = frame.grid_to_latlon_rad(g[0], g[1])
                gps = (math.degrees(float(lat)), math.degrees(float(lon)), float(g[2]))
            jobs.append((e, R, c, traj.velocity_enu(te), exif_bytes(camera_of[e.name], gps_time_to_utc(te), gps)))

        extra_gain = dict(zip([e.name for e in events],
                              exposure_gains(seed, [e.index for e in events], o.render.exposure_spread)))
        applied_gain: dict[str, float] = {}

        def job(item) -> Path:
            e, R, c, vel, exb = item
            rng = np.random.default_rng(np.random.SeedSequence([int(seed), 505, e.index]))
            g: list = []
            img = renderers[id(camera_of[e.name])].render(R, c, rng, velocity_enu_m_s=vel,
                                                          exposure_gain=extra_gain[e.name], gain_out=g)
            applied_gain[e.name] = g[0] if g else float(extra_gain[e.name])
            path = img_dir / e.name
            write_jpeg(path, img, exb, o.render.jpeg_quality)
            return path

        pr.images(len(events))
        workers = max(1, int(o.workers))
        if workers == 1:
            for i, item in enumerate(jobs):
                image_paths.append(job(item))
                pr.image_done(i + 1, len(events))
        else:
            for r in renderers.values():
                r.options = replace(o.render, threads=o.render.threads or 1)
            with ThreadPoolExecutor(max_workers=workers) as ex:
                for i, p in enumerate(ex.map(job, jobs)):
                    image_paths.append(p)
                    pr.image_done(i + 1, len(events))
        pr.close()
        radiometry = _radiometry_truth(o.render, events, applied_gain, extra_gain)
        tick("render", t)
        del mesh, texture, renderer, renderers

    t = time.perf_counter()
    pr.stage("truth")
    dsm_bounds = (-site.half_w - o.dsm_margin_m, -site.half_h - o.dsm_margin_m,
                  site.half_w + o.dsm_margin_m, site.half_h + o.dsm_margin_m)
    write_truth(out / "truth", site, plan, traj, events, camera, o.flight, o.dsm_resolution_m, dsm_bounds,
                extra={"simulation_options": asdict(o), "rendered_bounds_site_m": list(bounds)})
    write_gcp_points(out / "gcp", site, o.gcp_noise_m, seed)
    write_gcp_image_measurements(out / "gcp" / "gcp_list.txt", site, traj, events, camera, o.flight.lever_arm_cam_m,
                                 o.gcp_click_noise_px, seed, flight=o.flight, camera_of=camera_of)
    if radiometry is not None:
        from .truth import write_json

        write_json(out / "truth" / "radiometry.json", radiometry)
    if camera2 is not None:
        from .truth import write_json

        write_json(out / "truth" / "intrinsics_camera2.json", camera2.to_dict())
        write_json(out / "truth" / "cameras.json", {
            "cameras": {"1": "intrinsics.json", "2": "intrinsics_camera2.json"},
            "images": {e.name: 2 if camera_of[e.name] is camera2 else 1 for e in events}})
    _write_survey_json(out, site, traj, gnss)
    write_events_csv(out / "events.csv", events)
    _write_readmes(out, site, len(events), o.flight, gnss)
    tick("truth", t)

    total = time.perf_counter() - t_all
    if verbose:
        parts = ", ".join(f"{k} {v:.1f} s" for k, v in timings.items())
        print(f"simulate_site: {len(events)} images ({camera.width}x{camera.height}) in {total:.1f} s ({parts}) "
              f"-> {out}", file=sys.stderr, flush=True)
    return SimulationResult(out_dir=out, seed=int(seed), options=o, site=site, camera=camera, plan=plan,
                            trajectory=traj, events=events, image_paths=image_paths, timings_s=timings,
                            generation_time_s=total, gnss=gnss)
