"""The processing steps as data, read from their specs (georef_core.steps.contract: options, inputs,
outputs, version, dependencies, queue), plus the platform's own report step declared here the same way.
The backend plans runs, validates settings and names result files from these specs without importing any
science code; the worker's registry (worker/pipeline.py) runs the function each spec declares."""

from __future__ import annotations

from georef_core.steps.contract import Option, Output, Product, StepSpec, all_specs, get_spec, register

REPORT = StepSpec(
    name="report", title="Accuracy report", version=2,
    description="PDF survey report: project, flight and equipment, settings, GNSS quality, lever arm and delay, "
                "check-point residuals with the site-tolerance verdict and the ASPRS (2023) accuracy statement, "
                "maps, volumes (the platform's step; docs/deliverables.md).",
    function=None, depends_on=("gnss",), soft_after=("georef", "dense", "volumes", "design"),
    inputs=("gcp/", "survey.json"), site_data=("crs", "stockpiles", "names"),
    options=(Option("title", "string", None, "a title for the report's cover", advanced=True),
             Option("asprs_horizontal_class_cm", "number", None, "the horizontal accuracy class (RMSE_H) the survey "
                    "is tested against (default: the smallest class it meets)", minimum=0.1, maximum=1000.0,
                    unit="cm", advanced=True),
             Option("asprs_vertical_class_cm", "number", None, "the vertical accuracy class (RMSE_V) the survey is "
                    "tested against (default: the smallest class it meets)", minimum=0.1, maximum=1000.0, unit="cm",
                    advanced=True)),
    outputs=(Output("report", "report/accuracy_report.pdf", "the accuracy report", "application/pdf"),),
    products=(Product("report.pdf", "Accuracy report", "PDF: accuracy statement, check points, PPK quality, lever "
                      "arm, maps, volumes", ("report",), (("", "PDF"),)),),
    summary={"sections": "the report's sections", "tolerance": "the check points against the site tolerance",
             "accuracy": "RMSE_H, RMSE_V (cm), classes met, check points, compliance (ASPRS Edition 2)"},
)


def _ensure_report() -> None:
    names = [s.name for s in all_specs()]
    if "report" not in names:
        register(REPORT)


def _ordered() -> tuple[StepSpec, ...]:
    """The registered steps in registration order, the platform's report last (it reads the others)."""
    _ensure_report()
    return tuple(s for s in all_specs() if s.name != "report") + (get_spec("report"),)


STEPS: tuple[StepSpec, ...] = _ordered()
BY_NAME = {s.name: s for s in STEPS}
ORDER = [s.name for s in STEPS]
# the report is drawn from whatever earlier steps produced: it waits for them without needing them
SOFT_AFTER = {s.name: s.soft_after for s in STEPS if s.soft_after}


def refresh() -> None:
    """Re-reads the registry (after a step was registered, e.g. a plug-in or a test's toy step)."""
    global STEPS, BY_NAME, ORDER, SOFT_AFTER
    STEPS = _ordered()
    BY_NAME = {s.name: s for s in STEPS}
    ORDER = [s.name for s in STEPS]
    SOFT_AFTER = {s.name: s.soft_after for s in STEPS if s.soft_after}


def plan(requested: list[str] | None) -> list[str]:
    """Requested steps plus the steps they depend on, in pipeline order."""
    want = set(requested or ORDER)
    unknown = want - set(ORDER)
    if unknown:
        raise ValueError(f"unknown step(s) {', '.join(sorted(unknown))}; steps are {', '.join(ORDER)}")
    stack = list(want)
    while stack:
        for d in BY_NAME[stack.pop()].depends_on:
            if d not in want:
                want.add(d)
                stack.append(d)
    return [s for s in ORDER if s in want]


def queue_for(step: str, default_queue: str, heavy_queue: str) -> str:
    return heavy_queue if (heavy_queue and BY_NAME[step].heavy) else default_queue


def validate_settings(settings: dict | None) -> dict:
    """Run or survey settings ({step: {option: value}}) checked against the steps' specs; returns them
    normalised. Raises OptionError (a ProcessingError) naming the step and the bad option."""
    from georef_core.steps.contract import OptionError

    out = {}
    for section, values in (settings or {}).items():
        if section not in BY_NAME:
            raise OptionError(section, "(section)", f"unknown settings section; sections are {', '.join(ORDER)}")
        out[section] = get_spec(section).validate(values)
    return out
