"""The change between two surveys of a site's design is a queued job computed by a worker and stored (table
design_changes, services/design_changes.py), on both platform shapes (PostgreSQL and the embedded SQLite):
design-progress answers 202 with the totals' figures while it is queued, never computes a raster itself, creates
one job per pair however often it is asked, serves the stored result once the worker (worker.tasks.
execute_design_change, run here) has computed it; a job whose message was lost is queued again; a raster that
cannot be read fails the job with the run named, and the change falls back to the totals with the reason.

The runs' design results are recorded directly (the valley scene's difference rasters of tests/design/change_mc.py,
noise-free, June on a grid shifted by a fraction of a cell): the design step itself is tested in test_site_design."""

from __future__ import annotations

import json
from datetime import datetime, timedelta, timezone

import pytest
from sqlalchemy import select, update

from tests.design import change_mc, scenes

from .platform_helpers import Api, add_user, upload_bytes

CONTROL_CSV = ("name,easting_m,northing_m,ellipsoidal_height_m,role\n" + "".join(
    f"C{i},{scenes.E0 + 5 + 10 * i},{scenes.N0 + 5},100.0,control\n" for i in range(4)) +
    f"K1,{scenes.E0 + 20},{scenes.N0 + 30},100.0,check\n").encode()


@pytest.fixture(scope="module")
def site(platform, tmp_path_factory):
    p = platform
    add_user(p, "changes@example.com")
    api = Api(p, "changes@example.com")
    r = api.post("/api/v1/sites", json={"name": "Valley changes", "crs": f"EPSG:{scenes.EPSG}"})
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    files = tmp_path_factory.mktemp("changes")
    xml = scenes.write_design_landxml(files / "fg.xml").read_bytes()
    assert api.put(f"/api/v1/sites/{sid}/design/file", content=xml, params={"filename": "fg.xml"},
                   headers={"Content-Type": "application/octet-stream"}).status_code == 200
    r = api.patch(f"/api/v1/sites/{sid}/design", json={"area": change_mc.area_geometry()})
    assert r.status_code == 200, r.text
    return {"p": p, "api": api, "site": sid, "key": r.json()["key"], "files": files}


@pytest.fixture
def worker(site, monkeypatch):
    import worker.tasks as tasks
    from backend.storage import storage_for

    p = site["p"]
    monkeypatch.setattr(tasks, "_env", lambda: (p.settings, p.db(), storage_for(p.settings)))
    return tasks


def _recorded_run(site, name: str, flown: datetime, difference, accuracy: dict, control: bool = True,
                  summaries: dict | None = None) -> str:
    """A survey (with CONTROL_CSV unless not ``control``) and a succeeded run whose design step recorded
    ``difference`` and a cut_fill.json stating ``accuracy``; ``summaries``: other steps' summaries, by step."""
    from backend.models import Run, RunOutput, RunStep
    from backend.storage import storage_for

    api, p = site["api"], site["p"]
    r = api.post(f"/api/v1/sites/{site['site']}/surveys", json={"name": name, "flown_at": flown.isoformat()})
    assert r.status_code == 201, r.text
    survey = r.json()["id"]
    if control:
        assert upload_bytes(api, survey, "points.csv", CONTROL_CSV).status_code == 200
    else:   # a run needs a file: the survey's metadata, no control points
        meta = json.dumps({"project_crs": f"EPSG:{scenes.EPSG}", "points_crs": f"EPSG:{scenes.EPSG}"}).encode()
        assert upload_bytes(api, survey, "survey.json", meta).status_code == 200
    r = api.post(f"/api/v1/surveys/{survey}/runs", json={"steps": ["design"]})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    storage = storage_for(p.settings)
    cut_fill = site["files"] / f"{run_id}.json"
    cut_fill.write_text(json.dumps({"significance": accuracy}))
    summary = {"design_key": site["key"], "cut_m3": 1.0, "fill_m3": 1.0, "net_m3": 0.0, "surface": "dsm",
               "sigma_m3": {"cut_m3": 1.0, "fill_m3": 1.0, "net_m3": 1.0}}
    with p.db().session() as s:
        s.execute(update(RunStep).where(RunStep.run_id == run_id).values(state="succeeded"))
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == "design").values(summary=summary))
        s.execute(update(Run).where(Run.id == run_id).values(state="succeeded"))
        for step, summary_of_step in (summaries or {}).items():
            row = s.scalar(select(RunStep).where(RunStep.run_id == run_id, RunStep.name == step))
            if row is None:
                s.add(RunStep(run_id=run_id, name=step, position=-1, state="succeeded", summary=summary_of_step))
            else:
                row.summary = summary_of_step
        for path, f in (("design/difference.tif", difference), ("design/cut_fill.json", cut_fill)):
            sha, size = storage.put_blob(f)
            s.add(RunOutput(run_id=run_id, step_name="design", path=path, sha256=sha, size=size))
    return run_id


