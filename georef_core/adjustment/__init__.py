"""Photogrammetric adjustment: camera model, GNSS-aided bundle adjustment with lever arm and trigger
delay, control/check points, triangulation, residual tables."""
