"""The processing steps as data: order, dependencies, which survey files and settings each reads, and
which queue it belongs on. The worker's registry (worker/pipeline.py) binds each name to its function;
the backend plans runs from this catalogue without importing any science code."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StepInfo:
    name: str
    depends_on: tuple[str, ...]
    inputs: tuple[str, ...]      # survey-folder prefixes this step reads ("" = everything)
    settings: tuple[str, ...]    # settings sections that change its result
    heavy: bool                  # goes to the heavy queue when one is configured
    site_data: tuple[str, ...] = ()   # site-level data it reads (crs, stockpiles)
    version: int = 1             # bump when a step's code changes its outputs (invalidates reuse)


STEPS: tuple[StepInfo, ...] = (
    # DJI flight folders (flights/<name>/: photos, Timestamp.MRK, raw log) are read whole by both: the MRK
    # exposures are tied to the photos of their folder
    StepInfo("gnss", (), ("rover/", "base/", "nav/", "flights/", "events.csv", "survey.json"), ("gnss",), False,
             ("crs",)),
    # georef reads the PPK of the gnss step, and recomputes it from the observations when the images are
    # tied to their EXIF times (setting exif_time_offset_s): on a worker of its own (the heavy queue, its own
    # disk) it needs them in its survey folder as well
    StepInfo("georef", ("gnss",), ("rover/", "base/", "nav/", "flights/", "images/", "gcp/", "events.csv",
                                   "survey.json"),
             ("georef",), True, ("crs", "vertical")),
    StepInfo("dense", ("georef",), (), ("dense",), True, ("crs",)),
    StepInfo("volumes", ("dense",), (), ("volumes",), False, ("crs", "stockpiles")),
    StepInfo("report", ("gnss",), ("gcp/",), ("report",), False, ("crs", "stockpiles", "names")),
)
BY_NAME = {s.name: s for s in STEPS}
ORDER = [s.name for s in STEPS]
# the report is drawn from whatever earlier steps produced: it waits for them without needing them
SOFT_AFTER = {"report": ("georef", "dense", "volumes")}


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
