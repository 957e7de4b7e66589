"""Slow clients against the embedded server, on the loopback only.

Starts the embedded server as `make run` does (python -m backend.serve_embedded; here on a temporary
data folder, without the demo and the worker), logs two users in, then opens N connections (default 200)
that each send a login request's headers and then its body one byte every --interval seconds (the attack
that froze the API: 32 such connections took every admission slot). While they are connected it measures,
every 0.25 s, /health, an authenticated read (GET /api/v1/sites/{id}) and another user's write (POST
/api/v1/sites), and finally when and how the slow clients were answered (408 after the body deadline).

Prints latency figures (p50 / p99 / max) without and with the slow clients, the requests that failed, and
the ratio of the worst latency to the 1 s target; exits 1 when a latency reached 1 s or a request failed.

    .venv/bin/python bench/slow_clients.py [--clients 200] [--interval 2] [--duration 15] [--body-timeout 20]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

PASSWORD = "slow-clients-bench-2024"


def _stats(xs: list[float]) -> str:
    if not xs:
        return "no sample"
    s = sorted(xs)
    p99 = s[min(len(s) - 1, int(round(0.99 * (len(s) - 1))))]
    return (f"n={len(s):4d}  p50 {1000 * statistics.median(s):7.1f} ms  p99 {1000 * p99:7.1f} ms  "
            f"max {1000 * s[-1]:7.1f} ms")


def _login(url: str, email: str):
    import httpx

    c = httpx.Client(base_url=url, timeout=5)
    r = c.post("/api/v1/auth/login", json={"email": email, "password": PASSWORD})
    r.raise_for_status()
    c.headers["X-CSRF-Token"] = r.json()["csrf_token"]
    return c


def _measure(url: str, reader, writer, site_id: str, seconds: float, tag: str) -> dict[str, list[float]]:
    import httpx

    out: dict[str, list[float]] = {"health": [], "read": [], "write": [], "failed": []}
    anonymous = httpx.Client(base_url=url, timeout=5)       # /health as a monitor calls it: no login
    end = time.monotonic() + seconds
    k = 0
    while time.monotonic() < end:
        calls = (("health", lambda: anonymous.get("/api/v1/health")),
                 ("read", lambda: reader.get(f"/api/v1/sites/{site_id}")),
                 ("write", lambda: writer.post("/api/v1/sites", json={"name": f"{tag} {k}", "crs": "EPSG:32653"})))
        for what, call in calls:
            t0 = time.monotonic()
            try:
                ok = call().status_code in (200, 201)
            except httpx.HTTPError:
                ok = False
            dt = time.monotonic() - t0
            out[what].append(dt)
            if not ok:
                out["failed"].append(dt)
        k += 1
        time.sleep(0.25)
    return out


def _make_users(env: dict) -> None:
    """The two users, made in the server's database before it starts (through the services)."""
    os.environ.update({k: v for k, v in env.items() if k.startswith("GEOREF_")})
    from backend.core.settings import get_settings
    from backend.db.migrate import upgrade
    from backend.db.session import get_database
    from backend.services import accounts

    settings = get_settings()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.resolved_database_url())
    with get_database(settings.resolved_database_url()).session() as s:
        org = accounts.create_organisation(s, "Bench")
        for name in ("reader", "writer"):
            accounts.create_user(s, org.id, f"{name}@bench.example.org", PASSWORD, name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--interval", type=float, default=2.0, help="seconds between two bytes of a slow body")
    ap.add_argument("--duration", type=float, default=15.0, help="seconds of measurement with the clients on")
    ap.add_argument("--body-timeout", type=float, default=20.0, help="GEOREF_REQUEST_BODY_TIMEOUT_S of the server")
    args = ap.parse_args(argv)
    if args.duration >= args.body_timeout:
        ap.error("--duration must be shorter than --body-timeout (the clients are cut off then)")

    from tests.security.slow_clients import Server, SlowClients

    tmp = Path(tempfile.mkdtemp(prefix="georef-slow-clients-"))
    data = tmp / "platform"
    env = {k: v for k, v in os.environ.items() if not k.startswith("GEOREF_")}
    env.update({"GEOREF_DATA_DIR": str(data), "GEOREF_REQUEST_BODY_TIMEOUT_S": str(args.body_timeout),
                "GEOREF_SECRET_KEY": "bench", "OMP_NUM_THREADS": "1"})
    _make_users(env)
    server = Server(env, data, tmp / "server.log")
    slow = None
    try:
        reader = _login(server.url, "reader@bench.example.org")
        writer = _login(server.url, "writer@bench.example.org")
        site = reader.post("/api/v1/sites", json={"name": "Bench", "crs": "EPSG:32653"})
        site.raise_for_status()
        site_id = site.json()["id"]
        base = _measure(server.url, reader, writer, site_id, 3.0, "baseline")
        t0 = time.monotonic()
        slow = SlowClients(server.port, args.clients, interval_s=args.interval, body_len=64).start()
        connected_s = time.monotonic() - t0
        loaded = _measure(server.url, reader, writer, site_id, args.duration, "loaded")
        answered_early = len(slow.answers)
        slow.wait_answers(args.body_timeout + 10)
        cut = sorted(t for t, _ in slow.answers.values())
        statuses: dict[str, int] = {}
        for _t, st in slow.answers.values():
            key = st.decode(errors="replace")
            statuses[key] = statuses.get(key, 0) + 1
    finally:
        if slow is not None:
            slow.close()
        server.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    worst = max(loaded["health"] + loaded["read"] + loaded["write"])
    print(f"embedded server {server.url} (SQLite; body deadline {args.body_timeout:g} s; {os.cpu_count()} CPUs)")
    print(f"without slow clients   health {_stats(base['health'])}")
    print(f"                       read   {_stats(base['read'])}")
    print(f"                       write  {_stats(base['write'])}   failed: {len(base['failed'])}")
    print(f"with {args.clients} slow clients (one byte every {args.interval:g} s; all connected in {connected_s:.2f} s; "
          f"{answered_early} answered during the {args.duration:g} s measured):")
    print(f"                       health {_stats(loaded['health'])}")
    print(f"                       read   {_stats(loaded['read'])}")
    print(f"                       write  {_stats(loaded['write'])}   failed: {len(loaded['failed'])}")
    if cut:
        answers = ", ".join(f"{n} x '{s}'" for s, n in statuses.items())
        print(f"slow clients answered  {len(cut)} of {args.clients}: {answers}, {cut[0]:.1f}-{cut[-1]:.1f} s after "
              "connecting")
    print(f"worst latency / 1 s target: {worst:.3f}")
    return 0 if worst < 1.0 and not loaded["failed"] and not base["failed"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
