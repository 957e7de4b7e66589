"""The core pipeline steps' specs (contract.StepSpec): gnss, georef, dense, volumes; the platform registers
its report step (backend/services/steps_catalog.py). Importing this module loads no science code."""

from __future__ import annotations

from .contract import Option, Output, Product, StepSpec, options_from_dataclass, register
from .georef_options import FACTORY_CALIBRATION_CHOICES, MODES, SFM_MODELS, GeorefOptions

# ---------------------------------------------------------------------------------------------------- gnss
GNSS = StepSpec(
    name="gnss", title="GNSS baseline processing (PPK)", version=2,
    description="The drone receiver's raw observations against the base: antenna positions, velocities and "
                "covariances at every epoch and camera trigger (docs/gnss.md).",
    function="georef_core.steps.gnss_solve:step_entry",
    # DJI flight folders (flights/<name>/: photos, Timestamp.MRK, raw log) are read whole: the MRK exposures
    # are tied to the photos of their folder
    # images/: their EXIF times are the triggers when exif_time_offset_s is set
    inputs=("rover/", "base/", "nav/", "flights/", "images/", "events.csv", "survey.json"), site_data=("crs",),
    options=(
        Option("freq", "string", "auto", "frequencies (auto: both when the rover records a second band)",
               choices=("auto", "l1", "l1+l2", "l1+l2+l5")),
        Option("mode", "string", "auto", "positioning mode (auto: known-start for L1 with a take-off point, "
                                         "else kinematic)", choices=("auto", "kinematic", "static", "known-start")),
        Option("direction", "string", "combined", "filter direction", choices=("combined", "forward", "backward")),
        Option("filter", "string", None, "alias of direction", choices=("combined", "forward", "backward"),
               advanced=True),
        Option("elmask", "number", 15.0, "elevation mask", minimum=0.0, maximum=60.0, unit="deg"),
        Option("ar", "string", "fix-and-hold", "ambiguity resolution",
               choices=("off", "continuous", "instantaneous", "fix-and-hold")),
        Option("ratio", "number", 3.0, "ratio-test threshold", minimum=1.0, maximum=100.0),
        Option("navsys", "string", None, "systems, e.g. G,E,J (default: all)", advanced=True),
        Option("tdcp_slips", "number", 0.05, "time-differenced carrier-phase slip check threshold (0: off)",
               minimum=0.0, maximum=1.0, unit="m", advanced=True),
        Option("hold_variance", "number", 0.1, "fix-and-hold: variance of the held ambiguities", minimum=1e-6,
               maximum=100.0, unit="cycles^2", advanced=True),
        Option("event_edge", "string", "falling", "the TIM-TM2 edge of a UBX rover log that marks the exposure",
               choices=("falling", "rising"), advanced=True),
        Option("reverse_witness", "boolean", True, "forward/backward: the other pass refutes contradicted fixes",
               advanced=True),
        Option("base_position_ecef_m", "numbers", None, "base antenna position (default: the base file's header "
                                                       "or an averaged single-point solution)", length=3, unit="m"),
        Option("known_start_ecef_m", "numbers", None, "surveyed take-off antenna position (known-start mode)",
               length=3, unit="m", advanced=True),
        Option("epsg", "integer", None, "also write coordinates in this EPSG CRS (default: the site's)",
               minimum=1024, maximum=999999, advanced=True),
        Option("events_csv", "string", None, "a trigger-times file of the survey that overrides its own",
               advanced=True),
        Option("exif_time_offset_s", "number", None, "trigger times from the photos' EXIF times plus this "
               "camera-clock offset (for cameras whose exposures the receiver did not record)", minimum=-86400.0,
               maximum=86400.0, unit="s", advanced=True),
    ),
    outputs=(
        Output("trajectory", "ppk/trajectory.pos", "RTKLIB .pos of the antenna", "text/plain"),
        Output("trajectory_parquet", "ppk/trajectory.parquet", "positions with covariances and velocities"),
        Output("camera_positions", "ppk/events.csv", "the antenna at every camera trigger", "text/csv"),
        Output("summary", "ppk/summary.json", "the step summary", "application/json"),
    ),
    products=(
        Product("trajectory", "GNSS trajectory", "PPK antenna positions with quality", ("trajectory",),
                (("pos", "RTKLIB .pos"), ("csv", "CSV"), ("geojson", "GeoJSON"), ("json", "JSON"))),
        Product("camera-positions", "Camera positions", "Antenna at each camera trigger", ("camera_positions",),
                (("csv", "CSV"), ("geojson", "GeoJSON"), ("json", "JSON"))),
    ),
    summary={"epochs": "epochs solved", "fix_rate": "share of fixed epochs",
             "fix_conflicts": "epochs both filter directions fixed more than 5 cm apart",
             "events": "camera triggers and their quality",
             "skipped": "true when there was nothing to solve (photos alone), with 'reason'"},
)

