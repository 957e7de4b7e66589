"""Step "datum": the run's heights in the site's vertical datum (docs/datums.md).

The dense step writes ellipsoidal heights (GNSS); a site that works in orthometric heights (its
``vertical_datum``, e.g. EPSG:5773 EGM96 height, or this step's ``vertical_datum`` option) gets copies:

* ``datum/dsm_orthometric.tif``: the DSM, compound CRS horizontal + vertical in the GeoTIFF;
* ``datum/points_orthometric.laz``: the dense point cloud, compound CRS as the LAS WKT;
* ``datum/ground_points.csv`` / ``.geojson``: the survey's control and check points in the site CRS and the
  datum, with the georef step's residuals (dx, dy, dz: estimated - surveyed) and the datum named on every row.

A separate step rather than a change in the dense step: the ellipsoidal products stay what they are (the
volumes step reads them, and a volume does not depend on the datum to better than the geoid's slope times
the pile's size), the conversion is rerun alone when the site's datum changes, and the dense code is not
touched. A site without a vertical datum (ellipsoidal heights) skips the step at once. A missing grid fails
the step with the file's name (vertical_datum.GridMissingError), never a silently ellipsoidal copy.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import ProcessingError
from ..progress import no_progress


def _write_json(path: Path, doc: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(path)


def _site_crs(context: dict, workspace) -> str | None:
    if context.get("crs"):
        return str(context["crs"])
    dsm = workspace.path("dense", "dsm")
    if dsm.is_file():
        import rasterio

        with rasterio.open(dsm) as src:
            if src.crs is not None:
                return src.crs.to_wkt()
    res = workspace.path("georef", "residuals_json")
    if res.is_file():
        return json.loads(res.read_text()).get("crs") or None
    return None


def _ground_points(workspace, points_crs: str | None):
    from ..adjustment.control_points import load_control
    from .gnss_solve import read_survey_json

    gcp = Path(workspace.survey_dir) / "gcp"
    points_csv = gcp / "points.csv" if (gcp / "points.csv").is_file() else None
    gcp_list = gcp / "gcp_list.txt" if (gcp / "gcp_list.txt").is_file() else None
    if points_csv is None and gcp_list is None:
        return []
    crs = points_crs or read_survey_json(workspace.survey_dir).get("points_crs")
    return list(load_control(points_csv, gcp_list, crs).points.values())


def run_datum(workspace, options: dict, progress=None, context: dict | None = None) -> dict:
    from ..datums.point_cloud_heights import convert_point_cloud_heights
    from ..datums.point_tables import attach_residuals, points_in_datum, write_points_csv, write_points_geojson
    from ..datums.raster_heights import convert_raster_heights
    from ..datums.vertical_datum import resolve, transformation

    progress = progress or no_progress
    context = context or {}
    wanted = options.get("vertical_datum") or context.get("vertical_datum")
    try:
        datum = resolve(wanted)
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    summary_path = workspace.path("datum", "summary")
    if datum.is_ellipsoidal:
        doc = {"skipped": True, "reason": "the site's heights are ellipsoidal (no vertical datum set): the dense "
                                          "step's products already are in them", "datum": datum.label}
        _write_json(summary_path, doc)
        return doc
    step_m = float(options.get("node_step_m") or 10.0)
    op = transformation(datum)          # GridMissingError here, before anything is written
    done: dict = {"datum": datum.label, "vertical_datum": datum.code, "operation": op["operation"],
                  "grid": op["grid"], "node_step_m": step_m, "files": {}}
    progress("datum", 0, 3)
    dsm = workspace.path("dense", "dsm")
    if dsm.is_file():
        done["files"]["dsm"] = convert_raster_heights(dsm, workspace.path("datum", "dsm"), datum, step_m=step_m)
    progress("datum", 1, 3)
    cloud = workspace.path("dense", "point_cloud")
    if cloud.is_file() and options.get("point_cloud", True):
        done["files"]["point_cloud"] = convert_point_cloud_heights(cloud, workspace.path("datum", "point_cloud"),
                                                                   datum, step_m=step_m)
    progress("datum", 2, 3)
    points = _ground_points(workspace, options.get("points_crs"))
    crs = _site_crs(context, workspace)
    if points and crs:
        rows = attach_residuals(points_in_datum(points, crs, datum), workspace.path("georef", "residuals_json"))
        write_points_csv(workspace.path("datum", "points_csv"), rows, crs, datum)
        write_points_geojson(workspace.path("datum", "points_geojson"), rows, crs, datum)
        done["files"]["ground_points"] = {"points": len(rows), "path": str(workspace.path("datum", "points_csv"))}
    if not done["files"]:
        done["note"] = "nothing to convert: no DSM, point cloud or surveyed points in this run"
    progress("datum", 3, 3)
    _write_json(summary_path, done)
    return done


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The datum step as the contract runs it (specs.DATUM)."""
    from .contract import get_spec

    return run_datum(workspace, get_spec("datum").validate(options), progress, context)
