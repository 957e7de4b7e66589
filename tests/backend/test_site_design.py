"""A site's design surface on the platform (real PostgreSQL): upload checked by the core's reader (422 naming
the problem), area and tolerance, permissions (viewer reads, editor sets, another organisation sees
nothing), the worker's design step fed from it (the file fetched into the run folder, reuse while the design
is unchanged, recomputed when it changes), and the design progress over two surveys against the analytic
volumes of the scene (tests/design/scenes.py: valley design, cone cut, conical pit fill), the change between the
surveys surface against surface; and the site's calibration (set, checked, applied by the datum step of surveys
without their own: the section at the end)."""

from __future__ import annotations

import io
import math
from datetime import datetime, timezone

import numpy as np
import pytest
from sqlalchemy import select, update

from tests.design import scenes

from .platform_helpers import POINTS_CSV, Api, add_user, upload_bytes

AREA_GJ = {"type": "Polygon", "coordinates": [[[float(x), float(y)] for x, y in scenes.AREA]
                                              + [[float(scenes.AREA[0][0]), float(scenes.AREA[0][1])]]]}


@pytest.fixture(scope="module")
def world(pg_platform, tmp_path_factory):
    p = pg_platform
    owner_id, org = add_user(p, "designer@example.com")
    viewer_id, _ = add_user(p, "watcher@example.com", org)
    add_user(p, "stranger@example.com")
    owner, viewer, stranger = (Api(p, e) for e in ("designer@example.com", "watcher@example.com",
                                                    "stranger@example.com"))
    owner.platform = p
    r = owner.post("/api/v1/sites", json={"name": "Valley works", "crs": f"EPSG:{scenes.EPSG}"})
    assert r.status_code == 201, r.text
    site = r.json()["id"]
    assert owner.c.put(f"/api/v1/sites/{site}/members/{viewer_id}", json={"role": "viewer"},
                       headers={"X-CSRF-Token": owner.csrf}).status_code == 200
    files = tmp_path_factory.mktemp("design-files")
    xml = scenes.write_design_landxml(files / "fg.xml").read_bytes()
    return {"p": p, "owner": owner, "viewer": viewer, "stranger": stranger, "site": site, "xml": xml,
            "files": files}


def put_design(api: Api, site: str, data: bytes, filename: str, **params):
    return api.put(f"/api/v1/sites/{site}/design/file", content=data, params={"filename": filename, **params},
                   headers={"Content-Type": "application/octet-stream"})


