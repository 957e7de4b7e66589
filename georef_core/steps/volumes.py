"""Step "volumes": volumes of the polygons of a GeoJSON file on a DSM (one result per feature), written
to a JSON file; and the change between two surveys' DSMs. The CLI (`georef volume`, `georef change`)
and the worker call these functions. Library: georef_core.volumes (docs/volumes.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..errors import InputFileError, ProcessingError
from ..progress import ProgressFn, no_progress
from ..volumes.base_surfaces import BaseSpec
from ..volumes.change import compute_change
from ..volumes.polygons import read_polygons
from ..volumes.raster_io import open_elevation_raster
from ..volumes.uncertainty import Z95, NoiseModel
from ..volumes.volume import VolumeOptions, compute_volume


def _write_json(path, doc: dict) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(p)


def volume_totals(results: list[dict]) -> dict:
    """Sums over polygons. The 1-sigma of a total adds the vertical-bias terms linearly (one bias for the
    whole survey) and the other components in quadrature (independent between piles, an approximation
    for touching piles)."""
    cut = sum(r["cut_m3"] for r in results)
    fill = sum(r["fill_m3"] for r in results)
    bias = sum(r["uncertainty"]["components_m3"].get("height_bias_m3") or 0.0 for r in results)
    rnd2 = sum(sum((v or 0.0) ** 2 for k, v in r["uncertainty"]["components_m3"].items() if k != "height_bias_m3")
               for r in results)
    s = math.sqrt(rnd2 + bias * bias)
    return {"cut_m3": round(cut, 3), "fill_m3": round(fill, 3), "net_m3": round(cut - fill, 3),
            "area_m2": round(sum(r["area_m2"] for r in results), 3), "sigma_m3": round(s, 3),
            "ci95_m3": round(Z95 * s, 3), "n_polygons": len(results)}


def run_volumes(dsm_path, polygons_path, out_json=None, base: str = "lowest", dsm_sigma_m: float | None = None,
                height_bias_m: float | None = None, correlation_length_m: float | None = None,
                polygon_crs: str | None = None, options: VolumeOptions | dict | None = None,
                progress: ProgressFn | None = None) -> dict:
    """Volumes of every polygon feature of ``polygons_path`` on ``dsm_path`` above ``base`` (lowest,
    highest, mean, plane, tin, elevation:Z or surface:FILE.tif); written to ``out_json`` when given.
    Returns {"dsm", "polygons", "base", "noise_model", "results": [...], "totals"}."""
    progress = progress or no_progress
    if isinstance(options, dict):
        options = VolumeOptions(**options)
    try:
        spec = BaseSpec.parse(base)
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    info = open_elevation_raster(dsm_path)
    polys = read_polygons(polygons_path, polygon_crs)
    try:
        model = NoiseModel.for_dsm(info.path, dsm_sigma_m, height_bias_m, correlation_length_m)
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    results = []
    for k, p in enumerate(polys):
        progress("volumes", k, len(polys))
        r = compute_volume(info, p, spec, options, model).to_dict()
        pts = r["base"].pop("points_xyz_m", None)  # a TIN's outline points: kept by stockpile records, not here
        if pts is not None:
            r["base"]["n_points"] = len(pts)
        results.append(r)
    progress("volumes", len(polys), len(polys))
    doc = {"dsm": str(info.path), "crs": info.crs_label(), "cell_size_m": round(info.cell_size_m, 6),
           "polygons": str(polygons_path), "base": spec.label(), "noise_model": model.to_dict(),
           "results": results, "totals": volume_totals(results)}
    if out_json is not None:
        _write_json(out_json, doc)
        doc["output"] = str(out_json)
    return doc


def run_change(before_path, after_path, out_dir=None, polygons_path=None, stable_path=None, tolerance_m: float = 0.05,
               align: bool = False, dsm_sigma_m: float | None = None, height_bias_m: float | None = None,
               correlation_length_m: float | None = None, polygon_crs: str | None = None,
               progress: ProgressFn | None = None) -> dict:
    """Change from ``before_path`` to ``after_path``: ``out_dir/dz.tif`` and ``out_dir/change.json`` when
    ``out_dir`` is given. ``dsm_sigma_m``/``height_bias_m``/``correlation_length_m`` apply to both DSMs
    (else each DSM's dense_summary.json or the defaults)."""
    try:
        nb = NoiseModel.for_dsm(before_path, dsm_sigma_m, height_bias_m, correlation_length_m)
        na = NoiseModel.for_dsm(after_path, dsm_sigma_m, height_bias_m, correlation_length_m)
    except ValueError as exc:
        raise ProcessingError(str(exc)) from None
    polys = read_polygons(polygons_path, polygon_crs) if polygons_path else None
    stable = read_polygons(stable_path, polygon_crs) if stable_path else None
    res = compute_change(before_path, after_path, out_dir, polys, stable, tolerance_m, align, nb, na, progress)
    doc = res.to_dict()
    if out_dir is not None:
        _write_json(Path(out_dir) / "change.json", doc)
        doc["output"] = str(Path(out_dir) / "change.json")
    return doc


def stockpile_record(stockpile: dict, base: str, result: dict) -> dict:
    """One stockpile's entry of volumes/volumes.json (the shape specs.VOLUMES declares and the platform stores):
    net volume (cut - fill: the material above the base), cut, fill, area, and the details of run_volumes'
    result (scalars, its uncertainty's sigma and 95 % interval, the base elevation, its warnings)."""
    unc = result.get("uncertainty") or {}
    base_info = result.get("base") or {}
    details = {k: v for k, v in result.items() if isinstance(v, (int, float, str, bool))}
    details.update({k: unc[k] for k in ("sigma_m3", "ci95_m3") if isinstance(unc.get(k), (int, float))})
    # the survey-wide vertical bias term: common to every pile of the survey (the inventory's totals add it
    # linearly across piles; deliverables/inventory.py)
    bias = (unc.get("components_m3") or {}).get("height_bias_m3")
    if isinstance(bias, (int, float)):
        details["height_bias_m3"] = bias
    if isinstance(base_info.get("elevation_m"), (int, float)):
        details["base_elevation_m"] = base_info["elevation_m"]
    if result.get("warnings"):
        details["warnings"] = "; ".join(str(w) for w in result["warnings"])[:2000]
    return {"stockpile_id": stockpile["id"], "stockpile_name": stockpile["name"], "base": base,
            "volume_m3": result["net_m3"], "fill_m3": result["fill_m3"], "cut_m3": result["cut_m3"],
            "area_m2": result["area_m2"], "details": details}


def step_entry(workspace, options: dict, progress, context: dict) -> dict:
    """The volumes step as the contract runs it (specs.VOLUMES): every stockpile of the site (context
    "stockpiles": id, name, base, outline GeoJSON geometry in the site CRS, context "crs"), grouped by base,
    on the dense step's DSM; writes volumes/volumes.json {"crs", "units", "stockpiles": [stockpile_record]}."""
    from .contract import get_spec

    piles = list(context.get("stockpiles") or [])
    crs = context.get("crs")
    vol_path = workspace.path("volumes", "volumes")
    vol_dir = vol_path.parent
    vol_dir.mkdir(parents=True, exist_ok=True)
    opts = get_spec("volumes").validate(dict(options or {}))
    noise = {k: opts.pop(k) for k in ("dsm_sigma_m", "height_bias_m", "correlation_length_m") if k in opts}
    surface = opts.pop("surface", None) or "dsm"
    records: list[dict] = []
    if piles:
        if surface == "dtm":  # the bare earth: a machine standing on a pile is not counted as material
            dsm = workspace.path("dtm", "dtm")
            if not dsm.exists():
                raise InputFileError(dsm, "no DTM: volumes on the DTM (surface dtm) need the dtm step's dtm/dtm.tif")
        else:
            dsm = workspace.path("dense", "dsm")
            if not dsm.exists():
                raise InputFileError(dsm, "no DSM: the dense step did not write dense/dsm.tif")
        groups: dict[str, list[dict]] = {}
        for p in piles:
            groups.setdefault(p["base"], []).append(p)
        for n, (base, group) in enumerate(sorted(groups.items())):
            if progress:
                progress(f"volumes: base {base}", n, len(groups))
            fc = {"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": crs}},
                  "features": [{"type": "Feature", "properties": {"name": p["name"], "id": p["id"]},
                                "geometry": p["outline"]} for p in group]}
            slug = base.replace(":", "_").replace(".", "p")
            poly = vol_dir / f"stockpiles_{slug}.geojson"
            poly.write_text(json.dumps(fc))
            doc = run_volumes(dsm, poly, vol_dir / f"volumes_{slug}.json", base=base,
                              options={k: v for k, v in opts.items() if v is not None} or None,
                              **{k: v for k, v in noise.items() if v is not None})
            by_name = {r.get("name"): r for r in doc["results"]}
            for k, p in enumerate(group):     # results are named after the features (in their order)
                r = by_name.get(p["name"], doc["results"][k] if k < len(doc["results"]) else None)
                if r is not None:
                    records.append(stockpile_record(p, base, r))
    vol_path.write_text(json.dumps({"crs": crs, "units": "m3", "surface": surface, "stockpiles": records}, indent=2))
    return {"stockpiles": len(records), "surface": surface}
