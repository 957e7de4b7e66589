"""Uploads: the resumable protocol, content recognition, and bad uploads refused with a clear message
while the survey's existing files stay untouched (wrong type, truncated, checksum mismatch, zip bombs,
path traversal and symbolic links in archives, over-size)."""

from __future__ import annotations

import hashlib
import io
import re
import stat
import zipfile

import pytest

from .platform_helpers import POINTS_CSV, Api, add_user, upload_bytes, zip_folder


@pytest.fixture(scope="module")
def ctx(platform, small_survey):
    add_user(platform, f"up-{platform.shape}@example.org", org_admin=True)
    api = Api(platform, f"up-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "Uploads", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()
    assert upload_bytes(api, survey["id"], "points.csv", POINTS_CSV, "points").status_code == 200
    return api, survey["id"], small_survey


def _files(api, sid):
    return {f["path"]: f["sha256"] for f in api.get(f"/api/v1/surveys/{sid}/files").json()}


def _refused(r, *words):
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    detail = r.json()["detail"]
    for w in words:
        assert w.lower() in detail.lower(), detail
    return detail


def _zip(members: dict, symlink: str | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in members.items():
            z.writestr(name, data)
        if symlink:
            info = zipfile.ZipInfo(symlink)
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            z.writestr(info, "/etc/passwd")
    return buf.getvalue()


def test_recognised_by_content_not_name(ctx):
    api, sid, sim = ctx
    r = upload_bytes(api, sid, "mystery.dat", (sim / "nav" / "base.nav").read_bytes())
    assert r.status_code == 200, r.text
    assert r.json()["result"]["files"][0] == {**r.json()["result"]["files"][0], "path": "nav/mystery.dat",
                                              "kind": "rinex-nav"}
    r = upload_bytes(api, sid, "flight.obs", (sim / "rover" / "rover.obs").read_bytes(), kind="rover")
    f = r.json()["result"]["files"][0]
    assert (f["path"], f["kind"], f["role"]) == ("rover/flight.obs", "rinex-obs", "rover")
    files = api.get(f"/api/v1/surveys/{sid}/files").json()
    meta = next(x for x in files if x["path"] == "rover/flight.obs")["meta"]
    assert meta["epochs"] > 100 and meta["event_marks"] == 12 and meta["last_gps_time_s"] > meta["first_gps_time_s"]


def test_resume_and_idempotent_retry(ctx):
    api, sid, sim = ctx
    data = (sim / "images" / "IMG_0001.JPG").read_bytes()
    up = api.post(f"/api/v1/surveys/{sid}/uploads", json={"filename": "IMG_0001.JPG", "size": len(data),
                                                          "sha256": hashlib.sha256(data).hexdigest()}).json()
    n = 50000
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[:n], headers={"Content-Range": f"bytes 0-{n - 1}/{len(data)}"})
    assert r.json()["received_bytes"] == n
    # the same chunk again (a retry after a lost response): accepted, nothing appended
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[:n], headers={"Content-Range": f"bytes 0-{n - 1}/{len(data)}"})
    assert r.status_code == 200 and r.json()["received_bytes"] == n
    # a gap is refused and says where to resume
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[n + 10:2 * n],
                headers={"Content-Range": f"bytes {n + 10}-{2 * n - 1}/{len(data)}"})
    assert r.status_code == 409 and r.json()["received_bytes"] == n
    # a body shorter than its Content-Range is refused
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[n:n + 10],
                headers={"Content-Range": f"bytes {n}-{2 * n - 1}/{len(data)}"})
    assert r.status_code == 422
    assert api.get(f"/api/v1/uploads/{up['id']}").json()["received_bytes"] == n
    r = api.put(f"/api/v1/uploads/{up['id']}", content=data[n:],
                headers={"Content-Range": f"bytes {n}-{len(data) - 1}/{len(data)}"})
    assert r.json()["received_bytes"] == len(data)
    r = api.post(f"/api/v1/uploads/{up['id']}/complete")
    assert r.status_code == 200 and r.json()["result"]["files"][0]["path"] == "images/IMG_0001.JPG"
    assert api.post(f"/api/v1/uploads/{up['id']}/complete").status_code == 200   # idempotent


