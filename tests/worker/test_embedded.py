"""The embedded shape (SQLite database, local files, Celery over a SQLite broker file: no server at all)
runs the same code path end to end with a real worker process."""

from __future__ import annotations

import time


from ..backend.platform_helpers import Api, add_user, start_worker, upload_bytes, wait_run, zip_folder


def test_embedded_run(platform, small_survey):
    p = platform("embedded", queue="emb")
    assert p.settings.resolved_database_url().startswith("sqlite:")
    assert p.settings.resolved_broker_url().startswith("sqla+sqlite:")
    add_user(p, "emb@example.org", org_admin=True)
    api = Api(p, "emb@example.org")
    site = api.post("/api/v1/sites", json={"name": "S", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()
    r = upload_bytes(api, survey["id"], "gnss.zip", zip_folder(small_survey, skip=("truth/", "images/")),
                     chunk=256 * 1024)
    assert r.status_code == 200, r.text
    start_worker(p, "embedded", beat=True)
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss", "report"]}).json()
    final = wait_run(api, run["id"], timeout_s=180)
    assert final["state"] == "succeeded", final
    cams = api.get(f"/api/v1/runs/{run['id']}/results/camera-positions").json()
    assert cams["count"] == 12 and all(e["status"] == 1 for e in cams["events"])
    traj = api.get(f"/api/v1/runs/{run['id']}/results/trajectory?format=json&every=50").json()
    assert traj["count"] >= 10 and all(e["q"] == 1 for e in traj["epochs"])
    pdf = api.get(f"/api/v1/runs/{run['id']}/results/report.pdf")
    assert pdf.content[:4] == b"%PDF"
    assert api.post(f"/api/v1/runs/{run['id']}/cancel").status_code == 409     # already finished

    # a re-run forced from gnss, cancelled while gnss runs: the step stops at its next progress report
    r2 = api.post(f"/api/v1/runs/{run['id']}/rerun", json={"from_step": "gnss"}).json()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        st = api.get(f"/api/v1/runs/{r2['id']}").json()["step_details"][0]["state"]
        if st == "running":
            break
        time.sleep(0.1)
    assert api.post(f"/api/v1/runs/{r2['id']}/cancel").json()["cancel_requested"] is True
    final2 = wait_run(api, r2["id"], timeout_s=120)
    assert final2["state"] == "cancelled"
    assert [s["state"] for s in final2["step_details"]] == ["cancelled", "cancelled"]
    assert api.get(f"/api/v1/runs/{r2['id']}/results").json() == []
