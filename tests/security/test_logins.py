"""Logins: throttled per account and per client address (429 + Retry-After, decided before the Argon2
check and shared by every API process through the database), a password policy at account creation and
password change, and account deactivation by an organisation admin.

Against the real app on PostgreSQL and on the embedded SQLite shape, with small throttle settings (3 free
failures per account, 6 per client address, 4 s first back-off); the cross-process test starts a real
uvicorn on 127.0.0.1 against the same database."""

from __future__ import annotations

import os
import socket
import subprocess
import time

import httpx
import pytest

from backend.core import security

from ..backend.platform_helpers import (PASSWORD, PY, REPO, Api, add_user, close_platform, have_postgres, have_redis,
                                        make_platform, worker_env)

PER_ACCOUNT, PER_CLIENT, BACKOFF_S = 3, 6, 4.0   # the first back-off outlasts a slow Argon2 check


@pytest.fixture(scope="module", params=["postgres", "embedded"])
def auth_platform(request, tmp_path_factory):
    if request.param == "postgres" and not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed for the production shape")
    p = make_platform(tmp_path_factory.mktemp(f"auth-{request.param}"), request.param,
                      login_max_failures_per_account=PER_ACCOUNT, login_max_failures_per_client=PER_CLIENT,
                      login_backoff_base_s=BACKOFF_S, login_backoff_max_s=60)
    yield p
    close_platform(p)


def _client(p, address: str):
    from fastapi.testclient import TestClient

    return TestClient(p.app, base_url="https://testserver", client=(address, 40000))


def _login(c, email: str, password: str):
    return c.post("/api/v1/auth/login", json={"email": email, "password": password})


@pytest.fixture
def verifications(monkeypatch):
    """How many Argon2 verifications the server ran."""
    calls = []
    real = security.verify_password

    def counting(h, pw):
        calls.append(1)
        return real(h, pw)
    monkeypatch.setattr(security, "verify_password", counting)
    return calls


def _assert_429(r):
    assert r.status_code == 429, (r.status_code, r.text)
    assert r.headers["content-type"].startswith("application/problem+json")
    retry = int(r.headers["retry-after"])
    assert 1 <= retry <= 60
    assert "too many failed logins" in r.json()["detail"]
    return retry


def test_account_throttle_answers_429_before_the_password_check(auth_platform, verifications):
    p = auth_platform
    email = f"victim-{p.shape}@example.org"
    add_user(p, email)
    a, b = _client(p, "198.51.100.10"), _client(p, "198.51.100.11")
    for _ in range(PER_ACCOUNT):
        assert _login(a, email, "wrong-password-0").status_code == 401
    assert len(verifications) == PER_ACCOUNT
    # blocked: even the right password, even from another address, and without an Argon2 verification
    retry = _assert_429(_login(a, email, PASSWORD))
    _assert_429(_login(b, email, PASSWORD))
    assert len(verifications) == PER_ACCOUNT
    # an e-mail without an account is throttled the same way (nothing tells which addresses exist)
    ghost = f"nobody-{p.shape}@example.org"
    for _ in range(PER_ACCOUNT):
        assert _login(b, ghost, "wrong-password-0").status_code == 401
    _assert_429(_login(b, ghost, "wrong-password-0"))
    # after the wait the right password works and clears the account's count
    time.sleep(retry + 0.2)
    assert _login(b, email, PASSWORD).status_code == 200
    for _ in range(PER_ACCOUNT - 1):
        assert _login(a, email, "wrong-password-1").status_code == 401
    assert _login(a, email, PASSWORD).status_code == 200


def test_backoff_grows(auth_platform):
    p = auth_platform
    email = f"backoff-{p.shape}@example.org"
    add_user(p, email)
    c = _client(p, "198.51.100.20")
    for _ in range(PER_ACCOUNT):
        assert _login(c, email, "wrong-password-0").status_code == 401
    first = _assert_429(_login(c, email, "wrong-password-0"))
    time.sleep(first + 0.2)
    assert _login(c, email, "wrong-password-0").status_code == 401      # one more failure ...
    second = _assert_429(_login(c, email, "wrong-password-0"))
    assert second > first                                                # ... doubles the wait


