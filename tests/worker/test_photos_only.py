"""A survey of photos alone (EXIF GPS, no raw GNSS, no base, no control point) through the real API and a
real worker (embedded shape: SQLite, local files, Celery over a SQLite broker): the pre-flight warns, the
GNSS step is skipped with its reason, the run succeeds, and the georeferencing summary states that the
absolute accuracy rests on the photo positions at their stated sigma; the check points measure it."""

from __future__ import annotations

import json
import subprocess

import pytest

from ..backend.platform_helpers import PY, REPO, Api, add_user, start_worker, upload_bytes, wait_run, zip_folder

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def photo_survey(tmp_path_factory):
    """The small simulated site (12 photos of 640 x 480 with EXIF GPS good to 1.5 m / 3 m) without any GNSS
    file; every target a check point."""
    out = tmp_path_factory.mktemp("photos") / "site"
    subprocess.run([PY, "-m", "georef_core.cli.main", "simulate", str(out), "--seed", "7", "--small", "--no-gnss",
                    "--quiet"], cwd=REPO, check=True, capture_output=True)
    pts = (out / "gcp" / "points.csv").read_text().splitlines()
    (out / "gcp" / "points.csv").write_text("\n".join([pts[0]] + [",".join(r.split(",")[:-1] + ["check"])
                                                                  for r in pts[1:]]) + "\n")
    return out


def test_photos_alone_through_the_api(platform, photo_survey):
    p = platform("embedded", queue="photos")
    add_user(p, "photos@example.org", org_admin=True)
    api = Api(p, "photos@example.org")
    meta = json.loads((photo_survey / "survey.json").read_text())
    site = api.post("/api/v1/sites", json={"name": "Photos", "crs": meta["project_crs"]}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "EXIF GPS only"}).json()
    data = zip_folder(photo_survey, skip=("truth/", "rover/", "base/", "nav/", "README", "events.csv"))
    r = upload_bytes(api, survey["id"], "photos.zip", data, chunk=1 << 20)
    assert r.status_code == 200, r.text
    kinds = {f["path"]: f["kind"] for f in r.json()["result"]["files"]}
    assert sum(k == "image" for k in kinds.values()) == 12 and not any(k.startswith(("rover", "base")) for k in kinds)
    check = api.get(f"/api/v1/surveys/{survey['id']}/check").json()
    assert check["ok"], check["problems"]
    assert "photos-only" in {q["code"] for q in check["problems"]}

    start_worker(p, "photos", beat=False)
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss", "georef", "report"]}).json()
    final = wait_run(api, run["id"], timeout_s=240)
    steps = {s["name"]: s for s in final["step_details"]}
    assert final["state"] == "succeeded", (final["error"], steps)
    gnss = steps["gnss"]
    assert gnss["state"] == "skipped" and gnss["summary"]["skipped"] is True
    assert "no raw GNSS log" in gnss["summary"]["reason"]
    logs = api.get(f"/api/v1/runs/{run['id']}/logs").json()
    items = logs["items"] if isinstance(logs, dict) else logs
    assert any("step gnss skipped: no raw GNSS log" in e["message"] for e in items)

    geo = steps["georef"]
    assert geo["state"] == "succeeded"
    s = geo["summary"]
    assert s["images"]["registered"] == 12 and s["images"]["with_gnss"] == 12
    assert "EXIF GPS" in s["gnss_source"]
    acc = s["absolute_accuracy"]
    assert "no control point" in acc["text"] and "photo positions" in acc["text"]
    basis = {b["kind"]: b for b in acc["basis"]}
    assert set(basis) == {"photo positions"}
    # the check points measure the absolute accuracy: metre level, as the EXIF GPS sigma (3 m / 5 m) says
    res = api.get(f"/api/v1/runs/{run['id']}/results/residuals").json()
    assert len(res["points"]) == 5 and all(q["role"] == "check" for q in res["points"])
    d3 = s["check_points"]["statistics"]["3d"]["rmse_m"]
    print({k: v.get("summary", {}).get("duration_s") for k, v in steps.items()})
    print(f"photos alone (EXIF GPS 1.5 m / 3 m simulated noise): check points 3D RMSE {d3:.2f} m; "
          f"{acc['text']}")
    assert 0.05 < d3 < 3 * 5.0
    assert s["doming"]["text"].startswith("doming")
    pdf = api.get(f"/api/v1/runs/{run['id']}/results/report.pdf")
    assert pdf.status_code == 200 and pdf.content[:4] == b"%PDF"
