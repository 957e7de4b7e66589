"""Test helpers for the web platform: real PostgreSQL / Redis / SQLite databases, the app, real Celery
worker processes, simulated surveys and chunked uploads through the API. No mocks."""

from __future__ import annotations

import hashlib
import io
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PY = sys.executable
PG_HOST, PG_PORT, PG_USER = "127.0.0.1", 5432, "postgres"
REDIS_URL = "redis://127.0.0.1:6379"
PASSWORD = "correct-horse-battery"
POINTS_CSV = (b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.0,3889231.0,80.0,control\n"
              b"T2,679478.0,3889241.0,79.9,check\n")


def port_open(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1):
            return True
    except OSError:
        return False


def have_postgres() -> bool:
    return port_open(PG_HOST, PG_PORT)


def have_redis() -> bool:
    return port_open("127.0.0.1", 6379)


def _pg_admin(sql: str) -> None:
    import psycopg

    with psycopg.connect(host=PG_HOST, port=PG_PORT, user=PG_USER, dbname="postgres", autocommit=True) as c:
        c.execute(sql)


def create_pg_database() -> tuple[str, str]:
    name = f"georef_test_{os.getpid()}_{uuid.uuid4().hex[:8]}"
    _pg_admin(f'CREATE DATABASE "{name}"')
    return name, f"postgresql+psycopg://{PG_USER}@{PG_HOST}:{PG_PORT}/{name}"


def drop_pg_database(name: str) -> None:
    from backend.db.session import dispose_all

    dispose_all()
    _pg_admin(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def free_redis_db() -> int:
    """A Redis database number unlikely to be used by a parallel test process."""
    return 1 + (os.getpid() % 14)


@dataclass
class Platform:
    shape: str                      # "postgres" | "embedded"
    data_dir: Path
    env: dict                       # GEOREF_* variables for subprocesses (worker, beat, uvicorn)
    settings: object = None
    app: object = None
    pg_name: str | None = None
    workers: list = field(default_factory=list)

    def client(self):
        from fastapi.testclient import TestClient

        # https: the session cookie is Secure and is only sent over https
        return TestClient(self.app, base_url="https://testserver")

    def db(self):
        return self.app.state.database


def start_s3_server():
    """moto's S3 server on a free loopback port, as the object store in place of MinIO (which needs Docker):
    (server, overrides for make_platform). Stop it with server.stop()."""
    from moto.server import ThreadedMotoServer

    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        port = sk.getsockname()[1]
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    return server, {"storage": "s3", "s3_endpoint_url": f"http://127.0.0.1:{port}", "s3_bucket": "georef",
                    "s3_access_key_id": "georef", "s3_secret_access_key": "georef-secret"}


def make_platform(tmp: Path, shape: str, queue: str = "georef", **overrides) -> Platform:
    data = tmp / f"platform-{shape}"
    data.mkdir(parents=True, exist_ok=True)
    env = {"GEOREF_DATA_DIR": str(data), "GEOREF_DEFAULT_QUEUE": queue, "GEOREF_HEAVY_QUEUE": f"{queue}-heavy",
           "GEOREF_SECRET_KEY": "test"}
    pg_name = None
    if shape == "postgres":
        pg_name, url = create_pg_database()
        env["GEOREF_DATABASE_URL"] = url
        env["GEOREF_BROKER_URL"] = f"{REDIS_URL}/{free_redis_db()}"
        env["GEOREF_VISIBILITY_TIMEOUT_S"] = "30"
        import redis

        redis.Redis.from_url(env["GEOREF_BROKER_URL"]).flushdb()
    for k, v in overrides.items():
        env[f"GEOREF_{k.upper()}"] = str(v)
    from backend.core.settings import Settings

    settings = Settings(**{k.removeprefix("GEOREF_").lower(): v for k, v in env.items()})
    from backend.db.migrate import upgrade

    upgrade(settings.resolved_database_url())
    from backend.main import create_app

    p = Platform(shape, data, env, settings, create_app(settings), pg_name)
    return p


def close_platform(p: Platform) -> None:
    for w in list(p.workers):
        stop_worker(w)
    if p.pg_name:
        drop_pg_database(p.pg_name)


def worker_env(p: Platform, **extra) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GEOREF_")}
    env.update(p.env)
    env.update({f"GEOREF_{k.upper()}": str(v) for k, v in extra.items()})
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


@dataclass
class WorkerProc:
    proc: subprocess.Popen
    log: Path
    name: str


def start_worker(p: Platform, name: str, beat: bool = False, timeout_s: float = 60, queues: str = "both",
                 concurrency: int = 0, **extra) -> WorkerProc:
    """A Celery worker process (solo pool) on the platform's default queue, its heavy queue or both
    (`queues`); `extra` settings override the platform's (e.g. work_dir: a worker with a disk of its own).
    ``concurrency`` > 0: the prefork pool with that many child processes (as deployed) instead of solo."""
    queue = p.env["GEOREF_DEFAULT_QUEUE"]
    wanted = {"both": f"{queue},{queue}-heavy", "default": queue, "heavy": f"{queue}-heavy"}[queues]
    log = p.data_dir / f"worker-{name}.log"
    pool = ["prefork", "--concurrency", str(concurrency)] if concurrency > 0 else ["solo"]
    cmd = [PY, "-m", "celery", "-A", "worker.celery_app", "worker", "-Q", wanted, "--pool", *pool,
           "--loglevel", "INFO", "-n", f"{name}-{uuid.uuid4().hex[:6]}@%h", "--without-gossip", "--without-mingle",
           "--without-heartbeat"]
    if beat:
        cmd += ["-B", "-s", str(p.data_dir / f"beat-{name}.db")]
    f = open(log, "wb")
    proc = subprocess.Popen(cmd, cwd=REPO, env=worker_env(p, **extra), stdout=f, stderr=subprocess.STDOUT,
                            start_new_session=True)
    w = WorkerProc(proc, log, name)
    p.workers.append(w)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"worker {name} exited:\n{log.read_text()[-3000:]}")
        if b" ready." in log.read_bytes():
            return w
        time.sleep(0.2)
    stop_worker(w)
    raise RuntimeError(f"worker {name} not ready in {timeout_s} s:\n{log.read_text()[-3000:]}")