def test_client_address_throttle(auth_platform, verifications):
    p = auth_platform
    good = f"good-{p.shape}@example.org"
    add_user(p, good)
    attacker, other = _client(p, "203.0.113.66"), _client(p, "203.0.113.67")
    for i in range(PER_CLIENT):       # one guess per account: no account reaches its own limit
        assert _login(attacker, f"spray{i}-{p.shape}@example.org", "Winter2024!!").status_code == 401
    n = len(verifications)
    _assert_429(_login(attacker, good, PASSWORD))
    assert len(verifications) == n
    assert _login(other, good, PASSWORD).status_code == 200
    # IPv6: one /64 is one client
    v6 = [_client(p, f"2001:db8:77:1::{k:x}") for k in range(1, PER_CLIENT + 2)]
    for i in range(PER_CLIENT):
        assert _login(v6[i], f"v6spray{i}-{p.shape}@example.org", "Winter2024!!").status_code == 401
    _assert_429(_login(v6[-1], good, PASSWORD))
    assert _login(_client(p, "2001:db8:78:1::1"), good, PASSWORD).status_code == 200


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_throttle_is_shared_by_api_processes(auth_platform):
    """Failures counted by one API process are seen by another (a real uvicorn on the same database), in
    both directions: the counts are not in a process's memory."""
    p = auth_platform
    email, email2 = f"multi-{p.shape}@example.org", f"multi2-{p.shape}@example.org"
    add_user(p, email)
    add_user(p, email2)
    port = _free_port()
    env = worker_env(p, freeze_heap="false")
    log_path = p.data_dir / f"uvicorn-{port}.log"
    log = open(log_path, "wb")
    proc = subprocess.Popen([PY, "-m", "uvicorn", "backend.main:app", "--host", "127.0.0.1", "--port", str(port)],
                            cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 90
        up = False
        while time.monotonic() < deadline and proc.poll() is None and not up:
            try:
                up = httpx.get(url + "/api/v1/health", timeout=2).status_code == 200
            except httpx.HTTPError:
                time.sleep(0.3)
        assert up, log_path.read_text()[-2000:]
        # failures here, the block seen there (the first back-off lasts BACKOFF_S: checked at once)
        c = _client(p, "198.51.100.30")
        for _ in range(PER_ACCOUNT):
            assert _login(c, email, "wrong-password-0").status_code == 401
        _assert_429(httpx.post(url + "/api/v1/auth/login", json={"email": email, "password": PASSWORD}, timeout=30))
        # failures there, the block seen here
        for _ in range(PER_ACCOUNT):
            r = httpx.post(url + "/api/v1/auth/login", json={"email": email2, "password": "wrong-password-0"},
                           timeout=30)
            assert r.status_code == 401
        _assert_429(_login(c, email2, PASSWORD))
    finally:
        os.killpg(proc.pid, 15)
        proc.wait(timeout=20)
        log.close()


WEAK = [("aaaaaaaaaa", "repetitive"), ("password12", "common"), (" " * 12, "whitespace"), ("short-1", "min_length"),
        ("P@ssw0rd2024!", "common"), ("qwertyuiop", "common"), ("1234567890", "common"), ("iloveyou123", "common"),
        ("abababababab", "repetitive"), ("jane.doe-rocks-9", "contains_email"), ("JaneDoe-rocks-9", "contains_email")]


def test_password_policy_on_creation_and_change(auth_platform):
    p = auth_platform
    add_user(p, f"admin-{p.shape}@example.org", org_admin=True)
    admin = Api(p, f"admin-{p.shape}@example.org")
    email = f"jane.doe-{p.shape}@example.org"
    for pw, rule in WEAK:
        r = admin.post("/api/v1/users", json={"email": email.replace("-" + p.shape, ""), "password": pw})
        assert r.status_code == 422, (pw, r.status_code, r.text)
        body = r.json()
        assert body["rule"] == rule, (pw, body)
        assert body["detail"].startswith("password:")
    r = admin.post("/api/v1/users", json={"email": email, "password": "tarmac-lichen-47"})
    assert r.status_code == 201, r.text
    user = Api.__new__(Api)
    user.c = p.client()
    r = user.c.post("/api/v1/auth/login", json={"email": email, "password": "tarmac-lichen-47"})
    assert r.status_code == 200
    user.csrf = r.json()["csrf_token"]
    for pw, rule in WEAK:
        if rule == "contains_email":
            continue
        r = user.post("/api/v1/auth/password", json={"current_password": "tarmac-lichen-47", "new_password": pw})
        assert r.status_code == 422 and r.json()["rule"] == rule, (pw, r.text)
    r = user.post("/api/v1/auth/password", json={"current_password": "tarmac-lichen-47",
                                                 "new_password": "jane.doe-forever-1"})
    assert r.status_code == 422 and r.json()["rule"] == "contains_email"
    r = user.post("/api/v1/auth/password", json={"current_password": "tarmac-lichen-47",
                                                 "new_password": "basalt-orchid-93"})
    assert r.status_code == 204, r.text
    assert _login(p.client(), email, "basalt-orchid-93").status_code == 200


def test_password_change_is_throttled(auth_platform, verifications):
    p = auth_platform
    email = f"changer-{p.shape}@example.org"
    add_user(p, email)
    api = Api(p, email)
    for _ in range(PER_ACCOUNT):
        r = api.post("/api/v1/auth/password", json={"current_password": "not-it-at-all", "new_password": "fjord-cactus-12"})
        assert r.status_code == 403
    n = len(verifications)
    r = api.post("/api/v1/auth/password", json={"current_password": PASSWORD, "new_password": "fjord-cactus-12"})
    _assert_429(r)
    assert len(verifications) == n


def test_deactivated_users_are_locked_out(auth_platform):
    p = auth_platform
    add_user(p, f"boss-{p.shape}@example.org", org_admin=True)
    boss = Api(p, f"boss-{p.shape}@example.org")
    org = boss.get("/api/v1/auth/me").json()["organisation"]["id"]
    uid, _ = add_user(p, f"leaver-{p.shape}@example.org", org)
    peer_id, _ = add_user(p, f"peer-{p.shape}@example.org", org)
    leaver = Api(p, f"leaver-{p.shape}@example.org")
    token = leaver.post("/api/v1/tokens", json={"name": "gis", "scopes": ["read"]}).json()["token"]
    bearer = {"Authorization": f"Bearer {token}"}
    anon = p.client()
    assert anon.get("/api/v1/auth/me", headers=bearer).status_code == 200

    # only an organisation admin, never on oneself
    peer = Api(p, f"peer-{p.shape}@example.org")
    assert peer.patch(f"/api/v1/users/{uid}", json={"is_active": False}).status_code == 403
    me = boss.get("/api/v1/auth/me").json()["user"]["id"]
    assert boss.patch(f"/api/v1/users/{me}", json={"is_active": False}).status_code == 409

    r = boss.patch(f"/api/v1/users/{uid}", json={"is_active": False})
    assert r.status_code == 200 and r.json()["is_active"] is False
    assert {u["id"]: u["is_active"] for u in boss.get("/api/v1/users").json()}[uid] is False
    # the open session, the API token and a new login are all refused
    assert leaver.get("/api/v1/auth/me").status_code == 401
    assert anon.get("/api/v1/auth/me", headers=bearer).status_code == 401
    r = _login(p.client(), f"leaver-{p.shape}@example.org", PASSWORD)
    assert r.status_code == 401 and r.json()["detail"] == "e-mail or password is wrong"
    # reactivated: a new login and the token work again (the old session stays ended)
    assert boss.patch(f"/api/v1/users/{uid}", json={"is_active": True}).json()["is_active"] is True
    assert leaver.get("/api/v1/auth/me").status_code == 401
    assert _login(p.client(), f"leaver-{p.shape}@example.org", PASSWORD).status_code == 200
    assert anon.get("/api/v1/auth/me", headers=bearer).status_code == 200
    assert peer_id


def test_shipped_passwords_satisfy_the_policy():
    from backend.core import passwords
    from backend.serve_embedded import DEMO_EMAIL, DEMO_PASSWORD
    from tests.frontend import e2e_platform

    passwords.check(DEMO_PASSWORD, DEMO_EMAIL)
    passwords.check(e2e_platform.DEMO_PASSWORD, e2e_platform.DEMO_EMAIL)
    for email in ("surveyor@example.org", "a-postgres@example.org", "emb@example.org", "fuzz-embedded@example.org"):
        passwords.check(PASSWORD, email)
    assert len(passwords.common_passwords()) > 2000
