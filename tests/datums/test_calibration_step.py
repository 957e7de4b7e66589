"""The datum step applying a site calibration (localisation): from the survey's calibration/ folder (control
pairs solved in the step, or a calibration JSON) or the step's `calibration` setting, on a simulated site with a
known local grid (similarity + inclined plane); its residuals per point in the summary; bad input named.

The summary's calibration is also the browser's fixture (frontend/tests/fixtures/datum_calibration.json, read
by frontend/tests/calibration.test.ts); rewrite it with:  .venv/bin/python -m tests.datums.test_calibration_step
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from georef_core.datums.site_calibration import read_calibration
from georef_core.dense.cog_writer import HEIGHT_TAGS, write_cog
from georef_core.errors import InputFileError
from georef_core.steps.contract import Workspace, get_spec

FIXTURE = Path(__file__).resolve().parents[2] / "frontend" / "tests" / "fixtures" / "datum_calibration.json"
E0, N0 = 448_000.0, 5_412_000.0
# the site grid's truth: local = similarity(projected) about (E0 + 50, N0 + 50); H = h + plane
SCALE, THETA = 1.0 + 25e-6, math.radians(0.35)
LOCAL0 = (1000.0, 2000.0)
C0, SLOPE_N, SLOPE_E = -47.25, 2.0e-5, -1.2e-5
CTX = {"crs": "EPSG:32631", "vertical_datum": None}


def _truth(E, N, h):
    dE, dN = np.asarray(E) - (E0 + 50), np.asarray(N) - (N0 + 50)
    a, b = SCALE * math.cos(THETA), SCALE * math.sin(THETA)
    e = LOCAL0[0] + a * dE - b * dN
    n = LOCAL0[1] + b * dE + a * dN
    return e, n, np.asarray(h) + C0 + SLOPE_N * dN + SLOPE_E * dE


def _dsm_height(E, N):
    return 150.0 + 0.02 * (np.asarray(E) - E0) - 0.01 * (np.asarray(N) - N0)


CORNERS = [("K1", 5.0, 8.0), ("K2", 96.0, 4.0), ("K3", 93.0, 97.0), ("K4", 3.0, 92.0), ("K5", 52.0, 47.0)]


def _site(tmp_path, blunder_dh_m: float = 0.0, pairs: bool = True) -> Workspace:
    survey, out = tmp_path / "survey", tmp_path / "run"
    survey.mkdir(parents=True)
    (survey / "survey.json").write_text(json.dumps({"points_crs": "EPSG:32631"}))
    ws = Workspace(survey, out)
    rows = ["name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m"]
    for name, x, y in CORNERS:
        E, N = E0 + x, N0 + y
        h = float(_dsm_height(E, N))
        e, n, H = _truth(E, N, h)
        H = float(H) + (blunder_dh_m if name == "K5" else 0.0)
        rows.append(f"{name},{E:.4f},{N:.4f},{h:.4f},{float(e):.4f},{float(n):.4f},{H:.4f}")
    if pairs:
        (survey / "calibration").mkdir()
        (survey / "calibration" / "pairs.csv").write_text("\n".join(rows) + "\n")
    yy, xx = np.mgrid[0:50, 0:50]
    z = _dsm_height(E0 + (xx + 0.5) * 2.0, N0 + 100 - (yy + 0.5) * 2.0).astype(np.float32)
    write_cog(ws.path("dense", "dsm"), z, from_origin(E0, N0 + 100, 2.0, 2.0), 32631, nodata=-9999.0,
              tags=HEIGHT_TAGS)
    return ws


def test_datum_step_applies_a_calibration_solved_from_the_surveys_pairs(tmp_path):
    ws = _site(tmp_path)
    s = get_spec("datum").resolve()(ws, {}, None, CTX)
    assert not s.get("skipped") and s["vertical_datum"] == "ellipsoidal"
    cal = s["calibration"]
    assert cal["source"] == "calibration/pairs.csv" and cal["height_datum"] == "ellipsoidal"
    # the truth recovered (coordinates written to 0.1 mm)
    assert abs(cal["horizontal"]["scale_ppm"] - 25.0) < 2.0
    assert abs(cal["horizontal"]["rotation_deg"] - 0.35) < 2e-6 * 180 / math.pi
    assert cal["vertical"]["model"] == "inclined plane"
    assert abs(cal["vertical"]["slope_north"] - SLOPE_N) < 3e-6 and abs(cal["vertical"]["slope_east"] - SLOPE_E) < 3e-6
    assert [r["name"] for r in cal["residuals"]] == [c[0] for c in CORNERS]
    assert all(abs(r[k]) < 2e-4 for r in cal["residuals"] for k in ("dE_m", "dN_m", "dH_m"))
    # the calibration file and the DSM on the local grid: heights where the truth puts them
    assert read_calibration(ws.path("datum", "calibration")).pairs[0].name == "K1"
    with rasterio.open(ws.path("datum", "dsm_local")) as src:
        z = src.read(1)
        tr = src.transform
        assert "site calibration" in src.tags()["HEIGHTS"]
    errs = []
    for x, y in ((20.0, 30.0), (60.0, 70.0), (45.5, 12.25), (80.0, 85.0)):
        E, N = E0 + x, N0 + y
        e, n, H = _truth(E, N, _dsm_height(E, N))
        col, row = ~tr @ (float(e), float(n))
        r, c = int(row), int(col)
        # the cell centre nearest: the DSM is a plane in E, N, so the local grid's heights are a plane too
        ce, cn = tr @ (c + 0.5, r + 0.5)
        a, b = SCALE * math.cos(THETA), SCALE * math.sin(THETA)
        de, dn = ce - float(e), cn - float(n)
        dE, dN = (a * de + b * dn) / SCALE ** 2, (-b * de + a * dn) / SCALE ** 2
        want = float(H) + 0.02 * dE - 0.01 * dN + SLOPE_N * dN + SLOPE_E * dE
        errs.append(abs(float(z[r, c]) - want))
    assert max(errs) < 5e-4, errs


def test_a_blunder_shows_in_its_points_residual_and_the_setting_gives_the_same(tmp_path):
    ws = _site(tmp_path / "a", blunder_dh_m=0.05)
    s = get_spec("datum").resolve()(ws, {}, None, CTX)
    res = {r["name"]: r for r in s["calibration"]["residuals"]}
    worst = max(res, key=lambda k: abs(res[k]["dH_m"]))
    # 5 points, a plane of 3 parameters: the blunder leaks into the others, but stays largest on its own point
    assert worst == "K5" and abs(res["K5"]["dH_m"]) > 0.03
    assert abs(s["calibration"]["statistics"]["max_vertical_m"] - abs(res["K5"]["dH_m"])) < 1e-12
    assert all(abs(r["dE_m"]) < 2e-4 and abs(r["dN_m"]) < 2e-4 for r in res.values())
    # the same calibration given as the step's setting (the JSON georef datum calibrate writes), no file
    doc = json.loads(ws.path("datum", "calibration").read_text())
    ws2 = _site(tmp_path / "b", pairs=False)
    s2 = get_spec("datum").resolve()(ws2, {"calibration": doc}, None, CTX)
    assert s2["calibration"]["source"] == "settings datum.calibration"
    assert s2["calibration"]["residuals"] == s["calibration"]["residuals"]
    with rasterio.open(ws.path("datum", "dsm_local")) as a, rasterio.open(ws2.path("datum", "dsm_local")) as b:
        assert np.array_equal(a.read(1), b.read(1))


def test_bad_calibrations_are_named(tmp_path):
    fn = get_spec("datum").resolve()
    ws = _site(tmp_path / "two")
    (ws.survey_dir / "calibration" / "other.json").write_text("{}")
    with pytest.raises(InputFileError, match=r"2 calibration files \(other.json, pairs.csv\)"):
        fn(ws, {}, None, CTX)
    # naming one: the JSON is not a calibration
    with pytest.raises(InputFileError, match=r"other.json: not a site calibration"):
        fn(ws, {"calibration_file": "calibration/other.json"}, None, CTX)
    with pytest.raises(InputFileError, match=r"inside the survey"):
        fn(ws, {"calibration_file": "../run/datum/site_calibration.json"}, None, CTX)
    # a calibration in other heights than the site's
    ws = _site(tmp_path / "datum")
    fn(ws, {}, None, CTX)
    doc = json.loads(ws.path("datum", "calibration").read_text())
    doc["height_datum"] = "EPSG:5773"
    with pytest.raises(InputFileError, match=r"settings datum.calibration: the calibration's heights are EGM96"):
        fn(ws, {"calibration": doc}, None, CTX)
    doc["height_datum"] = "ellipsoidal"
    doc["crs"] = "EPSG:32632"
    with pytest.raises(InputFileError, match=r"the calibration is in EPSG:32632, the site in EPSG:32631"):
        fn(ws, {"calibration": doc}, None, CTX)
    # too few pairs: the core's message
    ws = _site(tmp_path / "few")
    p = ws.survey_dir / "calibration" / "pairs.csv"
    p.write_text("\n".join(p.read_text().splitlines()[:3]) + "\n")
    with pytest.raises(InputFileError, match=r"pairs.csv: a site calibration needs at least 3 horizontal control points \(got 2\)"):
        fn(ws, {}, None, CTX)
    # read by content: control pairs stored under a .json name (an upload named pairs.txt) are solved
    ws = _site(tmp_path / "named")
    (ws.survey_dir / "calibration" / "pairs.csv").rename(ws.survey_dir / "calibration" / "site_calibration.json")
    got = fn(ws, {}, None, CTX)["calibration"]
    assert got["source"] == "calibration/site_calibration.json" and got["statistics"]["n_vertical"] == 5
    # no calibration and ellipsoidal heights: skipped as before
    assert fn(_site(tmp_path / "none", pairs=False), {}, None, CTX)["skipped"] is True


def _fixture_doc(tmp_path) -> dict:
    ws = _site(tmp_path, blunder_dh_m=0.05)
    return json.loads(json.dumps(get_spec("datum").resolve()(ws, {}, None, CTX)["calibration"]))


def _close(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=1e-7, abs_tol=1e-9)
    return a == b


def test_the_browser_fixture_is_the_steps_calibration_summary(tmp_path):
    assert FIXTURE.is_file(), f"{FIXTURE} missing: python -m tests.datums.test_calibration_step writes it"
    assert _close(json.loads(FIXTURE.read_text()), _fixture_doc(tmp_path)), \
        "the datum step's calibration summary changed: rewrite the fixture and run the vitest"


if __name__ == "__main__":
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        FIXTURE.write_text(json.dumps(_fixture_doc(Path(d)), indent=1) + "\n")
    print(f"wrote {FIXTURE}")
