"""A split step's times (backend/services/jobs.py claim_step): the step is claimed for its plan and again for its
merge; its started_at stays the plan's claim (so started_at .. finished_at is the whole step, as the API shows
it), also when the merge's worker dies and the merge is claimed again; a step claimed again before it was split
(attempt 2 after a transient failure) gets a new started_at; the parts keep their own times. Driven through the
job state machine on the real databases (PostgreSQL and the embedded SQLite), read back through the API."""

from __future__ import annotations

import time
from datetime import datetime

import pytest

from backend.services import jobs

from ..backend.platform_helpers import Api, add_user, upload_bytes


def _t(s: str | None) -> datetime | None:
    return datetime.fromisoformat(s.replace("Z", "+00:00")) if s else None


def _step(api, run_id: str) -> dict:
    r = api.get(f"/api/v1/runs/{run_id}")
    assert r.status_code == 200, r.text
    return next(s for s in r.json()["step_details"] if s["name"] == "gnss")


def _tick():
    time.sleep(0.03)      # claims at distinct times on every database's clock resolution


@pytest.mark.parametrize("shape", ["postgres", "embedded"])
def test_split_step_started_at_is_its_plan_claim(platform, shape):
    p = platform(shape, queue=f"startedat-{shape}")
    add_user(p, f"t-{shape}@example.org", org_admin=True)
    api = Api(p, f"t-{shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "S", "crs": "EPSG:32631"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()
    assert upload_bytes(api, survey["id"], "survey.json", b'{"project_crs": "EPSG:32631"}').status_code == 200
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss"]}).json()
    db = p.db()

    # attempt 1 (the plan) fails transiently and goes back to the queue: attempt 2 is a new start
    c1 = jobs.claim_step(db, run["id"], "gnss", "w1")
    assert isinstance(c1, jobs.Claim) and c1.attempt == 1 and c1.phase is None
    t1 = _t(_step(api, run["id"])["started_at"])
    jobs.release_step(db, c1, "broker hiccup")
    _tick()
    c2 = jobs.claim_step(db, run["id"], "gnss", "w2")
    assert isinstance(c2, jobs.Claim) and c2.attempt == 2
    plan = _step(api, run["id"])
    t_plan = _t(plan["started_at"])
    assert t_plan > t1, (t1, t_plan)

    # the plan splits the step; two parts run and finish; the last one queues the merge
    ok, msgs = jobs.start_parts(db, c2, "hash", [], [{"k": 0}, {"k": 1}])
    assert ok and len(msgs) == 2
    part_times = {}
    for k in (0, 1):
        _tick()
        pc = jobs.claim_part(db, run["id"], "gnss", k, f"part-worker-{k}")
        assert isinstance(pc, jobs.PartClaim)
        _tick()
        ok, _ = jobs.finish_part(db, pc, [])
        assert ok
    st = _step(api, run["id"])
    assert st["state"] == "queued" and st["phase"] == "merge"
    for q in st["parts"]:
        part_times[q["index"]] = (q["started_at"], q["finished_at"])
        assert _t(q["started_at"]) > t_plan

    # the merge's claim keeps the plan's started_at; its worker dies (reaped), the next merge claim keeps it too
    _tick()
    c3 = jobs.claim_step(db, run["id"], "gnss", "w3")
    assert isinstance(c3, jobs.Claim) and c3.phase == "merge" and c3.attempt == 3
    assert _t(_step(api, run["id"])["started_at"]) == t_plan
    _tick()
    assert ("step", run["id"], "gnss") in jobs.reap(db, lease_s=0.0, requeue_queued_after_s=3600)
    _tick()
    t_merge = datetime.now().astimezone()
    c4 = jobs.claim_step(db, run["id"], "gnss", "w4")
    assert isinstance(c4, jobs.Claim) and c4.phase == "merge" and c4.attempt == 4
    ok, _ = jobs.finish_step(db, c4, "hash", [], {"merged": True})
    assert ok

    st = _step(api, run["id"])
    assert st["state"] == "succeeded" and st["attempt"] == 4
    assert _t(st["started_at"]) == t_plan                         # the whole step: plan .. merge's end
    assert _t(st["finished_at"]) >= t_merge > t_plan
    # the parts' own times are untouched
    assert {q["index"]: (q["started_at"], q["finished_at"]) for q in st["parts"]} == part_times