# -------------------------------------------------------------------------------------------------- georef
GEOREF = StepSpec(
    name="georef", title="Georeferencing", version=2,
    description="Structure from motion, GNSS-aided bundle adjustment with lever arm and trigger delay, and the "
                "check-point residual table (docs/georeferencing.md).",
    function="georef_core.steps.georef:step_entry", depends_on=("gnss",), heavy=True,
    # georef reads the PPK of the gnss step and, when the images are tied to their EXIF times, the survey's
    # observations as well
    inputs=("rover/", "base/", "nav/", "flights/", "images/", "gcp/", "events.csv", "survey.json"),
    site_data=("crs", "vertical"),
    options=options_from_dataclass(
        # exif_time_offset_s is a GNSS-step setting on the platform (the gnss step makes ppk/ with it)
        GeorefOptions, exclude=("gnss_options", "num_threads", "reuse", "exif_time_offset_s", "ppk_from_gnss_step"),
        help={"mode": "joint (c), gcp (a) or similarity (b): Daakir et al. 2015",
              "camera_model": "camera model, self-calibrated", "lever_arm_cam_m": "known lever arm, camera frame",
              "estimate_lever_arm": "estimate the lever arm (default: unless one is given without a sigma)",
              "lever_arm_sigma_m": "a given lever arm is a prior with this sigma (else fixed)",
              "estimate_delay": "estimate the trigger delay", "delay_s": "a-priori or fixed trigger delay",
              "control": "'all', 'none' or names of control points", "check": "names made check points",
              "points_crs": "CRS of gcp/points.csv", "project_epsg": "project CRS (default: the site's)",
              "sigma_px": "tie-point measurement sigma", "gcp_sigma_px": "target measurement sigma",
              "gcp_sigma_m": "control point survey sigma (horizontal, vertical)",
              "max_tie_points": "tie points in the adjustment", "blunder_threshold_px": "blunder test threshold",
              "refine_targets": "sub-pixel refinement of clicked targets",
              "leave_one_out": "each control point also left out once",
              "rolling_shutter": "the camera has a rolling shutter (default: from its model)",
              "readout_s": "rolling-shutter readout time (default: estimated)",
              "fixed_intrinsics": "a calibrated camera's 8 intrinsics, held fixed",
              "factory_calibration": "a DJI factory calibration: prior, fixed or ignore"},
        mode={"choices": MODES + ("a", "b", "c"), "nullable": False},
        camera_model={"choices": tuple(SFM_MODELS), "nullable": False},
        factory_calibration={"choices": FACTORY_CALIBRATION_CHOICES, "nullable": False},
        sigma_px={"minimum": 0.01, "maximum": 100.0, "unit": "px", "advanced": True},
        gcp_sigma_px={"minimum": 0.01, "maximum": 100.0, "unit": "px", "advanced": True},
        gcp_sigma_m={"minimum": 0.0, "maximum": 10.0, "unit": "m", "length": 2},
        lever_arm_cam_m={"length": 3, "unit": "m"}, fixed_intrinsics={"length": 8, "advanced": True},
        max_tie_points={"minimum": 100, "maximum": 1_000_000, "advanced": True},
        blunder_threshold_px={"minimum": 0.5, "maximum": 1000.0, "unit": "px", "advanced": True},
        readout_s={"minimum": 0.0, "maximum": 0.2, "unit": "s", "advanced": True},
        delay_s={"minimum": -1.0, "maximum": 1.0, "unit": "s"},
        lever_arm_sigma_m={"minimum": 0.0, "maximum": 10.0, "unit": "m"},
        project_epsg={"minimum": 1024, "maximum": 999999},
        refine_targets={"advanced": True}, leave_one_out={"advanced": True}, rolling_shutter={"advanced": True}),
    outputs=(
        Output("oriented_images", "oriented_images.json", "camera poses and intrinsics", "application/json"),
        Output("residuals_json", "residuals.json", "check-point residual table and statistics", "application/json"),
        Output("residuals_csv", "residuals.csv", "check-point residual table", "text/csv"),
        Output("control_loo", "control_loo.json", "control points left out one by one", "application/json"),
        Output("lever_arm", "lever_arm_delay.json", "lever arm and trigger delay", "application/json"),
        Output("gnss_residuals", "gnss_residuals.json", "GNSS camera-position residuals", "application/json"),
        Output("sparse_points", "sparse_points.ply", "tie points"),
        Output("summary", "georef_summary.json", "the step summary", "application/json"),
    ),
    products=(
        Product("residuals", "Check-point residuals", "dE, dN, dh, |d| per point and statistics",
                ("residuals_json", "residuals_csv"), (("csv", "CSV"), ("json", "JSON"), ("geojson", "GeoJSON"))),
        Product("lever-arm", "Lever arm and delay", "Estimated camera-antenna offset and trigger delay",
                ("lever_arm",), (("", "JSON"),)),
    ),
    summary={"check_points": "residual statistics (mean, std, RMSE per axis)", "lever_arm_delay": "estimates",
             "absolute_accuracy": "what the result's absolute position rests on"},
)

