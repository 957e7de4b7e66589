"""LAS 1.4 / LAZ point clouds in the project CRS (E, N, ellipsoidal h) with laspy.

Point format 7 (x, y, z, intensity, classification, GPS time, RGB); coordinates stored as integers of
1 mm with an offset; colours scaled to 16 bits as the LAS specification asks. The CRS is written as an
OGC WKT VLR: the project CRS made three-dimensional (easting, northing, *ellipsoidal* height), so that
the heights are not mistaken for orthometric ones. ``.laz`` paths are compressed (lazrs backend).
``user_data`` holds the number of views that agreed on each point.

Two ways in and out: whole (:func:`read_point_cloud`, :func:`write_point_cloud`: the cloud in memory) and
streamed (:func:`open_point_cloud` + :func:`iter_point_cloud`, :func:`point_cloud_writer`: a chunk of
``CHUNK_POINTS`` at a time, so a cloud larger than memory is read, converted or assembled). Both write to a
``.part`` file first and rename it when complete; both report a missing or unreadable file as an
:class:`InputFileError` naming it.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import laspy
import numpy as np
import pyproj

from ..errors import InputFileError

CLASS_UNCLASSIFIED = 1
CLASS_GROUND = 2
CHUNK_POINTS = 1_000_000  # points per chunk of the streamed reader (about 30 MB of format-7 records)


def dense_cloud_header(epsg: int, offsets) -> laspy.LasHeader:
    """The header of the dense clouds Georef writes: LAS 1.4 point format 7, 1 mm integers from ``offsets``
    (E, N, h), the project CRS made three-dimensional (ellipsoidal heights)."""
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.asarray(offsets, float)
    header.add_crs(pyproj.CRS.from_epsg(int(epsg)).to_3d())
    header.system_identifier = "georef dense"
    header.generating_software = "georef"
    return header


def dense_points(header: laspy.LasHeader, xyz: np.ndarray, rgb: np.ndarray, n_views: np.ndarray | None = None,
                 classification: np.ndarray | None = None) -> laspy.ScaleAwarePointRecord:
    """The records of points (N, 3) with colours uint8 (N, 3) for ``header``: colours scaled to 16 bits,
    class unclassified unless given, ``user_data`` the number of agreeing views (clipped to 255) when given."""
    xyz = np.asarray(xyz, float).reshape(-1, 3)
    rec = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
    rec.x, rec.y, rec.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb16 = np.asarray(rgb, np.uint16).reshape(-1, 3) * 257
    rec.red, rec.green, rec.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    rec.classification = (np.full(len(xyz), CLASS_UNCLASSIFIED, np.uint8) if classification is None
                          else np.asarray(classification, np.uint8))
    if n_views is not None:
        rec.user_data = np.clip(n_views, 0, 255).astype(np.uint8)
    return rec


@contextmanager
def point_cloud_writer(path, header: laspy.LasHeader):
    """A laspy writer (``write_points(records)``, chunk after chunk) to ``path``: compressed for ``.laz``.
    It writes ``NAME.part.SUFFIX`` and renames it to ``path`` when the block ends without an error (a failed
    write leaves no partial file under the final name)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part" + path.suffix)
    try:
        with laspy.open(str(tmp), mode="w", header=header, do_compress=path.suffix.lower() == ".laz") as writer:
            yield writer
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(path)


def write_point_cloud(path, xyz_grid: np.ndarray, rgb: np.ndarray, epsg: int, n_views: np.ndarray | None = None,
                      classification: np.ndarray | None = None) -> Path:
    xyz = np.asarray(xyz_grid, float).reshape(-1, 3)
    header = dense_cloud_header(epsg, np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3))
    with point_cloud_writer(path, header) as writer:
        writer.write_points(dense_points(header, xyz, rgb, n_views, classification))
    return Path(path)


@contextmanager
def open_point_cloud(path) -> Iterator[laspy.LasReader]:
    """The laspy reader of a LAS/LAZ file (``header`` read, points not yet): a missing or unreadable file is
    an InputFileError naming it."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "point cloud file not found")
    try:
        reader = laspy.open(str(path))
    except Exception as exc:  # noqa: BLE001 (laspy raises several unrelated types on bad files)
        raise _unreadable(path, exc) from None
    with reader:
        yield reader


def _unreadable(path, exc: Exception) -> InputFileError:
    return InputFileError(Path(path), f"not a readable LAS/LAZ file ({exc})")


def point_xyz(points) -> np.ndarray:
    """The coordinates (N, 3) of laspy records (a chunk or a whole cloud), scaled and offset."""
    return np.column_stack([np.asarray(points.x), np.asarray(points.y), np.asarray(points.z)])


def _xyz_rgb(points) -> tuple[np.ndarray, np.ndarray]:
    rgb = (np.column_stack([points.red, points.green, points.blue]) // 257).astype(np.uint8)
    return point_xyz(points), rgb


def point_chunks(reader: laspy.LasReader, path, chunk_points: int = CHUNK_POINTS):
    """The records of an open reader of ``path`` (:func:`open_point_cloud`), at most ``chunk_points`` at a
    time, in file order; a file that breaks off mid-way is an InputFileError naming it."""
    chunks = reader.chunk_iterator(int(chunk_points))
    while True:
        try:
            points = next(chunks)
        except StopIteration:
            return
        except Exception as exc:  # noqa: BLE001 (laspy/lazrs raise several unrelated types)
            raise _unreadable(path, exc) from None
        yield points


def iter_point_cloud(path, chunk_points: int = CHUNK_POINTS):
    """The cloud of ``path`` chunk by chunk: (xyz (n, 3), rgb uint8 (n, 3), the chunk's laspy records), at most
    ``chunk_points`` points each, in file order."""
    with open_point_cloud(path) as reader:
        for points in point_chunks(reader, path, chunk_points):
            xyz, rgb = _xyz_rgb(points)
            yield xyz, rgb, points


def copy_point_cloud(src, dst, chunk_points: int = CHUNK_POINTS) -> int:
    """``src`` rewritten as ``dst`` chunk by chunk, compressed or not by ``dst``'s suffix (a LAZ served as LAS),
    every attribute and VLR kept; the number of points."""
    n = 0
    with open_point_cloud(src) as reader:
        with point_cloud_writer(dst, reader.header) as writer:
            for points in point_chunks(reader, src, chunk_points):
                writer.write_points(points)
                n += len(points)
    return n


def read_point_cloud(path) -> tuple[np.ndarray, np.ndarray, pyproj.CRS | None, laspy.LasData]:
    """(xyz (N, 3), rgb uint8 (N, 3), CRS or None, the laspy object)."""
    with open_point_cloud(path) as reader:
        try:
            las = reader.read()
        except Exception as exc:  # noqa: BLE001 (laspy raises several unrelated types on bad files)
            raise _unreadable(path, exc) from None
    xyz, rgb = _xyz_rgb(las)
    return xyz, rgb, las.header.parse_crs(), las