def test_design_upload_checked_area_tolerance_and_permissions(world):
    owner, viewer, stranger, site = world["owner"], world["viewer"], world["stranger"], world["site"]
    assert owner.get(f"/api/v1/sites/{site}/design").status_code == 404
    # refused by the reader, nothing stored: the file named with its problem
    bad = world["xml"].replace(b"<F>100 101 104</F>", b"<F>100 101 999</F>")
    r = put_design(owner, site, bad, "broken.xml")
    assert r.status_code == 422 and r.json()["detail"].startswith("broken.xml: ") and "999" in r.json()["detail"], r.text
    r = put_design(owner, site, b"just some notes\n", "notes.txt")
    assert r.status_code == 422 and "unknown design surface format" in r.json()["detail"]
    assert owner.get(f"/api/v1/sites/{site}/design").status_code == 404
    # a viewer cannot set it, another organisation cannot see the site
    assert put_design(viewer, site, world["xml"], "fg.xml").status_code == 403
    assert put_design(stranger, site, world["xml"], "fg.xml").status_code == 404

    r = put_design(owner, site, world["xml"], "fg.xml")
    assert r.status_code == 200, r.text
    d = r.json()
    assert (d["format"], d["filename"], d["size"], d["tolerance_m"]) == ("landxml", "fg.xml", len(world["xml"]), 0.05)
    assert d["described"]["n_triangles"] == 4 and "path" not in d["described"]
    x0, y0, x1, y1 = d["described"]["extent"]          # the TIN reaches 1 m beyond the 40 m scene
    assert abs(x0 - (scenes.E0 - 1)) < 1e-3 and abs(y1 - (scenes.N0 + scenes.SIZE_M + 1)) < 1e-3
    assert d["area"] is None
    # viewer reads, stranger does not
    assert viewer.get(f"/api/v1/sites/{site}/design").json()["sha256"] == d["sha256"]
    assert stranger.get(f"/api/v1/sites/{site}/design").status_code == 404
    assert stranger.get(f"/api/v1/sites/{site}/design-progress").status_code == 404
    f = viewer.get(f"/api/v1/sites/{site}/design/file")
    assert f.status_code == 200 and f.content == world["xml"]

    # the area: checked, outside the design refused, then set with a tolerance (optimistic concurrency)
    far = {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 10], [0, 0]]]}
    r = owner.patch(f"/api/v1/sites/{site}/design", json={"area": far})
    assert r.status_code == 422 and "outside the design surface" in r.json()["detail"]
    r = owner.patch(f"/api/v1/sites/{site}/design", json={"area": {"type": "Polygon", "coordinates": [[[0, 0], [1, 1]]]}})
    assert r.status_code == 422
    assert viewer.patch(f"/api/v1/sites/{site}/design", json={"tolerance_m": 0.1}).status_code == 403
    etag = owner.get(f"/api/v1/sites/{site}/design").headers["etag"]
    r = owner.patch(f"/api/v1/sites/{site}/design", json={"area": AREA_GJ, "tolerance_m": 0.05},
                    headers={"If-Match": etag})
    assert r.status_code == 200, r.text
    assert abs(r.json()["area_m2"] - scenes.area_m2()) < 1e-3
    assert owner.patch(f"/api/v1/sites/{site}/design", json={"tolerance_m": 0.04},
                       headers={"If-Match": etag}).status_code == 412
    # an unknown LandXML surface name: refused by the reader, listing what is there
    r = owner.patch(f"/api/v1/sites/{site}/design", json={"surface_name": "EG"})
    assert r.status_code == 422 and "FG design" in r.json()["detail"]


# ------------------------------------------------------------------------------------ the worker's step


def _make_survey(world, name: str, flown: datetime) -> str:
    owner, site = world["owner"], world["site"]
    r = owner.post(f"/api/v1/sites/{site}/surveys", json={"name": name, "flown_at": flown.isoformat()})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    assert upload_bytes(owner, sid, "points.csv", POINTS_CSV).status_code == 200
    return sid


def _design_run(world, survey_id: str, dsm_path, settings: dict | None = None) -> str:
    """A run whose earlier steps are recorded as done (the dense step's DSM is the scene's), its design step
    queued: what the worker finds when the dense step of a real run has finished."""
    from backend.models import RunOutput, RunStep
    from backend.storage import storage_for

    p = world["p"]
    r = world["owner"].post(f"/api/v1/surveys/{survey_id}/runs", json={"steps": ["design"],
                                                                       "settings": settings or {}})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    sha, size = storage_for(p.settings).put_blob(dsm_path)
    with p.db().session() as s:
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name != "design")
                  .values(state="succeeded"))
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == "design").values(state="queued"))
        s.add(RunOutput(run_id=run_id, step_name="dense", path="dense/dsm.tif", sha256=sha, size=size))
    return run_id


@pytest.fixture
def worker_here(world, monkeypatch):
    """worker.tasks.execute_step in this process on the test platform (its messages to the broker kept)."""
    import worker.tasks as tasks
    from backend.storage import storage_for

    p = world["p"]
    monkeypatch.setattr(tasks, "_env", lambda: (p.settings, p.db(), storage_for(p.settings)))
    sent = []
    monkeypatch.setattr(tasks, "_send", lambda settings, db, storage, msgs: sent.extend(msgs))
    return tasks


