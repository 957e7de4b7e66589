"""The production shape's API server without nginx in front: the Dockerfile's own command (migrations, then
uvicorn with the options docker-compose's api service runs it with, `API_WORKERS` processes), against
PostgreSQL (127.0.0.1:5432) and Redis as docker-compose's environment names them (the object store is the
local one here: MinIO is not what is tested).

Before: plain `uvicorn` had no deadline on request headers (a connection that sent part of its headers, or
nothing, stayed open for ever: only nginx's client_header_timeout ended it) and no bound on their size
(httptools keeps them in memory), so the API relied on nginx. Now the command names the guarded protocol
(core/http_protocol.py SettingsHttpProtocol): 408 past GEOREF_REQUEST_HEADER_TIMEOUT_S, 431 past
GEOREF_MAX_REQUEST_HEADER_BYTES, one log line for a burst of refusals; /health, reads and writes answer
meanwhile."""

from __future__ import annotations

import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time

import httpx
import pytest

from ..backend.platform_helpers import Api, add_user, close_platform, have_postgres, have_redis, make_platform
from .slow_clients import SlowClients, free_port

REPO = __import__("pathlib").Path(__file__).resolve().parents[2]
HEADER_TIMEOUT_S = 4.0
N_SLOW = 40


def _api_command(port: int) -> list[str]:
    """The Dockerfile's CMD as scripts/compose_local.py runs it: this venv's python, the loopback, a free port."""
    sys.path.insert(0, str(REPO / "scripts"))
    try:
        from compose_local import dockerfile_cmd
    finally:
        sys.path.pop(0)
    cmd = dockerfile_cmd()
    assert cmd[:2] == ["sh", "-c"], cmd
    script = cmd[2].replace("--host 0.0.0.0", "--host 127.0.0.1").replace("--port 8000", f"--port {port}")
    script = re.sub(r"(?<![\w/])python -m ", f"{shlex.quote(sys.executable)} -m ", script)
    return ["sh", "-c", script.replace("exec uvicorn ", f"exec {shlex.quote(sys.executable)} -m uvicorn ")]


def _compose_api_env() -> dict[str, str]:
    import yaml

    sys.path.insert(0, str(REPO / "scripts"))
    try:
        from compose_local import expand
    finally:
        sys.path.pop(0)
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    return {k: expand(v) for k, v in (compose["services"]["api"].get("environment") or {}).items()}


@pytest.fixture(scope="module")
def production(tmp_path_factory):
    if not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed for the production shape")
    tmp = tmp_path_factory.mktemp("production-api")
    p = make_platform(tmp, "postgres")
    add_user(p, "user-prod@example.org")
    api = Api(p, "user-prod@example.org")
    token = api.post("/api/v1/tokens", json={"name": "t", "scopes": ["write"]}).json()["token"]
    tokens = {"reader": token, "writer": token}
    site = api.post("/api/v1/sites", json={"name": "S", "crs": "EPSG:32653"}).json()
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("GEOREF_")}
    env.update(_compose_api_env())
    env.update({k: v for k, v in p.env.items() if k in ("GEOREF_DATABASE_URL", "GEOREF_BROKER_URL", "GEOREF_DATA_DIR")})
    env.update({"GEOREF_STORAGE": "local", "GEOREF_COOKIE_SECURE": "false", "GEOREF_PUBLIC_URL": f"http://127.0.0.1:{port}",
                "GEOREF_REQUEST_HEADER_TIMEOUT_S": str(HEADER_TIMEOUT_S), "GEOREF_MAX_REQUEST_HEADER_BYTES": "16384",
                "GEOREF_REQUEST_BODY_TIMEOUT_S": "3", "API_WORKERS": "1", "PYTHONPATH": str(REPO)})
    log = tmp / "api.log"
    with open(log, "wb") as f:
        proc = subprocess.Popen(_api_command(port), cwd=REPO, env=env, stdout=f, stderr=subprocess.STDOUT,
                                start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 90
        while True:
            assert proc.poll() is None, log.read_text()[-3000:]
            try:
                if httpx.get(url + "/api/v1/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.2)
        yield {"url": url, "port": port, "tokens": tokens, "site": site["id"], "log": log}
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
        close_platform(p)


def test_slow_headers_and_bodies_without_nginx(production):
    url, tokens = production["url"], production["tokens"]
    reader = httpx.Client(base_url=url, timeout=5, headers={"Authorization": f"Bearer {tokens['reader']}"})
    writer = httpx.Client(base_url=url, timeout=5, headers={"Authorization": f"Bearer {tokens['writer']}"})
    # the process's first write loads the CRS database (a second on a busy machine): warm it up first
    assert writer.post("/api/v1/sites", json={"name": "warm", "crs": "EPSG:32653"}).status_code == 201
    assert reader.get(f"/api/v1/sites/{production['site']}").status_code == 200
    heads = SlowClients.slow_headers(production["port"], N_SLOW, N_SLOW // 4).start()
    bodies = SlowClients(production["port"], N_SLOW, interval_s=0.5).start()
    try:
        time.sleep(0.5)
        times = []
        for i in range(1):
            for what, fn in (("health", lambda: httpx.get(url + "/api/v1/health", timeout=5)),
                             ("read", lambda: reader.get(f"/api/v1/sites/{production['site']}")),
                             ("write", lambda: writer.post("/api/v1/sites", json={"name": f"P{i}", "crs": "EPSG:32653"}))):
                t0 = time.monotonic()
                r = fn()
                times.append((what, r.status_code, round(time.monotonic() - t0, 3)))
                assert r.status_code in (200, 201), (what, r.status_code, r.text[:300])
        assert max(t for _, _, t in times) < 1.0, times
        assert time.monotonic() - heads.connected_at < HEADER_TIMEOUT_S, "the checks must run while the slow clients wait"
        heads.wait_answers(HEADER_TIMEOUT_S + 5)
        bodies.wait_answers(3 + 5)
        # every slow or silent connection was answered 408 and closed by the server, at its deadline
        assert len(heads.answers) == len(heads.socks)
        assert {a for _, a in heads.answers.values()} == {b"HTTP/1.1 408 Request Timeout"}, heads.answers
        assert max(t for t, _ in heads.answers.values()) < HEADER_TIMEOUT_S + 2
        assert {a[1] for a in bodies.answers.values()} == {b"HTTP/1.1 408 Request Timeout"}
    finally:
        heads.close()
        bodies.close()
    assert httpx.get(url + "/api/v1/health", timeout=5).status_code == 200


def test_oversized_headers_431_and_one_log_line(production):
    url = production["url"]
    for _ in range(15):
        s = socket.create_connection(("127.0.0.1", production["port"]), timeout=10)
        try:
            s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Filler: " + b"a" * 100_000 + b"\r\n\r\n")
        except OSError:      # the server may close before everything is sent
            pass
        head = s.recv(4096)
        s.close()
        assert head.startswith(b"HTTP/1.1 431 "), head[:100]
    assert httpx.get(url + "/api/v1/health", timeout=5).status_code == 200
    time.sleep(0.3)
    text = production["log"].read_text(errors="replace")
    assert "Traceback" not in text and "Invalid HTTP request" not in text, text[-3000:]
    lines = [ln for ln in text.splitlines() if re.search(r"(?<![\d:])431(?!\d)", ln)]   # not a port like :44310
    # one line (one API process here), whatever the number of refused requests
    assert len(lines) == 1, lines
