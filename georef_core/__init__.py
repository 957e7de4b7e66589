"""Georef science library: GNSS baseline processing, photogrammetric georeferencing,
surfaces and volumes. Pure Python + numpy/scipy/pyproj (no web, database or queue imports)."""

__version__ = "0.1.0"
