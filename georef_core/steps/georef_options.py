"""The georeferencing step's options (GeorefOptions) and their checks: a module of its own, free of science
imports, so that the step's spec (specs.py) can declare them for the API and the browser."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import ProcessingError

MODES = ("joint", "gcp", "similarity")
MODE_ALIASES = {"a": "gcp", "b": "similarity", "c": "joint"}   # Daakir et al.'s letters
SFM_MODELS = {"radial": "RADIAL", "brown": "OPENCV", "fisheye": "OPENCV_FISHEYE"}
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".png")


@dataclass
class GeorefOptions:
    mode: str = "joint"                       # joint (c) | gcp (a) | similarity (b)
    camera_model: str = "brown"               # radial | brown | fisheye (see adjustment/camera_model.py)
    lever_arm_cam_m: tuple[float, float, float] | None = None  # known lever arm (needed by 'similarity')
    estimate_lever_arm: bool | None = None    # default: True unless a lever arm is given without a sigma
    lever_arm_sigma_m: float | None = None    # a given lever arm is a weighted prior with this sigma (else fixed)
    estimate_delay: bool = True
    delay_s: float = 0.0                      # a-priori / fixed delay
    control: str | None = None                # 'all', 'none' or comma-separated names (default: roles in the file)
    check: str | None = None                  # comma-separated names made check points
    points_crs: str | None = None             # CRS of gcp/points.csv (default survey.json, else the gcp_list's)
    project_epsg: int | None = None           # project CRS (default survey.json, else UTM of the site)
    sigma_px: float = 1.0                     # a-priori tie-point measurement sigma
    gcp_sigma_px: float = 1.0                 # a-priori sigma of the clicked target measurements
    gcp_sigma_m: tuple[float, float] = (0.01, 0.02)  # survey sigma of control points (horizontal, vertical)
    max_tie_points: int = 8000                # tie points in the adjustment (spatially even subset)
    reuse: bool = True                        # reuse OUT_DIR/ppk and OUT_DIR/sfm when present
    num_threads: int = 2
    gnss_options: dict = field(default_factory=dict)
    blunder_threshold_px: float = 5.0
    refine_targets: bool = True               # sub-pixel refinement of clicked checker-target centres
    leave_one_out: bool = True
    # trigger times from the images' EXIF time instead of camera events: trigger UTC = EXIF time (UTC, or
    # local with its OffsetTimeOriginal) + this offset (s), i.e. the camera clock's error negated
    exif_time_offset_s: float | None = None
    rolling_shutter: bool | None = None       # the camera has a rolling shutter (None: from the EXIF model)
    readout_s: float | None = None            # its readout time, first to last row (None: estimated)
    # a calibrated camera (e.g. from a calibration flight, see load_calibration): the 8 OpenCV intrinsics
    # (f, cx, cy, k1, k2, k3, p1, p2, pixels) held fixed instead of self-calibrated
    fixed_intrinsics: tuple[float, ...] | None = None
    # a camera's factory calibration written into its photos (DJI XMP DewarpData): "prior" weights it
    # (FACTORY_CALIBRATION_SIGMA) with the self-calibration, "fixed" holds it, "ignore" self-calibrates freely
    factory_calibration: str = "prior"
    # a common 3-D offset of the GNSS camera positions of each flight (battery), with a prior, in every mode's
    # adjustment (docs/georeferencing.md, "Several flights"): "auto" where the positions come in two or more
    # flights, their base position is not surveyed, some are not fixed or they are RTK-tagged photos, "on" always
    # (PPK / RTK positions), "off" never
    flight_offsets: str = "auto"
    # each flight's own offset sigma (horizontal, vertical; m): a wrong-but-consistent ambiguity set, an RTK
    # network's offset; an assumption (a survey-grade RTK specification), the base position's sigma adds to it;
    # raised per flight by its positions' own sigmas, and a flight's exposures that are not fixed get their own
    # offset (docs/dji.md, "The per-flight prior from the RTK quality")
    flight_offset_sigma_m: tuple[float, float] = (0.01, 0.015)
    flight_gap_s: float = 120.0               # without flight folders: a gap this long between photos starts a flight
    # the platform's georef step: OUT_DIR/ppk is the gnss step's result (made with the run's GNSS options and,
    # if set there, its EXIF trigger times): it is read, never re-run here
    ppk_from_gnss_step: bool = False


FACTORY_CALIBRATION_CHOICES = ("prior", "fixed", "ignore")
FLIGHT_OFFSET_CHOICES = ("auto", "on", "off")


def validate_shutter_options(opts: GeorefOptions) -> None:
    """A readout time is a rolling shutter's: between 0 and 0.2 s, and not with a global shutter."""
    if opts.readout_s is None:
        return
    if not 0.0 < opts.readout_s <= 0.2:
        raise ProcessingError(f"rolling-shutter readout time {1000 * opts.readout_s:g} ms: expected more than 0 and at "
                              f"most 200 ms (small drone cameras read out in 20-60 ms)")
    if opts.rolling_shutter is False:
        raise ProcessingError("a readout time was given for a camera declared global-shutter")


def georef_options_from_dict(d: dict) -> GeorefOptions:
    """GeorefOptions from a settings dict (the platform's run settings); unknown names are an error."""
    from dataclasses import fields

    names = {f.name for f in fields(GeorefOptions)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise ProcessingError(f"unknown georeferencing settings: {', '.join(unknown)} (known: {', '.join(sorted(names))})")
    d = dict(d)
    for key in ("lever_arm_cam_m", "fixed_intrinsics", "gcp_sigma_m", "flight_offset_sigma_m"):
        if d.get(key) is not None:
            d[key] = tuple(float(v) for v in d[key])
    opts = GeorefOptions(**d)
    validate_shutter_options(opts)
    opts.mode = MODE_ALIASES.get(opts.mode, opts.mode)
    if opts.mode not in MODES:
        raise ProcessingError(f"georeferencing mode {d.get('mode')!r}: one of {', '.join(MODES)}")
    if opts.camera_model not in SFM_MODELS:
        raise ProcessingError(f"camera_model {opts.camera_model!r}: one of {', '.join(SFM_MODELS)}")
    if opts.factory_calibration not in FACTORY_CALIBRATION_CHOICES:
        raise ProcessingError(f"factory_calibration {opts.factory_calibration!r}: one of "
                              f"{', '.join(FACTORY_CALIBRATION_CHOICES)}")
    validate_flight_options(opts)
    return opts


def validate_flight_options(opts: GeorefOptions) -> None:
    """The per-flight GNSS offsets' choice, sigmas (two, not negative) and flight gap (positive)."""
    if opts.flight_offsets not in FLIGHT_OFFSET_CHOICES:
        raise ProcessingError(f"flight_offsets {opts.flight_offsets!r}: one of {', '.join(FLIGHT_OFFSET_CHOICES)}")
    sig = tuple(opts.flight_offset_sigma_m)
    if len(sig) != 2 or not all(0.0 <= float(v) <= 10.0 for v in sig):
        raise ProcessingError(f"flight_offset_sigma_m {sig}: two sigmas (horizontal, vertical) of 0 to 10 m")
    if not float(opts.flight_gap_s) > 0.0:
        raise ProcessingError(f"flight_gap_s {opts.flight_gap_s}: a positive number of seconds")
