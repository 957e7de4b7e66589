"""Reprocessing schedules: due times, atomic dispatch (no duplicate run when two beats tick), runs only
when something changed, and the new-data trigger with its debounce."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from backend.models import Run, Schedule
from backend.services.context import Ctx
from backend.services.schedules import dispatch_due, next_due
from sqlalchemy import select, update

from .platform_helpers import POINTS_CSV, Api, add_user, upload_bytes

UTC = timezone.utc


def test_next_due():
    now = datetime(2024, 5, 6, 10, 30, tzinfo=UTC)   # a Monday
    assert next_due("daily", "02:00", 0, now) == datetime(2024, 5, 7, 2, 0, tzinfo=UTC)
    assert next_due("daily", "23:15", 0, now) == datetime(2024, 5, 6, 23, 15, tzinfo=UTC)
    assert next_due("hourly", "00:45", 0, now) == datetime(2024, 5, 6, 10, 45, tzinfo=UTC)
    assert next_due("hourly", "00:10", 0, now) == datetime(2024, 5, 6, 11, 10, tzinfo=UTC)
    assert next_due("weekly", "02:00", 0, now) == datetime(2024, 5, 13, 2, 0, tzinfo=UTC)
    assert next_due("weekly", "02:00", 2, now) == datetime(2024, 5, 8, 2, 0, tzinfo=UTC)
    assert next_due("none", "02:00", 0, now) is None


def _ctx(p):
    s = p.db().sessionmaker()
    return Ctx(db=s, settings=p.settings, storage=p.app.state.storage)


def _runs(p, survey_id):
    with p.db().session() as s:
        return list(s.scalars(select(Run).where(Run.survey_id == survey_id).order_by(Run.number)))


def test_dispatch(platform):
    add_user(platform, f"sched-{platform.shape}@example.org", org_admin=True)
    api = Api(platform, f"sched-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "S", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()
    assert upload_bytes(api, survey["id"], "points.csv", POINTS_CSV, "points").status_code == 200
    sch = api.post(f"/api/v1/sites/{site['id']}/schedules",
                   json={"name": "nightly", "cadence": "daily", "at_utc": "02:00", "on_new_points": True,
                         "steps": ["gnss"]}).json()
    due = datetime.fromisoformat(sch["next_run_at"])
    assert due.hour == 2 and due > datetime.now(UTC)

    # two beat processes tick at the same due time: one run, not two
    later = due + timedelta(minutes=1)
    c1, c2 = _ctx(platform), _ctx(platform)
    created = dispatch_due(c1, later)
    c1.db.commit()
    created += dispatch_due(c2, later)
    c2.db.commit()
    assert len(created) == 1
    runs = _runs(platform, survey["id"])
    assert [r.trigger for r in runs] == ["schedule"] and runs[0].steps == ["gnss"]
    nxt = api.get(f"/api/v1/schedules/{sch['id']}").json()["next_run_at"]
    assert datetime.fromisoformat(nxt) == due + timedelta(days=1)

    # next night, nothing changed since a successful run: no new run
    with platform.db().session() as s:
        s.execute(update(Run).where(Run.id == runs[0].id).values(state="succeeded"))
    c = _ctx(platform)
    assert dispatch_due(c, due + timedelta(days=1, minutes=1)) == []
    c.db.commit()

    # new points file: queued by the upload, started after the debounce, once
    r = api.patch(f"/api/v1/surveys/{survey['id']}/points/T1", json={"role": "check"})
    assert r.status_code == 200
    got = api.get(f"/api/v1/schedules/{sch['id']}").json()
    assert got["pending_survey_ids"] == [survey["id"]]
    c = _ctx(platform)
    assert dispatch_due(c, datetime.now(UTC)) == []          # within the debounce
    c.db.commit()
    c = _ctx(platform)
    created = dispatch_due(c, datetime.now(UTC) + timedelta(seconds=platform.settings.new_data_debounce_s + 1))
    c.db.commit()
    assert len(created) == 1
    assert [r.trigger for r in _runs(platform, survey["id"])] == ["schedule", "new-data"]
    with platform.db().session() as s:
        assert s.get(Schedule, sch["id"]).pending_survey_ids == []
