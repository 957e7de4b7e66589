"""End to end on the production shape (PostgreSQL + Redis + S3 object storage + a real Celery worker
process with beat; the S3 store is moto's S3 server on the loopback, in place of MinIO, which needs Docker):
a simulated survey is uploaded through the API in resumable chunks, checked, processed while the
test follows the server-sent events, and its results read back: camera positions, trajectory, the
check-point residual table (CSV/JSON/GeoJSON), the PDF report, the volumes (when the dense and
volume steps are installed), the webhook (HMAC-verified, after a transient failure), a re-run that
reuses identical steps, and a data-triggered scheduled run."""

from __future__ import annotations

import csv
import hashlib
import hmac
import io
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, HTTPServer

import pytest

from ..backend.platform_helpers import (Api, add_user, close_platform, have_postgres, have_redis, make_platform,
                                        start_s3_server, start_worker, wait_run, zip_folder)


def _importable(target: str) -> bool:
    import importlib

    mod, fn = target.split(":")
    try:
        return hasattr(importlib.import_module(mod), fn)
    except ModuleNotFoundError:
        return False


HAVE_DENSE = _importable("georef_core.steps.dense:run_dense") and _importable("georef_core.steps.volumes:run_volumes")
HAVE_GEOREF = _importable("georef_core.steps.georef:run_georef")


class Hook(BaseHTTPRequestHandler):
    received: list = []
    fail_first = 1

    def do_POST(self):
        body = self.rfile.read(int(self.headers["Content-Length"]))
        Hook.received.append((dict(self.headers), body))
        if Hook.fail_first > 0:
            Hook.fail_first -= 1
            self.send_response(503)
        else:
            self.send_response(204)
        self.end_headers()

    def log_message(self, *a):
        pass


@pytest.fixture(scope="module")
def env(tmp_path_factory, small_survey):
    if not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed")
    s3, s3_settings = start_s3_server()
    # the webhook receiver below listens on the loopback: allowed as an on-premise network would be
    # (webhook targets are public addresses only by default)
    p = make_platform(tmp_path_factory.mktemp("e2e"), "postgres", queue="e2e", new_data_debounce_s=0,
                      schedule_tick_s=1, webhook_allowed_networks="127.0.0.0/8", **s3_settings)
    server = HTTPServer(("127.0.0.1", 0), Hook)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    # as in docker-compose.yml: a worker on the default queue (with beat) and one on the heavy queue, each
    # with a disk of its own: a step finds what earlier steps made only through the store
    start_worker(p, "w1", beat=True, queues="default")
    start_worker(p, "w2", queues="heavy", work_dir=p.data_dir / "heavy-worker")
    a_id, org = add_user(p, "surveyor@example.org", org_admin=True)
    yield p, Api(p, "surveyor@example.org"), server
    server.shutdown()
    close_platform(p)
    s3.stop()


def _sse_events(api: Api, run_id: str, timeout_s: float = 400) -> list[tuple[str, dict]]:
    events = []
    with api.c.stream("GET", f"/api/v1/runs/{run_id}/events?poll_s=0.3&max_s={timeout_s}") as r:
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/event-stream")
        kind = None
        for line in r.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: ") and kind:
                events.append((kind, json.loads(line[6:])))
                if kind == "end":
                    break
    return events


