"""Run the application services of docker-compose.yml as local processes, without Docker, and push the
simulated demo survey through them with the REST API.

Where Docker cannot run (no daemon, or no container registry and no stand-in images: docs/deploy.md),
this script runs what the compose file would run inside its containers: the api service's command from
the Dockerfile (migrations, then uvicorn with API_WORKERS processes), the `worker` (queue georef, prefork
pool of 4), `worker-heavy` (queue heavy, concurrency 1) and `beat` commands exactly as written there, each
with the compose file's GEOREF_ environment and its own data folder. The hosts of the compose network
are mapped to this machine's services: `postgres` to PostgreSQL on 127.0.0.1 (a fresh database, dropped
afterwards), `redis` to Redis on 127.0.0.1 (one database number, flushed), `minio` to moto's S3 server
(MinIO needs Docker). Not run: the images' build, nginx (the `frontend` service) and the containers'
isolation.

Then, as an operator and a GIS integrator would: `python -m backend.create_user` (what
`docker compose run --rm api ...` runs), log in, create an API token, create a site with the survey's
stockpiles, upload the survey archive in chunks, start a run of every step, wait for it, and read the
check-point residuals and volumes back. Prints which service ran each step (the heavy steps must go to
worker-heavy) and compares the figures with the simulator's truth. Exit status 0 when everything
matched.

    .venv/bin/python scripts/compose_local.py [--keep] [--timeout 900]

With --running URL it starts nothing and walks through a real `docker compose up -d` deployment instead
(docs/deploy.md; scripts/standin_base_images.sh where no container registry is reachable):

    .venv/bin/python scripts/compose_local.py --running http://127.0.0.1:8080
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
APP_SERVICES = ("api", "worker", "worker-heavy", "beat")
ADMIN_EMAIL, ADMIN_PASSWORD = "admin@example.org", "compose-local-admin-1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def expand(value) -> str:
    """${VAR:-default} -> $VAR or the default, as compose substitutes it."""
    return re.sub(r"\$\{([A-Z0-9_]+):-([^}]*)\}", lambda m: os.environ.get(m.group(1), m.group(2)), str(value))


def dockerfile_cmd() -> list[str]:
    """The image's default command (the api service has none of its own)."""
    for line in (REPO / "Dockerfile").read_text().splitlines():
        if line.startswith("CMD "):
            return json.loads(line[4:])
    raise SystemExit("Dockerfile: no CMD")


def service_env(compose: dict, name: str, mapping: dict[str, str], data_dir: Path) -> dict[str, str]:
    svc = compose["services"][name]
    env = {k: expand(v) for k, v in (svc.get("environment") or {}).items()}
    env.update(mapping)
    env["GEOREF_DATA_DIR"] = str(data_dir)
    return env


def pids_of_group(pgid: int) -> set[int]:
    out = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid:
                out.add(int(d.name))
    return out


class Stack:
    def __init__(self, root: Path):
        self.root = root
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}

    def start(self, name: str, cmd: list[str], env: dict[str, str]) -> None:
        log = self.root / f"{name}.log"
        self.logs[name] = log
        self.procs[name] = subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **env, "PYTHONPATH": str(REPO)},
                                            stdout=open(log, "wb"), stderr=subprocess.STDOUT, start_new_session=True)

    def check_alive(self) -> None:
        for name, p in self.procs.items():
            if p.poll() is not None:
                raise RuntimeError(f"service {name} exited ({p.returncode}):\n{self.logs[name].read_text()[-3000:]}")

    def stop(self) -> None:
        for p in self.procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for name, p in self.procs.items():
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


def survey_archive(root: Path, seed: int) -> tuple[bytes, dict, dict]:
    sim = root / "survey"
    subprocess.run([PY, "-m", "georef_core.cli.main", "simulate", str(sim), "--seed", str(seed), "--small",
                    "--quiet"], check=True, cwd=REPO)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for f in sorted(sim.rglob("*")):
            rel = f.relative_to(sim).as_posix()
            if f.is_file() and not rel.startswith("truth/"):
                z.write(f, rel)
    meta = json.loads((sim / "survey.json").read_text())
    truth = json.loads((sim / "truth" / "stockpiles.geojson").read_text())
    return buf.getvalue(), meta, truth


