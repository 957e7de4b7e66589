"""Step "dtm": bare-earth DTM. Reads the dense step's ``dense/dsm.tif`` (with ``dsm_filled_mask.tif`` and
``dense_summary.json`` when present) and ``dense/points.laz``; writes ``dtm/``: ``dtm.tif`` (COG, float32, the
DSM's grid), ``dtm_interpolated_mask.tif`` (COG, uint8: 0 ground as measured, 1 object removed and
interpolated, 2 ground the dense step had interpolated, 255 no data), ``points_classified.laz`` (ASPRS 2 ground,
1 objects above it, 7 low noise) and ``dtm_summary.json``. The CLI (``georef dtm OUT_DIR``) and the worker
call this same function. Method: georef_core.dtm, docs/deliverables.md ("Bare-earth DTM").
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from ..dtm.ground_filter import GroundFilterOptions
from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn

DTM_DIR = "dtm"
# dense_summary.json keys of the DSM's error model, carried into dtm_summary.json so that the volume tools read
# the same uncertainty model next to the DTM (volumes.uncertainty.NoiseModel.for_dsm)
NOISE_KEYS = ("dsm_vertical_rmse_m", "dsm_height_bias_m", "check_height_bias_m", "dsm_error_correlation_length_m",
              "dsm_smoothing_radius_m")


def options_from_dict(d: dict | None) -> GroundFilterOptions:
    known = {f.name for f in fields(GroundFilterOptions)}
    bad = [k for k in (d or {}) if k not in known]
    if bad:
        raise ProcessingError(f"unknown dtm option {bad[0]!r} (known: {', '.join(sorted(known))})")
    o = GroundFilterOptions(**{k: v for k, v in (d or {}).items() if v is not None})
    try:
        o.check()
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    return o


def _read_raster(path: Path, what: str):
    import rasterio

    try:
        with rasterio.open(path) as ds:
            band = ds.read(1, masked=True)
            return np.asarray(band.astype(np.float64).filled(np.nan)), ds.transform, ds.crs, ds.res
    except rasterio.errors.RasterioIOError as exc:
        raise InputFileError(path, f"not a readable {what} GeoTIFF ({exc})") from None


def run_dtm(out_dir, options: GroundFilterOptions | dict | None = None, progress: ProgressFn | None = None,
            dsm_path=None, points_path=None, dtm_dir=None) -> dict:
    """Ground classification and DTM of a run folder holding dense/ (paths overridable); returns the summary."""
    from ..dense import cog_writer
    from ..dense.point_cloud_io import open_point_cloud, point_chunks, point_cloud_writer, point_xyz
    from ..dtm.bare_earth import MASK_NODATA, build_dtm, interpolation_check
    from ..dtm.ground_filter import classify_dsm
    from ..dtm.point_classes import CLASS_GROUND, CLASS_LOW_NOISE, CLASS_NAMES, CLASS_UNCLASSIFIED, classify_points
    from ..dtm.removed_objects import removed_objects

    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    report = progress or (lambda *a: None)
    o = options if isinstance(options, GroundFilterOptions) else options_from_dict(options)
    o.check()
    out = Path(out_dir)
    dense_dir = out / "dense"
    dsm_path = Path(dsm_path) if dsm_path else dense_dir / "dsm.tif"
    points_path = Path(points_path) if points_path else dense_dir / "points.laz"
    target = Path(dtm_dir) if dtm_dir else out / DTM_DIR
    if not dsm_path.is_file():
        raise InputFileError(dsm_path, "no DSM: run the dense step first (georef dense OUT_DIR)")
    if not points_path.is_file():
        raise InputFileError(points_path, "no dense point cloud: run the dense step first (georef dense OUT_DIR)")

    report("dtm: classify", 0, 3)
    t = time.perf_counter()
    dsm, transform, crs, res = _read_raster(dsm_path, "DSM")
    if crs is None or not crs.is_projected:
        raise InputFileError(dsm_path, "the DSM has no projected CRS (metres) to classify in")
    if abs(res[0] - res[1]) > 1e-9 * max(res):
        raise InputFileError(dsm_path, f"the DSM cells are not square ({res[0]:g} x {res[1]:g})")
    resolution = float(res[0])
    if not np.isfinite(dsm).any():
        raise InputFileError(dsm_path, "the DSM holds no data")
    epsg = crs.to_epsg()
    filled_by_dense = None
    mask_path = dsm_path.with_name("dsm_filled_mask.tif")
    if mask_path.is_file():
        m, *_ = _read_raster(mask_path, "DSM mask")
        if m.shape == dsm.shape:
            filled_by_dense = m == 1
    try:
        gc = classify_dsm(dsm, resolution, o)
    except ValueError as exc:
        raise ProcessingError(f"ground filter on {dsm_path}: {exc}") from None
    timings["classify"] = time.perf_counter() - t

    report("dtm: interpolate", 1, 3)
    t = time.perf_counter()
    try:
        dtm, mask = build_dtm(dsm, gc.nonground, filled_by_dense, gc.provisional_ground)
    except ValueError as exc:
        raise ProcessingError(f"DTM of {dsm_path}: {exc}") from None
    valid = np.isfinite(dsm)
    ground = valid & ~gc.nonground
    objects = removed_objects(gc.nonground, dsm, dtm, ground, transform, resolution, o.min_object_area_m2)
    sizes = [np.sqrt(it["area_m2"]) for it in objects["items"]]
    patch = float(np.median(sizes)) if sizes else 5.0
    check = interpolation_check(dsm, ground & (mask != 2), resolution, patch)
    target.mkdir(parents=True, exist_ok=True)
    nodata = -9999.0
    tags = {"HEIGHTS": "ellipsoidal (WGS84), metres", "PRODUCER": "georef dtm step",
            "CONTENT": "bare-earth DTM: the DSM with non-ground objects removed and interpolated"}
    cog_writer.write_cog(target / "dtm.tif", np.where(np.isfinite(dtm), dtm, nodata).astype(np.float32), transform,
                         epsg, nodata=nodata, overview_resampling="AVERAGE", descriptions=["bare-earth height (m)"],
                         tags=tags, units="metre")
    cog_writer.write_cog(target / "dtm_interpolated_mask.tif", mask, transform, epsg, nodata=MASK_NODATA,
                         overview_resampling="NEAREST",
                         descriptions=["0 ground measured, 1 object removed and interpolated, 2 ground interpolated "
                                       "by the dense step, 255 no data"],
                         tags={"PRODUCER": "georef dtm step"})
    timings["interpolate"] = time.perf_counter() - t

    report("dtm: points", 2, 3)
    t = time.perf_counter()
    # streamed, a million points at a time: memory does not grow with the cloud
    counts = dict.fromkeys((CLASS_GROUND, CLASS_UNCLASSIFIED, CLASS_LOW_NOISE), 0)
    n_points = 0
    with open_point_cloud(points_path) as reader:
        header = reader.header
        header.generating_software = "georef"
        with point_cloud_writer(target / "points_classified.laz", header) as writer:
            for pts in point_chunks(reader, points_path):
                cls, _dz = classify_points(point_xyz(pts), dtm, transform, o.ground_tolerance_m, o.low_noise_m)
                pts.classification = cls
                writer.write_points(pts)
                n_points += len(cls)
                for c in counts:
                    counts[c] += int(np.count_nonzero(cls == c))
    timings["points"] = time.perf_counter() - t
    report("dtm: points", 3, 3)

    dense_summary = {}
    ds_path = dsm_path.with_name("dense_summary.json")
    if ds_path.is_file():
        try:
            dense_summary = json.loads(ds_path.read_text())
        except (OSError, json.JSONDecodeError):
            dense_summary = {}
    n_valid = int(valid.sum())
    n_removed = int((gc.nonground & valid).sum())
    timings["total"] = time.perf_counter() - t_all
    summary = {
        "dsm": str(dsm_path), "points_input": str(points_path), "epsg": epsg, "resolution_m": resolution,
        "dtm": {"width": int(dsm.shape[1]), "height": int(dsm.shape[0]), "cells_with_data": n_valid,
                "ground_cells": n_valid - n_removed, "removed_cells": n_removed,
                "ground_share": round((n_valid - n_removed) / n_valid, 5),
                "removed_area_m2": round(n_removed * resolution * resolution, 3),
                "dsm_interpolated_ground_cells": int(np.count_nonzero(mask == 2))},
        "points": {"total": n_points, "ground": counts[CLASS_GROUND], "unclassified": counts[CLASS_UNCLASSIFIED],
                   "low_noise": counts[CLASS_LOW_NOISE],
                   "ground_share": round(counts[CLASS_GROUND] / max(1, n_points), 5),
                   "classes": {str(k): v for k, v in CLASS_NAMES.items()}},
        "removed_objects": objects,
        "interpolation_check": check,
        "parameters": {**asdict(o), "method": "progressive morphological filter on the minimum surface "
                                              "(georef_core.dtm.ground_filter)",
                       "classification_cell_m": round(gc.cell_m, 6), "opening_radii_m": gc.radii_m,
                       "drop_threshold_m": round(gc.drop_threshold_m, 4)},
        **{k: dense_summary[k] for k in NOISE_KEYS if isinstance(dense_summary.get(k), (int, float))},
        "outputs": {k: str(target / f) for k, f in (("dtm", "dtm.tif"), ("mask", "dtm_interpolated_mask.tif"),
                                                    ("points", "points_classified.laz"),
                                                    ("summary", "dtm_summary.json"))},
        "timings_s": {k: round(v, 2) for k, v in timings.items()},
    }
    tmp = target / "dtm_summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    tmp.replace(target / "dtm_summary.json")
    return summary


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The dtm step as the contract runs it (specs.DTM): inputs and outputs at the paths the specs declare."""
    from .contract import get_spec

    opts = get_spec("dtm").validate(dict(options or {}))
    s = run_dtm(workspace.out_dir, options_from_dict(opts), progress,
                dsm_path=workspace.path("dense", "dsm"), points_path=workspace.path("dense", "point_cloud"),
                dtm_dir=workspace.path("dtm", "dtm").parent)
    return {"ground_share": s["dtm"]["ground_share"], "removed_objects": s["removed_objects"]["count"],
            "removed_area_m2": s["removed_objects"]["area_m2"], "points_ground_share": s["points"]["ground_share"],
            "interpolation_check": s["interpolation_check"]}
