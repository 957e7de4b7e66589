"""Parsing of option values shared by the commands."""

from __future__ import annotations

import math

from ..errors import GeorefError


def parse_three_numbers(text: str, what: str) -> tuple[float, float, float]:
    """'A,B,C' (commas or spaces) -> three floats; a clear error naming the option otherwise."""
    try:
        vals = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise GeorefError(f"{what}: {text!r} is not three numbers") from None
    if len(vals) != 3:
        raise GeorefError(f"{what}: expected three numbers, got {len(vals)}")
    return vals[0], vals[1], vals[2]


def parse_position(text: str, what: str) -> tuple[float, float, float]:
    """'LAT,LON,H' (degrees, m ellipsoidal) or 'X,Y,Z' (ECEF m), told apart by magnitude -> ECEF (m)."""
    from ..gnss.frames import geodetic_to_ecef_m

    vals = parse_three_numbers(text, what)
    if max(abs(v) for v in vals) > 1e5:
        return vals
    if not (-90 <= vals[0] <= 90 and -180 <= vals[1] <= 360):
        raise GeorefError(f"{what}: latitude/longitude out of range: {text!r}")
    xyz = geodetic_to_ecef_m(math.radians(vals[0]), math.radians(vals[1]), vals[2])
    return tuple(float(v) for v in xyz)
