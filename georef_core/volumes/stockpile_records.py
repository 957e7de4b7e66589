"""Stockpile records that persist across surveys: a named pile keeps its outline and its *locked* base,
so that its volume over time is a series measured against the same ground.

The base is computed once (by default from the first survey measured, method ``plane``) and stored as
parameters (:meth:`BaseSurface.to_dict`: an elevation, plane coefficients, the TIN's points, or a
surface file) with its own 1-sigma height uncertainty. Later surveys reuse it unchanged: the volume
change of a pile is then the change of its surface, not of a re-estimated base (the toe of a growing
pile covers the ground the base was once measured on).

Plain dataclasses with ``to_dict``/``from_dict`` (the backend stores the same in its database); the
pure-Python registry keeps them in ``SITE_DIR/stockpiles.json`` (written atomically).
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from ..errors import InputFileError, ProcessingError
from .base_surfaces import OUTLINE_METHODS, BaseSpec, BaseSurface, base_from_dict
from .polygons import AreaPolygon, crs_label, parse_crs
from .uncertainty import NoiseModel
from .volume import VolumeOptions, compute_volume

REGISTRY_FILE = "stockpiles.json"
SCHEMA_VERSION = 1


def _now() -> str:
    return datetime.now(timezone.utc).replace(microsecond=0).isoformat()


@dataclass
class LockedBase:
    """A base frozen for a pile: its parameters in ``crs``, its own 1-sigma height error (noise of the
    outline it came from and the spread of the base methods then), and where it came from."""

    parameters: dict
    crs: str
    sigma_m: float = 0.0
    survey_id: str = ""
    dsm: str = ""
    locked_at: str = ""
    fit: dict = field(default_factory=dict)

    def surface(self) -> BaseSurface:
        return base_from_dict(self.parameters, self.sigma_m)

    @property
    def method(self) -> str:
        return str(self.parameters.get("method", ""))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "LockedBase":
        return cls(dict(d["parameters"]), str(d["crs"]), float(d.get("sigma_m", 0.0)), str(d.get("survey_id", "")),
                   str(d.get("dsm", "")), str(d.get("locked_at", "")), dict(d.get("fit", {})))


@dataclass
class VolumeMeasurement:
    """One survey's volume of a pile (conventions of :mod:`.volume`: cut = material above the base)."""

    survey_id: str
    survey_date: str  # ISO date of the survey (flight), for the series
    dsm: str
    cut_m3: float
    fill_m3: float
    net_m3: float
    area_m2: float
    sigma_m3: float
    ci95_m3: float
    base_method: str
    measured_at: str = ""
    filled_nodata_m2: float = 0.0
    warnings: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "VolumeMeasurement":
        keys = cls.__dataclass_fields__.keys()
        return cls(**{k: d[k] for k in keys if k in d})


@dataclass
class StockpileRecord:
    """A named pile: outline (GeoJSON geometry in ``crs``), material, locked base, measurements."""

    name: str
    outline: dict
    crs: str
    material: str = ""
    notes: str = ""
    base_method: str = "plane"  # how the base is computed when it gets locked
    created_at: str = ""
    locked_base: LockedBase | None = None
    measurements: list = field(default_factory=list)  # VolumeMeasurement

    def polygon(self) -> AreaPolygon:
        import shapely.geometry

        return AreaPolygon(self.name, shapely.geometry.shape(self.outline), parse_crs(self.crs), f"stockpile {self.name!r}")

    def series(self) -> list[dict]:
        """Measurements in survey-date order: date, survey, net volume and its uncertainty."""
        ms = sorted(self.measurements, key=lambda m: (m.survey_date, m.measured_at))
        return [{"survey_date": m.survey_date, "survey_id": m.survey_id, "net_m3": m.net_m3, "cut_m3": m.cut_m3,
                 "fill_m3": m.fill_m3, "sigma_m3": m.sigma_m3, "ci95_m3": m.ci95_m3} for m in ms]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["locked_base"] = self.locked_base.to_dict() if self.locked_base else None
        d["measurements"] = [m.to_dict() for m in self.measurements]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "StockpileRecord":
        lb = d.get("locked_base")
        return cls(str(d["name"]), dict(d["outline"]), str(d["crs"]), str(d.get("material", "")), str(d.get("notes", "")),
                   str(d.get("base_method", "plane")), str(d.get("created_at", "")),
                   LockedBase.from_dict(lb) if lb else None,
                   [VolumeMeasurement.from_dict(m) for m in d.get("measurements", [])])


