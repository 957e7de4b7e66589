"""The simulated surveys the dense benchmarks share: made once in the work folder, reused after."""

from __future__ import annotations

import time
from pathlib import Path


def simulated_survey(work: Path, images: int, seed: int) -> tuple[Path | None, float | None]:
    """(the survey folder, seconds it took to simulate; None when it was there already), or (None, None)
    when `georef simulate` failed (it printed why). Photos and truth only (--no-gnss): true orientations."""
    from georef_core.cli.main import main as georef

    survey = work / f"survey_{images}_seed{seed}"
    if (survey / "truth" / "dsm.tif").is_file():
        return survey, None
    t0 = time.perf_counter()
    if georef(["simulate", str(survey), "--images", str(images), "--seed", str(seed), "--no-gnss", "--quiet"]):
        return None, None
    return survey, time.perf_counter() - t0
