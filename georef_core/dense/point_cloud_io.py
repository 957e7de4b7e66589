"""LAS 1.4 / LAZ point clouds in the project CRS (E, N, ellipsoidal h) with laspy.

Point format 7 (x, y, z, intensity, classification, GPS time, RGB); coordinates stored as integers of
1 mm with an offset; colours scaled to 16 bits as the LAS specification asks. The CRS is written as an
OGC WKT VLR: the project CRS made three-dimensional (easting, northing, *ellipsoidal* height), so that
the heights are not mistaken for orthometric ones. ``.laz`` paths are compressed (lazrs backend).
``user_data`` holds the number of views that agreed on each point.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj

from ..errors import InputFileError

CLASS_UNCLASSIFIED = 1
CLASS_GROUND = 2


def write_point_cloud(path, xyz_grid: np.ndarray, rgb: np.ndarray, epsg: int, n_views: np.ndarray | None = None,
                      classification: np.ndarray | None = None) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    xyz = np.asarray(xyz_grid, float).reshape(-1, 3)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
    header.add_crs(pyproj.CRS.from_epsg(int(epsg)).to_3d())
    header.system_identifier = "georef dense"
    header.generating_software = "georef"
    las = laspy.LasData(header)
    las.x = xyz[:, 0]
    las.y = xyz[:, 1]
    las.z = xyz[:, 2]
    rgb16 = np.asarray(rgb, np.uint16) * 257
    las.red, las.green, las.blue = rgb16[:, 0], rgb16[:, 1], rgb16[:, 2]
    las.classification = (np.full(len(xyz), CLASS_UNCLASSIFIED, np.uint8) if classification is None
                          else np.asarray(classification, np.uint8))
    if n_views is not None:
        las.user_data = np.clip(n_views, 0, 255).astype(np.uint8)
    tmp = path.with_name(path.name + ".part" + path.suffix)
    las.write(str(tmp), do_compress=path.suffix.lower() == ".laz")
    tmp.replace(path)
    return path


def read_point_cloud(path) -> tuple[np.ndarray, np.ndarray, pyproj.CRS | None, laspy.LasData]:
    """(xyz (N, 3), rgb uint8 (N, 3), CRS or None, the laspy object)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "point cloud file not found")
    try:
        las = laspy.read(str(path))
    except Exception as exc:  # noqa: BLE001 (laspy raises several unrelated types on bad files)
        raise InputFileError(path, f"not a readable LAS/LAZ file ({exc})") from None
    xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    rgb = (np.column_stack([las.red, las.green, las.blue]) // 257).astype(np.uint8)
    return xyz, rgb, las.header.parse_crs(), las
