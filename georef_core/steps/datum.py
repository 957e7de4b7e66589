"""Step "datum": the run's heights in the site's vertical datum (docs/datums.md).

The dense step writes ellipsoidal heights (GNSS); a site that works in orthometric heights (its
``vertical_datum``, e.g. EPSG:5773 EGM96 height, or this step's ``vertical_datum`` option) gets copies:

* ``datum/dsm_orthometric.tif``: the DSM, compound CRS horizontal + vertical in the GeoTIFF;
* ``datum/points_orthometric.laz``: the dense point cloud, compound CRS as the LAS WKT;
* ``datum/ground_points.csv`` / ``.geojson``: the survey's control and check points in the site CRS and the
  datum, with the georef step's residuals (dx, dy, dz: estimated - surveyed) and the datum named on every row.

With a site calibration (localisation: the survey's calibration/ file or the step's ``calibration`` setting;
docs/datums.md) the step also writes ``datum/site_calibration.json`` and ``datum/dsm_local.tif`` (the DSM on the
site's local grid) and puts the calibration's parameters and residuals per point into its summary; a site in
ellipsoidal heights is then not skipped.

A separate step rather than a change in the dense step: the ellipsoidal products stay what they are (the
volumes step reads them, and a volume does not depend on the datum to better than the geoid's slope times
the pile's size), the conversion is rerun alone when the site's datum changes, and the dense code is not
touched. A site without a vertical datum (ellipsoidal heights) skips the step at once. A missing grid fails
the step with the file's name (vertical_datum.GridMissingError), never a silently ellipsoidal copy.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputFileError, ProcessingError
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


CALIBRATION_FOLDER = "calibration"


def _same_crs(a: str, b: str) -> bool:
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return CRS.from_user_input(a).equals(CRS.from_user_input(b), ignore_axis_order=True)
    except CRSError:
        return False


def _site_calibration(workspace, options: dict, datum, crs: str | None, site_cal: dict | None = None):
    """The site calibration this run applies, where it came from and which kind of source that is: the step's
    ``calibration`` setting (the JSON document `georef datum calibrate` writes; origin "settings"), else the
    survey's calibration/ folder (``calibration_file``, or the one file there: a calibration JSON, or a CSV of
    control pairs solved here in the site CRS and datum; origin "survey file"), else the site's stored calibration
    (``site_cal``: the platform's context "site_calibration" = {document, version, source_name, updated_at};
    origin "site"). (None, None, None) without one. The calibration's CRS and height datum must be the run's."""
    from ..datums.site_calibration import calibration_from_dict, read_calibration, read_control_pairs, solve_calibration
    from ..datums.vertical_datum import resolve

    survey = Path(workspace.survey_dir)
    origin = "survey file"
    if options.get("calibration"):
        where, origin = "settings datum.calibration", "settings"
        cal = calibration_from_dict(options["calibration"], where)
    elif site_cal and site_cal.get("document") and not options.get("calibration_file") and not (
            (survey / CALIBRATION_FOLDER).is_dir()
            and any(f.suffix.lower() in (".json", ".csv") for f in (survey / CALIBRATION_FOLDER).glob("*"))):
        origin = "site"
        where = (f"the site's calibration (version {site_cal.get('version')}"
                 + (f", from {site_cal['source_name']}" if site_cal.get("source_name") else "")
                 + (f", set {site_cal['updated_at'][:19]}" if site_cal.get("updated_at") else "") + ")")
        cal = calibration_from_dict(site_cal["document"], where)
    else:
        name = options.get("calibration_file")
        if name:
            path = survey / name
            if not path.resolve().is_relative_to(survey.resolve()):
                raise InputFileError(name, "the setting datum.calibration_file must name a file inside the survey")
            if not path.is_file():
                raise InputFileError(path, "calibration file not found in the survey (setting datum.calibration_file)")
        else:
            folder = survey / CALIBRATION_FOLDER
            found = sorted(f for f in folder.glob("*") if f.suffix.lower() in (".json", ".csv")) if folder.is_dir() else []
            if not found:
                return None, None, None
            if len(found) > 1:
                raise InputFileError(folder, f"{len(found)} calibration files ({', '.join(f.name for f in found)}): "
                                             "keep one, or name it with the setting datum.calibration_file")
            path = found[0]
        where = path.relative_to(survey).as_posix() if path.is_relative_to(survey) else str(path)
        with open(path, "rb") as fh:   # by content: a JSON document, or a CSV of pairs (whatever the name says)
            is_json = fh.read(4096).lstrip().startswith(b"{")
        if not is_json:
            try:
                cal = solve_calibration(read_control_pairs(path), crs=crs or "", height_datum=datum.code,
                                        name=path.stem)
            except ProcessingError as exc:   # too few points, coincident points...: the file named
                raise InputFileError(path, str(exc)) from None
        else:
            cal = read_calibration(path)
    try:
        cal_datum = resolve(cal.height_datum)
    except ValueError as exc:
        raise InputFileError(where, f"height datum: {exc}") from None
    if cal_datum.code != datum.code:
        raise InputFileError(where, f"the calibration's heights are {cal_datum.label}, the run's are {datum.label}: "
                                    "calibrate on the site's datum (georef datum calibrate --height-datum)")
    if cal.crs and crs and not _same_crs(cal.crs, crs):
        raise InputFileError(where, f"the calibration is in {cal.crs}, the site in {crs if len(crs) < 40 else crs[:40] + '...'}")
    return cal, where, origin


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
    crs = _site_crs(context, workspace)
    site_cal = context.get("site_calibration")
    # bad input fails before anything is written
    cal, cal_source, cal_origin = _site_calibration(workspace, options, datum, crs, site_cal)
    if datum.is_ellipsoidal and cal is None:
        doc = {"skipped": True, "reason": "the site's heights are ellipsoidal (no vertical datum set) and the run "
                                          "has no site calibration: the dense step's products already are in them",
               "datum": datum.label}
        _write_json(summary_path, doc)
        return doc
    done: dict = {"datum": datum.label, "vertical_datum": datum.code, "files": {}}
    if not datum.is_ellipsoidal:
        step_m = float(options.get("node_step_m") or 10.0)
        op = transformation(datum)          # GridMissingError here, before anything is written
        done.update(operation=op["operation"], grid=op["grid"], node_step_m=step_m)
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
        if points and crs:
            rows = attach_residuals(points_in_datum(points, crs, datum), workspace.path("georef", "residuals_json"))
            write_points_csv(workspace.path("datum", "points_csv"), rows, crs, datum)
            write_points_geojson(workspace.path("datum", "points_geojson"), rows, crs, datum)
            done["files"]["ground_points"] = {"points": len(rows),
                                              "path": str(workspace.path("datum", "points_csv"))}
    if cal is not None:
        from ..datums.site_calibration import calibrate_raster

        cal.write(workspace.path("datum", "calibration"))
        done["calibration"] = {"source": cal_source, "origin": cal_origin, **cal.summary()}
        if site_cal and cal_origin != "site":
            done["calibration"]["site_calibration_not_used"] = (
                f"the site's calibration (version {site_cal.get('version')}) was not applied: the "
                f"{'run or survey settings give' if cal_origin == 'settings' else 'survey gives'} its own")
        src = workspace.path("dense", "dsm") if datum.is_ellipsoidal else workspace.path("datum", "dsm")
        if src.is_file():
            done["files"]["dsm_local"] = calibrate_raster(cal, src, workspace.path("datum", "dsm_local"))
    if not done["files"]:
        done["note"] = "nothing to convert: no DSM, point cloud or surveyed points in this run"
    progress("datum", 3, 3)
    _write_json(summary_path, done)
    return done


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The datum step as the contract runs it (specs.DATUM)."""
    from .contract import get_spec

    return run_datum(workspace, get_spec("datum").validate(options), progress, context)
