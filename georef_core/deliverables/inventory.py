"""Stockpile inventory: every pile of a site at a date, in one table (docs/deliverables.md, "Stockpile
inventory").

For each pile, the latest survey on or before the date: its volume with its 1-sigma and 95 % uncertainty,
the material, a bulk density (t/m3: the pile's own, else the default of its material below, else none),
the tonnage with its uncertainty, and the change since the pile's previous survey. A pure function of the
stored volume records (:func:`build_inventory`): the CLI reads them from a site folder's stockpile
registry (``stockpiles.json``), the platform from its database, the PDF report from either.

Uncertainty (first order, 1 sigma; 95 % = 1.96 sigma):

* tonnes ``T = rho V``: ``sigma_T^2 = (rho sigma_V)^2 + (V sigma_rho)^2`` (volume and density errors
  independent);
* change ``dV = V_now - V_prev``: ``sigma_dV^2 = sigma_now^2 + sigma_prev^2``. Conservative: with a locked
  base (georef_core/volumes/stockpile_records.py) the base's error is common to both surveys and cancels
  in the difference; it is counted twice here;
* totals, correlated terms added linearly: a survey's vertical bias term (``height_bias_m3`` when the
  record has it) is the same error for every pile of that survey, and one density (value and sigma) used
  for several piles (a material's default) is the same error for all of them:
  ``sigma_Vtot^2 = sum_i (sigma_i^2 - b_i^2) + sum_surveys (sum_i b_i)^2``,
  ``sigma_Ttot^2 = sum_i rho_i^2 (sigma_i^2 - b_i^2) + sum_surveys (sum_i rho_i b_i)^2
  + sum_densities (sum_i V_i sigma_rho)^2``; everything else is independent between piles. The change
  total's terms are taken as independent between piles.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from datetime import date, datetime

Z95 = 1.959964

# Indicative loose (stockpiled) bulk densities, t/m3, with the spread met between sources and moisture
# states. Defaults only: a weighbridge or a density test on site replaces them (the pile's own density).
DEFAULT_DENSITIES_T_M3: dict[str, tuple[float, float]] = {
    "sand": (1.60, 0.10),
    "gravel": (1.70, 0.10),
    "crushed_stone": (1.60, 0.10),
    "limestone": (1.55, 0.10),
    "topsoil": (1.25, 0.15),
    "clay": (1.80, 0.15),
    "rubble": (1.40, 0.20),
    "asphalt_millings": (1.50, 0.10),
    "coal": (0.85, 0.08),
}


def material_key(material: str) -> str:
    return "_".join((material or "").strip().lower().replace("-", " ").split())


@dataclass
class Measurement:
    """One survey's volume of a pile (m3, 1 sigma); `bias_m3`: its survey-wide vertical bias term when
    known (part of sigma_m3)."""

    survey_date: date
    survey: str
    volume_m3: float
    sigma_m3: float
    bias_m3: float | None = None


@dataclass
class Pile:
    name: str
    material: str = ""
    density_t_m3: float | None = None
    density_sigma_t_m3: float | None = None
    measurements: list[Measurement] = field(default_factory=list)


COLUMNS = ["stockpile", "material", "survey", "survey_date", "volume_m3", "volume_sigma_m3", "volume_ci95_m3",
           "density_t_m3", "density_sigma_t_m3", "density_source", "tonnes_t", "tonnes_sigma_t", "tonnes_ci95_t",
           "previous_survey_date", "change_m3", "change_sigma_m3", "change_ci95_m3", "status"]


@dataclass
class Inventory:
    date: date
    rows: list[dict]
    totals: dict
    notes: list[str]

    def as_dict(self) -> dict:
        return {"date": self.date.isoformat(), "units": {"volume": "m3", "density": "t/m3", "mass": "t"},
                "uncertainty": "sigma: 1 sigma; ci95: 95 % half-width (1.96 sigma)", "columns": COLUMNS,
                "stockpiles": self.rows, "totals": self.totals, "notes": self.notes}


def _as_date(v) -> date:
    if isinstance(v, datetime):
        return v.date()
    if isinstance(v, date):
        return v
    return date.fromisoformat(str(v)[:10])


def _density(p: Pile, defaults: dict) -> tuple[float | None, float, str]:
    if p.density_t_m3:
        s = p.density_sigma_t_m3
        return float(p.density_t_m3), float(s or 0.0), "given" if s is not None else "given (no uncertainty given)"
    d = defaults.get(material_key(p.material))
    if d:
        return d[0], d[1], f"default for {material_key(p.material)}"
    return None, 0.0, "none"


def _r(v, nd=2):
    return None if v is None else round(float(v), nd)


def build_inventory(piles: list[Pile], on_date, defaults: dict | None = None) -> Inventory:
    """The inventory of `piles` at `on_date` (a date, datetime or ISO text): see the module's docstring."""
    day = _as_date(on_date)
    defaults = DEFAULT_DENSITIES_T_M3 if defaults is None else defaults
    rows = []
    var_v_ind = var_t_ind = var_dv = 0.0
    bias_v: dict[str, float] = {}
    bias_t: dict[str, float] = {}
    dens_groups: dict[tuple, float] = {}
    tot_v = tot_t = tot_dv = 0.0
    n_v = n_t = n_dv = 0
    for p in sorted(piles, key=lambda q: q.name.lower()):
        ms = sorted((m for m in p.measurements if _as_date(m.survey_date) <= day),
                    key=lambda m: _as_date(m.survey_date))
        rho, s_rho, source = _density(p, defaults)
        row = {c: None for c in COLUMNS}
        row.update({"stockpile": p.name, "material": p.material or "", "density_t_m3": _r(rho, 3),
                    "density_sigma_t_m3": _r(s_rho, 3) if rho is not None else None, "density_source": source})
        if not ms:
            row["status"] = f"no survey on or before {day.isoformat()}"
            rows.append(row)
            continue
        m = ms[-1]
        v, s = float(m.volume_m3), float(m.sigma_m3 or 0.0)
        b = min(abs(float(m.bias_m3)), s) if m.bias_m3 is not None else 0.0
        row.update({"survey": m.survey, "survey_date": _as_date(m.survey_date).isoformat(), "volume_m3": _r(v),
                    "volume_sigma_m3": _r(s), "volume_ci95_m3": _r(Z95 * s), "status": "measured"})
        tot_v += v
        n_v += 1
        var_v_ind += s * s - b * b
        bias_v[m.survey] = bias_v.get(m.survey, 0.0) + b
        if rho is not None:
            t = rho * v
            s_t = math.hypot(rho * s, v * s_rho)
            row.update({"tonnes_t": _r(t), "tonnes_sigma_t": _r(s_t), "tonnes_ci95_t": _r(Z95 * s_t)})
            tot_t += t
            n_t += 1
            var_t_ind += rho * rho * (s * s - b * b)
            bias_t[m.survey] = bias_t.get(m.survey, 0.0) + rho * b
            key = (material_key(p.material) if source.startswith("default") else f"pile:{p.name}", rho, s_rho)
            dens_groups[key] = dens_groups.get(key, 0.0) + v * s_rho
        if len(ms) >= 2:
            prev = ms[-2]
            dv = v - float(prev.volume_m3)
            s_dv = math.hypot(s, float(prev.sigma_m3 or 0.0))
            row.update({"previous_survey_date": _as_date(prev.survey_date).isoformat(), "change_m3": _r(dv),
                        "change_sigma_m3": _r(s_dv), "change_ci95_m3": _r(Z95 * s_dv)})
            tot_dv += dv
            var_dv += s_dv * s_dv
            n_dv += 1
        rows.append(row)
    s_tv = math.sqrt(max(var_v_ind, 0.0) + sum(x * x for x in bias_v.values()))
    s_tt = math.sqrt(max(var_t_ind, 0.0) + sum(x * x for x in bias_t.values()) + sum(x * x for x in dens_groups.values()))
    s_tdv = math.sqrt(var_dv)
    totals = {c: None for c in COLUMNS}
    totals.update({"stockpile": "TOTAL", "volume_m3": _r(tot_v) if n_v else None,
                   "volume_sigma_m3": _r(s_tv) if n_v else None, "volume_ci95_m3": _r(Z95 * s_tv) if n_v else None,
                   "tonnes_t": _r(tot_t) if n_t else None, "tonnes_sigma_t": _r(s_tt) if n_t else None,
                   "tonnes_ci95_t": _r(Z95 * s_tt) if n_t else None,
                   "change_m3": _r(tot_dv) if n_dv else None, "change_sigma_m3": _r(s_tdv) if n_dv else None,
                   "change_ci95_m3": _r(Z95 * s_tdv) if n_dv else None,
                   "status": f"{n_v} of {len(rows)} piles measured; tonnes of {n_t}; change of {n_dv}"})
    notes = ["Volume: the latest survey on or before the date; net volume above the pile's base (m3).",
             "Tonnes = density x volume; sigma_T^2 = (rho sigma_V)^2 + (V sigma_rho)^2.",
             "Change since the pile's previous survey; its sigma = sqrt(sigma_now^2 + sigma_prev^2) (conservative "
             "with a locked base).",
             "Totals: a survey's vertical bias term and a density shared by several piles are added linearly "
             "(correlated); other terms in quadrature.",
             "Default densities are indicative loose bulk densities; a measured density replaces them."]
    if n_t < n_v:
        notes.append(f"{n_v - n_t} measured pile(s) without a density: not in the tonnes total.")
    return Inventory(day, rows, totals, notes)