def test_bad_uploads_refused_and_survey_untouched(ctx):
    api, sid, sim = ctx
    before = _files(api, sid)
    jpeg = (sim / "images" / "IMG_0002.JPG").read_bytes()
    _refused(upload_bytes(api, sid, "report.pdf", b"%PDF-1.7\n" + b"x" * 500), "PDF document")
    _refused(upload_bytes(api, sid, "index.html", b"<!DOCTYPE html><html></html>"), "HTML page")
    _refused(upload_bytes(api, sid, "tool.exe", b"MZ\x90\x00" + b"\x00" * 200), "executable")
    _refused(upload_bytes(api, sid, "IMG.JPG", jpeg[: len(jpeg) // 2]), "truncated JPEG")
    _refused(upload_bytes(api, sid, "IMG.JPG", jpeg, kind="rover"), "kind=rover")
    _refused(upload_bytes(api, sid, "base.obs", (sim / "base" / "base.obs").read_bytes()[:1500]), "END OF HEADER")
    _refused(upload_bytes(api, sid, "points.csv", b"name,easting_m,northing_m,ellipsoidal_height_m,role\n"
                                                  b"T1,abc,1,2,control\n"), "easting_m", "line 2")
    _refused(upload_bytes(api, sid, "data.bin", POINTS_CSV, sha256="0" * 64), "SHA-256 mismatch")
    # a RINEX epoch with month 13 / a survey.json nested 50,000 deep: named, not a server error
    obs = (sim / "base" / "base.obs").read_text()
    head, body = obs.split("END OF HEADER", 1)
    line_no = head.count("\n") + 2
    first = body.split("\n", 2)[1]
    bad = head + "END OF HEADER" + body.replace(first, first[:7] + "13" + first[9:], 1)
    _refused(upload_bytes(api, sid, "base13.obs", bad.encode()), "impossible epoch date/time", f"line {line_no}")
    _refused(upload_bytes(api, sid, "survey.json", b'{"a":' + b"[" * 50000 + b"]" * 50000 + b"}"), "nested too deeply")
    # truncated transfer: completion refused until every byte arrived
    up = api.post(f"/api/v1/surveys/{sid}/uploads",
                  json={"filename": "x.csv", "size": len(POINTS_CSV) + 100,
                        "sha256": hashlib.sha256(POINTS_CSV).hexdigest()}).json()
    api.put(f"/api/v1/uploads/{up['id']}", content=POINTS_CSV,
            headers={"Content-Range": f"bytes 0-{len(POINTS_CSV) - 1}/{len(POINTS_CSV) + 100}"})
    r = api.post(f"/api/v1/uploads/{up['id']}/complete")
    assert r.status_code == 409 and "incomplete" in r.json()["detail"]
    # over-size: refused before any byte is sent
    r = api.post(f"/api/v1/surveys/{sid}/uploads", json={"filename": "huge.zip", "size": 10**15, "sha256": "0" * 64})
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    r = api.post(f"/api/v1/surveys/{sid}/uploads", json={"filename": "../../etc/passwd", "size": 5,
                                                         "sha256": "a" * 64})
    assert r.status_code == 201 and r.json()["filename"] == "passwd"
    assert _files(api, sid) == before


def test_archives(ctx):
    api, sid, sim = ctx
    before = _files(api, sid)
    nav = (sim / "nav" / "base.nav").read_bytes()
    _refused(upload_bytes(api, sid, "a.zip", _zip({"nav/ok.nav": nav, "../evil.nav": nav})), "outside")
    _refused(upload_bytes(api, sid, "b.zip", _zip({"/etc/cron.d/x": nav})), "absolute")
    _refused(upload_bytes(api, sid, "c.zip", _zip({"nav/ok.nav": nav}, symlink="nav/link.nav")), "symbolic link")
    bomb = _zip({"nav/zeros.nav": b"\0" * (64 * 1024**2)})
    assert len(bomb) < 200_000
    _refused(upload_bytes(api, sid, "d.zip", bomb), "zip bomb")
    _refused(upload_bytes(api, sid, "e.zip", bomb[: len(bomb) // 2]), "zip")          # truncated archive
    _refused(upload_bytes(api, sid, "f.zip", _zip({"readme.txt": b"hello"})), "no survey file")
    assert _files(api, sid) == before
    # a whole survey folder zipped (with a wrapper folder and extra material): placed by layout and content
    data = zip_folder(sim, skip=(), prefix="flight7/")
    r = upload_bytes(api, sid, "flight7.zip", data, kind="archive")
    assert r.status_code == 200, r.text
    placed = {f["path"] for f in r.json()["result"]["files"]}
    assert {"rover/rover.obs", "base/base.obs", "nav/base.nav", "events.csv", "gcp/points.csv",
            "gcp/gcp_list.txt", "survey.json"} <= placed
    assert sum(p.startswith("images/") for p in placed) == 12
    ignored = {i["name"] for i in r.json()["result"]["ignored"]}
    assert any(n.startswith("flight7/truth/") for n in ignored)       # truth/ is not survey input
    # a second rover log in the same survey (tests may run on other workers, so do not rely on their files)
    r = upload_bytes(api, sid, "second_flight.obs", (sim / "rover" / "rover.obs").read_bytes(), kind="rover")
    assert r.status_code == 200, r.text
    # several rover files are joined in time order (flights after battery swaps): named, not refused;
    # this one is the same log twice, which is said
    check = api.get(f"/api/v1/surveys/{sid}/check").json()
    codes = {p["code"]: p for p in check["problems"]}
    assert check["ok"] and check["errors"] == 0, check
    assert "several-rover-files" not in codes
    joined = codes["rover-files-joined"]
    assert joined["severity"] == "info" and {"rover/rover.obs", "rover/second_flight.obs"} <= set(joined["files"])
    assert re.match(r"rover: \d RINEX files, 2024-06-24 08:10-08:12, no gap", joined["message"]), joined
    assert codes["duplicate-files"]["severity"] == "warning"
    assert not {"missing-navigation", "no-time-overlap", "missing-base"} & set(codes)
    assert re.search(r"\d RINEX rover files, base: 1 RINEX file, navigation: \d RINEX files?", check["summary"]), check


def test_preflight_finds_problems(platform, ctx):
    api, _, sim = ctx
    site = api.get("/api/v1/sites").json()["items"][0]
    sv = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "incomplete"}).json()["id"]
    upload_bytes(api, sv, "rover.obs", (sim / "rover" / "rover.obs").read_bytes(), kind="rover")
    for i in (1, 2, 3):
        upload_bytes(api, sv, f"IMG_000{i}.JPG", (sim / "images" / f"IMG_000{i}.JPG").read_bytes())
    check = api.get(f"/api/v1/surveys/{sv}/check").json()
    codes = {p["code"]: p for p in check["problems"]}
    assert not check["ok"]
    assert {"missing-base", "missing-navigation", "no-points", "images-without-events"} <= set(codes)
    assert "3 images but 12 event marks" in codes["images-without-events"]["message"]
    # a base that does not overlap the rover in time
    text = (sim / "base" / "base.obs").read_text().replace("  2024     6    24", "  2024     6    25")
    lines = [ln if not ln.startswith("> 2024 06 24") else ln.replace("> 2024 06 24", "> 2024 06 25")
             for ln in text.splitlines()]
    upload_bytes(api, sv, "base.obs", ("\n".join(lines) + "\n").encode(), kind="base")
    codes = {p["code"] for p in api.get(f"/api/v1/surveys/{sv}/check").json()["problems"]}
    assert "no-time-overlap" in codes
