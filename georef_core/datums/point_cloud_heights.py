"""A LAS/LAZ point cloud converted to another vertical datum, its compound CRS written as the OGC WKT VLR.

Read and written in chunks of a million points (the streamed reader and writer of dense/point_cloud_io.py),
so a cloud larger than memory converts; the points keep every attribute; z changes by
height_shift.HeightShift (PROJ at nodes 10 m apart, bilinear between) and the header's CRS
becomes horizontal + vertical (e.g. "WGS 84 / UTM zone 31N + EGM96 height").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputFileError
from .height_shift import DEFAULT_STEP_M, HeightShift
from .vertical_datum import compound_crs, datum_of_crs, horizontal_crs, resolve, transformation


def convert_point_cloud_heights(src_path, dst_path, to_datum, from_datum=None,
                                step_m: float = DEFAULT_STEP_M) -> dict:
    """Writes ``dst_path`` (.laz compressed, .las not): the cloud of ``src_path`` in ``to_datum``. The source
    datum is ``from_datum`` when given, else the one its CRS states (a 3-D projected CRS: ellipsoidal)."""
    import laspy

    from ..dense.point_cloud_io import open_point_cloud, point_chunks, point_cloud_writer

    src_path, dst_path = Path(src_path), Path(dst_path)
    with open_point_cloud(src_path) as reader:
        header = reader.header
        crs = header.parse_crs()
        if crs is None:
            raise InputFileError(src_path, "the point cloud has no CRS")
        a = resolve(from_datum) if from_datum is not None else datum_of_crs(crs)
        if a is None:
            raise InputFileError(src_path, f"the datum of its heights is not stated (CRS {crs.name} is 2-D): give "
                                           "it (--from ellipsoidal | egm96 | EPSG:code)")
        b = resolve(to_datum)
        hcrs = horizontal_crs(crs)
        if not hcrs.is_projected:
            raise InputFileError(src_path, f"the cloud's CRS ({hcrs.name}) is not projected")
        shift = HeightShift.over(hcrs, header.mins[0], header.maxs[0], header.mins[1], header.maxs[1], a, b, step_m)
        out_header = laspy.LasHeader(point_format=header.point_format, version=header.version)
        out_header.scales, out_header.offsets = header.scales, header.offsets
        out_header.system_identifier = header.system_identifier
        out_header.generating_software = "georef datum"
        for v in header.vlrs:
            if type(v).__name__ not in ("WktCoordinateSystemVlr", "GeoKeyDirectoryVlr", "GeoAsciiParamsVlr",
                                        "GeoDoubleParamsVlr", "LasZipVlr"):
                out_header.vlrs.append(v)
        out_header.add_crs(compound_crs(hcrs, b))
        n = 0
        lo, hi = np.inf, -np.inf
        with point_cloud_writer(dst_path, out_header) as writer:
            for pts in point_chunks(reader, src_path):
                x, y = np.asarray(pts.x), np.asarray(pts.y)
                dz = shift.at(x, y)
                pts.z = np.asarray(pts.z) + dz
                if len(dz):
                    lo, hi = min(lo, float(dz.min())), max(hi, float(dz.max()))
                writer.write_points(pts)
                n += len(x)
    op = transformation(b if not b.is_ellipsoidal else a)
    return {"from": a.label, "to": b.label, "crs": compound_crs(hcrs, b).name, "path": str(dst_path), "points": n,
            "dz_m": {"min": None if n == 0 else round(lo, 4), "max": None if n == 0 else round(hi, 4)},
            "operation": op["operation"], "grid": op["grid"], "node_step_m": step_m}
