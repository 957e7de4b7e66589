"""A step that runs as parts on several workers (contract.Split; worker/tasks.py run_part): a toy split step
(tests/steps/toy_split_step.py, a plug-in) through the real API and two real workers on PostgreSQL + Redis:
the plan's file reaches every part, the parts run in both worker processes, the merge gives the same result
as the step run in one process (contract.run_split), the run shows every part; a failing part fails the
step and the run, naming the part; and in the embedded shape (SQLite) with one worker."""

from __future__ import annotations

import json
from datetime import datetime

import pytest

from georef_core.steps.contract import Workspace, get_spec, run_split

from ..backend.platform_helpers import Api, add_user, start_worker, upload_bytes, wait_run
from ..steps.plugin_registration import plugin_registered

PLUGIN = "tests.steps.toy_split_step"


@pytest.fixture
def toysplit_registered(monkeypatch):
    with plugin_registered(monkeypatch, PLUGIN, "toysplit"):
        yield


FILES = {"survey.json": b'{"project_crs": "EPSG:32631"}', "gcp/points.csv": b"name,x,y,z\nA,1,2,3\n",
         "events.csv": b"gps_time_s\n1400000000.0\n1400000002.0\n"}


def _survey(api, name: str) -> str:
    site = api.post("/api/v1/sites", json={"name": name, "crs": "EPSG:32631"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": name}).json()
    for path, data in FILES.items():
        r = upload_bytes(api, survey["id"], path, data)
        assert r.status_code == 200, r.text
    return survey["id"]


def _local_result(tmp_path, parts: int, phases: bool = False) -> dict:
    """The same step in one process, on the same files."""
    survey = tmp_path / "local_survey"
    for path, data in FILES.items():
        (survey / path).parent.mkdir(parents=True, exist_ok=True)
        (survey / path).write_bytes(data)
    ws = Workspace(survey, tmp_path / "local_out")
    summary = run_split(get_spec("toysplit"), ws, {"parts": parts, "phases": phases}, None, {"crs": "EPSG:32631"})
    assert summary["parts"] == parts + phases
    return json.loads(ws.path("toysplit", "result").read_text())


def test_parts_on_two_workers_merge_like_one_process(platform, tmp_path, toysplit_registered):
    p = platform("postgres", queue="split")
    add_user(p, "split@example.org", org_admin=True)
    api = Api(p, "split@example.org")
    steps = {s["name"]: s for s in api.get("/api/v1/steps").json()["items"]}
    assert steps["toysplit"]["parallel_parts"] is True and steps["gnss"]["parallel_parts"] is False
    survey = _survey(api, "split")
    start_worker(p, "a", step_plugins=PLUGIN)
    start_worker(p, "b", step_plugins=PLUGIN)
    run = api.post(f"/api/v1/surveys/{survey}/runs",
                   json={"steps": ["toysplit"], "settings": {"toysplit": {"parts": 4, "work_s": 1.5}}}).json()
    final = wait_run(api, run["id"], timeout_s=120)
    assert final["state"] == "succeeded", final
    step = next(s for s in final["step_details"] if s["name"] == "toysplit")
    assert step["summary"]["parts"] == 4 and step["summary"]["files"] == len(FILES), step["summary"]
    assert step["summary"]["processes"] == 2, step["summary"]        # both workers ran parts
    assert [q["index"] for q in step["parts"]] == [0, 1, 2, 3]
    assert all(q["state"] == "succeeded" and q["worker"] for q in step["parts"]), step["parts"]
    assert step["progress_done"] == step["progress_total"] == 4 or step["progress_stage"] == "done"
    merged = json.loads(api.get(f"/api/v1/runs/{run['id']}/results/files/toysplit/result.json").text)
    assert merged == _local_result(tmp_path, 4)
    logs = api.get(f"/api/v1/runs/{run['id']}/logs").json()
    items = logs["items"] if isinstance(logs, dict) else logs
    text = "\n".join(e["message"] for e in items)
    assert "split into 4 parts" in text and "merging its parts" in text and "part 3 done" in text

    # a part that fails fails its step and the run, naming the part; the parts not run are cancelled
    run = api.post(f"/api/v1/surveys/{survey}/runs",
                   json={"steps": ["toysplit"], "settings": {"toysplit": {"parts": 3, "fail_part": 1}}}).json()
    final = wait_run(api, run["id"], timeout_s=120)
    assert final["state"] == "failed"
    step = next(s for s in final["step_details"] if s["name"] == "toysplit")
    assert step["state"] == "failed" and "part 1: toy part 1 failed as asked" in step["error"], step
    assert {q["index"]: q["state"] for q in step["parts"]}[1] == "failed"


def test_parts_in_the_embedded_shape(platform, tmp_path, toysplit_registered):
    p = platform("embedded", queue="splitemb")
    add_user(p, "emb-split@example.org", org_admin=True)
    api = Api(p, "emb-split@example.org")
    survey = _survey(api, "split-embedded")
    start_worker(p, "one", step_plugins=PLUGIN)
    # two phases (contract.Split "after"): a third part waits for the first two and reads their files
    run = api.post(f"/api/v1/surveys/{survey}/runs",
                   json={"steps": ["toysplit"], "settings": {"toysplit": {"parts": 2, "phases": True}}}).json()
    final = wait_run(api, run["id"], timeout_s=120)
    assert final["state"] == "succeeded", final
    step = next(s for s in final["step_details"] if s["name"] == "toysplit")
    assert step["summary"]["parts"] == 3 and step["summary"]["processes"] == 1
    assert step["summary"]["read"] == [[], [], [0, 1]]          # the second phase found the first's files
    # the step's time in the API is its whole time: from its plan's claim (before any part) to its merge's end
    at = lambda v: datetime.fromisoformat(v.replace("Z", "+00:00"))  # noqa: E731
    assert at(step["started_at"]) <= min(at(q["started_at"]) for q in step["parts"]), step
    assert at(step["finished_at"]) >= max(at(q["finished_at"]) for q in step["parts"]), step
    merged = json.loads(api.get(f"/api/v1/runs/{run['id']}/results/files/toysplit/result.json").text)
    assert merged == _local_result(tmp_path, 2, phases=True)
    logs = api.get(f"/api/v1/runs/{run['id']}/logs").json()
    text = "\n".join(e["message"] for e in (logs["items"] if isinstance(logs, dict) else logs))
    assert "part(s) 2 ready" in text


def test_a_step_or_part_failure_is_recorded_alike(tmp_path, monkeypatch):
    """worker.tasks._record_failure, shared by steps and parts: a cancellation, the project's error with its
    file named relative to the run folder, anything else as an internal error with its traceback logged."""
    from georef_core.errors import InputFileError, ProcessingError, StepCancelled
    from worker import tasks

    run_dir = tmp_path / "runs" / "r1"
    logged, recorded = [], []
    monkeypatch.setattr(tasks.jobs, "log", lambda db, run_id, message, step, level: logged.append((level, message)))

    def fail(reason, cancelled):
        recorded.append((reason, cancelled))
        return True, []

    cases = [StepCancelled("run cancelled during dense"),
             InputFileError(run_dir / "survey" / "rover" / "f.obs", "no epochs"),
             ProcessingError("no image pair overlaps"), KeyError(str(run_dir / "out" / "x"))]
    outcomes = []
    for exc in cases:
        try:
            raise exc
        except Exception as e:   # noqa: BLE001 - the worker's own catch-all
            outcomes.append(tasks._record_failure(None, None, None, "r1", "dense", run_dir, e, fail))
    assert outcomes == ["cancelled", "failed", "failed", "failed"]
    assert recorded[0] == ("run cancelled during dense", True)
    assert recorded[1] == ("rover/f.obs: no epochs", False)
    assert recorded[2] == ("no image pair overlaps", False)
    assert recorded[3] == ("internal error (KeyError: 'x')", False)
    assert len(logged) == 1 and logged[0][0] == "error" and "Traceback" in logged[0][1]
