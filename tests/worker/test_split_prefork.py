"""The parts of a split step in ONE worker process with the prefork pool (``--concurrency 2``, as deployed and
as bench/dense_over_workers.py runs the tiled dense step) on the embedded shape (SQLite database and broker):
the parts are claimed atomically by the two child processes, each part once, both children take parts,
and the run_step_parts rows name the child (host:pid) that ran each. tests/worker/test_split_steps.py runs
parts in separate solo workers only."""

from __future__ import annotations

import pytest

from ..backend.platform_helpers import Api, add_user, start_worker, upload_bytes, wait_run
from ..steps.plugin_registration import plugin_registered

PLUGIN = "tests.steps.toy_split_step"


@pytest.fixture
def toysplit_registered(monkeypatch):
    with plugin_registered(monkeypatch, PLUGIN, "toysplit"):
        yield


def test_parts_in_the_children_of_one_prefork_worker(platform, toysplit_registered):
    p = platform("embedded", queue="prefork")
    add_user(p, "prefork@example.org", org_admin=True)
    api = Api(p, "prefork@example.org")
    site = api.post("/api/v1/sites", json={"name": "prefork", "crs": "EPSG:32631"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "prefork"}).json()
    for path, data in {"survey.json": b'{"project_crs": "EPSG:32631"}', "gcp/points.csv": b"name,x,y,z\nA,1,2,3\n",
                       "events.csv": b"gps_time_s\n1400000000.0\n1400000002.0\n"}.items():
        r = upload_bytes(api, survey["id"], path, data)
        assert r.status_code == 200, r.text
    w = start_worker(p, "pre", step_plugins=PLUGIN, concurrency=2)
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs",
                   json={"steps": ["toysplit"], "settings": {"toysplit": {"parts": 4, "work_s": 0.5}}}).json()
    final = wait_run(api, run["id"], timeout_s=120)
    assert final["state"] == "succeeded", final
    step = next(s for s in final["step_details"] if s["name"] == "toysplit")
    assert step["summary"]["parts"] == 4 and step["summary"]["files"] == 3, step["summary"]
    assert step["summary"]["processes"] == 2, step["summary"]          # both children ran parts
    workers = [q["worker"] for q in step["parts"]]
    assert all(q["state"] == "succeeded" and q["attempt"] == 1 for q in step["parts"]), step["parts"]
    assert len(set(workers)) == 2 and len({x.rsplit(":", 1)[0] for x in workers}) == 1, workers   # one host, 2 pids
    assert all(int(x.rsplit(":", 1)[1]) != w.proc.pid for x in workers)   # the children, not the main process