# --------------------------------------------------------------------------------------------------- dense
DENSE = StepSpec(
    name="dense", title="Dense surface", version=1,
    description="Dense point cloud, DSM and orthophoto on the CPU (docs/dense.md).",
    function="georef_core.steps.dense:step_entry", depends_on=("georef",), heavy=True, site_data=("crs",),
    # the names and defaults of DenseOptions (steps/dense.py; tests/steps/test_step_contract.py holds them equal)
    options=(
        Option("max_image_size", "integer", 1600, "images are matched at most this large (longer side)",
               minimum=200, maximum=20000, unit="px"),
        Option("depth_map_downscale", "number", 2.0, "depth maps at this fraction of the matching size",
               minimum=1.0, maximum=8.0, advanced=True),
        Option("resolution_m", "number", None, "DSM cell (default: 2 x the ground sample distance)",
               minimum=0.005, maximum=100.0, unit="m"),
        Option("ortho_resolution_m", "number", None, "orthophoto cell (default: half the DSM cell)",
               minimum=0.002, maximum=100.0, unit="m"),
        Option("workers", "integer", 2, "threads", minimum=1, maximum=256, advanced=True),
        Option("max_gap_m", "number", 3.0, "DSM gaps at the coverage border up to twice this are filled",
               minimum=0.0, maximum=1000.0, unit="m", advanced=True),
        Option("min_points_per_cell", "integer", 1, "points a DSM cell needs", minimum=1, maximum=1000,
               advanced=True),
        Option("outlier_k", "number", 4.0, "surface outlier test: robust sigmas (0: off)", minimum=0.0,
               maximum=100.0, advanced=True),
        Option("outlier_min_offset_m", "number", 0.10, "smallest offset called an outlier", minimum=0.0,
               maximum=100.0, unit="m", advanced=True),
        Option("voxel_m", "number", None, "thin the point cloud to one point per voxel", minimum=0.001,
               maximum=100.0, unit="m", advanced=True),
        Option("ortho", "boolean", True, "write the orthophoto"),
        Option("ortho_compress", "string", "DEFLATE", "orthophoto compression", choices=("DEFLATE", "JPEG"),
               advanced=True),
        Option("keep_depth_maps", "boolean", False, "keep the depth maps", advanced=True),
        Option("oriented_path", "string", None, "oriented images file (default: the georef step's)",
               advanced=True),
        Option("pairs", "object", None, "pair selection settings (dense/pair_selection.py)", advanced=True),
        Option("stereo", "object", None, "stereo matching settings (dense/rectified_stereo.py)", advanced=True),
        Option("fusion", "object", None, "depth fusion settings (dense/depth_fusion.py)", advanced=True),
        Option("ortho_options", "object", None, "orthophoto settings (dense/orthophoto.py)", advanced=True),
    ),
    outputs=(
        Output("dsm", "dense/dsm.tif", "surface model, cloud-optimised GeoTIFF", "image/tiff"),
        Output("dsm_filled_mask", "dense/dsm_filled_mask.tif", "DSM cells filled by interpolation", "image/tiff"),
        Output("ortho", "dense/ortho.tif", "orthophoto, cloud-optimised GeoTIFF", "image/tiff"),
        Output("point_cloud", "dense/points.laz", "dense points", "application/vnd.laszip"),
        Output("summary", "dense/dense_summary.json", "the step summary", "application/json"),
    ),
    products=(
        Product("dsm", "Surface model (DSM)", "Cloud-optimised GeoTIFF, ellipsoidal heights", ("dsm",),
                (("", "GeoTIFF"),)),
        Product("ortho", "Orthophoto", "Cloud-optimised GeoTIFF", ("ortho",), (("", "GeoTIFF"),)),
        Product("point-cloud", "Point cloud", "Dense points", ("point_cloud",), (("laz", "LAZ"), ("las", "LAS"))),
    ),
    summary={"dsm": "grid and coverage", "noise": "DSM noise on flat areas", "timings_s": "seconds per stage"},
)