def _step(world, run_id: str) -> dict:
    r = world["owner"].get(f"/api/v1/runs/{run_id}")
    assert r.status_code == 200
    return {s["name"]: s for s in r.json()["step_details"]}["design"]


def test_design_step_and_progress_over_two_surveys(world, worker_here, tmp_path):
    import rasterio

    from backend.models import RunOutput

    owner, viewer, site = world["owner"], world["viewer"], world["site"]
    have = owner.get(f"/api/v1/sites/{site}/design")
    if have.status_code == 404 or have.json()["area"] is None:   # run alone: the first test's state
        assert put_design(owner, site, world["xml"], "fg.xml").status_code == 200
        assert owner.patch(f"/api/v1/sites/{site}/design", json={"area": AREA_GJ, "tolerance_m": 0.05}).status_code == 200
    # survey 1: cone 1 m high (37.70 m3 cut), pit 0.8 m (20.94 m3 fill); survey 2: the cone cut down to 0.4 m
    early = scenes.write_scene(tmp_path / "s1")
    low_bump = {**scenes.BUMP, "h": 0.4}
    later = scenes.write_scene(tmp_path / "s2", bump=low_bump)
    s1 = _make_survey(world, "May flight", datetime(2026, 5, 4, 9, tzinfo=timezone.utc))
    s2 = _make_survey(world, "June flight", datetime(2026, 6, 8, 9, tzinfo=timezone.utc))
    run2 = _design_run(world, s2, later["dsm"])
    run1 = _design_run(world, s1, early["dsm"])
    assert worker_here.execute_step(run1, "design") == "done"
    assert worker_here.execute_step(run2, "design") == "done"
    st = _step(world, run1)
    assert st["state"] == "succeeded", st
    # the design file was fetched into the run folder under its uploaded name
    run_dir = world["p"].settings.resolved_work_dir() / "runs" / run1
    assert (run_dir / "site" / "design" / "fg.xml").read_bytes() == world["xml"]
    with world["p"].db().session(read_only=True) as s:
        outs = {o.path for o in s.scalars(select(RunOutput).where(RunOutput.run_id == run1,
                                                                 RunOutput.step_name == "design"))}
    assert {"design/difference.tif", "design/classes.tif", "design/cut_fill.json"} <= outs
    with rasterio.open(run_dir / "out" / "design" / "classes.tif") as ds:   # a COG with its colour table
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG" and ds.colormap(1)[1][:3] == (214, 39, 40)

    # the difference is a map layer: listed with the run's tiles and rendered as a web map tile
    layers = {x["name"]: x for x in viewer.get(f"/api/v1/runs/{run1}/tiles").json()["layers"]}
    diff = next(x for x in layers.values() if x["source"] == "design/difference.tif")
    assert diff["style"] == "difference"
    lon0, lat0, lon1, lat1 = diff["lonlat_bounds"]
    z = 18
    n = 2 ** z
    tx = int((lon0 + lon1) / 2 / 360 * n + n / 2)
    lat = math.radians((lat0 + lat1) / 2)
    ty = int((1 - math.log(math.tan(lat) + 1 / math.cos(lat)) / math.pi) / 2 * n)
    png = viewer.get("/api/v1" + diff["tiles"].split("/api/v1", 1)[1].format(z=z, x=tx, y=ty))
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    alpha = np.asarray(Image.open(io.BytesIO(png.content)).convert("RGBA"))[..., 3]
    # a z18 tile is about 110 m across here: the 889 m2 design area is drawn (at most 7.5 % of the tile if the
    # whole area falls in it), the rest is transparent
    assert 0.01 < (alpha > 0).mean() < 0.076

    # the change between the surveys is computed by a worker, not in the request: queued, 202 with the totals' figures
    prog = viewer.get(f"/api/v1/sites/{site}/design-progress")
    assert prog.status_code == 202, prog.text
    pend = prog.json()["surveys"][1]["since_previous"]
    assert pend["surfaces_state"] == "queued" and pend["method"] == "totals" and prog.json()["changes_pending"]
    from backend.models import DesignChangeJob

    with world["p"].db().session(read_only=True) as s:
        jobs = list(s.scalars(select(DesignChangeJob).where(DesignChangeJob.site_id == site)))
    assert len(jobs) == 1 and jobs[0].state == "queued" and jobs[0].later_run_id == run2
    assert viewer.get(f"/api/v1/sites/{site}/design-progress").status_code == 202   # asked again: no second job
    with world["p"].db().session(read_only=True) as s:
        assert len(list(s.scalars(select(DesignChangeJob).where(DesignChangeJob.site_id == site)))) == 1
    assert worker_here.execute_design_change(jobs[0].id) == "done"
    assert worker_here.execute_design_change(jobs[0].id) == "skipped: not queued"   # a duplicate message
    prog = viewer.get(f"/api/v1/sites/{site}/design-progress")
    assert prog.status_code == 200, prog.text
    doc = prog.json()
    assert doc["changes_pending"] is False
    assert [e["survey_name"] for e in doc["surveys"]] == ["May flight", "June flight"] and doc["not_compared"] == []
    may, june = doc["surveys"]
    cut1, cut2, fill = scenes.cut_volume(), scenes.cone_volume(low_bump["radius"], low_bump["h"]), scenes.fill_volume()
    assert abs(may["cut_m3"] - cut1) < 0.001 * cut1 and abs(june["cut_m3"] - cut2) < 0.001 * cut2
    assert abs(may["fill_m3"] - fill) < 0.001 * fill and abs(june["fill_m3"] - fill) < 0.001 * fill
    assert abs(may["net_m3"] - (cut1 - fill)) < 0.01 and may["run_id"] == run1 and june["run_id"] == run2
    for e in (may, june):
        assert set(e["sigma_m3"]) == {"cut_m3", "fill_m3", "net_m3"} and 0 < e["sigma_m3"]["net_m3"] < 20
        assert e["tolerance_m"] == 0.05 and abs(e["area_m2"] - scenes.area_m2()) < 0.01
    A = scenes.area_m2()
    on1 = 1 - scenes.off_grade_area(0.05) / A
    on2 = 1 - (math.pi * (low_bump["radius"] * (1 - 0.05 / low_bump["h"])) ** 2
               + math.pi * (scenes.PIT["radius"] * (1 - 0.05 / scenes.PIT["h"])) ** 2) / A
    assert abs(may["on_grade_share"] - on1) < 0.005 and abs(june["on_grade_share"] - on2) < 0.005
    assert june["on_grade_share"] > may["on_grade_share"]
    # the change since the previous survey: the cone cut down, the pit unchanged, what remains
    ch = june["since_previous"]
    assert may["since_previous"] is None and ch["previous_survey_name"] == "May flight" and ch["days"] == 35.0
    assert abs(ch["cut_moved_m3"] - (cut1 - cut2)) < 0.002 * (cut1 - cut2) and abs(ch["fill_placed_m3"]) < 0.001 * fill
    assert abs(ch["remaining_cut_m3"] - cut2) < 0.001 * cut2 and 0 < ch["sigma_m3"]["cut_moved_m3"] < 20
    # surface against surface (the two runs' difference rasters, cell by cell), not from the two totals
    assert ch["method"] == "surfaces" and ch["cut_below_design_m3"] < 0.01 and ch["notes"] == [], ch
    # both surveys tied to the same control point (POINTS_CSV: one, 2 cm): their bias is common, clipped to the 2 cm
    # vertical RMSE each states, and cancels in the change
    model = ch["uncertainty"]["model"]
    assert ch["surfaces_state"] == "succeeded" and model["common_bias_m"] == 0.02 and model["relative_bias_m"] == 0
    assert "same 1 control point" in model["common_bias_source"], model
    assert abs(ch["area_m2"] - scenes.area_m2()) < 0.01 * scenes.area_m2()

    # an identical run reuses the result; a new tolerance computes it again (and keeps the design key)
    again = _design_run(world, s2, later["dsm"])
    assert worker_here.execute_step(again, "design") == "reused"
    assert owner.patch(f"/api/v1/sites/{site}/design", json={"tolerance_m": 0.1}).status_code == 200
    tol = _design_run(world, s2, later["dsm"])
    assert worker_here.execute_step(tol, "design") == "done"
    june2 = viewer.get(f"/api/v1/sites/{site}/design-progress").json()["surveys"][1]
    assert june2["run_id"] == tol and june2["tolerance_m"] == 0.1 and june2["on_grade_share"] > june["on_grade_share"]
    # a new area: earlier results are of another design; the progress says which surveys to process again
    smaller = {"type": "Polygon", "coordinates": [[[scenes.XC - 10, scenes.YC - 10], [scenes.XC + 10, scenes.YC - 10],
                                                  [scenes.XC + 10, scenes.YC + 10], [scenes.XC - 10, scenes.YC - 10]]]}
    assert owner.patch(f"/api/v1/sites/{site}/design", json={"area": smaller}).status_code == 200
    doc = viewer.get(f"/api/v1/sites/{site}/design-progress").json()
    assert doc["surveys"] == [] and {m["survey_name"] for m in doc["not_compared"]} == {"May flight", "June flight"}
    assert all("another design" in m["reason"] for m in doc["not_compared"])


