"""The stockpile inventory of a site at a date (GET /sites/{id}/inventory): every stockpile, its latest
survey on or before the date, volume, tonnes and change since its previous survey with their uncertainty
(computed by georef_core.deliverables.inventory from the stored volume records), as JSON, CSV or XLSX.

`site_piles` reads the stored records into the core's plain records; the PDF report reads the same
(`inventory_for(db, site_id, date)`)."""

from __future__ import annotations

from datetime import date, datetime

from sqlalchemy import select

from ..core.problems import Unprocessable
from ..models import Run, Stockpile, Survey, VolumeMeasurement
from .context import Ctx
from .permissions import require_site

FORMATS = ("json", "csv", "xlsx")
XLSX = "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet"


def site_piles(db, site_id: str):
    """The site's stockpiles with one measurement per survey (the latest successful run's), dated by the
    survey's flight time (the volume row's `measured_at`, else the survey's `flown_at`)."""
    from georef_core.deliverables.inventory import Measurement, Pile

    piles = {sp.id: Pile(sp.name, sp.material or "", sp.density_t_m3, None)
             for sp in db.scalars(select(Stockpile).where(Stockpile.site_id == site_id))}
    rows = db.execute(select(VolumeMeasurement, Survey.name, Survey.flown_at)
                      .join(Run, Run.id == VolumeMeasurement.run_id)
                      .join(Survey, Survey.id == VolumeMeasurement.survey_id)
                      .where(VolumeMeasurement.site_id == site_id, Run.state == "succeeded",
                             VolumeMeasurement.stockpile_id.is_not(None), VolumeMeasurement.volume_m3.is_not(None))
                      .order_by(Run.created_at, Run.number)).all()
    latest: dict[tuple[str, str], tuple] = {}
    for vm, survey_name, flown_at in rows:        # later runs of a survey replace earlier ones
        latest[(vm.stockpile_id, vm.survey_id)] = (vm, survey_name, flown_at)
    for (pile_id, _), (vm, survey_name, flown_at) in latest.items():
        when = vm.measured_at or flown_at
        if pile_id not in piles or when is None:
            continue
        d = vm.details or {}
        sigma = d.get("sigma_m3")
        piles[pile_id].measurements.append(Measurement(when.date(), survey_name, vm.volume_m3,
                                                       float(sigma) if sigma is not None else 0.0,
                                                       d.get("height_bias_m3")))
    return list(piles.values())


def inventory_for(db, site_id: str, on_date: date):
    from georef_core.deliverables.inventory import build_inventory

    return build_inventory(site_piles(db, site_id), on_date)


def parse_date(value: str | None) -> date:
    if not value:
        return datetime.utcnow().date()
    try:
        return date.fromisoformat(value[:10])
    except ValueError:
        raise Unprocessable(f"date: {value!r} is not a date (YYYY-MM-DD)") from None


def inventory(ctx: Ctx, site_id: str, on_date: str | None, fmt: str) -> tuple[bytes, str, str]:
    """(body, media type, file name) of the site's inventory at `on_date` (default: today, UTC)."""
    from georef_core.deliverables.inventory import to_csv, to_xlsx

    if fmt not in FORMATS:
        raise Unprocessable(f"format: one of {', '.join(FORMATS)}")
    site = require_site(ctx, site_id, "viewer")
    day = parse_date(on_date)
    inv = inventory_for(ctx.db, site_id, day)
    name = f"inventory_{day.isoformat()}"
    if fmt == "csv":
        return to_csv(inv), "text/csv; charset=utf-8", name + ".csv"
    if fmt == "xlsx":
        return to_xlsx(inv, {"site": site.name, "crs": site.crs}), XLSX, name + ".xlsx"
    import json

    doc = {"site_id": site_id, "site": site.name, **inv.as_dict()}
    return json.dumps(doc, separators=(",", ":")).encode(), "application/json", name + ".json"