def _jobs(site) -> list:
    from backend.models import DesignChangeJob

    with site["p"].db().session(read_only=True) as s:
        return list(s.scalars(select(DesignChangeJob).where(DesignChangeJob.site_id == site["site"])
                              .order_by(DesignChangeJob.queued_at)))


def test_change_is_queued_computed_by_a_worker_and_served_stored(site, worker, tmp_path):
    api, sid = site["api"], site["site"]
    sc = change_mc.one_seed(3, tmp_path, noise_m=0.0, common_bias_m=0.0, own_bias_m=0.0)
    acc = {"dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02, "correlation_length_m": 1.0}
    may = _recorded_run(site, "May", datetime(2026, 5, 4, tzinfo=timezone.utc), sc["may"], acc)
    june = _recorded_run(site, "June", datetime(2026, 6, 8, tzinfo=timezone.utc), sc["june"], acc)

    r = api.get(f"/api/v1/sites/{sid}/design-progress")
    assert r.status_code == 202 and r.headers["Retry-After"], r.text
    ch = r.json()["surveys"][1]["since_previous"]
    assert ch["surfaces_state"] == "queued" and ch["method"] == "totals" and "being computed" in ch["notes"][0]
    assert api.get(f"/api/v1/sites/{sid}/design-progress").status_code == 202
    jobs = _jobs(site)
    assert len(jobs) == 1 and (jobs[0].earlier_run_id, jobs[0].later_run_id) == (may, june)

    # a message lost (the job queued for longer than requeue_queued_after_s): the next request queues it again
    from backend.models import DesignChangeJob

    old = datetime.now(timezone.utc) - timedelta(seconds=site["p"].settings.requeue_queued_after_s + 60)
    with site["p"].db().session() as s:
        s.execute(update(DesignChangeJob).where(DesignChangeJob.id == jobs[0].id).values(queued_at=old))
    assert api.get(f"/api/v1/sites/{sid}/design-progress").status_code == 202
    again = _jobs(site)
    assert len(again) == 1 and again[0].queued_at > old + timedelta(seconds=30)

    assert worker.execute_design_change(jobs[0].id) == "done"
    r = api.get(f"/api/v1/sites/{sid}/design-progress")
    assert r.status_code == 200 and r.json()["changes_pending"] is False, r.text
    ch = r.json()["surveys"][1]["since_previous"]
    truth = change_mc.truth()
    assert ch["method"] == "surfaces" and ch["surfaces_state"] == "succeeded"
    for k in ("cut_moved_m3", "fill_placed_m3"):
        assert abs(ch[k] - truth[k]) < 0.01 * truth[k], (k, ch[k], truth[k])
    # the same four control points under both surveys: 2 cm / sqrt(4) of their 2 cm bias is common and cancels
    model = ch["uncertainty"]["model"]
    assert model["common_bias_m"] == pytest.approx(0.01) and "same 4 control point" in model["common_bias_source"]
    assert model["relative_bias_m"] == pytest.approx((2 * 0.02 ** 2 - 2 * 0.01 ** 2) ** 0.5, rel=1e-4)
    net = ch["uncertainty"]["net_change_m3"]["components_m3"]
    assert net["vertical_bias_m3"] == pytest.approx(model["relative_bias_m"] * ch["area_m2"], rel=1e-3)
    assert 0 < net["resampling_m3"] < net["dsm_noise_later_m3"]   # June's grid is shifted: resampled

    # a raster that cannot be read: the job fails naming the run, the change stays the totals' with the reason
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not a tiff")
    _recorded_run(site, "July", datetime(2026, 7, 6, tzinfo=timezone.utc), bad, acc)
    assert api.get(f"/api/v1/sites/{sid}/design-progress").status_code == 202
    job = _jobs(site)[-1]
    assert worker.execute_design_change(job.id) == "failed"
    r = api.get(f"/api/v1/sites/{sid}/design-progress")
    assert r.status_code == 200, r.text
    july = r.json()["surveys"][2]["since_previous"]
    assert july["surfaces_state"] == "failed" and july["method"] == "totals"
    assert any("of 'July': design/difference.tif: not a readable GeoTIFF" in n for n in july["notes"]), july["notes"]


def test_a_finished_run_queues_the_sites_changes_ahead_of_the_first_view(site, tmp_path):
    """When a run ends (services/changes.on_run_finished, as the worker calls it), the changes design-progress will
    show are queued at once, so that the page usually finds them done; once, however often it is called."""
    from backend.services.changes import on_run_finished
    from backend.storage import storage_for

    sc = change_mc.one_seed(5, tmp_path, noise_m=0.0, common_bias_m=0.0, own_bias_m=0.0)
    acc = {"dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02, "correlation_length_m": 1.0}
    _recorded_run(site, "August", datetime(2026, 8, 3, tzinfo=timezone.utc), sc["may"], acc)
    sep = _recorded_run(site, "September", datetime(2026, 9, 7, tzinfo=timezone.utc), sc["june"], acc)
    db, storage = site["p"].db(), storage_for(site["p"].settings)
    msgs = [m for m in on_run_finished(db, storage, sep) if m[0] == "design-change"]
    job = next(j for j in _jobs(site) if j.later_run_id == sep)
    assert job.state == "queued" and ("design-change", job.id) in msgs
    assert [m for m in on_run_finished(db, storage, sep) if m[0] == "design-change"] == []


def test_a_running_job_is_queued_again_on_a_stopped_heartbeat_not_on_its_age(site, worker, tmp_path, monkeypatch):
    """A worker that dies mid-job (its heartbeat stops) loses the job after step_lease_s, to the next request or to
    the reaper, however recently it started; a job running for hours whose worker beats is left alone; the dead
    attempts' late results are refused (fenced by the attempt number)."""
    import time

    from backend.models import DesignChangeJob
    from backend.services import design_changes

    p, api, sid = site["p"], site["api"], site["site"]
    lease_s = 2.0   # beats every 0.5 s (lease / 4), stale after 2 s
    monkeypatch.setattr(p.settings, "step_lease_s", lease_s)
    sc = change_mc.one_seed(7, tmp_path, noise_m=0.0, common_bias_m=0.0, own_bias_m=0.0)
    acc = {"dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02, "correlation_length_m": 1.0}
    _recorded_run(site, "October", datetime(2026, 10, 5, tzinfo=timezone.utc), sc["may"], acc)
    nov = _recorded_run(site, "November", datetime(2026, 11, 2, tzinfo=timezone.utc), sc["june"], acc)
    assert api.get(f"/api/v1/sites/{sid}/design-progress").status_code == 202
    job_id = next(j.id for j in _jobs(site) if j.later_run_id == nov)

    def row():
        with p.db().session(read_only=True) as s:
            return s.get(DesignChangeJob, job_id)

    def set_times(**values):
        with p.db().session() as s:
            s.execute(update(DesignChangeJob).where(DesignChangeJob.id == job_id).values(**values))

    def ago(seconds):
        return datetime.now(timezone.utc) - timedelta(seconds=seconds)

    # a worker dies 10 s into the job (far less than requeue_queued_after_s): its heartbeat is 3 s old
    assert design_changes.claim(p.db(), job_id, "dead-host:1")[1] == 1
    set_times(started_at=ago(10), heartbeat_at=ago(lease_s + 1))
    assert api.get(f"/api/v1/sites/{sid}/design-progress").status_code == 202
    j = row()
    assert (j.state, j.worker, j.attempt) == ("queued", None, 1)
    # again, found by the reaper this time (no request)
    assert design_changes.claim(p.db(), job_id, "dead-host:2")[1] == 2
    set_times(started_at=ago(10), heartbeat_at=ago(lease_s + 1))
    assert design_changes.reap(p.db(), p.settings) == [("design-change", job_id)]
    assert design_changes.reap(p.db(), p.settings) == []
    assert (row().state, row().attempt) == ("queued", 2)
    assert design_changes.heartbeat(p.db(), job_id, 2) is False

    # a live worker whose job has been running for two hours: its heartbeat thread keeps it
    real, seen = design_changes.compute, {}

    def long_compute(storage, inputs, work_dir):
        set_times(started_at=ago(7200), heartbeat_at=ago(7200))
        time.sleep(4 * lease_s / 4 + 0.5)   # the thread beats at 0.5, 1.0, 1.5, 2.0 s
        seen["beat_age_s"] = (datetime.now(timezone.utc) - row().heartbeat_at).total_seconds()
        seen["status"] = api.get(f"/api/v1/sites/{sid}/design-progress").status_code
        seen["reaped"] = design_changes.reap(p.db(), p.settings)
        j = row()
        seen["after"] = (j.state, j.attempt)
        return real(storage, inputs, work_dir)

    monkeypatch.setattr(design_changes, "compute", long_compute)
    assert worker.execute_design_change(job_id) == "done"
    assert seen["beat_age_s"] < lease_s and seen["status"] == 202 and seen["reaped"] == []
    assert seen["after"] == ("running", 3)
    j = row()
    assert (j.state, j.attempt) == ("succeeded", 3) and j.result["accuracy"]["common_bias_source"]
    # the dead attempts cannot record anything now
    assert design_changes.finish(p.db(), job_id, 1, error="late") is False
    assert design_changes.finish(p.db(), job_id, 2, result={}) is False
    assert row().state == "succeeded"


def test_two_ppk_surveys_on_the_same_base_position_share_its_error(site, tmp_path):
    """No control points under either survey, both PPK against the same averaged single-point base position: the
    pair's inputs carry that base (read from the runs' gnss and georef summaries) and its vertical sigma is the
    common bias; a third survey on another base position shares nothing with the second."""
    from backend.services import design_changes
    from tests.backend.test_design_change_common_bias import BASE_ECEF_M, georef_summary, gnss_summary

    sc = change_mc.one_seed(11, tmp_path, noise_m=0.0, common_bias_m=0.0, own_bias_m=0.0)
    acc = {"dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02, "correlation_length_m": 1.0}
    same = {"gnss": gnss_summary(), "georef": georef_summary()}
    other = {"gnss": gnss_summary([v + 1.5 for v in BASE_ECEF_M]), "georef": georef_summary()}
    entries = []
    for i, (name, summaries) in enumerate((("Dec A", same), ("Dec B", same), ("Dec C", other))):
        run = _recorded_run(site, name, datetime(2026, 12, 1 + 7 * i, tzinfo=timezone.utc), sc["may"], acc,
                            control=False, summaries=summaries)
        entries.append({"run_id": run, "run_number": 1, "survey_name": name})
    area = change_mc.area_geometry()
    with site["p"].db().session(read_only=True) as s:
        ab = design_changes.pair_inputs(s, entries[0], entries[1], area)
        bc = design_changes.pair_inputs(s, entries[1], entries[2], area)
    assert ab["control"] is None and ab["base"]["source"] == "averaged-single-point"
    sigma, source = design_changes.common_bias(None, ab["control"], tmp_path, ab["base"])
    assert sigma == pytest.approx(2.05) and "same base position" in source
    assert bc["base"] is None and design_changes.common_bias(None, None, tmp_path, bc["base"])[0] == 0.0
    assert design_changes.job_key(ab) != design_changes.job_key({**ab, "base": None})