def test_design_without_area_is_skipped_not_failed(tmp_path):
    """A design uploaded before its area is drawn: the step says so and the run goes on."""
    from georef_core.steps.contract import Workspace
    from georef_core.steps.design import step_entry

    ws = Workspace(tmp_path / "survey", tmp_path / "out")
    doc = step_entry(ws, {}, None, {"crs": f"EPSG:{scenes.EPSG}", "design": {"path": str(tmp_path / "fg.xml"),
                                                                           "polygon": None, "tolerance_m": 0.05}})
    assert doc["skipped"] is True and "no area" in doc["reason"]
    assert (tmp_path / "out" / "design" / "cut_fill.json").exists()


# ---------------------------------------------------------------------------------------------------------------
# The site's calibration (services/calibrations.py): set from a calibration document or control pairs (solved in the
# site CRS and datum), checked at once (422 naming the problem), permissions (viewer reads, admin sets, another
# organisation sees nothing); the worker's datum step of a survey without a calibration of its own applies the
# site's (its summary says which and from where), a survey with its own file keeps it, and a new site calibration
# makes the step compute again. The simulated site with a known local grid of tests/datums/test_calibration_step.py.

from georef_core.datums.site_calibration import ControlPair, solve_calibration  # noqa: E402
from georef_core.dense.cog_writer import HEIGHT_TAGS, write_cog  # noqa: E402
from rasterio.transform import from_origin  # noqa: E402
from tests.datums.test_calibration_step import CORNERS, _dsm_height, _truth  # noqa: E402
from tests.datums.test_calibration_step import E0 as CAL_E0, N0 as CAL_N0  # noqa: E402

