"""The rough edges a new user met on a fresh clone (issue 24), on both platform shapes where a platform is
needed: the flight time read from the data (GNSS solution, DJI MRK, EXIF) stored on the survey and used by
the survey list's date filter, the volume history and the PDF; ISO 8601 times in the site summary and the
volume history; the run log as a page; /health checking the broker; one way of writing volumes and
materials. The worker is driven through the job state machine (backend/services/jobs.py), no Celery."""

from __future__ import annotations

import json
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from backend.services import jobs
from backend.services.display import format_volume, format_volume_pm, material_label
from georef_core.steps import flight_time as ft

from .platform_helpers import POINTS_CSV, Api, add_user, close_platform, make_platform, upload_bytes

REPO = Path(__file__).resolve().parents[2]
OUTLINE = {"type": "Polygon", "coordinates": [[[679500.0, 3889230.0], [679510.0, 3889230.0], [679510.0, 3889240.0],
                                               [679500.0, 3889230.0]]]}
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=timezone.utc)
FLIGHT = {"start": "2024-06-24T08:10:05Z", "end": "2024-06-24T08:14:40Z", "source": "gnss",
          "detail": "GNSS solution (camera triggers)"}


def _iso_with_zone(value: str) -> bool:
    return isinstance(value, str) and "T" in value and " " not in value and (value.endswith("Z") or value[-6] in "+-")


def _step(db, run_id: str, step: str, summary: dict, volumes=None) -> None:
    """What a worker does with one step: claim it, record its summary (and volumes)."""
    claim = jobs.claim_step(db, run_id, step, "test-worker")
    assert isinstance(claim, jobs.Claim), claim
    ok, _ = jobs.finish_step(db, claim, f"hash-{step}", [], summary, volumes=volumes)
    assert ok


@pytest.fixture(scope="module")
def processed(platform):
    """A survey given no date, with a stockpile, run through gnss (whose summary read the flight time from
    the data), georef, dense and volumes."""
    add_user(platform, f"edges-{platform.shape}@example.org")
    api = Api(platform, f"edges-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "Quarry", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "Flight without a date"}).json()
    assert survey["flown_at"] is None and survey["flown_at_source"] is None
    assert upload_bytes(api, survey["id"], "points.csv", POINTS_CSV, kind="points").status_code == 200
    pile = api.post(f"/api/v1/sites/{site['id']}/stockpiles",
                    json={"name": "P1", "outline": OUTLINE, "material": "crushed_stone"}).json()
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["volumes"]}).json()
    db = platform.db()
    _step(db, run["id"], "gnss", {"epochs": 550, "flight_time": FLIGHT})
    _step(db, run["id"], "georef", {})
    _step(db, run["id"], "dense", {})
    _step(db, run["id"], "volumes", {"stockpiles": 1}, volumes=[
        {"stockpile_id": pile["id"], "stockpile_name": "P1", "base": "plane", "volume_m3": 24.448, "fill_m3": 0.0,
         "cut_m3": 24.448, "area_m2": 61.2, "details": {"sigma_m3": 0.161}}])
    return {"api": api, "site": site, "survey": survey, "pile": pile, "run": run, "platform": platform}


def test_flight_time_from_the_data_is_the_surveys(processed):
    api, survey, site = processed["api"], processed["survey"], processed["site"]
    s = api.get(f"/api/v1/surveys/{survey['id']}").json()
    assert s["flown_at"] == FLIGHT["start"] and s["flown_at_source"] == "gnss"
    # the date filter finds it (it found nothing when the date stayed empty)
    found = api.get(f"/api/v1/sites/{site['id']}/surveys", params={"flown_after": "2024-06-24T00:00:00Z"}).json()
    assert [x["id"] for x in found["items"]] == [survey["id"]]
    none = api.get(f"/api/v1/sites/{site['id']}/surveys", params={"flown_before": "2024-06-24T00:00:00Z"}).json()
    assert none["items"] == []
    # the volumes are dated by the flight, not by the run's creation
    hist = api.get(f"/api/v1/stockpiles/{processed['pile']['id']}/volumes").json()
    assert [h["measured_at"] for h in hist] == [FLIGHT["start"]]
    vols = api.get(f"/api/v1/runs/{processed['run']['id']}/results/volumes").json()["stockpiles"]
    assert vols[0]["measured_at"] == FLIGHT["start"]


