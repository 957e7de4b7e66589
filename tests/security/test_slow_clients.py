"""Slow and oversized requests against the real embedded server (python -m backend.serve_embedded, as
`make run` starts it), on the embedded SQLite shape and on PostgreSQL.

Before the fix, 32 connections that sent a login request's headers and then the body one byte every 5 s
took every admission slot: /health and authenticated reads timed out, and a write request held SQLite's
write lock while its body trickled in. Now a body is received in full before the request is admitted,
against a deadline (408), and its size is bounded (413); the embedded server also bounds the headers'
time (408) and size (431). The server runs here with small limits: 8 requests admitted at once, a 3 s body
deadline."""

from __future__ import annotations

import hashlib
import json
import socket
import threading
import time

import httpx
import pytest

from ..backend.platform_helpers import Api, add_user, close_platform, have_postgres, have_redis, make_platform, worker_env
from .slow_clients import Server, SlowClients

BODY_TIMEOUT_S = 3.0
ADMITTED = 8
N_SLOW = 40          # five times the admission slots


@pytest.fixture(scope="module", params=["embedded", "postgres"])
def served(request, tmp_path_factory):
    """(platform, server, {name: token}): the platform's database served by a real server process."""
    if request.param == "postgres" and not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed for the production shape")
    tmp = tmp_path_factory.mktemp(f"slow-{request.param}")
    p = make_platform(tmp, request.param)
    tokens = {}
    for name in ("reader", "writer"):
        add_user(p, f"{name}-{p.shape}@example.org")
        api = Api(p, f"{name}-{p.shape}@example.org")
        tokens[name] = api.post("/api/v1/tokens", json={"name": "t", "scopes": ["write"]}).json()["token"]
    site = Api(p, f"reader-{p.shape}@example.org").post("/api/v1/sites", json={"name": "S", "crs": "EPSG:32653"})
    assert site.status_code == 201, site.text
    env = worker_env(p, request_body_timeout_s=BODY_TIMEOUT_S, max_concurrent_requests=ADMITTED,
                     max_concurrent_reads=4, request_header_timeout_s=3, max_request_header_bytes=16384)
    server = Server(env, p.data_dir, tmp / "server.log")
    yield p, server, tokens, site.json()["id"]
    server.stop()
    close_platform(p)


def _timed(fn):
    t0 = time.monotonic()
    r = fn()
    return r, time.monotonic() - t0


def test_slow_bodies_take_no_admission_slot_and_are_cut_off(served):
    p, server, tokens, site_id = served
    reader = httpx.Client(base_url=server.url, timeout=5, headers={"Authorization": f"Bearer {tokens['reader']}"})
    writer = httpx.Client(base_url=server.url, timeout=5, headers={"Authorization": f"Bearer {tokens['writer']}"})
    slow = SlowClients(server.port, N_SLOW, interval_s=0.5).start()
    try:
        time.sleep(0.5)            # every slow client is connected and sending
        times = []
        for i in range(4):
            r, dt = _timed(lambda: httpx.get(server.url + "/api/v1/health", timeout=5))
            assert r.status_code == 200, r.text
            times.append(("health", dt))
            r, dt = _timed(lambda: reader.get(f"/api/v1/sites/{site_id}"))
            assert r.status_code == 200, r.text
            times.append(("read", dt))
            r, dt = _timed(lambda: writer.post("/api/v1/sites", json={"name": f"W{i}", "crs": "EPSG:32653"}))
            assert r.status_code == 201, r.text
            times.append(("write", dt))
        assert max(dt for _, dt in times) < 1.0, times
        assert time.monotonic() - slow.connected_at < BODY_TIMEOUT_S, "the checks must run while the clients wait"
        slow.wait_answers(BODY_TIMEOUT_S + 5)
        assert len(slow.answers) == N_SLOW
        statuses = {a[1] for a in slow.answers.values()}
        assert statuses == {b"HTTP/1.1 408 Request Timeout"}, statuses
        assert max(a[0] for a in slow.answers.values()) < BODY_TIMEOUT_S + 3
    finally:
        slow.close()


