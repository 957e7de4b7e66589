"""The per-survey PDF report: built by backend.services.report (cover, equipment, settings, GNSS quality,
lever arm and delay, check-point residuals with the tolerance verdict and the ASPRS accuracy statement, maps,
volumes, steps). This module keeps the name the worker and the tests import."""

from __future__ import annotations

from .report.document import build_report
from .report.text import esc as _esc
from .report.text import scrub as _scrub

__all__ = ["build_report", "_esc", "_scrub"]