def stop_worker(w: WorkerProc, sig=signal.SIGTERM) -> None:
    if w.proc.poll() is None:
        try:
            os.killpg(w.proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            w.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(w.proc.pid, signal.SIGKILL)
            w.proc.wait(timeout=10)


# ----------------------------------------------------------------------------------------------- network

# public addresses that the tests' fake resolver hands out for names: never connected to (a webhook
# delivery to them is refused or not attempted in the tests), documentation-free and globally routable
PUBLIC_TEST_IP = "93.184.215.14"


class FakeDNS:
    """socket.getaddrinfo for the tests: names in `names` resolve to the given addresses, numeric hosts
    go to the real function (no lookup), anything else fails as an unknown name. No DNS query leaves the
    machine. `asked` records the names looked up, in order."""

    def __init__(self, names: dict[str, list[str]]):
        self.names = {k.lower(): list(v) for k, v in names.items()}
        self.asked: list[str] = []
        self._real = socket.getaddrinfo

    def __call__(self, host, port, family=0, type=0, proto=0, flags=0):
        h = host.decode() if isinstance(host, bytes) else str(host)
        try:
            import ipaddress

            ipaddress.ip_address(h.split("%", 1)[0])
            return self._real(host, port, family, type, proto, flags)
        except ValueError:
            pass
        self.asked.append(h.lower())
        addrs = self.names.get(h.lower().rstrip("."))
        if addrs is None:
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        out = []
        for a in addrs:
            fam = socket.AF_INET6 if ":" in a else socket.AF_INET
            sockaddr = (a, int(port or 0), 0, 0) if fam == socket.AF_INET6 else (a, int(port or 0))
            out.append((fam, socket.SOCK_STREAM, 6, "", sockaddr))
        return out


# ----------------------------------------------------------------------------------------------- accounts


def add_user(p: Platform, email: str, org_id: str | None = None, org_admin: bool = False) -> tuple[str, str]:
    """(user id, organisation id)."""
    from backend.services import accounts

    with p.db().session() as s:
        if org_id is None:
            org_id = accounts.create_organisation(s, "Org " + email).id
        u = accounts.create_user(s, org_id, email, PASSWORD, email.split("@")[0], org_admin)
        return u.id, org_id


class Api:
    """A logged-in browser-like client (cookie + CSRF header) on the test app."""

    def __init__(self, p: Platform, email: str):
        self.c = p.client()
        r = self.c.post("/api/v1/auth/login", json={"email": email, "password": PASSWORD})
        assert r.status_code == 200, r.text
        self.csrf = r.json()["csrf_token"]

    def _h(self, headers):
        return {"X-CSRF-Token": self.csrf, **(headers or {})}

    def get(self, url, **kw):
        return self.c.get(url, **kw)

    def post(self, url, json=None, headers=None, **kw):
        return self.c.post(url, json=json, headers=self._h(headers), **kw)

    def put(self, url, headers=None, **kw):
        return self.c.put(url, headers=self._h(headers), **kw)

    def patch(self, url, json=None, headers=None, **kw):
        return self.c.patch(url, json=json, headers=self._h(headers), **kw)

    def delete(self, url, headers=None, **kw):
        return self.c.delete(url, headers=self._h(headers), **kw)


def upload_bytes(api: Api, survey_id: str, filename: str, data: bytes, kind: str | None = None,
                 chunk: int = 1 << 20, sha256: str | None = None, folder: str | None = None):
    """The whole chunked protocol: create, PUT chunks, complete; returns the completion response.
    ``folder``: the relative folder the file was dropped in (DJI flight folders)."""
    body = {"filename": filename, "size": len(data), "sha256": sha256 or hashlib.sha256(data).hexdigest()}
    if kind:
        body["kind"] = kind
    if folder:
        body["folder"] = folder
    r = api.post(f"/api/v1/surveys/{survey_id}/uploads", json=body)
    assert r.status_code == 201, r.text
    up = r.json()["id"]
    for off in range(0, len(data), chunk):
        part = data[off:off + chunk]
        r = api.put(f"/api/v1/uploads/{up}", content=part,
                    headers={"Content-Range": f"bytes {off}-{off + len(part) - 1}/{len(data)}"})
        assert r.status_code == 200, r.text
    return api.post(f"/api/v1/uploads/{up}/complete")


def zip_folder(folder: Path, skip: tuple[str, ...] = ("truth/",), prefix: str = "") -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(folder.rglob("*")):
            rel = f.relative_to(folder).as_posix()
            if f.is_file() and not rel.startswith(skip):
                z.write(f, prefix + rel)
    return buf.getvalue()


def simulate_small(out: Path, seed: int = 7) -> Path:
    if not (out / "survey.json").exists():
        subprocess.run([PY, "-m", "georef_core.cli.main", "simulate", str(out), "--seed", str(seed), "--small"],
                       cwd=REPO, check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    return out


def wait_run(api: Api, run_id: str, timeout_s: float = 300) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        r = api.get(f"/api/v1/runs/{run_id}")
        assert r.status_code == 200, r.text
        d = r.json()
        if d["state"] in ("succeeded", "failed", "cancelled"):
            return d
        time.sleep(0.5)
    raise AssertionError(f"run {run_id} did not finish in {timeout_s} s: {d['state']} "
                         f"{[(s['name'], s['state']) for s in d['step_details']]}")