class StockpileRegistry:
    """The piles of one site, kept in ``site_dir/stockpiles.json``."""

    def __init__(self, site_dir, records: dict | None = None):
        self.site_dir = Path(site_dir)
        self.records: dict[str, StockpileRecord] = dict(records or {})

    @property
    def path(self) -> Path:
        return self.site_dir / REGISTRY_FILE

    @classmethod
    def load(cls, site_dir) -> "StockpileRegistry":
        reg = cls(site_dir)
        if not reg.path.exists():
            return reg
        try:
            doc = json.loads(reg.path.read_text())
            if int(doc.get("schema_version", 0)) > SCHEMA_VERSION:
                raise InputFileError(reg.path, f"written by a newer version (schema {doc['schema_version']})")
            for d in doc.get("stockpiles", []):
                rec = StockpileRecord.from_dict(d)
                reg.records[rec.name] = rec
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise InputFileError(reg.path, f"not a stockpile registry ({exc})") from None
        return reg

    def to_dict(self) -> dict:
        return {"schema_version": SCHEMA_VERSION, "stockpiles": [r.to_dict() for r in self.records.values()]}

    def save(self) -> Path:
        self.site_dir.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".stockpiles.", suffix=".json", dir=self.site_dir)
        with os.fdopen(fd, "w") as f:
            json.dump(self.to_dict(), f, indent=1)
        os.replace(tmp, self.path)
        return self.path

    # ---- editing -----------------------------------------------------------------------------------
    def get(self, name: str) -> StockpileRecord:
        if name not in self.records:
            known = ", ".join(sorted(self.records)) or "none"
            raise ProcessingError(f"no stockpile named {name!r} in {self.path} (known: {known})")
        return self.records[name]

    def add(self, polygon: AreaPolygon, material: str = "", base_method: str = "plane", notes: str = "",
            replace: bool = False) -> StockpileRecord:
        """A new pile from ``polygon`` (its name and CRS kept). ``base_method``: how its base is computed when
        first measured (lowest|highest|mean|plane|tin|elevation:Z|surface:FILE)."""
        if polygon.name in self.records and not replace:
            raise ProcessingError(f"a stockpile named {polygon.name!r} already exists in {self.path}")
        BaseSpec.parse(base_method)  # validates
        rec = StockpileRecord(polygon.name, polygon.to_geojson_geometry(9 if polygon.crs.is_geographic else 4),
                              crs_label(polygon.crs), material, notes, base_method, _now())
        self.records[rec.name] = rec
        return rec

    def remove(self, name: str) -> None:
        self.get(name)
        del self.records[name]

    def lock_base(self, name: str, dsm, survey_id: str = "", options: VolumeOptions | None = None,
                  noise: NoiseModel | None = None, method: str | None = None) -> LockedBase:
        """Compute the pile's base on ``dsm`` (its ``base_method`` unless ``method``) and lock it."""
        rec = self.get(name)
        spec = BaseSpec.parse(method or rec.base_method)
        res = compute_volume(dsm, rec.polygon(), spec, options, noise)
        params = {k: v for k, v in res.base.items() if k not in ("description", "fit", "depends_on_dsm", "sigma_m",
                                                                  "sigma_source")}
        rec.locked_base = LockedBase(params, res.dsm["crs"], round(res.base_height_sigma_m, 5), survey_id,
                                     res.dsm["path"], _now(), dict(res.base.get("fit", {})))
        return rec.locked_base

    def measure(self, name: str, dsm, survey_id: str, survey_date: str = "", options: VolumeOptions | None = None,
                noise: NoiseModel | None = None) -> VolumeMeasurement:
        """The pile's volume on ``dsm`` against its locked base (locked on this survey if not yet). A second
        measurement with the same ``survey_id`` replaces the first (re-runs are idempotent)."""
        from .raster_io import open_elevation_raster

        rec = self.get(name)
        info = open_elevation_raster(dsm)
        if rec.locked_base is None:
            self.lock_base(name, info, survey_id, options, noise)
        lb = rec.locked_base
        if parse_crs(lb.crs) != info.crs:
            raise ProcessingError(f"stockpile {name!r}: its base is locked in {lb.crs} but {info.path.name} is in "
                                  f"{info.crs_label()}; reproject the DSM to {lb.crs}")
        if lb.method in OUTLINE_METHODS and lb.dsm and Path(lb.dsm).resolve() == info.path.resolve():
            # the survey the base was locked on: the base comes from this DSM (its bias cancels), so the
            # outline base is recomputed (identical parameters) and its uncertainty used
            base = BaseSpec(lb.method, percentile=lb.parameters.get("percentile"))
        else:
            base = lb.surface()
        res = compute_volume(info, rec.polygon(), base, options, noise)
        m = VolumeMeasurement(survey_id, survey_date or "", str(info.path), round(res.cut_m3, 4), round(res.fill_m3, 4),
                              round(res.net_m3, 4), round(res.area_m2, 4), res.uncertainty["sigma_m3"],
                              res.uncertainty["ci95_m3"], f"locked {lb.method}", _now(), round(res.filled_nodata_m2, 4),
                              list(res.warnings))
        rec.measurements = [x for x in rec.measurements if x.survey_id != survey_id] + [m]
        return m

    def measure_all(self, dsm, survey_id: str, survey_date: str = "", options: VolumeOptions | None = None,
                    noise: NoiseModel | None = None) -> dict[str, VolumeMeasurement]:
        return {n: self.measure(n, dsm, survey_id, survey_date, options, noise) for n in list(self.records)}
