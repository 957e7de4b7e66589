"""Load test of the result endpoints: N concurrent readers (default 200) on the loopback.

Sets up a platform in a temporary folder (embedded SQLite by default, or PostgreSQL with --pg),
uploads a simulated 12-image survey through the upload service, processes it (gnss + report steps
by default, --full for the whole chain), starts uvicorn, then runs the readers with httpx:

  open loop (default): each reader issues one request every 1/--rate s (a dashboard polling results),
                       so the offered load is readers x rate requests/s;
  closed loop (--closed): each reader issues its next request as soon as the last one answered
                       (saturation: throughput and the latency it costs).

Prints p50/p90/p99/max latency, throughput and lost requests (timeouts, connection errors, any status
other than 200/304), and the ratio of p99 to the 100 ms target.

    .venv/bin/python bench/api_load.py [--readers 200] [--duration 20] [--rate 1] [--workers 2] [--pg]
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import os
import random
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def setup(data_dir: Path, pg: bool, full: bool) -> tuple[dict, list[str], str]:
    """Environment for the server, the result URLs to read, an API token."""
    env = {"GEOREF_DATA_DIR": str(data_dir), "GEOREF_COOKIE_SECURE": "false"}
    pg_name = None
    if pg:
        import psycopg

        pg_name = f"georef_bench_{os.getpid()}"
        with psycopg.connect(host="127.0.0.1", user="postgres", dbname="postgres", autocommit=True) as c:
            c.execute(f'CREATE DATABASE "{pg_name}"')
        env["GEOREF_DATABASE_URL"] = f"postgresql+psycopg://postgres@127.0.0.1:5432/{pg_name}"
    os.environ.update(env)
    from backend.core.settings import get_settings
    from backend.db.migrate import upgrade
    from backend.db.session import get_database
    from backend.services import accounts, runs, sites, surveys, uploads
    from backend.services.context import Ctx, Principal
    from backend.storage import storage_for

    settings = get_settings()
    upgrade(settings.resolved_database_url())
    sim = data_dir / "sim"
    subprocess.run([sys.executable, "-m", "georef_core.cli.main", "simulate", str(sim), "--seed", "3", "--small"],
                   check=True, capture_output=True, cwd=REPO)
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for f in sorted(sim.rglob("*")):
            rel = f.relative_to(sim).as_posix()
            if f.is_file() and not rel.startswith("truth/") and (full or not rel.startswith("images/")):
                z.write(f, rel)
    data = buf.getvalue()
    db = get_database(settings.resolved_database_url())
    s = db.sessionmaker()
    with db.session() as t:
        org = accounts.create_organisation(t, "Bench")
        accounts.create_user(t, org.id, "bench@example.org", "load-test-secret-1", "bench", True)
    from sqlalchemy import select

    from backend.models import User

    user = s.scalar(select(User))
    ctx = Ctx(db=s, settings=settings, storage=storage_for(settings), principal=Principal(user=user, via="session"))
    site = sites.create_site(ctx, "Bench site", "EPSG:32653", None, None, "")
    survey = surveys.create_survey(ctx, site.id, "Bench flight", None, "", {})
    up = uploads.create_upload(ctx, survey.id, "survey.zip", len(data), hashlib.sha256(data).hexdigest(), None, None)
    s.commit()
    tmp = data_dir / "upload.part"
    tmp.write_bytes(data)
    uploads.store_chunk(ctx, up.id, 0, len(data), tmp)
    s.commit()
    uploads.complete_upload(ctx, up.id)
    steps = None if full else ["gnss", "report"]
    run = runs.create_run(ctx, survey.id, steps)
    s.commit()                                   # no broker message: the steps run here, in this process
    _, token = accounts.create_token(Ctx(db=s, settings=settings, storage=ctx.storage,
                                         principal=Principal(user=user, via="session")), "bench", ["read"], None)
    s.commit()
    from worker.tasks import execute_step

    t0 = time.monotonic()
    names = [st.name for st in runs.run_steps(s, run.id)]
    s.commit()                                   # SQLite: release the write lock before the steps write
    for name in names:
        print(f"  step {name}: {execute_step(run.id, name)}", flush=True)
    print(f"processed in {time.monotonic() - t0:.0f} s", flush=True)
    s.close()
    base = f"/api/v1/runs/{run.id}"
    urls = [base, f"{base}/results", f"{base}/results/camera-positions", f"{base}/results/camera-positions?format=csv",
            f"{base}/results/trajectory?every=10", f"{base}/results/trajectory?format=geojson&every=25",
            f"{base}/results/report.pdf", f"/api/v1/surveys/{survey.id}/runs", f"/api/v1/sites/{site.id}/summary"]
    if full:
        urls += [f"{base}/results/residuals", f"{base}/results/residuals?format=geojson", f"{base}/results/volumes"]
    env["_PG_NAME"] = pg_name or ""
    return env, urls, token


class _Connection:
    """A minimal HTTP/1.1 keep-alive client on asyncio streams (GET only; Content-Length or chunked
    bodies). httpx spent most of a core on 200 requests/s and, sharing the two cores with the server,
    its own event-loop delays dominated the latencies it measured."""

    def __init__(self, port: int, token: str):
        self.port, self.token = port, token
        self.reader = self.writer = None

    async def get(self, url: str, headers: dict) -> tuple[int, dict]:
        if self.writer is None:
            self.reader, self.writer = await asyncio.open_connection("127.0.0.1", self.port)
        extra = "".join(f"{k}: {v}\r\n" for k, v in headers.items())
        self.writer.write(f"GET {url} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {self.token}\r\n"
                          f"{extra}\r\n".encode())
        head = await self.reader.readuntil(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split(" ", 2)[1])
        hdr = {}
        for line in lines[1:]:
            if ":" in line:
                k, v = line.split(":", 1)
                hdr[k.strip().lower()] = v.strip()
        if "content-length" in hdr:
            await self.reader.readexactly(int(hdr["content-length"]))
        elif hdr.get("transfer-encoding", "").lower() == "chunked":
            while True:
                size = int((await self.reader.readuntil(b"\r\n")).split(b";")[0], 16)
                await self.reader.readexactly(size + 2)
                if size == 0:
                    break
        if hdr.get("connection", "").lower() == "close":
            self.close()
        return status, hdr

    def close(self):
        if self.writer is not None:
            self.writer.close()
        self.reader = self.writer = None


async def load(port: int, urls: list[str], token: str, readers: int, duration_s: float, rate: float,
               closed: bool, timeout_s: float) -> tuple[list[float], int, dict, dict]:
    lat: list[float] = []
    by_url: dict[str, list[float]] = {}
    lost = 0
    codes: dict = {}
    t_end = time.monotonic() + duration_s
    etags: dict[str, str] = {}

    async def reader(i: int):
        nonlocal lost
        rnd = random.Random(i)
        conn = _Connection(port, token)
        await asyncio.sleep(rnd.random() / max(rate, 1e-9) if not closed else 0)
        while time.monotonic() < t_end:
            url = rnd.choice(urls)
            headers = {}
            if rnd.random() < 0.3 and url in etags:       # some clients revalidate
                headers["If-None-Match"] = etags[url]
            t0 = time.perf_counter()
            try:
                status, hdr = await asyncio.wait_for(conn.get(url, headers), timeout_s)
                dt = time.perf_counter() - t0
                codes[status] = codes.get(status, 0) + 1
                if status in (200, 304):
                    lat.append(dt)
                    by_url.setdefault(url, []).append(dt)
                    if "etag" in hdr:
                        etags[url] = hdr["etag"]
                else:
                    lost += 1
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError, ValueError):
                lost += 1
                conn.close()
                dt = time.perf_counter() - t0
            if not closed:
                await asyncio.sleep(max(0.0, 1.0 / rate - dt) * (0.8 + 0.4 * rnd.random()))
        conn.close()

    await asyncio.gather(*(reader(i) for i in range(readers)))
    return lat, lost, codes, by_url


def report_by_url(by_url: dict) -> None:
    """p50 / p99 per endpoint: which one makes the tail."""
    for url, ts in sorted(by_url.items(), key=lambda kv: -statistics.quantiles(kv[1], n=100)[98]):
        q = statistics.quantiles(ts, n=100, method="inclusive")
        print(f"  {url.split('/api/v1/')[-1][:70]:70s} n {len(ts):4d}  p50 {q[49] * 1000:6.1f} ms  p99 {q[98] * 1000:6.1f} ms")


def report(name: str, lat: list[float], lost: int, codes: dict, duration_s: float) -> None:
    if not lat:
        print(f"{name}: no successful request; lost {lost}; statuses {codes}")
        return
    q = statistics.quantiles(lat, n=100, method="inclusive")
    p50, p90, p99 = q[49] * 1000, q[89] * 1000, q[98] * 1000
    print(f"{name}: {len(lat) + lost} requests in {duration_s:.0f} s = {(len(lat) + lost) / duration_s:.0f} req/s; "
          f"latency p50 {p50:.1f} ms, p90 {p90:.1f} ms, p99 {p99:.1f} ms, max {max(lat) * 1000:.1f} ms; "
          f"lost {lost}; statuses {dict(sorted(codes.items()))}; p99 / 100 ms target = {p99 / 100:.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readers", type=int, default=200)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=1.0, help="requests per second per reader (open loop)")
    ap.add_argument("--closed", action="store_true", help="closed loop (saturation) as well")
    ap.add_argument("--workers", type=int, default=2, help="uvicorn worker processes")
    ap.add_argument("--timeout", type=float, default=10.0, help="a request slower than this is lost")
    ap.add_argument("--pg", action="store_true", help="PostgreSQL at 127.0.0.1:5432 instead of SQLite")
    ap.add_argument("--full", action="store_true", help="process the whole chain (residuals, volumes too)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="georef-bench-"))
    print(f"setting up ({'PostgreSQL' if args.pg else 'embedded SQLite'}) in {tmp} ...", flush=True)
    env, urls, token = setup(tmp, args.pg, args.full)
    pg_name = env.pop("_PG_NAME")
    port = free_port()
    server = subprocess.Popen([sys.executable, "-m", "uvicorn", "backend.main:app", "--host", "127.0.0.1", "--port",
                               str(port), "--workers", str(args.workers), "--log-level", "warning",
                               "--backlog", "2048"],
                              cwd=REPO, env={**os.environ, **env, "PYTHONPATH": str(REPO)}, start_new_session=True)
    try:
        import httpx

        for _ in range(100):
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        print(f"uvicorn: {args.workers} worker(s); {len(urls)} result URLs; {os.cpu_count()} CPU cores (shared with "
              "this load generator)", flush=True)
        asyncio.run(load(port, urls, token, 20, 3, 2, False, args.timeout))       # warm-up (caches, pools)
        # one request at a time: what each endpoint costs without queueing
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", headers={"Authorization": f"Bearer {token}"}) as cl:
            seq = {}
            for url in ["/api/v1/health"] + urls:
                ts = []
                for _ in range(40):
                    t0 = time.perf_counter()
                    cl.get(url)
                    ts.append(time.perf_counter() - t0)
                seq[url] = statistics.median(ts) * 1000
            print("sequential median latency (ms): " + ", ".join(f"{u.split('/api/v1/')[-1][:48]} {v:.1f}"
                                                                 for u, v in seq.items()), flush=True)
        lat, lost, codes, by_url = asyncio.run(load(port, urls, token, args.readers, args.duration, args.rate, False,
                                                    args.timeout))
        report(f"open loop, {args.readers} readers x {args.rate:g} req/s", lat, lost, codes, args.duration)
        report_by_url(by_url)
        if args.closed:
            lat, lost, codes, _ = asyncio.run(load(port, urls, token, args.readers, args.duration, args.rate, True,
                                                   args.timeout))
            report(f"closed loop, {args.readers} readers", lat, lost, codes, args.duration)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)
        if pg_name:
            from backend.db.session import dispose_all

            dispose_all()
            import psycopg

            with psycopg.connect(host="127.0.0.1", user="postgres", dbname="postgres", autocommit=True) as c:
                c.execute(f'DROP DATABASE IF EXISTS "{pg_name}" WITH (FORCE)')
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
