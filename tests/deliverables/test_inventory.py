"""Stockpile inventory (georef_core/deliverables/inventory.py, `georef inventory`): tonnes and their
uncertainty computed by hand, the correlation rules of the totals, the choice of survey per date, and the
CSV / XLSX / CLI outputs on a site folder's registry."""

from __future__ import annotations

import csv
import io
import json
import math
from datetime import date

import pytest

from georef_core.deliverables.inventory import Measurement, Pile, build_inventory, to_csv, to_xlsx

Z95 = 1.959964


def _piles():
    a = Pile("A", "Sand", measurements=[Measurement(date(2024, 5, 1), "s1", 80.0, 1.5),
                                        Measurement(date(2024, 6, 1), "s2", 100.0, 2.0)])
    b = Pile("B", "granite", 2.0, 0.05, [Measurement(date(2024, 6, 1), "s2", 50.0, 1.0)])
    c = Pile("C", "Sand", measurements=[Measurement(date(2024, 6, 1), "s2", 30.0, 0.6),
                                        Measurement(date(2024, 7, 1), "s3", 45.0, 0.7)])
    d = Pile("D", "wood chips", measurements=[Measurement(date(2024, 6, 1), "s2", 10.0, 0.4)])
    return [a, b, c, d]


def test_tonnes_and_uncertainty_by_hand():
    inv = build_inventory(_piles(), "2024-06-15")
    rows = {r["stockpile"]: r for r in inv.rows}
    a, b, c, d = rows["A"], rows["B"], rows["C"], rows["D"]
    # A: sand default 1.60 +- 0.10 t/m3, 100 +- 2 m3 -> 160 t, sigma sqrt((1.6*2)^2 + (100*0.1)^2) = 10.50 t
    assert a["survey_date"] == "2024-06-01" and a["density_source"].startswith("default")
    assert a["tonnes_t"] == 160.0 and a["tonnes_sigma_t"] == pytest.approx(math.hypot(3.2, 10.0), abs=0.006)
    assert a["tonnes_ci95_t"] == pytest.approx(Z95 * math.hypot(3.2, 10.0), abs=0.006)
    # change since 2024-05-01: +20 +- sqrt(2^2 + 1.5^2) = 2.5 m3
    assert a["change_m3"] == 20.0 and a["change_sigma_m3"] == 2.5 and a["previous_survey_date"] == "2024-05-01"
    # B: its own density 2.0 +- 0.05 -> 100 t +- sqrt(2^2 + 2.5^2) = 3.20 t
    assert b["tonnes_t"] == 100.0 and b["tonnes_sigma_t"] == pytest.approx(math.hypot(2.0, 2.5), abs=0.006)
    assert b["change_m3"] is None
    # C: the survey of July is after the date: June's 30 m3 -> 48 t
    assert c["volume_m3"] == 30.0 and c["tonnes_t"] == 48.0
    # D: no density for "wood chips": volume only
    assert d["tonnes_t"] is None and d["density_source"] == "none" and d["volume_m3"] == 10.0
    t = inv.totals
    assert t["volume_m3"] == 190.0
    assert t["volume_sigma_m3"] == pytest.approx(math.sqrt(4 + 1 + 0.36 + 0.16), abs=0.006)
    # tonnes: A and C share the sand default density: their density terms add linearly
    # (100 + 30) * 0.1 = 13 t; then B's 2.5 t and the volume terms in quadrature
    want = math.sqrt((1.6 * 2) ** 2 + (1.6 * 0.6) ** 2 + (2.0 * 1.0) ** 2 + 13.0 ** 2 + 2.5 ** 2)
    assert t["tonnes_t"] == 308.0 and t["tonnes_sigma_t"] == pytest.approx(want, abs=0.006)
    assert any("without a density" in n for n in inv.notes)


def test_survey_bias_is_correlated_in_the_totals():
    piles = [Pile(n, "", 1.0, 0.0, [Measurement(date(2024, 6, 1), "s", 100.0, 5.0, bias_m3=4.0)]) for n in "PQ"]
    inv = build_inventory(piles, date(2024, 6, 1))
    # independent parts 3 m3 each in quadrature, bias 4 + 4 linearly: sqrt(9 + 9 + 64)
    assert inv.totals["volume_sigma_m3"] == pytest.approx(math.sqrt(82), abs=0.006)
    assert inv.totals["tonnes_sigma_t"] == pytest.approx(math.sqrt(82), abs=0.006)
    # different surveys: no correlation
    piles[1].measurements[0].survey = "other"
    assert build_inventory(piles, date(2024, 6, 1)).totals["volume_sigma_m3"] == pytest.approx(math.sqrt(50), abs=0.006)


def test_before_any_survey_and_outputs():
    inv = build_inventory(_piles(), "2024-04-01")
    assert all(r["volume_m3"] is None and r["status"].startswith("no survey") for r in inv.rows)
    inv = build_inventory(_piles() + [Pile("=HYPERLINK(\"x\")", "sand",
                                           measurements=[Measurement(date(2024, 6, 1), "s2", 1.0, 0.1)])], "2024-06-30")
    rows = list(csv.reader(io.StringIO(to_csv(inv).decode())))
    assert rows[0][4] == "volume_m3" and rows[-1][0] == "TOTAL" and len(rows) == 2 + 5
    assert any(r[0].startswith("'=") for r in rows)
    from openpyxl import load_workbook

    wb = load_workbook(io.BytesIO(to_xlsx(inv)))
    ws = wb["Inventory"]
    assert [c.value for c in ws[1]][:5] == ["stockpile", "material", "survey", "survey_date", "volume_m3"]
    assert ws.cell(ws.max_row, 1).value == "TOTAL" and ws.cell(ws.max_row, 5).value == inv.totals["volume_m3"]
    assert "About" in wb.sheetnames


def test_cli_on_a_site_registry(tmp_path, capsys):
    from georef_core.cli.main import main

    outline = {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]]}

    def meas(survey, day, v, s):
        return {"survey_id": survey, "survey_date": day, "dsm": "", "cut_m3": v, "fill_m3": 0.0, "net_m3": v,
                "area_m2": 100.0, "sigma_m3": s, "ci95_m3": Z95 * s, "base_method": "locked plane"}

    reg = {"schema_version": 1, "stockpiles": [
        {"name": "North", "outline": outline, "crs": "EPSG:32631", "material": "gravel",
         "measurements": [meas("f1", "2024-03-01", 200.0, 3.0), meas("f2", "2024-04-01", 150.0, 4.0)]},
        {"name": "South", "outline": outline, "crs": "EPSG:32631", "material": "",
         "measurements": [meas("f2", "2024-04-01", 60.0, 1.0)]}]}
    (tmp_path / "stockpiles.json").write_text(json.dumps(reg))
    assert main([ "inventory", str(tmp_path), "--date", "2024-04-10", "--json", "--density", "South=1.9+-0.1"]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = {r["stockpile"]: r for r in doc["stockpiles"]}
    assert rows["North"]["tonnes_t"] == pytest.approx(255.0) and rows["North"]["change_m3"] == -50.0
    assert rows["North"]["change_sigma_m3"] == 5.0
    assert rows["South"]["tonnes_t"] == pytest.approx(114.0) and rows["South"]["density_source"] == "given"
    assert main(["inventory", str(tmp_path), "--date", "2024-04-10", "--out", str(tmp_path / "inv.xlsx")]) == 0
    assert (tmp_path / "inv.xlsx").read_bytes()[:2] == b"PK"
    assert main(["inventory", str(tmp_path), "--date", "April"]) == 2
    assert "YYYY-MM-DD" in capsys.readouterr().err
