"""Step registry: each pipeline step of the catalogue (its StepSpec, georef_core.steps.contract) bound to the
function its spec declares (imported lazily, by name), through one adapter that calls it on a run's
Workspace; the platform's report step has its own. Steps whose function is not installed are reported
'unavailable'. Every adapter has the signature (survey_dir, out_dir, options, progress, run) -> summary dict;
results that the platform stores (volumes) are read from the step's declared outputs (stored_volumes)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from georef_core.steps.contract import StepUnavailable, resolve_function

__all__ = ["REGISTRY", "StepBinding", "StepUnavailable", "check_available", "merge_parts", "plan_parts", "run_part",
           "stored_volumes"]


# ------------------------------------------------------------------------------------------ contract steps


def _context(run: dict) -> dict:
    """What a step function may read of the platform (its spec's site_data): the site's CRS, vertical datum,
    stockpiles, design surface (the file fetched into the run folder by tasks.materialise)."""
    ctx = {"crs": run["site"]["crs"], "vertical_datum": run["site"].get("vertical_datum"),
           "stockpiles": run.get("stockpiles") or []}
    if run["site"].get("calibration"):   # the site's calibration (the datum step: unless the survey gives its own)
        ctx["site_calibration"] = run["site"]["calibration"]
    design = run.get("design")
    if design and design.get("path"):
        ctx["design"] = {"path": design["path"], "polygon": design.get("area"), "name": design.get("name"),
                         "surface_name": design.get("surface_name"), "tolerance_m": design.get("tolerance_m"),
                         "key": design.get("key")}
    return ctx


def _contract_adapter(step: str) -> Callable:
    """An adapter that runs a step through its spec (georef_core.steps.contract): the function declared there,
    called with the run's Workspace, its settings for the step and the site context."""
    def adapter(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
        from georef_core.steps.contract import Workspace, get_spec

        fn = get_spec(step).resolve()
        return fn(Workspace(survey_dir, out_dir), dict(options or {}), progress, _context(run))
    return adapter


# ---------------------------------------------------------------------------- steps that run as parts


def plan_parts(step: str, survey_dir: Path, out_dir: Path, options: dict, run: dict) -> list[dict] | None:
    """The parts of a step that can run on several workers (its spec's Split), None for any other step."""
    from georef_core.steps.contract import Workspace, check_part_order, get_spec

    spec = get_spec(step) if step != "report" else None
    if spec is None or spec.split is None:
        return None
    parts = resolve_function(spec.split.plan)(Workspace(survey_dir, out_dir), dict(options), _context(run))
    parts = [dict(p) for p in parts]
    check_part_order(step, parts)     # "after" names earlier parts only
    return parts


def run_part(step: str, survey_dir: Path, out_dir: Path, options: dict, part: dict, progress, run: dict) -> None:
    """One part (its descriptor with its ``index``), writing under its part folder only."""
    from georef_core.steps.contract import Workspace, get_spec

    ws = Workspace(survey_dir, out_dir)
    ws.part_dir(step, part["index"]).mkdir(parents=True, exist_ok=True)
    resolve_function(get_spec(step).split.part)(ws, dict(options), part, progress, _context(run))


def merge_parts(step: str, survey_dir: Path, out_dir: Path, options: dict, parts: list[dict], progress,
                run: dict) -> dict:
    from georef_core.steps.contract import Workspace, get_spec

    summary = resolve_function(get_spec(step).split.merge)(Workspace(survey_dir, out_dir), dict(options), parts,
                                                          progress, _context(run)) or {}
    return {**summary, "parts": len(parts)}


def stored_volumes(out_dir: Path) -> list[dict]:
    """The volumes step's records, as the step wrote them in its declared output (volumes/volumes.json)."""
    from georef_core.steps.contract import Workspace

    path = Workspace(out_dir, out_dir).path("volumes", "volumes")
    return json.loads(path.read_text())["stockpiles"] if path.exists() else []


def _report(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    from backend.services.report_pdf import build_report

    progress("report", 0, 1)
    site = run["site"]
    opts = dict(options or {})
    meta = {"site": site["name"], "crs": site["crs"], "vertical_datum": site["vertical_datum"],
            "geoid": site.get("geoid"), "company": site.get("organisation"),
            "tolerance_horizontal_m": site.get("tolerance_horizontal_m"),
            "tolerance_vertical_m": site.get("tolerance_vertical_m"),
            "survey": run["survey"]["name"], "flown_at": run["survey"]["flown_at"], "title": opts.get("title"),
            "flown_at_source": run["survey"].get("flown_at_source"), "run_number": run["number"],
            "steps": [s for s in run["step_states"] if s["name"] != "report"],
            "settings": run.get("settings") or {},
            "asprs_horizontal_class_cm": opts.get("asprs_horizontal_class_cm"),
            "asprs_vertical_class_cm": opts.get("asprs_vertical_class_cm"),
            "volumes": [{"name": v["stockpile_name"], "base": v["base"], "volume_m3": v["volume_m3"],
                         "sigma_m3": (v.get("details") or {}).get("sigma_m3"), "material": v.get("material") or "",
                         "density_t_m3": v.get("density_t_m3"),
                         "height_bias_m3": (v.get("details") or {}).get("height_bias_m3")}
                        for v in run.get("volumes", [])],
            "stockpile_outlines": [{"name": p["name"], "outline": p.get("outline")} for p in run.get("stockpiles") or []],
            "previous": run.get("previous_metrics") or {}}
    out = build_report(out_dir, out_dir / "report" / "accuracy_report.pdf", meta, survey_dir=survey_dir)
    progress("report", 1, 1)
    summary = {"sections": out["sections"], "tolerance": out["tolerance"]}
    acc = out.get("accuracy")
    if acc:      # what the run's summary keeps of the accuracy statement (the PDF has it in full)
        summary["accuracy"] = {"n_check_points": acc["n_check_points"], "compliant": acc["compliant"],
                               **{f"{k}_rmse_cm": acc[k]["product_rmse_cm"] for k in ("horizontal", "vertical")},
                               **{f"{k}_class_cm": acc[k]["class_cm"] for k in ("horizontal", "vertical")}}
    return summary


@dataclass(frozen=True)
class StepBinding:
    name: str
    adapter: Callable
    target: str | None      # the georef_core function it needs (None: platform step)


class _Registry:
    """Step name -> StepBinding, read from the catalogue at each use (a plug-in step registered after this
    module was imported is found too)."""

    def __getitem__(self, step: str) -> StepBinding:
        from backend.services import steps_catalog

        spec = steps_catalog.BY_NAME.get(step)
        if spec is None:
            steps_catalog.refresh()
            spec = steps_catalog.BY_NAME[step]
        if spec.name == "report":
            return StepBinding("report", _report, None)
        return StepBinding(spec.name, _contract_adapter(spec.name), spec.function)


REGISTRY = _Registry()


def check_available(step: str, run: dict) -> None:
    """StepUnavailable when the step's science function is not installed (volumes without stockpiles
    needs nothing)."""
    b = REGISTRY[step]
    if b.target is None or (step == "volumes" and not run["stockpiles"]):
        return
    resolve_function(b.target)
