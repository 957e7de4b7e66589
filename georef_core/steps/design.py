"""Step "design": the surveyed surface (the dense step's DSM, or the DTM) against the site's design surface
inside the site's design area, with the survey's measured accuracy (check-point vertical RMSE, DSM noise).
`georef design` and the worker call these functions. Library: georef_core.design (docs/design.md)."""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn, no_progress

SUMMARY_KEYS = ("cut_m3", "fill_m3", "net_m3", "area_m2", "tolerance_m", "noise_inflation_m3",
                "cut_beyond_tolerance_m3", "fill_beyond_tolerance_m3")


def area_polygon(polygons_path, polygon_crs: str | None = None):
    """The area of a GeoJSON file as one AreaPolygon (several features: their union)."""
    import shapely

    from ..volumes.polygons import AreaPolygon, read_polygons

    polys = read_polygons(polygons_path, polygon_crs)
    if len(polys) == 1:
        return polys[0]
    crs = polys[0].crs
    geom = shapely.union_all([p.to_crs(crs).geometry for p in polys])
    return AreaPolygon(" + ".join(p.name for p in polys), geom, crs, str(polygons_path))


def run_design(dsm_path, design_path, polygons_path, out_dir=None, options: dict | None = None,
               surface_name: str | None = None, site_crs: str | None = None, polygon_crs: str | None = None,
               run_dir=None, progress: ProgressFn | None = None) -> dict:
    """Cut/fill of ``dsm_path`` against the design file inside the polygon(s) of ``polygons_path``; outputs
    in ``out_dir`` (difference.tif, classes.tif, contours.geojson, cut_fill.json) when given. ``options``:
    CutFillOptions fields (tolerance_m, k, dsm_sigma_m, vertical_rmse_m, correlation_length_m, ...).
    ``site_crs``: CRS of a DXF / LandXML without CRS (default: the DSM's)."""
    from ..design.cut_fill import compute_cut_fill, options_from
    from ..design.design_surface import read_design
    from ..volumes.polygons import parse_crs
    from ..volumes.raster_io import open_elevation_raster

    progress = progress or no_progress
    try:
        opts = options_from(options)
    except TypeError as exc:
        raise ProcessingError(f"design options: {exc}") from None
    info = open_elevation_raster(dsm_path, "surveyed surface")
    crs = parse_crs(site_crs) if site_crs else info.crs
    design = read_design(design_path, surface_name, crs)
    poly = area_polygon(polygons_path, polygon_crs)
    return compute_cut_fill(info, design, poly, out_dir, opts, run_dir, progress)


def summary_of(doc: dict) -> dict:
    """What the step's summary keeps of cut_fill.json (the platform's progress list reads it)."""
    out = {k: doc[k] for k in SUMMARY_KEYS if k in doc}
    out.update(sigma_m3={k: doc["uncertainty"][k]["sigma_m3"] for k in ("cut_m3", "fill_m3", "net_m3")},
               # the design's own share of each sigma: common to every survey compared with the same design, so
               # it does not add in quadrature in a change between surveys (the platform's design-progress)
               design_sigma_m3={k: doc["uncertainty"][k]["components_m3"].get("design_m3", 0.0)
                                for k in ("cut_m3", "fill_m3", "net_m3")},
               on_grade_share=doc["on_grade"]["share"], on_grade_expected_share=doc["on_grade"]["expected_share"],
               not_significant_m2=doc["classes_m2"]["not_significant"],
               sigma_cell_m=doc["significance"]["sigma_cell_m"], design=doc["design"]["name"],
               design_file=Path(doc["design"]["path"]).name, warnings=doc["warnings"])
    return out


def _surface_path(workspace, which: str) -> Path:
    from .contract import get_spec

    if which == "dtm":
        try:
            p = workspace.path("dtm", "dtm")
        except (ProcessingError, KeyError):
            p = workspace.out_dir / "dtm" / "dtm.tif"
        if not p.exists():
            raise InputFileError(p, "no DTM: run the dtm step first (or choose surface = dsm)")
        return p
    get_spec("dense")
    p = workspace.path("dense", "dsm")
    if not p.exists():
        raise InputFileError(p, "no DSM: the dense step did not write dense/dsm.tif")
    return p


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The design step as the contract runs it (specs.DESIGN): context "design" = {"path": the design file
    (LandXML, DXF or GeoTIFF), "polygon": GeoJSON geometry of the area in the site CRS, "name",
    "surface_name": the LandXML surface (optional)}, context "crs": the site CRS. Without a design the step
    writes a cut_fill.json that says so and is skipped. Optional: "tolerance_m" (the site's; the step's option
    overrides it), "key" (returned in the summary as design_key)."""
    from .contract import get_spec

    opts = get_spec("design").validate(dict(options or {}))
    out_json = workspace.path("design", "quantities")
    out_dir = out_json.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    design = context.get("design") or None
    if not design or not design.get("path"):
        doc = {"skipped": True, "reason": "the site has no design surface"}
        out_json.write_text(json.dumps(doc, indent=1))
        return doc
    if not design.get("polygon"):   # a design uploaded, its area not drawn yet: nothing to compare (the run goes on)
        doc = {"skipped": True, "reason": "the site's design surface has no area yet (where to compare)"}
        out_json.write_text(json.dumps(doc, indent=1))
        return doc
    crs = context.get("crs")
    area = out_dir / "area.geojson"
    fc = {"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"name": design.get("name") or "design area"},
                                                     "geometry": design["polygon"]}]}
    if crs:
        fc["crs"] = {"type": "name", "properties": {"name": crs}}
    area.write_text(json.dumps(fc))
    if opts.get("tolerance_m") is None and design.get("tolerance_m") is not None:
        opts["tolerance_m"] = float(design["tolerance_m"])   # the site's tolerance unless the run sets one
    surface = opts.pop("surface", None) or "dsm"
    dsm = _surface_path(workspace, surface)
    surface_name = opts.pop("surface_name", None) or design.get("surface_name")
    doc = run_design(dsm, design["path"], area, out_dir, opts, surface_name, crs, None, workspace.out_dir,
                     progress or no_progress)
    summary = summary_of(doc)
    summary["surface"] = surface
    if design.get("key"):   # the platform's identifier of the design (its progress list matches on it)
        summary["design_key"] = design["key"]
    return summary
