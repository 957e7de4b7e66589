"""Step "exports": the run's deliverables (contours, stockpile outlines, surveyed points, the TIN, the
orthophoto overlay, tables) as DXF, GeoPackage, Shapefile, GeoJSON, LandXML, KMZ, XLSX and CSV, written to
``exports/`` (docs/deliverables.md, "Exports"). The CLI twin is `georef export OUT_DIR`."""

from __future__ import annotations

from ..errors import ProcessingError


def parse_formats(text: str | None) -> list[str] | None:
    """'all' / None -> None (every format); else the comma-separated names, checked."""
    from ..deliverables.exports import FORMATS

    if text is None or text.strip().lower() in ("", "all"):
        return None
    out = [f.strip().lower() for f in text.split(",") if f.strip()]
    bad = [f for f in out if f not in FORMATS]
    if bad:
        raise ProcessingError(f"exports settings: formats: {', '.join(bad)} not among {', '.join(FORMATS)}")
    return out


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The exports step as the contract runs it (specs.EXPORTS): export_run on the run folder, the survey's
    gcp/points.csv for the surveyed points."""
    from ..deliverables.exports import export_run
    from .contract import get_spec

    opts = get_spec("exports").validate(dict(options or {}))
    out = workspace.path("exports", "manifest").parent
    m = export_run(workspace.out_dir, out, parse_formats(opts.get("formats")), opts.get("interval_m"),
                   opts.get("surface") or "dsm", workspace.survey_dir, opts.get("index_every") or 5,
                   opts.get("smoothing_m"), opts.get("tin_spacing_m"), opts.get("geojson_crs") or "wgs84",
                   heights=opts.get("heights") or "site", progress=progress,
                   kmz_tile_threshold_px=opts.get("kmz_tile_px") or 2048)
    return {"written": m["written"], "skipped": m["skipped"], "crs": m["crs"], "vertical_datum": m["vertical_datum"],
            "contours": {k: m["contours"][k] for k in ("interval_m", "lines", "index_lines")} if "contours" in m
            else None, "tin": m.get("tin")}