def test_a_date_given_wins_and_the_volumes_follow_it(processed, tmp_path):
    api, survey = processed["api"], processed["survey"]
    r = api.patch(f"/api/v1/surveys/{survey['id']}", json={"flown_at": "2024-06-25T07:00:00Z"})
    assert r.status_code == 200, r.text
    assert r.json()["flown_at_source"] == "user"
    hist = api.get(f"/api/v1/stockpiles/{processed['pile']['id']}/volumes").json()
    assert hist[0]["measured_at"] == "2024-06-25T07:00:00Z"
    db = processed["platform"].db()
    with db.session() as s:           # a later run's data does not overwrite what the user gave
        jobs.record_flight_time(s, survey["id"], FLIGHT)
    assert api.get(f"/api/v1/surveys/{survey['id']}").json()["flown_at"] == "2024-06-25T07:00:00Z"
    # null hands the date back to the data
    assert api.patch(f"/api/v1/surveys/{survey['id']}", json={"flown_at": None}).json()["flown_at_source"] is None
    with db.session() as s:
        jobs.record_flight_time(s, survey["id"], FLIGHT)
    assert api.get(f"/api/v1/surveys/{survey['id']}").json()["flown_at"] == FLIGHT["start"]


def test_report_shows_the_flight_time_volumes_and_materials(processed, tmp_path):
    """The PDF: the flight time read from the data (was 'date not given'), volumes written by the UI's rule,
    the material's label."""
    from tests.security.conftest import pdf_text
    from worker import pipeline

    db = processed["platform"].db()
    run = jobs.run_context(db, processed["run"]["id"])
    run["volumes"] = jobs.volumes_of_run(db, processed["run"]["id"], with_material=True)
    pipeline._report(tmp_path, tmp_path, {}, lambda *a: None, run)
    text = pdf_text((tmp_path / "report" / "accuracy_report.pdf").read_bytes()).replace("\\261", "±")
    flat = "".join(text.split())      # a wrapped line's words are joined without their space
    assert "Flight:2024-06-2408:10UTC(readfromtheGNSSsolution)" in flat, text
    assert "24.45 ± 0.16" in text and "Crushed stone" in text, text


def test_times_are_iso_8601_with_zone(processed):
    api = processed["api"]
    summary = api.get(f"/api/v1/sites/{processed['site']['id']}/summary").json()
    assert _iso_with_zone(summary["latest_survey"]["flown_at"]), summary
    assert _iso_with_zone(summary["latest_run"]["finished_at"]), summary
    hist = api.get(f"/api/v1/stockpiles/{processed['pile']['id']}/volumes").json()
    assert hist and all(_iso_with_zone(h["measured_at"]) for h in hist), hist


def test_materials_are_labelled(processed):
    piles = processed["api"].get(f"/api/v1/sites/{processed['site']['id']}/stockpiles").json()
    assert piles[0]["material"] == "crushed_stone" and piles[0]["material_label"] == "Crushed stone"
    assert material_label("Crushed granite 20/40") == "Crushed granite 20/40"     # words stay as typed
    assert material_label("topsoil") == "Topsoil" and material_label("") == ""


def test_run_log_is_a_page(processed):
    api, run_id = processed["api"], processed["run"]["id"]
    r = api.get(f"/api/v1/runs/{run_id}/logs")
    body = r.json()
    assert set(body) == {"items", "total", "limit", "offset"} and body["limit"] == 50 and body["offset"] == 0
    n = body["total"]
    assert n >= 6 and r.headers["x-total-count"] == str(n)
    first = api.get(f"/api/v1/runs/{run_id}/logs?limit=2")
    assert len(first.json()["items"]) == 2 and 'rel="next"' in first.headers["link"]
    ids = [x["id"] for x in body["items"]]
    assert ids == sorted(ids)
    rest = api.get(f"/api/v1/runs/{run_id}/logs", params={"limit": 2, "offset": 2}).json()["items"]
    assert [x["id"] for x in rest] == ids[2:4]
    after = api.get(f"/api/v1/runs/{run_id}/logs", params={"after_id": ids[-2]}).json()
    assert [x["id"] for x in after["items"]] == ids[-1:] and after["total"] == 1
    assert api.get(f"/api/v1/runs/{run_id}/logs?limit=501").status_code == 422


