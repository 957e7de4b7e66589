"""The height change between two vertical datums over a site, sampled once and interpolated.

Converting every cell of a DSM or every point of a cloud through PROJ would cost a transformation per
point; the change dz = N_from - N_to (vertical_datum.convert_heights) is smooth over a site, so it is
computed by PROJ at the nodes of a regular grid in the site CRS (``step_m`` apart, default 10 m) and
interpolated bilinearly in between.

Interpolation error: PROJ itself interpolates the geoid grid bilinearly in latitude/longitude, so dz is
piecewise bilinear with kinks along the geoid grid's node lines (every 15' for EGM96, about 28 km). Between
kinks bilinear interpolation of a bilinear function is exact up to the projection's curvature (below 1 um
over 10 m); across a kink the error is at most |slope change| x step / 4. Geoid slopes are below 1e-4
(10 cm per km), so a kink changes the slope by less than 2e-4 and the error is under 0.5 mm at 10 m
(tests/datums/test_vertical_datum.py measures it against PROJ at every cell of a DSM: docs/datums.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .vertical_datum import convert_heights, lat_lon_of, resolve

DEFAULT_STEP_M = 10.0


@dataclass
class HeightShift:
    """dz(E, N) = height in ``to_datum`` - height in ``from_datum`` on a grid of nodes (bilinear between)."""

    e_nodes_m: np.ndarray
    n_nodes_m: np.ndarray
    dz_m: np.ndarray             # (len(n_nodes), len(e_nodes))
    from_datum: object
    to_datum: object

    @classmethod
    def over(cls, crs, e_min_m: float, e_max_m: float, n_min_m: float, n_max_m: float, from_datum, to_datum,
             step_m: float = DEFAULT_STEP_M) -> "HeightShift":
        """Sampled over the rectangle [e_min, e_max] x [n_min, n_max] of ``crs`` (projected, metres)."""
        a, b = resolve(from_datum), resolve(to_datum)
        ne = max(2, int(np.ceil((e_max_m - e_min_m) / step_m)) + 1)
        nn = max(2, int(np.ceil((n_max_m - n_min_m) / step_m)) + 1)
        e = np.linspace(e_min_m, e_max_m if e_max_m > e_min_m else e_min_m + step_m, ne)
        n = np.linspace(n_min_m, n_max_m if n_max_m > n_min_m else n_min_m + step_m, nn)
        if a == b:
            return cls(e, n, np.zeros((nn, ne)), a, b)
        ee, nnn = np.meshgrid(e, n)
        lat, lon = lat_lon_of(crs, ee, nnn)
        dz = convert_heights(lat, lon, np.zeros_like(lat), a, b)
        return cls(e, n, dz, a, b)

    def at(self, e_m, n_m) -> np.ndarray:
        """dz at these points (bilinear; clamped to the sampled rectangle's edge outside it)."""
        e = np.asarray(e_m, dtype=float)
        n = np.asarray(n_m, dtype=float)
        ie, we = _cell(self.e_nodes_m, e)
        jn, wn = _cell(self.n_nodes_m, n)
        z = self.dz_m
        return ((1 - wn) * ((1 - we) * z[jn, ie] + we * z[jn, ie + 1])
                + wn * ((1 - we) * z[jn + 1, ie] + we * z[jn + 1, ie + 1]))


def _cell(nodes: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the node interval holding x (clamped) and the fraction along it."""
    i = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, len(nodes) - 2)
    w = np.clip((x - nodes[i]) / (nodes[i + 1] - nodes[i]), 0.0, 1.0)
    return i, w
