"""A site's design surface (services/designs.py) and its progress over the surveys."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field

from .common import ORM


class DesignPatch(BaseModel):
    area: dict | None = Field(default=None, description="GeoJSON Polygon or MultiPolygon, coordinates in the site "
                              "CRS (E, N) in metres: where the surveyed surface is compared with the design")
    tolerance_m: float | None = Field(default=None, ge=0, le=10, description="on grade within +- this (m)")
    surface_name: str | None = Field(default=None, max_length=200,
                                     description="which surface of a LandXML file holding several")


class DesignOut(ORM):
    site_id: str
    filename: str
    format: str
    sha256: str
    size: int
    surface_name: str | None
    described: dict
    area: dict | None
    area_m2: float | None = None
    tolerance_m: float
    key: str = Field(description="identifies the design as the runs used it (file, surface and area): the "
                     "design step's summary carries it; design-progress lists the runs that used this key")
    created_at: datetime
    updated_at: datetime
    version: int