# ------------------------------------------------------------------------------------------------- volumes
VOLUMES = StepSpec(
    name="volumes", title="Stockpile volumes", version=2,
    description="The volume of every stockpile outline of the site on the DSM above its base surface, with its "
                "uncertainty (docs/volumes.md).",
    function="georef_core.steps.volumes:step_entry", depends_on=("dense",), site_data=("crs", "stockpiles"),
    options=(
        Option("dsm_sigma_m", "number", None, "DSM noise (default: the dense step's figure)", minimum=0.0,
               maximum=10.0, unit="m", advanced=True),
        Option("height_bias_m", "number", None, "DSM height bias uncertainty", minimum=0.0, maximum=10.0,
               unit="m", advanced=True),
        Option("correlation_length_m", "number", None, "correlation length of the DSM noise", minimum=0.0,
               maximum=1000.0, unit="m", advanced=True),
        # the names and defaults of VolumeOptions (volumes/volume.py; held equal by the contract test)
        Option("percentile", "number", None, "lowest/highest base: percentile of the outline heights",
               minimum=0.0, maximum=100.0, advanced=True),
        Option("smoothing_m", "number", 1.0, "running median along the outline before the percentile",
               minimum=0.0, maximum=100.0, unit="m", advanced=True),
        Option("outline_spacing_m", "number", None, "outline sampling (default: one cell)", minimum=0.001,
               maximum=100.0, unit="m", advanced=True),
        Option("outline_offset_m", "number", None, "outline offset outward (default: 1.5 cells)", minimum=0.0,
               maximum=100.0, unit="m", advanced=True),
        Option("max_fill_fraction", "number", 0.05, "no-data inside an outline filled up to this share of its "
                                                    "area", minimum=0.0, maximum=1.0, advanced=True),
        Option("base_model_spread", "boolean", True, "compute the base-model uncertainty term", advanced=True),
        Option("surface_sigma_m", "number", None, "noise of an imported base surface", minimum=0.0, maximum=10.0,
               unit="m", advanced=True),
    ),
    outputs=(
        Output("volumes", "volumes/volumes.json", "per stockpile: volume, cut, fill, area, uncertainty",
               "application/json"),
    ),
    products=(
        Product("volumes", "Stockpile volumes", "Cut, fill, net and area per stockpile", ("volumes",),
                (("csv", "CSV"), ("json", "JSON"), ("geojson", "GeoJSON"))),
    ),
    summary={"stockpiles": "number of stockpiles measured"},
)

for _spec in (GNSS, GEOREF, DENSE, VOLUMES):
    register(_spec)
