"""Stockpile volumes, change between surveys and stockpile records (docs/volumes.md).

* :func:`compute_volume` / :func:`compute_volumes`: cut, fill and net of polygons on a DSM above a base
  (lowest, highest, mean, plane, tin, elevation:Z, surface:FILE), exact edge-cell coverage, with a
  1-sigma / 95 % uncertainty and its components.
* :func:`compute_change`: DSM difference map, cut/fill over the common area and per polygon,
  stable-ground check.
* :class:`StockpileRegistry`: named piles with locked bases and their volume series.
"""

from .base_surfaces import BaseSpec, BaseSurface, base_from_dict
from .change import ChangeResult, compute_change
from .polygons import AreaPolygon, read_polygons
from .stockpile_records import LockedBase, StockpileRecord, StockpileRegistry, VolumeMeasurement
from .uncertainty import NoiseModel
from .volume import VolumeOptions, VolumeResult, compute_volume, compute_volumes

__all__ = ["AreaPolygon", "BaseSpec", "BaseSurface", "ChangeResult", "LockedBase", "NoiseModel", "StockpileRecord",
           "StockpileRegistry", "VolumeMeasurement", "VolumeOptions", "VolumeResult", "base_from_dict",
           "compute_change", "compute_volume", "compute_volumes", "read_polygons"]
