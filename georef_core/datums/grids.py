"""Where the geoid grids are, for pyproj: installed folders only, never the network.

PROJ finds a grid by its file name in its data folders. pyproj's wheel carries its own folder (proj.db, no
geoid grid); this module appends the folders where installed grids live, in this order:

* ``$GEOREF_GRID_DIRS`` (folders separated by ``:``): grids a site supplies itself (a national geoid, EGM2008);
* ``/usr/share/proj`` and ``/usr/local/share/proj``: Debian's ``proj-data`` package (``make install`` installs
  it: it carries ``egm96_15.gtx``, the EGM96 15' grid PROJ also knows under its CDN name
  ``us_nga_egm96_15.tif``).

and switches PROJ's network access off explicitly (``pyproj.network.set_network_enabled(False)``), so a missing
grid is an error here (vertical_datum.GridMissingError), never a silent download nor a silently
ellipsoidal "orthometric" height.
"""

from __future__ import annotations

import os
from pathlib import Path

GRID_DIRS_ENV = "GEOREF_GRID_DIRS"
SYSTEM_GRID_DIRS = ("/usr/share/proj", "/usr/local/share/proj")
_configured: tuple[str, ...] | None = None


def grid_dirs() -> list[Path]:
    """The folders searched for grids, existing ones only, in search order."""
    env = [p for p in os.environ.get(GRID_DIRS_ENV, "").split(os.pathsep) if p.strip()]
    out: list[Path] = []
    for d in (*env, *SYSTEM_GRID_DIRS):
        p = Path(d).expanduser()
        if p.is_dir() and p not in out:
            out.append(p)
    return out


def configure_pyproj() -> list[Path]:
    """Network off, the grid folders appended to pyproj's data path (once per set of folders); returns the
    folders. Every function that transforms heights calls this first."""
    global _configured
    import pyproj.datadir
    import pyproj.network

    pyproj.network.set_network_enabled(False)
    dirs = grid_dirs()
    key = tuple(str(d) for d in dirs)
    if key != _configured:
        present = set(pyproj.datadir.get_data_dir().split(os.pathsep))
        for d in key:
            if d not in present:
                pyproj.datadir.append_data_dir(d)
        _configured = key
    return dirs


def find_grid(*names: str) -> Path | None:
    """The first installed file of these names (a grid's CDN name and its older names), else None."""
    for d in [*grid_dirs(), _pyproj_dir(), _user_dir()]:
        if d is None:
            continue
        for n in names:
            if (d / n).is_file():
                return d / n
    return None


def _pyproj_dir() -> Path | None:
    import pyproj.datadir

    first = pyproj.datadir.get_data_dir().split(os.pathsep)[0]
    return Path(first) if first else None


def _user_dir() -> Path | None:
    import pyproj.datadir

    try:
        return Path(pyproj.datadir.get_user_data_dir(False))
    except Exception:  # noqa: BLE001 (no user folder: nothing there)
        return None
