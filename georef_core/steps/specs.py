"""The core pipeline steps' specs (contract.StepSpec): gnss, georef, dense, volumes; the platform registers
its report step (backend/services/steps_catalog.py). Importing this module loads no science code."""

from __future__ import annotations

from .contract import Option, Output, Product, Split, StepSpec, options_from_dataclass, register
from .georef_options import FACTORY_CALIBRATION_CHOICES, FLIGHT_OFFSET_CHOICES, MODES, SFM_MODELS, GeorefOptions

# ---------------------------------------------------------------------------------------------------- gnss
GNSS = StepSpec(
    name="gnss", title="GNSS baseline processing (PPK)", version=4,
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
        Option("fix_max_sigma", "number", 0.05, "a fix whose position's formal 3-D sigma exceeds this is output "
               "as float (0: off)", minimum=0.0, maximum=10.0, unit="m", advanced=True),
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
             "equipment": "rover and base receiver and antenna models (RINEX header REC # / TYPE / VERS and "
                          "ANT # / TYPE, RTCM 1033, UBX MON-VER) and the file format they came from",
             "skipped": "true when there was nothing to solve (photos alone), with 'reason'",
             "triggers_sha256": "hash of the trigger times the camera events were made for (the georef "
                                "command's PPK reuse key, with inputs_sha256)",
             "inputs_sha256": "hash of every GNSS file's content and the GNSS options (the PPK reuse key)"},
)

