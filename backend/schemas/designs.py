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


class DesignChange(BaseModel):
    """One survey of design-progress against the survey before it (services/designs.changes_between): what
    moved toward the design between the two flights, and what remains to the design. Volumes in m3, sigmas
    1 sigma: each survey's own error (DSM noise, georeferencing bias, unmeasured area) is independent of the
    other's, the design's own error is common to both and cancels (only the change of its share remains)."""

    previous_survey_id: str
    previous_survey_name: str
    days: float | None = Field(default=None, description="days between the two flights (null: a date missing)")
    cut_moved_m3: float | None = Field(default=None, description="cut to design removed since the previous survey: "
                                       "its cut minus this one's (negative: more cut to do than before)")
    fill_placed_m3: float | None = Field(default=None, description="fill to design placed since the previous "
                                         "survey: its fill minus this one's")
    net_change_m3: float | None = Field(default=None, description="this net minus the previous net")
    sigma_m3: dict[str, float | None] = Field(default_factory=dict,
                                              description="1 sigma of cut_moved_m3, fill_placed_m3, net_change_m3")
    remaining_cut_m3: float | None = Field(default=None, description="cut still to remove (this survey's cut)")
    remaining_fill_m3: float | None = Field(default=None, description="fill still to place (this survey's fill)")
    done_share: dict[str, float | None] = Field(default_factory=dict, description="cut_m3, fill_m3: share of the "
                                                "first compared survey's cut (fill) done by this survey")
    method: str = Field(default="totals", description="surfaces: the two surveys' differences to the design compared "
                        "cell by cell inside the design area (cut_moved_m3: where the ground went down, fill_placed_m3: "
                        "where it went up); totals: from the two results' cut/fill totals (a difference file missing)")
    cut_below_design_m3: float | None = Field(default=None, description="of cut_moved_m3, what lay below the design "
                                              "(over-excavation); surfaces only")
    fill_above_design_m3: float | None = Field(default=None, description="of fill_placed_m3, what lies above the "
                                               "design; surfaces only")
    area_m2: float | None = Field(default=None, description="area compared in both surveys (surfaces only)")
    notes: list[str] = Field(default_factory=list)
    surfaces_state: str | None = Field(default=None, description="the surface-against-surface comparison, computed by "
                                       "a worker and stored: queued | running (the figures are the totals' until it "
                                       "is done) | succeeded | failed (notes say why); null: not possible (a file "
                                       "missing)")
    uncertainty: dict | None = Field(default=None, description="surfaces only: each quantity's 1 sigma with its "
                                     "components (DSM noise of each survey, the surveys' relative vertical bias, "
                                     "resampling, unmeasured area) and the bias model (common_bias_m and its source)")