def test_health_checks_the_broker(platform, tmp_path):
    r = platform.client().get("/api/v1/health")
    assert r.status_code == 200 and r.json()["checks"]["broker"] == "ok", r.text
    # a broker that cannot be reached: 503 naming it, within the short timeout
    dead = make_platform(tmp_path, platform.shape, broker_url="redis://127.0.0.1:9/0")
    try:
        t0 = time.monotonic()
        r = dead.client().get("/api/v1/health")
        assert r.status_code == 503, r.text
        assert r.json()["checks"]["broker"].startswith("error"), r.text
        assert time.monotonic() - t0 < 5
    finally:
        close_platform(dead)


# ------------------------------------------------------------------------------------------- no platform


def test_volume_format_rule_is_the_uis():
    cases = json.loads((REPO / "frontend" / "tests" / "fixtures" / "volume_format_cases.json").read_text())["cases"]
    for c in cases:
        assert format_volume(c["m3"], c["sigma_m3"]) == c["number"], c
        assert format_volume_pm(c["m3"], c["sigma_m3"]) == c["with_sigma"], c


def _utc_of_gps(week: int, sow: float) -> str:
    return (GPS_EPOCH + timedelta(seconds=week * 604800 + sow - 18)).strftime("%Y-%m-%dT%H:%M:%SZ")


def test_flight_time_read_from_gnss_mrk_and_exif(tmp_path):
    survey, out = tmp_path / "survey", tmp_path / "out"
    (survey / "images").mkdir(parents=True)
    assert ft.survey_flight_time(survey, out) is None
    # EXIF DateTimeOriginal of the photos (the camera's clock; its zone when the camera wrote one)
    import piexif
    from PIL import Image

    for i, (when, offset) in enumerate((("2024:06:24 10:12:00", b"+02:00"), ("2024:06:24 10:15:30", b"+02:00"))):
        exif = piexif.dump({"Exif": {piexif.ExifIFD.DateTimeOriginal: when.encode(),
                                     piexif.ExifIFD.OffsetTimeOriginal: offset}})
        Image.new("RGB", (8, 8)).save(survey / "images" / f"IMG_{i}.JPG", exif=exif)
    got = ft.survey_flight_time(survey, out)
    assert got == {"start": "2024-06-24T08:12:00Z", "end": "2024-06-24T08:15:30Z", "source": "exif",
                   "detail": "photos' EXIF DateTimeOriginal"}
    # a DJI MRK's exposures (GPS time) come before the camera's clock
    from tests.gnss.test_dji_mrk import _synthetic

    (survey / "flights" / "100_0001").mkdir(parents=True)
    (survey / "flights" / "100_0001" / "100_0001_Timestamp.MRK").write_text(_synthetic(5, 200000.0, week=2320))
    got = ft.survey_flight_time(survey, out)
    assert got["source"] == "dji-mrk" and got["start"] == _utc_of_gps(2320, 200000.0)
    assert got["end"] == _utc_of_gps(2320, 200010.0)
    # the GNSS step's solution comes first (camera triggers, GPS seconds)
    (out / "ppk").mkdir(parents=True)
    t0 = 2320 * 604800 + 300000.0
    (out / "ppk" / "summary.json").write_text(json.dumps({"time_span": ft.gnss_time_span([t0 - 60, t0 + 400],
                                                                                         [t0, t0 + 275])}))
    got = ft.survey_flight_time(survey, out)
    assert got["source"] == "gnss" and got["start"] == _utc_of_gps(2320, 300000.0)
    assert got["end"] == _utc_of_gps(2320, 300275.0) and "camera triggers" in got["detail"]
    # without triggers, the solution's span
    assert ft.gnss_time_span([t0, t0 + 10.0], [])["of"] == "solution epochs"