CAL_CRS = "EPSG:32631"


def _pairs(dh_m: float = 0.0) -> list[tuple]:
    out = []
    for name, x, y in CORNERS:
        E, N = CAL_E0 + x, CAL_N0 + y
        h = float(_dsm_height(E, N))
        e, n, H = _truth(E, N, h)
        out.append((name, round(E, 4), round(N, 4), round(h, 4), round(float(e), 4), round(float(n), 4),
                    round(float(H) + dh_m, 4)))
    return out


def _csv(dh_m: float = 0.0) -> str:
    return "name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m\n" + "".join(
        ",".join(str(v) for v in r) + "\n" for r in _pairs(dh_m))


@pytest.fixture(scope="module")
def cal_world(world, tmp_path_factory):
    """A second site of the same owner, in the calibration scene's CRS, the viewer a member; a plane DSM."""
    owner = world["owner"]
    r = owner.post("/api/v1/sites", json={"name": "Local grid works", "crs": CAL_CRS})
    assert r.status_code == 201, r.text
    site = r.json()["id"]
    with world["p"].db().session(read_only=True) as s:
        from backend.models import User

        viewer_id = s.scalar(select(User.id).where(User.email == "watcher@example.com"))
    assert owner.c.put(f"/api/v1/sites/{site}/members/{viewer_id}", json={"role": "viewer"},
                       headers={"X-CSRF-Token": owner.csrf}).status_code == 200
    d = tmp_path_factory.mktemp("cal-dsm")
    yy, xx = np.mgrid[0:50, 0:50]
    z = _dsm_height(CAL_E0 + (xx + 0.5) * 2.0, CAL_N0 + 100 - (yy + 0.5) * 2.0).astype(np.float32)
    dsm = write_cog(d / "dsm.tif", z, from_origin(CAL_E0, CAL_N0 + 100, 2.0, 2.0), 32631, nodata=-9999.0,
                    tags=HEIGHT_TAGS)
    return {**world, "site": site, "dsm": dsm}