def test_survey_through_the_api(env, small_survey):
    p, api, server = env
    meta = json.loads((small_survey / "survey.json").read_text())
    site = api.post("/api/v1/sites", json={"name": "Quarry", "crs": meta["project_crs"]}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys",
                      json={"name": "Flight 7", "flown_at": "2024-06-24T08:10:00Z"}).json()
    truth = json.loads((small_survey / "truth" / "stockpiles.geojson").read_text())
    for f in truth["features"]:
        ring = [[c[0], c[1]] for c in f["geometry"]["coordinates"][0]]
        r = api.post(f"/api/v1/sites/{site['id']}/stockpiles",
                     json={"name": f["properties"]["name"], "outline": {"type": "Polygon", "coordinates": [ring]},
                           "base": "plane"})
        assert r.status_code == 201, r.text
    hook = api.post("/api/v1/webhooks", json={"site_id": site["id"], "url": f"http://127.0.0.1:{server.server_port}/h",
                                              "events": ["run.finished"]}).json()

    # resumable upload: half the chunks, a wrong offset refused, the status says where to resume, the rest
    data = zip_folder(small_survey)
    sha = hashlib.sha256(data).hexdigest()
    up = api.post(f"/api/v1/surveys/{survey['id']}/uploads",
                  json={"filename": "flight7.zip", "size": len(data), "sha256": sha, "kind": "archive"}).json()
    chunk = 1 << 20
    half = (len(data) // chunk // 2) * chunk
    for off in range(0, half, chunk):
        r = api.put(f"/api/v1/uploads/{up['id']}", content=data[off:off + chunk],
                    headers={"Content-Range": f"bytes {off}-{off + chunk - 1}/{len(data)}"})
        assert r.status_code == 200
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[half + chunk:half + 2 * chunk],
                headers={"Content-Range": f"bytes {half + chunk}-{half + 2 * chunk - 1}/{len(data)}"})
    assert r.status_code == 409 and r.json()["received_bytes"] == half
    assert api.post(f"/api/v1/uploads/{up['id']}/complete").status_code == 409     # incomplete
    resume = api.get(f"/api/v1/uploads/{up['id']}").json()["received_bytes"]
    for off in range(resume, len(data), chunk):
        part = data[off:off + chunk]
        r = api.put(f"/api/v1/uploads/{up['id']}", content=part,
                    headers={"Content-Range": f"bytes {off}-{off + len(part) - 1}/{len(data)}"})
        assert r.status_code == 200, r.text
    r = api.post(f"/api/v1/uploads/{up['id']}/complete")
    assert r.status_code == 200, r.text
    attached = {f["path"]: f["kind"] for f in r.json()["result"]["files"]}
    assert attached["rover/rover.obs"] == "rinex-obs" and attached["base/base.obs"] == "rinex-obs"
    assert attached["nav/base.nav"] == "rinex-nav" and attached["gcp/points.csv"] == "points"
    assert sum(k == "image" for k in attached.values()) == 12

    check = api.get(f"/api/v1/surveys/{survey['id']}/check").json()
    assert check["ok"], check["problems"]

    r = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={})
    assert r.status_code == 201, r.text
    run = r.json()
    events = _sse_events(api, run["id"])
    kinds = {k for k, _ in events}
    assert {"state", "log", "end"} <= kinds
    assert any(k == "state" and d["state"] == "running" for k, d in events)
    final = wait_run(api, run["id"])
    steps = {s["name"]: s for s in final["step_details"]}
    assert final["state"] == "succeeded", (final["error"], steps)
    # georeferencing and dense on the heavy worker (its own disk), the rest on the default one
    pid_of = {w.name: w.proc.pid for w in p.workers}
    for name, s in steps.items():
        want = "w2" if name in ("georef", "dense") else "w1"
        assert s["worker"].endswith(f":{pid_of[want]}"), (name, s["worker"], pid_of)
    assert steps["gnss"]["state"] == "succeeded" and steps["report"]["state"] == "succeeded"

    # antenna at the 12 camera triggers, all fixed, within centimetres of the simulated truth
    cam = api.get(f"/api/v1/runs/{run['id']}/results/camera-positions").json()
    assert cam["count"] == 12 and all(e["status"] == 1 for e in cam["events"])
    truth_traj = list(csv.DictReader((small_survey / "truth" / "trajectory.csv").open()))
    assert truth_traj
    gj = api.get(f"/api/v1/runs/{run['id']}/results/camera-positions?format=geojson")
    assert gj.headers["content-type"].startswith("application/geo+json")
    lon, lat = gj.json()["features"][0]["geometry"]["coordinates"][:2]
    assert abs(lat - 35.13) < 0.01 and abs(lon - 136.97) < 0.01        # RFC 7946: lon, lat order
    pos = api.get(f"/api/v1/runs/{run['id']}/results/trajectory?format=pos")
    assert pos.status_code == 200 and pos.text.startswith("%")
    etag = pos.headers["etag"]
    # the stored file through the object store, whole and by byte range (resumable downloads)
    assert p.settings.storage == "s3"
    whole = api.get(f"/api/v1/runs/{run['id']}/results/files/ppk/trajectory.pos")
    assert whole.status_code == 200 and whole.content == pos.content
    part = api.get(f"/api/v1/runs/{run['id']}/results/files/ppk/trajectory.pos", headers={"Range": "bytes=100-299"})
    assert part.status_code == 206 and part.content == pos.content[100:300]
    assert part.headers["content-range"] == f"bytes 100-299/{len(pos.content)}"
    assert api.get(f"/api/v1/runs/{run['id']}/results/trajectory?format=pos",
                   headers={"If-None-Match": etag}).status_code == 304
    pdf = api.get(f"/api/v1/surveys/{survey['id']}/report.pdf")
    assert pdf.status_code == 200 and pdf.content[:4] == b"%PDF"

    if HAVE_GEOREF:
        assert steps["georef"]["state"] == "succeeded", steps["georef"]
        res = api.get(f"/api/v1/runs/{run['id']}/results/residuals").json()
        names = {q["name"] for q in res["points"]}
        assert names and names <= {"T01", "T02", "T03", "T04", "T05"}
        for q in res["points"]:
            assert abs(q["dx_m"]) < 0.05 and abs(q["dy_m"]) < 0.05 and abs(q["dz_m"]) < 0.10, q
        rows = list(csv.DictReader(io.StringIO(api.get(f"/api/v1/runs/{run['id']}/results/residuals?format=csv").text)))
        assert rows
        feats = api.get(f"/api/v1/runs/{run['id']}/results/residuals?format=geojson").json()["features"]
        assert len(feats) == len(res["points"])
        lev = api.get(f"/api/v1/runs/{run['id']}/results/lever-arm").json()
        assert lev
        summary = api.get(f"/api/v1/sites/{site['id']}/summary").json()
        assert summary["surveys"] == 1 and summary["latest_run"]["id"] == run["id"]
        assert summary["check_rmse_m"]["n"] == len(res["points"]) and summary["check_rmse_m"]["3d"] < 0.1
    if HAVE_DENSE:
        assert steps["volumes"]["state"] == "succeeded", steps["volumes"]
        vols = {v["name"]: v for v in api.get(f"/api/v1/runs/{run['id']}/results/volumes").json()["stockpiles"]}
        for f in truth["features"]:
            got = vols[f["properties"]["name"]]
            err = got["volume_m3"] - f["properties"]["volume_m3"]
            # the small scene's tolerance (tests/adjustment/test_georef_step.py): 3 % and inside 3 sigma
            assert abs(err) < 0.03 * f["properties"]["volume_m3"], (got, f["properties"])
            assert abs(err) < 3 * got["sigma_m3"], (got, f["properties"])
        # the same outline measured ad hoc gives the same volume as the volumes step
        f0 = truth["features"][0]
        ring = [[c[0], c[1]] for c in f0["geometry"]["coordinates"][0]]
        adhoc = api.post(f"/api/v1/runs/{run['id']}/volumes",
                         json={"outline": {"type": "Polygon", "coordinates": [ring]}, "base": "plane"})
        assert adhoc.status_code == 200, adhoc.text
        assert abs(adhoc.json()["volume_m3"] - vols[f0["properties"]["name"]]["volume_m3"]) < 1e-6
        piles = api.get(f"/api/v1/sites/{site['id']}/stockpiles").json()
        hist = api.get(f"/api/v1/stockpiles/{piles[0]['id']}/volumes").json()
        assert len(hist) == 1 and hist[0]["run_id"] == run["id"]
    else:
        assert steps["dense"]["state"] == "unavailable"
        assert api.get(f"/api/v1/runs/{run['id']}/results/volumes").status_code == 404

    # webhook: first attempt answered 503, retried, delivered, signature verifiable with the secret
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and len(Hook.received) < 2:
        time.sleep(0.5)
    assert len(Hook.received) >= 2, Hook.received
    headers, body = Hook.received[-1]
    t, v1 = (kv.split("=", 1)[1] for kv in headers["Georef-Signature"].split(","))
    expect = hmac.new(hook["secret"].encode(), f"{t}.".encode() + body, hashlib.sha256).hexdigest()
    assert hmac.compare_digest(v1, expect)
    payload = json.loads(body)
    assert payload["event"] == "run.succeeded" and payload["data"]["run_id"] == run["id"]
    deliveries = api.get(f"/api/v1/webhooks/{hook['id']}/deliveries").json()
    assert deliveries[0]["state"] == "delivered" and deliveries[0]["attempts"] == 2

    # re-run from the report: gnss (and georef) are reused, not recomputed
    r2 = api.post(f"/api/v1/runs/{run['id']}/rerun", json={"from_step": "report"}).json()
    final2 = wait_run(api, r2["id"])
    s2 = {s["name"]: s for s in final2["step_details"]}
    assert final2["state"] == "succeeded"
    assert s2["gnss"]["state"] == "skipped" and s2["gnss"]["reused_from_step_id"] == steps["gnss"]["id"]
    if HAVE_GEOREF:
        assert s2["georef"]["state"] == "skipped"
    assert s2["report"]["state"] == "succeeded"
    outs1 = {o["path"]: o["sha256"] for o in api.get(f"/api/v1/runs/{run['id']}/results").json()}
    outs2 = {o["path"]: o["sha256"] for o in api.get(f"/api/v1/runs/{r2['id']}/results").json()}
    assert outs2["ppk/trajectory.pos"] == outs1["ppk/trajectory.pos"]
    ch = api.get(f"/api/v1/runs/{r2['id']}/changes").json()
    assert ch["previous_run_id"] == run["id"] and ch["inputs"] == {"added": [], "removed": [], "modified": []}

    # a new points file (a point switched to check) triggers the site's schedule: a gnss-only run
    # (gnss does not read the points: reused), whose changes name the modified input
    sch = api.post(f"/api/v1/sites/{site['id']}/schedules",
                   json={"name": "on new points", "cadence": "none", "on_new_points": True, "steps": ["gnss"]})
    assert sch.status_code == 201, sch.text
    r = api.patch(f"/api/v1/surveys/{survey['id']}/points/T03", json={"role": "check"})
    assert r.status_code == 200 and r.json()["role"] == "check"
    deadline = time.monotonic() + 60
    new = []
    while time.monotonic() < deadline and not new:
        new = [x for x in api.get(f"/api/v1/surveys/{survey['id']}/runs").json()["items"] if x["trigger"] == "new-data"]
        time.sleep(0.5)
    assert new, "the schedule did not start a run"
    final3 = wait_run(api, new[0]["id"])
    assert final3["state"] == "succeeded"
    assert {s["name"]: s["state"] for s in final3["step_details"]} == {"gnss": "skipped"}
    assert final3["changes"]["inputs"]["modified"] == ["gcp/points.csv"]