def _cell(v):
    if isinstance(v, str) and v[:1] in ("=", "+", "-", "@", "\t", "\r"):
        try:
            float(v)
        except ValueError:
            return "'" + v
    return "" if v is None else v


def to_csv(inv: Inventory) -> bytes:
    """CSV: one header row with units in the names, one row per pile, the TOTAL row last (formula-like
    text neutralised)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for r in inv.rows + [inv.totals]:
        w.writerow([_cell(r.get(c)) for c in COLUMNS])
    return buf.getvalue().encode("utf-8")


def to_xlsx(inv: Inventory, about: dict | None = None) -> bytes:
    """XLSX: an "Inventory" sheet (piles, then the TOTAL row in bold) and an "About" sheet (date, units,
    the uncertainty rules)."""
    from openpyxl import Workbook
    from openpyxl.styles import Font

    wb = Workbook()
    ws = wb.active
    ws.title = "Inventory"
    ws.append(COLUMNS)
    for cell in ws[1]:
        cell.font = Font(bold=True)
    for r in inv.rows + [inv.totals]:
        ws.append([r.get(c) for c in COLUMNS])
        for cell in ws[ws.max_row]:
            if isinstance(cell.value, str):
                cell.data_type = "s"          # text, never a formula
    for cell in ws[ws.max_row]:
        cell.font = Font(bold=True)
    for col in ws.columns:
        width = max(len(str(c.value)) if c.value is not None else 0 for c in col)
        ws.column_dimensions[col[0].column_letter].width = min(50, max(8, width + 2))
    info = wb.create_sheet("About")
    info.append(["item", "value"])
    for k, v in {"date": inv.date.isoformat(), "units": "m3, t/m3, t", **(about or {})}.items():
        info.append([k, str(v)])
    for i, n in enumerate(inv.notes):
        info.append([f"note {i + 1}", n])
    for row in info.iter_rows():
        for cell in row:
            if isinstance(cell.value, str):
                cell.data_type = "s"
    info.column_dimensions["A"].width = 14
    info.column_dimensions["B"].width = 110
    buf = io.BytesIO()
    wb.save(buf)
    return buf.getvalue()


def piles_from_registry(registry) -> list[Pile]:
    """The piles of a site folder's StockpileRegistry (georef stockpile), with their measurements; a
    record's `density_t_m3`/`density_sigma_t_m3` are read when present."""
    out = []
    for rec in registry.records.values():
        ms = [Measurement(_as_date(m.survey_date or m.measured_at), m.survey_id, m.net_m3, m.sigma_m3)
              for m in rec.measurements if (m.survey_date or m.measured_at)]
        out.append(Pile(rec.name, rec.material, getattr(rec, "density_t_m3", None),
                        getattr(rec, "density_sigma_t_m3", None), ms))
    return out