def exercise(api, create_admin, service_of, check_alive, root: Path, seed: int, timeout_s: float,
             email: str = ADMIN_EMAIL) -> bool:
    """What an operator and a GIS integrator do, against the API client `api` (base URL .../api/v1):
    create the admin (`create_admin(email)`), log in, create a token, a site with the survey's stockpiles, upload
    the simulated survey in chunks, run every step, check which service ran each (`service_of(worker id)`)
    and compare the check points and volumes with the simulator's truth. True when everything matched."""
    create_admin(email)
    ok = True
    login = api.post("/auth/login", json={"email": email, "password": ADMIN_PASSWORD})
    login.raise_for_status()
    tok = api.post("/tokens", json={"name": "compose-local", "scopes": ["read", "write", "admin"]},
                   headers={"X-CSRF-Token": login.json()["csrf_token"]})
    tok.raise_for_status()
    api.cookies.clear()
    api.headers["Authorization"] = f"Bearer {tok.json()['token']}"

    data, meta, truth = survey_archive(root, seed)
    site = api.post("/sites", json={"name": "Compose site", "crs": meta["project_crs"]}).json()
    for f in truth["features"]:
        ring = [[c[0], c[1]] for c in f["geometry"]["coordinates"][0]]
        api.post(f"/sites/{site['id']}/stockpiles", json={
            "name": f["properties"]["name"], "outline": {"type": "Polygon", "coordinates": [ring]},
            "base": "plane"}).raise_for_status()
    survey = api.post(f"/sites/{site['id']}/surveys", json={"name": "Compose flight"}).json()
    up = api.post(f"/surveys/{survey['id']}/uploads", json={
        "filename": "survey.zip", "size": len(data), "sha256": hashlib.sha256(data).hexdigest(),
        "kind": "archive"}).json()
    chunk = 1 << 20
    for offset in range(0, len(data), chunk):
        part = data[offset:offset + chunk]
        api.put(f"/uploads/{up['id']}", content=part, headers={
            "Content-Range": f"bytes {offset}-{offset + len(part) - 1}/{len(data)}"}).raise_for_status()
    api.post(f"/uploads/{up['id']}/complete").raise_for_status()
    check = api.get(f"/surveys/{survey['id']}/check").json()
    if not check["ok"]:
        raise RuntimeError(f"survey check: {check['problems']}")
    run = api.post(f"/surveys/{survey['id']}/runs", json={}).json()
    t_run = time.monotonic()
    while run["state"] not in ("succeeded", "failed", "cancelled"):
        check_alive()
        if time.monotonic() - t_run > timeout_s:
            raise RuntimeError(f"run not finished in {timeout_s:.0f} s: {run['state']}")
        time.sleep(2)
        run = api.get(f"/runs/{run['id']}").json()
    print(f"run {run['state']} in {time.monotonic() - t_run:.0f} s", flush=True)
    ok &= run["state"] == "succeeded"

    for s in run["step_details"]:
        service = service_of(s.get("worker") or "")
        want = "worker-heavy" if s["name"] in ("georef", "dense") else "worker"
        ok &= service == want and s["state"] == "succeeded"
        print(f"  step {s['name']:8s} {s['state']:9s} on {service} ({s.get('worker')})"
              f"{'' if service == want else f'  <- expected {want}'}")
        if s.get("error"):
            print(f"    error: {s['error'][:1500]}")
    summary = api.get(f"/sites/{site['id']}/summary").json()
    rmse = (summary.get("check_rmse_m") or {}).get("3d")
    ok &= rmse is not None and rmse < 0.05
    print(f"check points (site summary): {json.dumps(summary.get('check_rmse_m'))}")
    got = api.get(f"/runs/{run['id']}/results/volumes")
    vols = {v["name"]: v for v in got.json()["stockpiles"]} if got.status_code == 200 else {}
    for f in truth["features"]:
        name, true_m3 = f["properties"]["name"], f["properties"].get("volume_m3")
        v = vols.get(name)
        if v is None or true_m3 is None:
            ok = False
            print(f"  volume {name}: missing")
            continue
        err = v["volume_m3"] - true_m3
        good = abs(err) <= max(3 * (v["sigma_m3"] or 0.0), 0.02 * true_m3)
        ok &= good
        print(f"  volume {name}: {v['volume_m3']:.2f} m3 +- {v['sigma_m3']:.2f} (truth {true_m3:.2f}, "
              f"{err:+.2f}){'' if good else '  <- outside 3 sigma and 2 %'}")
    return ok