def test_site_calibration_set_checked_and_permissions(cal_world):
    world = cal_world
    owner, viewer, stranger, site = world["owner"], world["viewer"], world["stranger"], world["site"]
    url = f"/api/v1/sites/{site}/calibration"
    assert viewer.get(url).status_code == 404          # none yet
    assert viewer.put(url, json={"pairs_csv": _csv()}).status_code == 403
    assert stranger.put(url, json={"pairs_csv": _csv()}).status_code == 404
    # control pairs solved here in the site CRS and datum (ellipsoidal)
    r = owner.put(url, json={"pairs_csv": _csv(), "source_name": "site pairs.csv"})
    assert r.status_code == 200, r.text
    c = r.json()
    assert c["crs"] == CAL_CRS and c["height_datum"] == "ellipsoidal" and c["source_name"] == "site pairs.csv"
    assert abs(c["summary"]["horizontal"]["scale_ppm"] - 25.0) < 2.0 and c["version"] == 1
    assert [x["name"] for x in c["summary"]["residuals"]] == [n for n, _, _ in CORNERS]
    assert c["summary"]["statistics"]["rms_vertical_m"] < 1e-3
    got = viewer.get(url)
    assert got.status_code == 200 and got.json()["document"] == c["document"] and stranger.get(url).status_code == 404
    # the same as a document (what georef datum calibrate writes): the same parameters
    cal = solve_calibration([ControlPair(n, (E, N, h), (e, nn, H), "hv") for n, E, N, h, e, nn, H in _pairs()],
                            crs=CAL_CRS, height_datum="ellipsoidal", name="from the office")
    r = owner.put(url, json={"document": cal.to_dict()}, headers={"If-Match": got.headers["ETag"]})
    assert r.status_code == 200 and r.json()["name"] == "from the office" and r.json()["version"] == 2
    assert math.isclose(r.json()["summary"]["horizontal"]["scale"], c["summary"]["horizontal"]["scale"], rel_tol=1e-12)
    # refused with the reason, nothing changed
    bad = owner.put(url, json={"pairs_csv": _csv().replace("K3,", "K3,north,", 1)})
    assert bad.status_code == 422 and "line 4" in bad.json()["detail"], bad.text
    other = solve_calibration([ControlPair(n, (E, N, h), (e, nn, H), "hv") for n, E, N, h, e, nn, H in _pairs()],
                              crs="EPSG:32632", height_datum="ellipsoidal")
    bad = owner.put(url, json={"document": other.to_dict()})
    assert bad.status_code == 422 and "EPSG:32632" in bad.json()["detail"] and "site CRS" in bad.json()["detail"]
    bad = owner.put(url, json={"document": {"format": "georef-site-calibration", "version": 2}})
    assert bad.status_code == 422 and "version 2" in bad.json()["detail"]
    assert owner.put(url, json={}).status_code == 422
    assert viewer.get(url).json()["version"] == 2
    assert viewer.delete(url).status_code == 403