# -------------------------------------------------------------------------------------------------- georef
GEOREF = StepSpec(
    name="georef", title="Georeferencing", version=5,
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
              "factory_calibration": "a DJI factory calibration: prior, fixed or ignore",
              "flight_offsets": "a common GNSS offset per flight, with a prior: auto, on or off",
              "flight_offset_sigma_m": "each flight's own GNSS offset sigma (horizontal, vertical)",
              "flight_gap_s": "without flight folders, a gap this long between photos starts a flight"},
        mode={"choices": MODES + ("a", "b", "c"), "nullable": False},
        camera_model={"choices": tuple(SFM_MODELS), "nullable": False},
        factory_calibration={"choices": FACTORY_CALIBRATION_CHOICES, "nullable": False},
        flight_offsets={"choices": FLIGHT_OFFSET_CHOICES, "nullable": False, "advanced": True},
        flight_offset_sigma_m={"minimum": 0.0, "maximum": 10.0, "unit": "m", "length": 2, "advanced": True},
        flight_gap_s={"minimum": 1.0, "maximum": 86400.0, "unit": "s", "advanced": True},
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
    name="dense", title="Dense surface", version=6,
    description="Dense point cloud, DSM and orthophoto on the CPU (docs/dense.md).",
    function="georef_core.steps.dense:step_entry", depends_on=("georef",), heavy=True, site_data=("crs",),
    # spatial tiles that workers run in parallel (steps/dense_tiles.py; docs/dense.md "Large surveys")
    split=Split(plan="georef_core.steps.dense_tiles:plan", part="georef_core.steps.dense_tiles:part",
                merge="georef_core.steps.dense_tiles:merge",
                # the merge reads the parts' summaries, the tiles' cores and the block's radiometry, not the depth maps
                merge_reads=("depth_summary.json", "core_summary.json", "core_rasters.npz", "core_points.npz",
                             "radiometry.json")),
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
        Option("coarse", "object", None, "coarse pass settings (dense/coarse_pass.py: factor, 1 = off)",
               advanced=True),
        Option("tiles", "integer", 0, "spatial tiles run as parts (0: auto, 1 up to 250 images then about one "
               "per 100, for memory: tiles cost CPU; 1: one run)", minimum=0, maximum=64, advanced=True),
        Option("tile_margin", "number", 0.25, "a tile takes the images whose ground footprint meets it grown by this "
               "many footprints", minimum=0.0, maximum=5.0, advanced=True),
    ),
    outputs=(
        Output("dsm", "dense/dsm.tif", "surface model, cloud-optimised GeoTIFF", "image/tiff", tile="heights"),
        Output("dsm_filled_mask", "dense/dsm_filled_mask.tif", "DSM cells: 0 measured, 2 measured at coarse "
               "resolution, 1 interpolated, 255 no data", "image/tiff"),
        Output("dsm_support", "dense/dsm_support.tif", "DSM cells: views agreeing (0: interpolated); band 2: why a "
               "cell lacks a measurement (seen by 2+ images without a consistent depth, or not seen)", "image/tiff"),
        Output("ortho", "dense/ortho.tif", "orthophoto, cloud-optimised GeoTIFF", "image/tiff", tile="rgb"),
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

# ----------------------------------------------------------------------------------------------------- dtm
DTM = StepSpec(
    name="dtm", title="Bare-earth DTM", version=1,
    description="Ground classification of the dense surface (progressive morphological filter: machines, vehicles "
                "and other steep-sided objects removed, stockpiles kept), the bare-earth DTM and the classified "
                "point cloud (docs/deliverables.md).",
    function="georef_core.steps.dtm:step_entry", depends_on=("dense",), site_data=("crs",),
    # the names and defaults of dtm.ground_filter.GroundFilterOptions (held equal by tests/dtm/test_dtm_step.py)
    options=(
        Option("cell_m", "number", 0.5, "classification cell", minimum=0.05, maximum=10.0, unit="m", advanced=True),
        Option("max_object_m", "number", 14.0, "objects up to this wide (narrow side) are removed", minimum=0.5,
               maximum=200.0, unit="m"),
        Option("slope", "number", 1.2, "steepest ground (rise over run; 1.2 = 50 deg): steeper steps mark objects",
               minimum=0.05, maximum=10.0),
        Option("elevation_threshold_m", "number", 0.3, "added to slope x cell: the drop per opening step that "
               "marks an object", minimum=0.0, maximum=10.0, unit="m", advanced=True),
        Option("ground_tolerance_m", "number", 0.25, "cells and points within this above the ground are ground",
               minimum=0.01, maximum=10.0, unit="m"),
        Option("low_outlier_m", "number", 1.0, "minimum-surface cells this far below their neighbours are clamped",
               minimum=0.01, maximum=100.0, unit="m", advanced=True),
        Option("low_noise_m", "number", 1.0, "points this far below the DTM are low noise (class 7)", minimum=0.01,
               maximum=100.0, unit="m", advanced=True),
        Option("min_object_area_m2", "number", 1.0, "smaller removed regions are counted as spikes", minimum=0.0,
               maximum=10000.0, unit="m2", advanced=True),
    ),
    outputs=(
        Output("dtm", "dtm/dtm.tif", "bare-earth terrain model, cloud-optimised GeoTIFF", "image/tiff"),
        Output("dtm_mask", "dtm/dtm_interpolated_mask.tif", "DTM cells: 0 ground measured, 1 object removed and "
               "interpolated, 2 ground interpolated by the dense step, 255 no data", "image/tiff"),
        Output("classified_points", "dtm/points_classified.laz", "dense points with ASPRS classes (2 ground, 1 "
               "objects, 7 low noise)", "application/vnd.laszip"),
        Output("summary", "dtm/dtm_summary.json", "ground share, removed objects, parameters", "application/json"),
    ),
    products=(
        Product("dtm", "Terrain model (DTM)", "Bare earth: machines and other objects removed; cloud-optimised "
                "GeoTIFF, ellipsoidal heights", ("dtm",), (("", "GeoTIFF"),)),
        Product("dtm-mask", "DTM interpolation mask", "Where the DTM was interpolated under removed objects",
                ("dtm_mask",), (("", "GeoTIFF"),)),
        Product("classified-points", "Classified point cloud", "Dense points, ASPRS classes: 2 ground, 1 objects, "
                "7 low noise", ("classified_points",), (("", "LAZ"),)),
    ),
    summary={"ground_share": "share of DSM cells kept as ground", "removed_objects": "objects removed",
             "removed_area_m2": "their area", "points_ground_share": "share of points classed ground",
             "interpolation_check": "hidden ground patches refilled: RMS and 95th percentile error"},
)

# ------------------------------------------------------------------------------------------------- volumes
VOLUMES = StepSpec(
    name="volumes", title="Stockpile volumes", version=3,
    description="The volume of every stockpile outline of the site on the DSM above its base surface, with its "
                "uncertainty (docs/volumes.md).",
    function="georef_core.steps.volumes:step_entry", depends_on=("dense",), soft_after=("dtm",),
    site_data=("crs", "stockpiles"),
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
        Option("surface", "string", "dsm", "the surface measured: the DSM, or the DTM (bare earth: machines "
               "standing on a pile removed; needs the dtm step)", choices=("dsm", "dtm")),
        Option("accept_interpolated", "boolean", False, "count interpolated DSM cells as measured in the "
               "uncertainty (off: they get their own bound, outside the stated uncertainty)", advanced=True),
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

# -------------------------------------------------------------------------------------------------- design
DESIGN = StepSpec(
    name="design", title="Cut/fill to design", version=1,
    description="The surveyed surface against the site's design surface (LandXML, DXF or GeoTIFF) inside its area: "
                "cut, fill, on-grade share and the cells whose difference the survey's accuracy cannot resolve "
                "(docs/design.md).",
    function="georef_core.steps.design:step_entry", depends_on=("dense",), soft_after=("dtm",),
    site_data=("crs", "design"),
    options=(
        Option("tolerance_m", "number", 0.05, "on grade within +- this", minimum=0.0, maximum=10.0, unit="m"),
        Option("surface", "string", "dsm", "the surveyed surface compared: the DSM or the DTM (bare ground)",
               choices=("dsm", "dtm")),
        Option("k", "number", 1.96, "a difference below k x the cell's height sigma is not significant "
               "(1.96: 95 %)", minimum=0.0, maximum=10.0, advanced=True),
        Option("dsm_sigma_m", "number", None, "DSM noise (default: the dense step's figure)", minimum=0.0,
               maximum=10.0, unit="m", advanced=True),
        Option("vertical_rmse_m", "number", None, "vertical accuracy (default: the check points' vertical RMSE)",
               minimum=0.0, maximum=10.0, unit="m", advanced=True),
        Option("correlation_length_m", "number", None, "correlation length of the DSM noise", minimum=0.0,
               maximum=1000.0, unit="m", advanced=True),
        Option("design_sigma_m", "number", None, "the design surface's own height error (default 0: exact)",
               minimum=0.0, maximum=10.0, unit="m", advanced=True),
        Option("surface_name", "string", None, "which surface of a LandXML file holding several", advanced=True),
    ),
    outputs=(
        Output("quantities", "design/cut_fill.json", "cut, fill, net, on-grade share and their uncertainty",
               "application/json"),
        Output("difference", "design/difference.tif", "surveyed minus design (m), GeoTIFF", "image/tiff",
               tile="difference"),
        Output("classes", "design/classes.tif", "cut / fill / on grade / not significant / no data, GeoTIFF with a "
               "colour table", "image/tiff"),
        Output("contours", "design/contours.geojson", "the tolerance band's edges and the zero line",
               "application/geo+json"),
    ),
    products=(
        Product("design-cut-fill", "Cut/fill to design", "Cut, fill, net and on-grade share", ("quantities",),
                (("", "JSON"),)),
        Product("design-difference", "Difference to design", "Surveyed minus design, GeoTIFF (m)", ("difference",),
                (("", "GeoTIFF"),)),
        Product("design-classes", "Cut/fill map", "Cut / fill / on grade / not significant, GeoTIFF", ("classes",),
                (("", "GeoTIFF"),)),
        Product("design-contours", "Tolerance band edges", "Difference contours at +-tolerance and 0, GeoJSON",
                ("contours",), (("", "GeoJSON"),)),
    ),
    summary={"cut_m3": "above design (to remove)", "fill_m3": "below design (to place)", "net_m3": "cut - fill",
             "sigma_m3": "1 sigma of cut, fill, net", "on_grade_share": "share within +-tolerance",
             "design_sigma_m3": "the design's own share of each sigma (common to all surveys against this design)",
             "skipped": "true when the site has no design surface"},
)

for _spec in (GNSS, GEOREF, DENSE, DTM, VOLUMES, DESIGN):
    register(_spec)

# --------------------------------------------------------------------------------------------------- datum
DATUM = StepSpec(
    name="datum", title="Heights in the site's datum", version=1,
    description="Copies of the DSM, the point cloud and the control/check-point table in the site's vertical datum "
                "(orthometric heights through the installed geoid grid), the datum written into each file "
                "(docs/datums.md). Skipped for a site in ellipsoidal heights.",
    function="georef_core.steps.datum:step_entry", depends_on=("georef",), soft_after=("dense",),
    inputs=("gcp/", "survey.json", "calibration/"), site_data=("crs", "vertical"),
    options=(
        Option("vertical_datum", "string", None, "heights in this datum (default: the site's vertical datum): "
               "egm96, egm2008 (where its grid is installed), jgd2011 (Japan, GSIGEO2011) or an EPSG vertical CRS "
               "code such as EPSG:5773"),
        Option("node_step_m", "number", 10.0, "the height change is computed by PROJ at nodes this far apart and "
               "interpolated bilinearly in between", minimum=0.5, maximum=1000.0, unit="m", advanced=True),
        Option("point_cloud", "boolean", True, "also convert the point cloud", advanced=True),
        Option("points_crs", "string", None, "CRS of gcp/points.csv (default: survey.json's points_crs)",
               advanced=True),
        Option("calibration", "object", None, "a site calibration (localisation) to apply: the JSON document "
               "'georef datum calibrate' writes (default: the survey's calibration/ file, if any)", advanced=True),
        Option("calibration_file", "string", None, "the survey's calibration file (a calibration JSON, or a CSV "
               "of control pairs solved in the site CRS and datum; default: the one file in calibration/)",
               advanced=True),
    ),
    outputs=(
        Output("dsm", "datum/dsm_orthometric.tif", "DSM in the site's vertical datum (compound CRS)", "image/tiff"),
        Output("point_cloud", "datum/points_orthometric.laz", "point cloud in the site's vertical datum",
               "application/vnd.laszip"),
        Output("points_csv", "datum/ground_points.csv", "control and check points with residuals, heights in the "
               "site's datum", "text/csv"),
        Output("points_geojson", "datum/ground_points.geojson", "the same points as GeoJSON",
               "application/geo+json"),
        Output("summary", "datum/datum_summary.json", "the step summary", "application/json"),
        Output("calibration", "datum/site_calibration.json", "the site calibration applied: parameters, sigmas, "
               "residuals per control point", "application/json"),
        Output("dsm_local", "datum/dsm_local.tif", "DSM on the site's local grid (site calibration applied)",
               "image/tiff"),
    ),
    products=(
        Product("files/datum/dsm_orthometric.tif", "Surface model (DSM), site heights",
                "Cloud-optimised GeoTIFF in the site's vertical datum", ("dsm",), (("", "GeoTIFF"),)),
        Product("files/datum/points_orthometric.laz", "Point cloud, site heights",
                "LAZ in the site's vertical datum", ("point_cloud",), (("", "LAZ"),)),
        Product("files/datum/ground_points.csv", "Control and check points, site heights",
                "Surveyed points and their residuals, heights in the site's vertical datum", ("points_csv",),
                (("", "CSV"),)),
        Product("files/datum/dsm_local.tif", "Surface model (DSM), site grid",
                "GeoTIFF on the site's local grid (site calibration applied)", ("dsm_local",), (("", "GeoTIFF"),)),
        Product("files/datum/site_calibration.json", "Site calibration",
                "The calibration applied: parameters, sigmas and residuals per control point", ("calibration",),
                (("", "JSON"),)),
    ),
    summary={"datum": "the vertical datum written", "operation": "PROJ's transformation and grid",
             "files": "what was converted (height change range per file)",
             "calibration": "the site calibration applied: source, parameters, sigmas, residuals per point (dE, "
                            "dN, dH: given local - calibrated), their RMS and maximum",
             "skipped": "true for a site in ellipsoidal heights without a site calibration"},
)
register(DATUM)

# ------------------------------------------------------------------------------------------------- exports
_EXPORT_FILES = (
    ("dxf", "exports/site.dxf", "contours (minor, index, labels), stockpile outlines, surveyed points: DXF",
     "image/vnd.dxf", "DXF drawing", "Contours, index labels, stockpile outlines and surveyed points (AutoCAD, "
     "Civil 3D, TBC)", "DXF"),
    ("dxf_prj", "exports/site.prj", "the DXF's CRS (ESRI WKT: DXF has none)", "text/plain", "DXF projection file",
     "The CRS of the DXF drawing (.prj)", "PRJ"),
    ("gpkg", "exports/site.gpkg", "layers contours, stockpiles, points: GeoPackage", "application/geopackage+sqlite3",
     "GeoPackage", "Contours, stockpile outlines with volumes, surveyed points (QGIS, ArcGIS)", "GeoPackage"),
    ("shp", "exports/shapefiles.zip", "contours, stockpiles, points: Shapefiles, zipped", "application/zip",
     "Shapefiles", "Contours, stockpile outlines, surveyed points as zipped Shapefiles", "ZIP"),
    ("contours_geojson", "exports/contours.geojson", "contours: GeoJSON (elevation_m, index)",
     "application/geo+json", "Contours (GeoJSON)", "Contour lines with elevation and index attributes", "GeoJSON"),
    ("landxml", "exports/surface.xml", "the surveyed TIN: LandXML 1.2", "application/xml", "Surface TIN (LandXML)",
     "The surveyed surface as a LandXML 1.2 TIN (Civil 3D, TBC, 12d)", "LandXML"),
    ("kmz", "exports/ortho.kmz", "the orthophoto as a Google Earth overlay (tiled when large)",
     "application/vnd.google-earth.kmz", "Orthophoto overlay (KMZ)",
     "The orthophoto for Google Earth and phones (one image, or tiles loaded as you zoom in)", "KMZ"),
    ("xlsx", "exports/site.xlsx", "surveyed points and volumes: XLSX",
     "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet", "Points and volumes (XLSX)",
     "Surveyed points with residuals and stockpile volumes, one sheet each", "XLSX"),
)
EXPORTS = StepSpec(
    name="exports", title="Exports", version=1,
    description="Contours of the DSM or DTM and the run's deliverables as DXF, GeoPackage, Shapefile, GeoJSON, "
                "LandXML (surveyed TIN), KMZ (orthophoto overlay), XLSX and CSV (docs/deliverables.md).",
    function="georef_core.steps.exports:step_entry", depends_on=("dense",),
    soft_after=("dtm", "volumes", "datum"),
    inputs=("gcp/", "survey.json"), site_data=("crs",),
    options=(
        Option("interval_m", "number", None, "contour interval (default: a round interval giving at most 40 "
               "levels)", minimum=0.01, maximum=1000.0, unit="m"),
        Option("surface", "string", "dsm", "contours and TIN of the DSM or of the DTM (bare ground; the DSM when "
               "the run has no DTM)", choices=("dsm", "dtm")),
        Option("formats", "string", "all", "'all' or a comma-separated list of geojson, dxf, gpkg, shp, landxml, "
               "kmz, xlsx, csv"),
        Option("index_every", "integer", 5, "every N-th contour is an index contour (labelled)", minimum=1,
               maximum=100),
        Option("heights", "string", "site", "site: the DSM in the site's vertical datum where the datum step wrote "
               "one; ellipsoidal: the dense step's DSM", choices=("site", "ellipsoidal"), advanced=True),
        Option("smoothing_m", "number", None, "Gaussian sigma of the smoothing before contouring (default 1.5 "
               "cells; 0: none)", minimum=0.0, maximum=100.0, unit="m", advanced=True),
        Option("tin_spacing_m", "number", None, "LandXML TIN vertex spacing (default 0.5 m or more, at most "
               "250 000 vertices)", minimum=0.01, maximum=1000.0, unit="m", advanced=True),
        Option("geojson_crs", "string", "wgs84", "GeoJSON coordinates: WGS 84 (RFC 7946) or the site CRS",
               choices=("wgs84", "site"), advanced=True),
        Option("kmz_tile_px", "integer", 2048, "KMZ: an orthophoto longer than this on its longer side is "
               "written as tiles over a few zoom levels (a super-overlay Google Earth loads as it zooms in), "
               "else as one image", minimum=256, maximum=1_000_000, unit="px", advanced=True),
    ),
    outputs=tuple(Output(k, p, d, m) for k, p, d, m, *_ in _EXPORT_FILES) + (
        Output("stockpiles_geojson", "exports/stockpiles.geojson", "stockpile outlines with volumes: GeoJSON",
               "application/geo+json"),
        Output("points_geojson", "exports/points.geojson", "surveyed points with residuals: GeoJSON",
               "application/geo+json"),
        Output("points_csv", "exports/points.csv", "surveyed points with residuals: CSV", "text/csv"),
        Output("volumes_csv", "exports/volumes.csv", "stockpile volumes: CSV", "text/csv"),
        Output("manifest", "exports/exports.json", "what was written and what was skipped, CRS, vertical datum",
               "application/json"),
    ),
    products=tuple(Product(f"files/{p}", title, desc, (k,), (("", label),))
                   for k, p, _d, _m, title, desc, label in _EXPORT_FILES),
    summary={"written": "files written per format", "skipped": "what was not written and why",
             "contours": "interval and number of lines", "tin": "TIN points, faces, spacing, departure from the "
             "surface", "crs": "CRS of every file", "vertical_datum": "the heights' datum"},
)
register(EXPORTS)