def test_a_slow_upload_chunk_holds_no_write_lock(served):
    """A chunk sent slowly (within the deadline) does not stop another user's writes meanwhile: the body is
    received before the upload is looked at, and the check's transaction ends before the chunk is stored."""
    p, server, tokens, site_id = served
    writer = httpx.Client(base_url=server.url, timeout=5, headers={"Authorization": f"Bearer {tokens['writer']}"})
    reader = httpx.Client(base_url=server.url, timeout=5, headers={"Authorization": f"Bearer {tokens['reader']}"})
    survey = reader.post(f"/api/v1/sites/{site_id}/surveys", json={"name": "slow upload"}).json()
    data = b"name,easting_m,northing_m,ellipsoidal_height_m\nA,1,2,3\n"
    up = reader.post(f"/api/v1/surveys/{survey['id']}/uploads",
                     json={"filename": "points.csv", "size": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    assert up.status_code == 201, up.text
    up = up.json()["id"]
    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    s.sendall((f"PUT /api/v1/uploads/{up} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {tokens['reader']}\r\n"
               f"Content-Range: bytes 0-{len(data) - 1}/{len(data)}\r\nContent-Length: {len(data)}\r\n\r\n").encode())
    answer = {}

    def send_slowly():
        half = len(data) // 2
        s.sendall(data[:half])
        time.sleep(1.5)
        s.sendall(data[half:])
        answer["head"] = s.recv(4096).split(b"\r\n", 1)[0]
    t = threading.Thread(target=send_slowly)
    t.start()
    time.sleep(0.3)
    r, dt = _timed(lambda: writer.post("/api/v1/sites", json={"name": "during upload", "crs": "EPSG:32653"}))
    assert r.status_code == 201 and dt < 1.0, (r.status_code, dt)
    t.join(10)
    s.close()
    assert answer.get("head") == b"HTTP/1.1 200 OK", answer
    done = reader.post(f"/api/v1/uploads/{up}/complete")
    assert done.status_code == 200 and done.json()["state"] == "complete", done.text


def test_oversized_bodies_are_refused_before_they_are_read(served):
    p, server, tokens, site_id = served
    h = {"Authorization": f"Bearer {tokens['writer']}", "Content-Type": "application/json"}
    # declared: 413 at once, before the body (of which nothing is sent)
    s = socket.create_connection(("127.0.0.1", server.port), timeout=5)
    s.sendall(b"POST /api/v1/sites HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
              b"Content-Length: 50000000\r\n\r\n")
    head = s.recv(4096)
    s.close()
    assert head.startswith(b"HTTP/1.1 413 "), head[:200]
    # chunked, no length announced: cut off when it passes the limit
    big = b"[" + b"0," * (1_500_000) + b"0]"
    r = httpx.post(server.url + "/api/v1/sites", content=iter([big[i:i + 65536] for i in range(0, len(big), 65536)]),
                   headers=h, timeout=10)
    assert r.status_code == 413, r.text[:300]
    assert r.headers["content-type"].startswith("application/problem+json")
    assert "at most" in r.json()["detail"] or "longer than" in r.json()["detail"]


def test_polygons_with_too_many_vertices_are_refused_at_once(served):
    """A million vertices (about 20 MB of JSON) is refused by its size before it is read (413); 50,000
    short ones (under the body limit) by their count before any query or geometry (422)."""
    p, server, tokens, site_id = served
    url = "/api/v1/runs/00000000-0000-0000-0000-000000000000/volumes"
    ring = [[i % 1000, i // 1000] for i in range(1_000_000)] + [[0, 0]]
    body = json.dumps({"outline": {"type": "Polygon", "coordinates": [ring]}}).encode()
    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    t0 = time.monotonic()
    s.sendall((f"POST {url} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {tokens['reader']}\r\n"
               f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n").encode())
    head = s.recv(4096)
    s.close()
    assert head.startswith(b"HTTP/1.1 413 "), head[:300]
    assert time.monotonic() - t0 < 2
    ring = [[i % 300, i // 300] for i in range(50_000)] + [[0, 0]]
    r, dt = _timed(lambda: httpx.post(server.url + url, json={"outline": {"type": "Polygon", "coordinates": [ring]}},
                                      headers={"Authorization": f"Bearer {tokens['reader']}"}, timeout=30))
    assert r.status_code == 422, r.text[:300]
    assert "50001 vertices" in r.json()["detail"] and dt < 2, (r.json()["detail"], dt)


def test_slow_and_oversized_headers(served):
    p, server, tokens, site_id = served
    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n")      # ... and the rest never comes
    t0 = time.monotonic()
    head = s.recv(4096)
    s.close()
    assert head.startswith(b"HTTP/1.1 408 "), head[:100]
    assert time.monotonic() - t0 < 6
    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    try:
        s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Filler: " + b"a" * 100_000 + b"\r\n\r\n")
    except OSError:      # the server may close before everything is sent
        pass
    head = s.recv(4096)
    s.close()
    assert head.startswith(b"HTTP/1.1 431 "), head[:100]
    assert httpx.get(server.url + "/api/v1/health", timeout=5).status_code == 200