def _cal_survey(world, name: str, own_pairs: str | None = None) -> str:
    owner = world["owner"]
    r = owner.post(f"/api/v1/sites/{world['site']}/surveys",
                   json={"name": name, "flown_at": datetime(2026, 5, 4, 9, tzinfo=timezone.utc).isoformat()})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    assert upload_bytes(owner, sid, "points.csv", POINTS_CSV).status_code == 200
    if own_pairs:
        assert upload_bytes(owner, sid, "my pairs.csv", own_pairs.encode()).status_code == 200
    return sid


def _datum_run(world, survey_id: str) -> str:
    from backend.models import RunOutput, RunStep
    from backend.storage import storage_for

    p = world["p"]
    r = world["owner"].post(f"/api/v1/surveys/{survey_id}/runs", json={"steps": ["datum"]})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    sha, size = storage_for(p.settings).put_blob(world["dsm"])
    with p.db().session() as s:
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name != "datum").values(state="succeeded"))
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == "datum").values(state="queued"))
        s.add(RunOutput(run_id=run_id, step_name="dense", path="dense/dsm.tif", sha256=sha, size=size))
    return run_id


def _datum_summary(world, run_id: str) -> dict:
    steps = {s["name"]: s for s in world["owner"].get(f"/api/v1/runs/{run_id}").json()["step_details"]}
    assert steps["datum"]["state"] == "succeeded", steps["datum"]
    return steps["datum"]["summary"]


def test_datum_step_applies_the_sites_calibration_unless_the_survey_has_its_own(cal_world, worker_here):
    world = cal_world
    owner, site = world["owner"], world["site"]
    url = f"/api/v1/sites/{site}/calibration"
    if owner.get(url).status_code == 404:    # run alone
        assert owner.put(url, json={"pairs_csv": _csv()}).status_code == 200
    site_version = owner.get(url).json()["version"]
    plain = _cal_survey(world, "May flight")
    run = _datum_run(world, plain)
    assert worker_here.execute_step(run, "datum") == "done"
    cal = _datum_summary(world, run)["calibration"]
    assert cal["origin"] == "site" and f"version {site_version}" in cal["source"], cal
    assert abs(cal["horizontal"]["scale_ppm"] - 25.0) < 2.0 and "site_calibration_not_used" not in cal
    # a survey with its own pairs (its local heights 3 cm higher) keeps them; the summary says the site's was not used
    own = _cal_survey(world, "June flight", own_pairs=_csv(dh_m=0.03))
    run2 = _datum_run(world, own)
    assert worker_here.execute_step(run2, "datum") == "done"
    cal2 = _datum_summary(world, run2)["calibration"]
    assert cal2["origin"] == "survey file" and cal2["source"] == "calibration/pairs.csv"
    assert abs(cal2["vertical"]["constant_m"] - cal["vertical"]["constant_m"] - 0.03) < 1e-3
    assert f"version {site_version}" in cal2["site_calibration_not_used"]
    # the same site calibration: reused; a new one: the step computes again with it
    assert worker_here.execute_step(_datum_run(world, plain), "datum") == "reused"
    assert owner.put(url, json={"pairs_csv": _csv(dh_m=-0.05), "source_name": "resurvey.csv"}).status_code == 200
    run3 = _datum_run(world, plain)
    assert worker_here.execute_step(run3, "datum") == "done"
    cal3 = _datum_summary(world, run3)["calibration"]
    assert cal3["origin"] == "site" and "resurvey.csv" in cal3["source"]
    assert abs(cal3["vertical"]["constant_m"] - cal["vertical"]["constant_m"] + 0.05) < 1e-3
