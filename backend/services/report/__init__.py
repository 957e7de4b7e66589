"""The survey report (PDF): document.build_report assembles it from a run folder; text.py escapes and words
what it shows, run_data.py reads the run's outputs, figures.py draws its plot and maps."""

from .document import build_report

__all__ = ["build_report"]
