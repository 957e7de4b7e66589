"""Step registry: each pipeline step bound to its georef_core function (imported lazily, by name), with
an adapter that calls it on a run folder. Steps that are not installed yet are reported 'unavailable'.

Every adapter has the signature (survey_dir, out_dir, options, progress, run) -> summary dict and may
also return volumes (the volumes step) through the summary's "_volumes" key."""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


class StepUnavailable(Exception):
    pass


def resolve(target: str) -> Callable:
    """'package.module:function' -> the function; StepUnavailable when the module or the function is
    not there (a module that exists but fails to import is a bug and raises)."""
    module_name, func_name = target.split(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            raise StepUnavailable(f"{module_name} is not installed") from None
        raise
    fn = getattr(module, func_name, None)
    if fn is None:
        raise StepUnavailable(f"{module_name}.{func_name} does not exist")
    return fn


# ----------------------------------------------------------------------------------------------- gnss


def _gnss(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    fn = resolve("georef_core.steps.gnss_solve:run_survey_gnss")
    options = dict(options or {})
    crs = run["site"]["crs"]
    if "epsg" not in options and crs.upper().startswith("EPSG:"):
        options["epsg"] = int(crs.split(":")[1])   # coordinates also in the project CRS
    return fn(survey_dir, out_dir, options, progress)


# ----------------------------------------------------------------------------------------------- others


def _georef(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    fn = resolve("georef_core.steps.georef:run_georef")
    return fn(survey_dir, out_dir, options or None, progress)


def _dense(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    fn = resolve("georef_core.steps.dense:run_dense")
    return fn(out_dir, options or None, progress)


def _volume_entries(result, names: list[str]) -> list[dict]:
    """The per-polygon entries of run_volumes' result, whatever its exact shape."""
    if isinstance(result, list):
        items = result
    elif isinstance(result, dict):
        items = next((result[k] for k in ("stockpiles", "polygons", "piles", "results", "features", "volumes")
                      if isinstance(result.get(k), list)), None)
        if items is None:
            items = [result]
    else:
        items = []
    out = []
    for i, it in enumerate(items):
        if isinstance(it, dict) and "properties" in it and isinstance(it["properties"], dict):
            it = {**it["properties"], **{k: v for k, v in it.items() if k != "properties"}}
        if not isinstance(it, dict):
            continue
        name = it.get("name") or (names[i] if i < len(names) else None)
        out.append({"name": name, **it})
    return out


def _num(d: dict, *keys):
    for k in keys:
        v = d.get(k)
        if isinstance(v, (int, float)):
            return float(v)
    return None


def _volumes(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    piles = run["stockpiles"]
    dsm = out_dir / "dense" / "dsm.tif"
    vol_dir = out_dir / "volumes"
    vol_dir.mkdir(parents=True, exist_ok=True)
    volumes: list[dict] = []
    if piles:
        fn = resolve("georef_core.steps.volumes:run_volumes")
        if not dsm.exists():
            from georef_core.errors import InputFileError

            raise InputFileError(dsm, "no DSM: the dense step did not write dense/dsm.tif")
        groups: dict[str, list[dict]] = {}
        for p in piles:
            groups.setdefault(p["base"], []).append(p)
        for n, (base, group) in enumerate(sorted(groups.items())):
            progress(f"volumes: base {base}", n, len(groups))
            fc = {"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": run["site"]["crs"]}},
                  "features": [{"type": "Feature", "properties": {"name": p["name"], "id": p["id"]},
                                "geometry": p["outline"]} for p in group]}
            slug = base.replace(":", "_").replace(".", "p")
            poly = vol_dir / f"stockpiles_{slug}.geojson"
            poly.write_text(json.dumps(fc))
            extra = {k: v for k, v in (options or {}).items() if k not in ("base",)}
            result = fn(dsm, poly, vol_dir / f"volumes_{slug}.json", base=base, **extra)
            by_name = {p["name"]: p for p in group}
            for e in _volume_entries(result, [p["name"] for p in group]):
                p = by_name.get(e.get("name"))
                if p is None:
                    continue
                unc = e.get("uncertainty") if isinstance(e.get("uncertainty"), dict) else {}
                base_info = e.get("base") if isinstance(e.get("base"), dict) else {}
                details = {k: v for k, v in e.items() if isinstance(v, (int, float, str, bool))}
                details.update({k: unc[k] for k in ("sigma_m3", "ci95_m3") if isinstance(unc.get(k), (int, float))})
                if isinstance(base_info.get("elevation_m"), (int, float)):
                    details["base_elevation_m"] = base_info["elevation_m"]
                if isinstance(e.get("warnings"), list):
                    details["warnings"] = "; ".join(str(w) for w in e["warnings"])[:2000]
                # conventions of georef_core.volumes: cut = material above the base, fill = void below,
                # net = cut - fill: the stockpile's volume
                volumes.append({"stockpile_id": p["id"], "stockpile_name": p["name"], "base": base,
                                "volume_m3": _num(e, "net_m3", "volume_m3", "net_volume_m3"),
                                "fill_m3": _num(e, "fill_m3", "fill_volume_m3"),
                                "cut_m3": _num(e, "cut_m3", "cut_volume_m3"),
                                "area_m2": _num(e, "area_m2", "footprint_area_m2", "planar_area_m2"),
                                "details": details})
    (vol_dir / "volumes.json").write_text(json.dumps({"crs": run["site"]["crs"], "units": "m3",
                                                      "stockpiles": volumes}, indent=2))
    return {"stockpiles": len(volumes), "_volumes": volumes}


def _report(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    from backend.services.report_pdf import build_report

    progress("report", 0, 1)
    meta = {"site": run["site"]["name"], "crs": run["site"]["crs"], "vertical_datum": run["site"]["vertical_datum"],
            "survey": run["survey"]["name"], "flown_at": run["survey"]["flown_at"], "run_number": run["number"],
            "steps": [s for s in run["step_states"] if s["name"] != "report"],
            "volumes": [{"name": v["stockpile_name"], "base": v["base"], "volume_m3": v["volume_m3"]}
                        for v in run.get("volumes", [])],
            "previous": run.get("previous_metrics") or {}}
    out = build_report(out_dir, out_dir / "report" / "accuracy_report.pdf", meta)
    progress("report", 1, 1)
    return {"sections": out["sections"]}


@dataclass(frozen=True)
class StepBinding:
    name: str
    adapter: Callable
    target: str | None      # the georef_core function it needs (None: platform step)


REGISTRY: dict[str, StepBinding] = {
    "gnss": StepBinding("gnss", _gnss, "georef_core.steps.gnss_solve:run_gnss_solve"),
    "georef": StepBinding("georef", _georef, "georef_core.steps.georef:run_georef"),
    "dense": StepBinding("dense", _dense, "georef_core.steps.dense:run_dense"),
    "volumes": StepBinding("volumes", _volumes, "georef_core.steps.volumes:run_volumes"),
    "report": StepBinding("report", _report, None),
}


def check_available(step: str, run: dict) -> None:
    """StepUnavailable when the step's science function is not installed (volumes without stockpiles
    needs nothing)."""
    b = REGISTRY[step]
    if b.target is None or (step == "volumes" and not run["stockpiles"]):
        return
    resolve(b.target)
