"""Access control, proved for EVERY endpoint of the app (the routes are enumerated from the app: a new
endpoint without an entry here fails `test_every_route_is_covered`).

World: user A is admin of site A (with a survey, files, an upload, a run, a stockpile, a schedule and a
webhook); user B is in the same organisation with no role on site A; user C is a viewer of site A.
Checked for each site-scoped endpoint: B gets 404 (the same answer as for an object that does not
exist, so nothing leaks), C gets 403 on anything above viewer, anonymous callers get 401, a read-only
API token gets 403 on writes; and after all of B's attempts site A is unchanged."""

from __future__ import annotations

import hashlib

import pytest
from fastapi.routing import iter_route_contexts

from .platform_helpers import PUBLIC_TEST_IP, Api, FakeDNS, add_user, upload_bytes

POINTS = b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.0,3889231.0,80.0,control\n" \
         b"T2,679478.0,3889241.0,79.9,check\n"
OUTLINE = {"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]]]}

# (method, path) -> (scope object, minimal role, request body or None)
SCOPED = {
    ("GET", "/api/v1/sites/{site_id}"): ("site", "viewer", None),
    ("PATCH", "/api/v1/sites/{site_id}"): ("site", "admin", {"name": "hacked"}),
    ("DELETE", "/api/v1/sites/{site_id}"): ("site", "admin", None),
    ("GET", "/api/v1/sites/{site_id}/members"): ("site", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/summary"): ("site", "viewer", None),
    ("PUT", "/api/v1/sites/{site_id}/members/{user_id}"): ("site", "admin", {"role": "admin"}),
    ("DELETE", "/api/v1/sites/{site_id}/members/{user_id}"): ("site", "admin", None),
    ("GET", "/api/v1/sites/{site_id}/surveys"): ("site", "viewer", None),
    ("POST", "/api/v1/sites/{site_id}/surveys"): ("site", "editor", {"name": "intruder"}),
    ("GET", "/api/v1/surveys/{survey_id}"): ("survey", "viewer", None),
    ("PATCH", "/api/v1/surveys/{survey_id}"): ("survey", "editor", {"name": "hacked"}),
    ("DELETE", "/api/v1/surveys/{survey_id}"): ("survey", "editor", None),
    ("GET", "/api/v1/surveys/{survey_id}/files"): ("survey", "viewer", None),
    ("PATCH", "/api/v1/surveys/{survey_id}/files/{file_id}"): ("survey", "editor", {"role": "base"}),
    ("DELETE", "/api/v1/surveys/{survey_id}/files/{file_id}"): ("survey", "editor", None),
    ("GET", "/api/v1/surveys/{survey_id}/check"): ("survey", "viewer", None),
    ("GET", "/api/v1/surveys/{survey_id}/points"): ("survey", "viewer", None),
    ("PATCH", "/api/v1/surveys/{survey_id}/points/{name}"): ("survey", "editor", {"role": "check"}),
    ("GET", "/api/v1/surveys/{survey_id}/report.pdf"): ("survey", "viewer", None),
    ("POST", "/api/v1/surveys/{survey_id}/uploads"): ("survey", "editor",
                                                     {"filename": "x.csv", "size": 10, "sha256": "0" * 64}),
    ("GET", "/api/v1/surveys/{survey_id}/uploads"): ("survey", "viewer", None),
    ("GET", "/api/v1/uploads/{upload_id}"): ("upload", "viewer", None),
    ("PUT", "/api/v1/uploads/{upload_id}"): ("upload", "editor", b"0123456789"),
    ("POST", "/api/v1/uploads/{upload_id}/complete"): ("upload", "editor", None),
    ("DELETE", "/api/v1/uploads/{upload_id}"): ("upload", "editor", None),
    ("GET", "/api/v1/surveys/{survey_id}/runs"): ("survey", "viewer", None),
    ("POST", "/api/v1/surveys/{survey_id}/runs"): ("survey", "editor", {"steps": ["gnss"]}),
    ("GET", "/api/v1/runs/{run_id}"): ("run", "viewer", None),
    ("POST", "/api/v1/runs/{run_id}/cancel"): ("run", "editor", None),
    ("POST", "/api/v1/runs/{run_id}/rerun"): ("run", "editor", {"from_step": "gnss"}),
    ("GET", "/api/v1/runs/{run_id}/logs"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/changes"): ("run", "viewer", None),
    ("POST", "/api/v1/runs/{run_id}/volumes"): ("run", "viewer", {"outline": OUTLINE, "base": "lowest"}),
    ("GET", "/api/v1/runs/{run_id}/events"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/trajectory"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/camera-positions"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/residuals"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/lever-arm"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/volumes"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/dsm"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/ortho"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/point-cloud"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/report.pdf"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/results/files/{path:path}"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/tiles"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/tiles/{layer}/legend.json"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/tiles/{layer}/{z}/{x}/{y}.png"): ("run", "viewer", None),
    ("GET", "/api/v1/runs/{run_id}/wmts/1.0.0/WMTSCapabilities.xml"): ("run", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/stockpiles"): ("site", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/inventory"): ("site", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/design"): ("site", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/design/file"): ("site", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/design-progress"): ("site", "viewer", None),
    ("PUT", "/api/v1/sites/{site_id}/design/file"): ("site", "editor", b"<LandXML/>"),
    ("PATCH", "/api/v1/sites/{site_id}/design"): ("site", "editor", {"tolerance_m": 0.1}),
    ("DELETE", "/api/v1/sites/{site_id}/design"): ("site", "editor", None),
    ("GET", "/api/v1/sites/{site_id}/calibration"): ("site", "viewer", None),
    ("PUT", "/api/v1/sites/{site_id}/calibration"): ("site", "admin", {"pairs_csv": "name,easting_m\n"}),
    ("DELETE", "/api/v1/sites/{site_id}/calibration"): ("site", "admin", None),
    ("POST", "/api/v1/sites/{site_id}/stockpiles"): ("site", "editor", {"name": "intruder", "outline": OUTLINE}),
    ("GET", "/api/v1/stockpiles/{stockpile_id}"): ("stockpile", "viewer", None),
    ("PATCH", "/api/v1/stockpiles/{stockpile_id}"): ("stockpile", "editor", {"name": "hacked"}),
    ("DELETE", "/api/v1/stockpiles/{stockpile_id}"): ("stockpile", "editor", None),
    ("GET", "/api/v1/stockpiles/{stockpile_id}/volumes"): ("stockpile", "viewer", None),
    ("GET", "/api/v1/sites/{site_id}/schedules"): ("site", "viewer", None),
    ("POST", "/api/v1/sites/{site_id}/schedules"): ("site", "admin", {"name": "intruder"}),
    ("GET", "/api/v1/schedules/{schedule_id}"): ("schedule", "viewer", None),
    ("PATCH", "/api/v1/schedules/{schedule_id}"): ("schedule", "admin", {"name": "hacked"}),
    ("DELETE", "/api/v1/schedules/{schedule_id}"): ("schedule", "admin", None),
    ("GET", "/api/v1/webhooks/{webhook_id}"): ("webhook", "admin", None),
    ("PATCH", "/api/v1/webhooks/{webhook_id}"): ("webhook", "admin", {"active": False}),
    ("DELETE", "/api/v1/webhooks/{webhook_id}"): ("webhook", "admin", None),
    ("GET", "/api/v1/webhooks/{webhook_id}/deliveries"): ("webhook", "admin", None),
}
# not scoped by a path parameter: each has its own proof in test_unscoped_routes
UNSCOPED = {
    ("POST", "/api/v1/auth/login"), ("POST", "/api/v1/auth/logout"), ("GET", "/api/v1/auth/me"),
    ("POST", "/api/v1/auth/password"), ("GET", "/api/v1/tokens"), ("POST", "/api/v1/tokens"),
    ("DELETE", "/api/v1/tokens/{token_id}"), ("POST", "/api/v1/tokens/tile"), ("GET", "/api/v1/users"), ("POST", "/api/v1/users"),
    ("PATCH", "/api/v1/users/{user_id}"),
    ("GET", "/api/v1/sites"), ("POST", "/api/v1/sites"), ("GET", "/api/v1/webhooks"), ("POST", "/api/v1/webhooks"),
    ("GET", "/api/v1/health"), ("GET", "/api/v1/steps"), ("GET", "/api/v1/steps/{name}"), ("GET", "/api/v1/file-kinds"),
}
PUBLIC = {("POST", "/api/v1/auth/login"), ("GET", "/api/v1/health")}
NOT_FOUND_WORD = {"site": "site", "survey": "survey", "run": "run", "upload": "upload", "stockpile": "stockpile",
                  "schedule": "schedule", "webhook": "webhook"}
ROLE_RANK = {"viewer": 1, "editor": 2, "admin": 3}


def app_routes(app) -> set[tuple[str, str]]:
    out = set()
    for r in iter_route_contexts(app.routes):
        if not r.path.startswith("/api/"):
            continue
        for m in r.methods or ():
            if m != "HEAD":
                out.add((m, r.path))
    return out


@pytest.fixture(scope="module")
def world(platform):
    a_id, org = add_user(platform, f"a-{platform.shape}@example.org", org_admin=True)
    b_id, _ = add_user(platform, f"b-{platform.shape}@example.org", org)
    c_id, _ = add_user(platform, f"c-{platform.shape}@example.org", org)
    a, b, c = (Api(platform, f"{x}-{platform.shape}@example.org") for x in "abc")
    site = a.post("/api/v1/sites", json={"name": "Site A", "crs": "EPSG:32653"}).json()
    assert a.put(f"/api/v1/sites/{site['id']}/members/{c_id}", json={"role": "viewer"}).status_code == 200
    survey = a.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "Flight 1"}).json()
    r = upload_bytes(a, survey["id"], "points.csv", POINTS, kind="points")
    assert r.status_code == 200, r.text
    files = a.get(f"/api/v1/surveys/{survey['id']}/files").json()
    r = a.post(f"/api/v1/surveys/{survey['id']}/uploads",
               json={"filename": "rover.obs", "size": 10, "sha256": hashlib.sha256(b"0123456789").hexdigest()})
    upload = r.json()
    run = a.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss"]}).json()
    pile = a.post(f"/api/v1/sites/{site['id']}/stockpiles", json={"name": "P1", "outline": OUTLINE}).json()
    sched = a.post(f"/api/v1/sites/{site['id']}/schedules", json={"name": "nightly"}).json()
    with pytest.MonkeyPatch.context() as mp:   # the webhook's name resolves without a DNS query
        mp.setattr("socket.getaddrinfo", FakeDNS({"gis.example.com": [PUBLIC_TEST_IP]}))
        hook = a.post("/api/v1/webhooks", json={"site_id": site["id"], "url": "https://gis.example.com/hook"}).json()
    tok = a.post("/api/v1/tokens", json={"name": "gis", "scopes": ["read"]}).json()
    ids = {"site_id": site["id"], "survey_id": survey["id"], "file_id": files[0]["id"], "upload_id": upload["id"],
           "run_id": run["id"], "stockpile_id": pile["id"], "schedule_id": sched["id"], "webhook_id": hook["id"],
           "user_id": c_id, "name": "T1", "path": "ppk/trajectory.pos", "token_id": tok["id"],
           "layer": "ortho", "z": 0, "x": 0, "y": 0}
    return {"a": a, "b": b, "c": c, "ids": ids, "read_token": tok["token"], "platform": platform, "b_id": b_id}


def _call(client, method: str, path: str, body, headers=None):
    url = path
    kw = {"headers": dict(headers or {})}
    if isinstance(body, bytes):
        kw["content"] = body
        kw["headers"]["Content-Range"] = f"bytes 0-{len(body) - 1}/{len(body)}"
    elif body is not None:
        kw["json"] = body
    if path.endswith("/events"):
        url += "?poll_s=0.1&max_s=0.3"
    if method == "PUT" and path.endswith("/design/file"):
        url += "?filename=design.xml"
    m = getattr(client, method.lower())
    if method in ("GET", "DELETE"):
        kw.pop("json", None)
    return m(url, **kw)


def _fill(path: str, ids: dict) -> str:
    return path.replace("{path:path}", "{path}").format(**ids)


def test_every_route_is_covered(platform):
    routes = app_routes(platform.app)
    missing = routes - set(SCOPED) - UNSCOPED
    stale = (set(SCOPED) | UNSCOPED) - routes
    assert not missing, f"endpoints without an access test: {sorted(missing)}"
    assert not stale, f"access table lists endpoints that no longer exist: {sorted(stale)}"


def test_outsider_gets_not_found_everywhere(world):
    b, ids = world["b"], world["ids"]
    for (method, path), (scope, _, body) in sorted(SCOPED.items()):
        r = _call(b, method, _fill(path, ids), body)
        assert r.status_code == 404, (method, path, r.status_code, r.text[:200])
        assert r.headers["content-type"].startswith("application/problem+json"), (method, path)
        assert f"{NOT_FOUND_WORD[scope]} not found" in r.json()["detail"], (method, path, r.json()["detail"])
    # and nothing changed
    a = world["a"]
    assert a.get(f"/api/v1/sites/{ids['site_id']}").json()["name"] == "Site A"
    assert a.get(f"/api/v1/surveys/{ids['survey_id']}").json()["name"] == "Flight 1"
    assert a.get(f"/api/v1/stockpiles/{ids['stockpile_id']}").json()["name"] == "P1"
    assert a.get(f"/api/v1/schedules/{ids['schedule_id']}").json()["name"] == "nightly"
    assert a.get(f"/api/v1/webhooks/{ids['webhook_id']}").json()["active"] is True
    assert a.get(f"/api/v1/runs/{ids['run_id']}").json()["state"] in ("queued", "running")
    members = {m["user_id"] for m in a.get(f"/api/v1/sites/{ids['site_id']}/members").json()}
    assert world["b_id"] not in members
    assert [p["role"] for p in a.get(f"/api/v1/surveys/{ids['survey_id']}/points").json()] == ["control", "check"]


def test_viewer_reads_but_cannot_change(world):
    c, ids = world["c"], world["ids"]
    for (method, path), (scope, role, body) in sorted(SCOPED.items()):
        if ROLE_RANK[role] <= ROLE_RANK["viewer"]:
            if method != "GET":
                continue
            r = _call(c, method, _fill(path, ids), body)
            # allowed: data, or "no such result yet" -- but never the scope's not-found nor forbidden
            assert r.status_code not in (401, 403), (path, r.status_code, r.text[:200])
            if r.status_code == 404:
                assert f"{NOT_FOUND_WORD[scope]} not found" not in r.json()["detail"], (path, r.text)
        else:
            r = _call(c, method, _fill(path, ids), body)
            assert r.status_code == 403, (method, path, r.status_code, r.text[:200])


def test_anonymous_gets_401(world):
    anon = world["platform"].client()
    ids = world["ids"]
    for (method, path), (_, _, body) in sorted(SCOPED.items()):
        r = _call(anon, method, _fill(path, ids), body)
        assert r.status_code == 401, (method, path, r.status_code)
        assert r.headers["content-type"].startswith("application/problem+json")
    for method, path in sorted(UNSCOPED - PUBLIC):
        body = {} if method in ("POST", "PUT", "PATCH") else None
        r = _call(anon, method, _fill(path, ids), body)
        assert r.status_code in (401, 422), (method, path, r.status_code)


def test_read_token_cannot_write(world):
    ids = world["ids"]
    client = world["platform"].client()
    h = {"Authorization": f"Bearer {world['read_token']}"}
    for (method, path), (scope, role, body) in sorted(SCOPED.items()):
        r = _call(client, method, _fill(path, ids), body, headers=h)
        if role == "viewer":
            assert r.status_code not in (401, 403), (path, r.status_code, r.text[:200])
        else:
            assert r.status_code == 403, (method, path, r.status_code, r.text[:200])
    # tokens cannot mint tokens
    assert client.post("/api/v1/tokens", json={"name": "x", "scopes": ["admin"]}, headers=h).status_code == 403


def test_unscoped_routes(world):
    a, b, ids = world["a"], world["b"], world["ids"]
    # site lists only show sites with a role; webhooks only those of sites one administers
    assert ids["site_id"] not in [s["id"] for s in b.get("/api/v1/sites").json()["items"]]
    assert ids["site_id"] in [s["id"] for s in a.get("/api/v1/sites").json()["items"]]
    assert ids["webhook_id"] not in [w["id"] for w in b.get("/api/v1/webhooks").json()]
    assert b.get(f"/api/v1/webhooks?site_id={ids['site_id']}").status_code == 404
    assert world["c"].get(f"/api/v1/webhooks?site_id={ids['site_id']}").status_code == 403
    r = b.post("/api/v1/webhooks", json={"site_id": ids["site_id"], "url": "http://127.0.0.1:9/x"})
    assert r.status_code == 404
    # a site created by B is B's alone
    r = b.post("/api/v1/sites", json={"name": "Site B", "crs": "EPSG:32631"})
    assert r.status_code == 201
    assert a.get(f"/api/v1/sites/{r.json()['id']}").status_code == 404
    # tokens and sessions are per user: B cannot revoke A's token
    assert b.delete(f"/api/v1/tokens/{ids['token_id']}").status_code == 404
    assert ids["token_id"] not in [t["id"] for t in b.get("/api/v1/tokens").json()]
    me = b.get("/api/v1/auth/me").json()
    assert all(r["site_id"] != ids["site_id"] for r in me["site_roles"])
    # only organisation admins add users, and (de)activate them; never in another organisation
    assert b.post("/api/v1/users", json={"email": "z@example.org", "password": "long-enough-1"}).status_code == 403
    assert b.patch(f"/api/v1/users/{ids['user_id']}", json={"is_active": False}).status_code == 403
    assert world["c"].get("/api/v1/auth/me").status_code == 200     # C untouched
    outsider_id, _ = add_user(world["platform"], f"o-{world['platform'].shape}@example.org")
    assert a.patch(f"/api/v1/users/{outsider_id}", json={"is_active": False}).status_code == 404
    assert a.get("/api/v1/health").status_code == 200


def test_csrf_required_for_cookie_sessions(world):
    a, ids = world["a"], world["ids"]
    r = a.c.patch(f"/api/v1/sites/{ids['site_id']}", json={"name": "no csrf"})
    assert r.status_code == 403 and "CSRF" in r.json()["detail"]
    r = a.c.patch(f"/api/v1/sites/{ids['site_id']}", json={"name": "wrong"}, headers={"X-CSRF-Token": "nope"})
    assert r.status_code == 403
    assert a.get(f"/api/v1/sites/{ids['site_id']}").json()["name"] == "Site A"