def exercise_running(url: str, seed: int, timeout_s: float) -> int:
    """The same walk-through against a deployment already up (`docker compose up -d` in this folder),
    through its front door `url` (the frontend service's nginx): the admin is created the way docs/deploy.md
    says (`docker compose run --rm api python -m backend.create_user ...`), and each step's worker id (the
    container's host name) is matched with the containers of `docker compose ps`."""
    import httpx

    def compose(*argv: str, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(["docker", "compose", *argv], cwd=REPO, check=True, **kw)

    def create_admin(email: str):
        compose("run", "--rm", "-T", "-e", f"GEOREF_NEW_PASSWORD={ADMIN_PASSWORD}", "api",
                "python", "-m", "backend.create_user", email, "--org-admin")

    containers = {name: compose("ps", "-q", name, capture_output=True, text=True).stdout.split()
                  for name in ("worker", "worker-heavy")}

    def service_of(worker_id: str) -> str:
        host = worker_id.rsplit(":", 1)[0]
        return next((n for n, ids in containers.items() if host and any(i.startswith(host) for i in ids)), "?")

    root = Path(tempfile.mkdtemp(prefix="georef-compose-"))
    t0 = time.monotonic()
    api = httpx.Client(base_url=url.rstrip("/") + "/api/v1", timeout=60)
    ok = exercise(api, create_admin, service_of, lambda: None, root, seed, timeout_s,
                  email=f"admin-{int(time.time())}@example.org")
    print(f"{'OK' if ok else 'FAILED'}: the docker compose deployment at {url} ({time.monotonic() - t0:.0f} s)")
    import shutil

    shutil.rmtree(root, ignore_errors=True)
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timeout", type=float, default=900, help="seconds for the run to finish")
    ap.add_argument("--seed", type=int, default=42, help="seed of the simulated survey")
    ap.add_argument("--redis-db", type=int, default=13)
    ap.add_argument("--keep", action="store_true", help="keep the data folders and logs")
    ap.add_argument("--running", metavar="URL",
                    help="start nothing: walk through the docker compose deployment already up at URL "
                         "(e.g. http://127.0.0.1:8080; GEOREF_COOKIE_SECURE=false without TLS in front)")
    args = ap.parse_args()
    if args.running:
        return exercise_running(args.running, args.seed, args.timeout)
    import httpx
    import psycopg
    import redis
    from moto.server import ThreadedMotoServer

    import logging

    logging.getLogger("werkzeug").setLevel(logging.ERROR)     # moto's request log
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    root = Path(tempfile.mkdtemp(prefix="georef-compose-"))
    pg_name = f"georef_compose_{os.getpid()}"
    with psycopg.connect(host="127.0.0.1", user="postgres", dbname="postgres", autocommit=True) as c:
        c.execute(f'CREATE DATABASE "{pg_name}"')
    broker = f"redis://127.0.0.1:6379/{args.redis_db}"
    redis.Redis.from_url(broker).flushdb()
    s3_port = free_port()
    s3 = ThreadedMotoServer(ip_address="127.0.0.1", port=s3_port, verbose=False)
    s3.start()
    api_port = free_port()
    # the compose network's hosts, mapped to this machine; plain http on the loopback (no TLS in front)
    mapping = {"GEOREF_DATABASE_URL": f"postgresql+psycopg://postgres@127.0.0.1:5432/{pg_name}",
               "GEOREF_BROKER_URL": broker, "GEOREF_S3_ENDPOINT_URL": f"http://127.0.0.1:{s3_port}",
               "GEOREF_COOKIE_SECURE": "false", "GEOREF_PUBLIC_URL": f"http://127.0.0.1:{api_port}"}
    stack = Stack(root)
    ok = True
    try:
        t_start = time.monotonic()
        for name in APP_SERVICES:
            data = root / name
            data.mkdir()
            env = service_env(compose, name, mapping, data)
            cmd = compose["services"][name].get("command") or dockerfile_cmd()
            cmd = [c.replace("/data/", f"{data}/") for c in cmd]
            if cmd[:2] == ["sh", "-c"]:
                script = cmd[2].replace("--host 0.0.0.0", "--host 127.0.0.1").replace("--port 8000",
                                                                                      f"--port {api_port}")
                script = re.sub(r"(?<![\w/])python -m ", f"{shlex.quote(PY)} -m ", script)  # this venv's
                cmd = ["sh", "-c", script.replace("exec uvicorn ", f"exec {shlex.quote(PY)} -m uvicorn ")]
            elif cmd[0] == "celery":
                cmd = [PY, "-m", "celery", *cmd[1:]]
            print(f"{name}: {' '.join(cmd)[:160]}", flush=True)
            stack.start(name, cmd, env)
        api = httpx.Client(base_url=f"http://127.0.0.1:{api_port}/api/v1", timeout=60)
        deadline = time.monotonic() + 180
        while True:
            stack.check_alive()
            try:
                if api.get("/health").status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the api did not answer /health in 180 s")
            time.sleep(0.5)
        for name in ("worker", "worker-heavy"):
            while b" ready." not in stack.logs[name].read_bytes():
                stack.check_alive()
                time.sleep(0.5)
        print(f"services up in {time.monotonic() - t_start:.0f} s", flush=True)

        env = service_env(compose, "api", mapping, root / "api")

        def create_admin(email: str):
            subprocess.run([PY, "-m", "backend.create_user", email, "--org-admin"], check=True, cwd=REPO,
                           env={**os.environ, **env, "GEOREF_NEW_PASSWORD": ADMIN_PASSWORD,
                                "PYTHONPATH": str(REPO)})

        groups = {}

        def service_of(worker_id: str) -> str:
            if not groups:
                groups.update({name: pids_of_group(p.pid) for name, p in stack.procs.items()})
            pid = int(worker_id.rsplit(":", 1)[1]) if worker_id else None
            return next((n for n, pids in groups.items() if pid in pids), "?")

        ok = exercise(api, create_admin, service_of, stack.check_alive, root, args.seed, args.timeout)
        print(f"{'OK' if ok else 'FAILED'}: services of docker-compose.yml as local processes "
              f"({time.monotonic() - t_start:.0f} s in all)")
    except Exception as exc:   # noqa: BLE001 - report, tear down, fail
        ok = False
        print(f"FAILED: {exc}", file=sys.stderr)
        for name, log in stack.logs.items():
            print(f"--- {name} log (end)\n{log.read_text(errors='replace')[-1500:]}", file=sys.stderr)
    finally:
        stack.stop()
        s3.stop()
        redis.Redis.from_url(broker).flushdb()
        with psycopg.connect(host="127.0.0.1", user="postgres", dbname="postgres", autocommit=True) as c:
            c.execute(f'DROP DATABASE IF EXISTS "{pg_name}" WITH (FORCE)')
        if args.keep:
            print(f"logs and data in {root}")
        else:
            import shutil

            shutil.rmtree(root, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
