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

__all__ = ["REGISTRY", "StepBinding", "StepUnavailable", "check_available", "stored_volumes"]


# ------------------------------------------------------------------------------------------ contract steps


def _context(run: dict) -> dict:
    """What a step function may read of the platform (its spec's site_data): the site's CRS, vertical datum,
    stockpiles."""
    return {"crs": run["site"]["crs"], "vertical_datum": run["site"].get("vertical_datum"),
            "stockpiles": run.get("stockpiles") or []}


def _contract_adapter(step: str) -> Callable:
    """An adapter that runs a step through its spec (georef_core.steps.contract): the function declared there,
    called with the run's Workspace, its settings for the step and the site context."""
    def adapter(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
        from georef_core.steps.contract import Workspace, get_spec

        fn = get_spec(step).resolve()
        return fn(Workspace(survey_dir, out_dir), dict(options or {}), progress, _context(run))
    return adapter


def stored_volumes(out_dir: Path) -> list[dict]:
    """The volumes step's records, as the step wrote them in its declared output (volumes/volumes.json)."""
    from georef_core.steps.contract import Workspace

    path = Workspace(out_dir, out_dir).path("volumes", "volumes")
    return json.loads(path.read_text())["stockpiles"] if path.exists() else []


def _report(survey_dir: Path, out_dir: Path, options: dict, progress, run: dict) -> dict:
    from backend.services.report_pdf import build_report

    progress("report", 0, 1)
    meta = {"site": run["site"]["name"], "crs": run["site"]["crs"], "vertical_datum": run["site"]["vertical_datum"],
            "survey": run["survey"]["name"], "flown_at": run["survey"]["flown_at"],
            "flown_at_source": run["survey"].get("flown_at_source"), "run_number": run["number"],
            "steps": [s for s in run["step_states"] if s["name"] != "report"],
            "volumes": [{"name": v["stockpile_name"], "base": v["base"], "volume_m3": v["volume_m3"],
                         "sigma_m3": (v.get("details") or {}).get("sigma_m3"), "material": v.get("material") or ""}
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
