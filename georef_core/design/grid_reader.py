"""Design surfaces as GeoTIFF grids: validated as an elevation raster (projected CRS in metres, north-up;
the volume module's checks), resampled bilinearly onto the DSM grid when used."""

from __future__ import annotations

from pathlib import Path

from .design_surface import GridDesign


def read_grid_design(path) -> GridDesign:
    from ..volumes.raster_io import open_elevation_raster

    p = Path(path)
    info = open_elevation_raster(p, "design surface")  # InputFileError naming the file when unusable
    return GridDesign(p, p.stem, info.crs, [f"GeoTIFF grid {info.width} x {info.height}, "
                                            f"{info.cell_size_m:g} m cells, {info.crs_label()}"])
