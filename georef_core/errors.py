"""Exceptions that carry a user-readable message naming the input at fault."""

from __future__ import annotations


class GeorefError(Exception):
    """Base class of every error Georef reports to a user (CLI prints the message, no traceback)."""


class InputFileError(GeorefError):
    """A user-supplied file is missing, unreadable, of the wrong type or corrupt."""

    def __init__(self, path, problem: str, line: int | None = None):
        self.path = str(path)
        self.problem = problem
        self.line = line
        where = f"{self.path}" + (f", line {line}" if line is not None else "")
        super().__init__(f"{where}: {problem}")


class ProcessingError(GeorefError):
    """Inputs are individually valid but cannot be processed together (no common epochs, ...)."""


class StepCancelled(GeorefError):
    """Raised (typically from a progress callback) to stop a running step; the step leaves its work
    folder in a state from which it can be re-run."""
