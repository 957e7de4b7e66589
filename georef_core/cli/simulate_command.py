"""`georef simulate OUT_DIR --seed N [options]`: a whole simulated survey (images, GNSS, GCPs, truth).

``python -m georef_core.sim`` runs this same command (:func:`main`)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from types import SimpleNamespace

from ..errors import GeorefError
from .arguments import parse_three_numbers

STAGES = ("site", "flight", "gnss", "mesh", "texture", "render", "truth")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out_dir", help="output folder (created): images/, rover/, base/, nav/, gcp/, events.csv, truth/")
    p.add_argument("--seed", type=int, default=0, help="random seed: same seed and options, same files (default 0)")
    p.add_argument("--small", action="store_true", help="small scene: 12 images of 640x480 over a 36 x 16 m site")
    p.add_argument("--height", type=float, help="flight height above take-off (m; default 60, small 40)")
    p.add_argument("--second-height", type=float, metavar="M",
                   help="a calibration flight: every other pair of lines at this second height (m above take-off; "
                        "higher than --height keeps the overlaps)")
    p.add_argument("--second-speed", type=float, metavar="M_S",
                   help="... and at this ground speed (with --second-height: the same lines; alone: every other pair)")
    p.add_argument("--speed", type=float, help="ground speed on the lines (m/s; default 5, small 4)")
    p.add_argument("--size", type=float, nargs=2, metavar=("EAST_M", "NORTH_M"), help="work area size (m)")
    p.add_argument("--crs", type=int, metavar="EPSG", help="projected CRS of the site (default: its UTM zone)")
    p.add_argument("--image-size", type=int, nargs=2, metavar=("W", "H"), help="image size in pixels")
    p.add_argument("--lens", choices=["perspective", "fisheye"],
                   help="camera lens: perspective (default; Brown distortion) or fisheye (a wide-angle action "
                        "camera, OpenCV fisheye model, about 90 degrees across)")
    p.add_argument("--second-camera", metavar="WxH[:FOCAL_MM]",
                   help="a second camera (another drone or setting) of this image size and optionally focal length "
                        "(mm; default the first camera's, same sensor width), e.g. 800x600:5.2; every other image "
                        "is taken with it (--second-camera-every)")
    p.add_argument("--second-camera-every", type=int, default=2, metavar="N",
                   help="images whose flight-order index is 1 modulo N are the second camera's (default 2)")
    p.add_argument("--images", type=int, metavar="N",
                   help="about N images: the work area (both sides, aspect ratio kept) is scaled until the planned "
                        "flight takes the image count nearest N; height, overlaps and camera are kept; on a small "
                        "area what does not fit (pit, hillside, piles, roads) is left out (printed)")
    p.add_argument("--receiver", choices=["l1", "l1l2"],
                   help="GNSS receivers: l1 (u-blox-like GPS+GLONASS L1, noisier, cycle slips) or l1l2 (geodetic "
                        "multi-GNSS dual-frequency, default)")
    p.add_argument("--rover-rate", type=float, metavar="HZ", help="rover observation rate (Hz; default 5, e.g. 10)")
    p.add_argument("--lever-arm", metavar="X,Y,Z", help="antenna phase centre to camera centre, camera frame "
                                                        "(x right, y down, z forward; m); write --lever-arm=X,Y,Z "
                                                        "when X is negative")
    p.add_argument("--delay", type=float, metavar="S", help="exposure time minus trigger (time mark) time (s)")
    p.add_argument("--code-noise", type=float, metavar="M", help="rover code noise, zenith sigma (m)")
    p.add_argument("--phase-noise", type=float, metavar="M", help="rover carrier-phase noise, zenith sigma (m)")
    p.add_argument("--base-gaps", action="store_true", help="a few logging gaps (2-15 s) in the base file")
    p.add_argument("--rinex-version", type=int, choices=[2, 3], help="RINEX version of rover/base files (default 3)")
    p.add_argument("--no-gnss", action="store_true", help="no rover/base/nav files")
    p.add_argument("--no-images", action="store_true", help="no images (site, flight, GNSS and truth only)")
    p.add_argument("--readout-ms", type=float, metavar="MS",
                   help="a rolling-shutter camera with this readout time, first to last row (ms; default: global "
                        "shutter); EXIF model SimCam-RS")
    p.add_argument("--aircraft", choices=["generic", "dji-rtk"], default="generic",
                   help="generic: images/, rover/, base/, nav/, events.csv with a camera fixed to the airframe; "
                        "dji-rtk: the flight folder(s) a DJI RTK aircraft writes (photos with RTK XMP tags, "
                        "Timestamp.MRK with per-exposure antenna-to-camera offsets, RTCM 3 raw log) from a "
                        "gimbal-stabilised camera, plus base/ and gcp/ (docs/dji.md)")
    p.add_argument("--flights", type=int, default=1, metavar="N",
                   help="with --aircraft dji-rtk: split the survey into N flights (battery swaps), each its own "
                        "folder, and the base file in two (default 1)")
    p.add_argument("--no-rtk-session-error", action="store_true",
                   help="with --aircraft dji-rtk: the photos' and MRK's real-time RTK positions without the error "
                        "common to a flight (an RTK network's or base's; by default drawn per flight at 1 cm / 1.5 cm)")
    p.add_argument("--exposure-spread", type=float, metavar="FRACTION",
                   help="per-image exposure gain drawn uniformly in 1 +- FRACTION (seeded; e.g. 0.15), on top of "
                        "the 3 %% jitter; truth in truth/radiometry.json (default 0: off)")
    p.add_argument("--vignetting", type=float, metavar="FRACTION",
                   help="an extra cos^4-like radial falloff this much darker at the image corners (e.g. 0.3; "
                        "default 0: only the mild 12 %% quadratic one)")
    p.add_argument("--machines", type=int, metavar="N",
                   help="park N machines (trucks, excavators, boxes: 2.5-4 m tall, 3-10 m footprints) on open ground; "
                        "truth/machines.geojson and truth/dtm.tif (the bare earth) are written (default 0)")
    p.add_argument("--workers", type=int, help="images rendered concurrently (default 2)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a survey: images, GNSS rover/base/nav, GCPs and ground truth",
                       description=__doc__.splitlines()[0])
    add_arguments(p)
    p.set_defaults(func=cmd_simulate)


# ----------------------------------------------------------------------------------------------------------


def planned_image_count(options, size_m: tuple[float, float]) -> int:
    """Images the flight plan takes over a work area of ``size_m`` (same formulas as flight.plan_flight)."""
    from ..sim.camera import CameraModel
    from ..sim.flight import plan_flight

    stub = SimpleNamespace(half_w=0.5 * size_m[0], half_h=0.5 * size_m[1], piles=[], pit=None, targets=[],
                           surface=lambda x, y: 0.0)
    plan = plan_flight(stub, CameraModel.from_options(options.camera), options.flight)
    return int(sum(len(ln["triggers_s"]) for ln in plan.lines))


def scale_for_image_count(options, n_images: int):
    """Options whose work area (both sides scaled by one factor) gives the planned image count nearest
    ``n_images`` (ties: the factor nearest 1). Returns (options, count)."""
    if n_images < 1:
        raise GeorefError("--images must be at least 1")
    w, h = options.site.size_m
    best = None
    for k in [math.exp(x / 200.0) for x in range(-600, 601)]:   # factors 0.05 .. 20, 0.5 % steps
        size = (w * k, h * k)
        if min(size) < 2.0:
            continue
        n = planned_image_count(options, size)
        key = (abs(n - n_images), abs(math.log(k)))
        if best is None or key < best[0]:
            best = (key, size, n)
    _, size, n = best
    return replace(options, site=replace(options.site, size_m=(round(size[0], 1), round(size[1], 1)))), n


def fit_site_content(options, seed: int):
    """Options whose site can be laid out: if the stockpiles, pit and roads do not fit the work area (a small
    ``--images``), drop the pit, then the hillside (and its pile), then piles from the last, then roads, then
    targets. Returns (options, list of what was dropped)."""
    from ..sim.site import build_site

    site_o = options.site
    dropped: list[str] = []
    steps = []
    if site_o.pit:
        steps.append(("the pit", lambda o: replace(o, pit=False)))
    if site_o.hillside or "slope_cone" in site_o.stockpiles:
        steps.append(("the hillside", lambda o: replace(o, hillside=False, stockpiles=tuple(
            k for k in o.stockpiles if k != "slope_cone"))))
    for _ in range(max(len(site_o.stockpiles) - 1, 0)):
        steps.append(("a stockpile", lambda o: replace(o, stockpiles=o.stockpiles[:-1])))
    for _ in range(site_o.n_roads):
        steps.append(("a road", lambda o: replace(o, n_roads=max(o.n_roads - 1, 0))))
    steps.append(("some targets and their margin", lambda o: replace(
        o, n_targets=min(o.n_targets, 5), n_control=min(o.n_control, 3),
        target_margin_m=min(o.target_margin_m, 0.15 * min(o.size_m)), pad_margin_m=min(o.pad_margin_m, 1.0),
        pad_blend_m=min(o.pad_blend_m, 2.0))))
    while True:
        try:
            build_site(site_o, seed)
            return replace(options, site=site_o), dropped
        except ValueError as exc:
            if not steps:
                raise GeorefError(f"the site cannot be laid out on a {site_o.size_m[0]:g} x {site_o.size_m[1]:g} m "
                                  f"work area ({exc}); ask for more images") from None
        what, step = steps.pop(0)
        site_o = step(site_o)
        dropped.append(what)


def options_from_args(args):
    from ..sim.scenario import SimulationOptions
    from ..sim.survey_gnss import GnssOptions

    o = SimulationOptions.small() if args.small else SimulationOptions()
    fl = {}
    if args.height is not None:
        fl["height_m"] = args.height
    if args.second_height is not None:
        fl["second_height_m"] = args.second_height
    if args.second_speed is not None:
        fl["second_speed_m_s"] = args.second_speed
    if args.speed is not None:
        fl["speed_m_s"] = args.speed
    if args.lever_arm is not None:
        fl["lever_arm_cam_m"] = parse_three_numbers(args.lever_arm, "--lever-arm")
    if args.delay is not None:
        fl["trigger_delay_s"] = args.delay
    if args.aircraft == "dji-rtk":
        if args.lever_arm is not None:
            raise GeorefError("--lever-arm: a DJI RTK aircraft's gimbal camera has no fixed lever arm (its MRK logs "
                              "the antenna-to-camera offset of every exposure)")
        if args.no_gnss:
            raise GeorefError("--aircraft dji-rtk writes the aircraft's raw GNSS log: not with --no-gnss")
        fl["camera_mount"] = "gimbal"
        fl.setdefault("trigger_delay_s", 0.0)        # DJI's MRK times are exposure times
        if args.receiver is None:
            args.receiver = "l1l2"                      # DJI RTK receivers track two frequencies
    elif args.flights != 1:
        raise GeorefError("--flights: only with --aircraft dji-rtk")
    if args.flights < 1:
        raise GeorefError(f"--flights {args.flights}: at least 1")
    if fl:
        o.flight = replace(o.flight, **fl)
    if args.size is not None:
        o.site = replace(o.site, size_m=(float(args.size[0]), float(args.size[1])))
    if args.machines is not None:
        if args.machines < 0:
            raise GeorefError(f"--machines {args.machines}: at least 0")
        o.site = replace(o.site, machines=int(args.machines))
    if args.crs is not None:
        from pyproj import CRS
        from pyproj.exceptions import CRSError

        try:
            crs = CRS.from_epsg(args.crs)
        except CRSError:
            raise GeorefError(f"--crs {args.crs}: not an EPSG code pyproj knows") from None
        if not crs.is_projected:
            raise GeorefError(f"--crs {args.crs} ({crs.name}) is not a projected CRS: the site needs metric E/N axes")
        o.site = replace(o.site, epsg=args.crs)
    if args.lens == "fisheye":
        from ..sim.camera import CameraOptions

        o.camera = CameraOptions.fisheye().scaled(o.camera.width_px, o.camera.height_px)
    if args.image_size is not None:
        o.camera = o.camera.scaled(*args.image_size)
    if args.readout_ms is not None:
        if not 0.0 < args.readout_ms <= 200.0:
            raise GeorefError(f"--readout-ms {args.readout_ms:g}: expected more than 0 and at most 200 ms")
        o.camera = o.camera.rolling(args.readout_ms / 1000.0)
    if args.second_camera:
        o.second_camera = parse_second_camera(args.second_camera, o.camera)
        if args.second_camera_every < 2:
            raise GeorefError(f"--second-camera-every {args.second_camera_every}: at least 2")
        o.second_camera_every = int(args.second_camera_every)
    radiometry = {}
    if args.exposure_spread is not None:
        if not 0.0 <= args.exposure_spread < 0.9:
            raise GeorefError(f"--exposure-spread {args.exposure_spread:g}: expected 0 to 0.9")
        radiometry["exposure_spread"] = float(args.exposure_spread)
    if args.vignetting is not None:
        if not 0.0 <= args.vignetting < 0.9:
            raise GeorefError(f"--vignetting {args.vignetting:g}: expected 0 to 0.9")
        radiometry["vignetting_cos4"] = float(args.vignetting)
    if radiometry:
        o.render = replace(o.render, **radiometry)
    if args.workers is not None:
        o.workers = args.workers
    if args.no_images:
        o.write_images = False
    if args.no_gnss:
        o.gnss = None
    else:
        g = {}
        for arg, key in (("receiver", "receiver"), ("rover_rate", "rover_rate_hz"), ("code_noise", "code_noise_m"),
                         ("phase_noise", "phase_noise_m"), ("rinex_version", "rinex_version")):
            if getattr(args, arg) is not None:
                g[key] = getattr(args, arg)
        if args.base_gaps:
            g["base_gaps"] = True
        o.gnss = replace(o.gnss or GnssOptions(), **g)
        try:
            o.gnss.validate()
        except ValueError as exc:
            raise GeorefError(str(exc)) from None
    n_planned = None
    if args.images is not None:
        o, n_planned = scale_for_image_count(o, args.images)
        o, dropped = fit_site_content(o, args.seed)
        if dropped:
            print(f"--images {args.images}: left out to fit the {o.site.size_m[0]:g} x {o.site.size_m[1]:g} m work "
                  f"area: {', '.join(dropped)}", file=sys.stderr)
    return o, n_planned


def parse_second_camera(text: str, first):
    """``WxH[:FOCAL_MM]`` -> CameraOptions of a second camera: the first camera's optics (distortion,
    principal point, sensor width) with another pixel count and, when given, another focal length, a
    slightly different distortion (another lens) and another EXIF model name."""
    from dataclasses import replace as _replace

    try:
        size, _, focal = text.partition(":")
        w, h = (int(v) for v in size.lower().split("x"))
        f = float(focal) if focal else first.focal_mm
    except ValueError:
        raise GeorefError(f"--second-camera {text!r}: expected WxH or WxH:FOCAL_MM, e.g. 800x600:5.2") from None
    if not (64 <= w <= 10000 and 64 <= h <= 10000 and 0.5 <= f <= 200):
        raise GeorefError(f"--second-camera {text!r}: size 64-10000 px and focal length 0.5-200 mm")
    return _replace(first.scaled(w, h), focal_mm=f, model=first.model + "-B", k1=first.k1 * 0.8, k2=first.k2 * 0.7,
                    principal_offset=(-first.principal_offset[0], first.principal_offset[1] * 0.5))


class ProgressBar:
    """One bar over the stages and the rendered images (tqdm if installed, else a line per stage)."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.bar = None
        self.n_images = 0
        self.stage_index = -1
        if enabled:
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=len(STAGES) - 1, desc="simulate", unit="step", file=sys.stderr,
                                bar_format="{desc:<26} {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}]")
            except ImportError:
                self.bar = None

    def _set(self, position: int, desc: str) -> None:
        if self.bar is not None:
            self.bar.n = position
            self.bar.set_description_str(desc, refresh=False)
            self.bar.refresh()
        elif self.enabled:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {desc}", file=sys.stderr, flush=True)

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage == "render" and total:
            if self.n_images != total:
                self.n_images = total
                if self.bar is not None:
                    self.bar.total = len(STAGES) - 1 + total
            if self.bar is not None or done == total or done % max(1, total // 10) == 0:
                self._set(STAGES.index("render") + done, f"render {done}/{total}")
            return
        if stage in STAGES:
            self.stage_index = STAGES.index(stage)
            pos = self.stage_index + (self.n_images if self.stage_index > STAGES.index("render") else 0)
            self._set(pos, stage)
        elif self.bar is not None:   # sub-steps (texture layers): keep the position, show what is done
            self.bar.set_description_str(f"{STAGES[max(self.stage_index, 0)]}: {stage}"[:26], refresh=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.n = self.bar.total
            self.bar.set_description_str("done", refresh=False)
            self.bar.close()


def run(args) -> int:
    from ..sim.scenario import simulate_site

    o, n_planned = options_from_args(args)
    if n_planned is not None:
        print(f"--images {args.images}: work area {o.site.size_m[0]:g} x {o.site.size_m[1]:g} m, "
              f"{n_planned} images planned", file=sys.stderr)
    bar = ProgressBar(enabled=not args.quiet)
    t0 = time.perf_counter()
    try:
        res = simulate_site(args.out_dir, seed=args.seed, options=o, progress=bar, verbose=False)
    except ValueError as exc:
        raise GeorefError(f"{exc} (a shorter survey fits; --no-gnss leaves the GNSS files out)"
                          if "navigation file" in str(exc) else str(exc)) from None
    finally:
        bar.close()
    dji = None
    if args.aircraft == "dji-rtk":
        from ..sim.dji_flight import write_dji_flights

        dji = write_dji_flights(res, n_flights=args.flights, seed=args.seed,
                                rtk_session_error=not args.no_rtk_session_error)
    total = time.perf_counter() - t0
    parts = ", ".join(f"{k} {v:.1f} s" for k, v in res.timings_s.items())
    what = f"{len(res.image_paths)} images ({res.camera.width}x{res.camera.height})" if res.image_paths else \
        f"{res.n_images} camera events, no images"
    gnss = ""
    if res.gnss is not None:
        s = res.gnss.summary
        gnss = (f", GNSS {s['receiver']['rover']} RINEX {s['rinex_version']} (rover {s['rover']['n_epochs']} epochs "
                f"at {s['rover']['rate_hz']:g} Hz, base {s['base']['n_epochs']})")
    print(f"simulated {what}{gnss} in {total:.1f} s ({parts}) -> {res.out_dir}")
    if dji is not None:
        print(f"DJI RTK flight folder(s): {', '.join(dji['flights'])} ({dji['photos']} photos)")
        print(f"georeference: georef georef {res.out_dir} --out {res.out_dir}/out")
    elif res.gnss is not None:
        print(f"PPK: cd {res.out_dir} && {res.gnss.summary['solve_command']}")
    return 0


def cmd_simulate(args) -> int:
    return run(args)


def main(argv=None) -> int:
    """``python -m georef_core.sim``: the same command as ``georef simulate``."""
    ap = argparse.ArgumentParser(prog="python -m georef_core.sim", description=__doc__.splitlines()[0])
    add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        return run(args)
    except GeorefError as exc:
        print(f"georef simulate: error: {exc}", file=sys.stderr)
        return 2
