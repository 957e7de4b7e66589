"""The real platform for the browser tests: the API (uvicorn, serving frontend/dist), a Celery worker and
an embedded SQLite database in a temporary folder, with a demo organisation, user and site. No mocks.

Also usable by hand to look at the UI:  .venv/bin/python -m tests.frontend.e2e_platform /tmp/georef-ui
(prints the URL and the demo login, runs until Ctrl-C)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PY = sys.executable
DEMO_EMAIL = "manager@demo.example"
DEMO_PASSWORD = "quarry-lead-2024"   # the password policy: not containing "manager" (the e-mail's name)
DEMO_SITE = "Demo quarry"
DEMO_CRS = "EPSG:32653"   # the simulator's default site CRS (UTM 53N)
QUEUE = "georef-ui"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class UiPlatform:
    data_dir: Path
    env: dict
    url: str = ""
    procs: list = field(default_factory=list)
    site_id: str = ""

    def api(self, path: str) -> str:
        return f"{self.url}/api/v1{path}"


def platform_env(data_dir: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GEOREF_")}
    env.update({
        "GEOREF_DATA_DIR": str(data_dir), "GEOREF_DEFAULT_QUEUE": QUEUE, "GEOREF_HEAVY_QUEUE": f"{QUEUE}-heavy",
        "GEOREF_SECRET_KEY": "ui-test", "GEOREF_COOKIE_SECURE": "false",
        "GEOREF_FRONTEND_DIST": str(REPO / "frontend" / "dist"),
        "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
        "OMP_NUM_THREADS": "1",
    })
    return env


def seed(env: dict) -> str:
    """Database schema, the demo organisation, user (site admin) and site; returns the site id."""
    code = f"""
import json
from backend.core.settings import Settings
from backend.db.migrate import upgrade
from backend.db.session import get_database
from backend.services import accounts
from backend.models import Site, SiteRole
s = Settings()
upgrade(s.resolved_database_url())
db = get_database(s.resolved_database_url())
with db.session() as x:
    org = accounts.create_organisation(x, "Demo Earthworks Ltd")
    u = accounts.create_user(x, org.id, {DEMO_EMAIL!r}, {DEMO_PASSWORD!r}, name="Sam Site-Manager")
    site = Site(organisation_id=org.id, name={DEMO_SITE!r}, crs={DEMO_CRS!r}, description="simulated earthworks site")
    x.add(site); x.flush()
    x.add(SiteRole(site_id=site.id, user_id=u.id, role="admin"))
    x.commit()
    print(json.dumps({{"site_id": site.id}}))
"""
    out = subprocess.run([PY, "-c", code], cwd=REPO, env=env, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])["site_id"]


def _wait_http(url: str, proc: subprocess.Popen, log: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited:\n{log.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status < 500:
                    return
        except Exception:
            time.sleep(0.3)
    raise RuntimeError(f"{url} not answering after {timeout_s} s:\n{log.read_text()[-3000:]}")


def start(data_dir: Path, worker: bool = True) -> UiPlatform:
    data_dir.mkdir(parents=True, exist_ok=True)
    env = platform_env(data_dir)
    p = UiPlatform(data_dir, env)
    p.site_id = seed(env)
    port = free_port()
    p.url = f"http://127.0.0.1:{port}"
    log = data_dir / "api.log"
    api = subprocess.Popen([PY, "-m", "uvicorn", "backend.main:app", "--host", "127.0.0.1", "--port", str(port),
                            "--log-level", "warning"], cwd=REPO, env=env, stdout=open(log, "wb"),
                           stderr=subprocess.STDOUT, start_new_session=True)
    p.procs.append(api)
    _wait_http(p.api("/health"), api, log, 60)
    if worker:
        wlog = data_dir / "worker.log"
        w = subprocess.Popen([PY, "-m", "celery", "-A", "worker.celery_app", "worker", "-Q", f"{QUEUE},{QUEUE}-heavy",
                              "--pool", "solo", "--loglevel", "INFO", "-n", f"ui-{port}@%h", "--without-gossip",
                              "--without-mingle", "--without-heartbeat"], cwd=REPO, env=env, stdout=open(wlog, "wb"),
                             stderr=subprocess.STDOUT, start_new_session=True)
        p.procs.append(w)
        deadline = time.monotonic() + 90
        while b" ready." not in wlog.read_bytes():
            if w.poll() is not None or time.monotonic() > deadline:
                stop(p)
                raise RuntimeError(f"worker not ready:\n{wlog.read_text()[-3000:]}")
            time.sleep(0.3)
    return p


def stop(p: UiPlatform) -> None:
    for proc in reversed(p.procs):
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    p.procs.clear()


def simulate_small(out: Path, seed_value: int = 7) -> Path:
    if not (out / "survey.json").exists():
        subprocess.run([PY, "-m", "georef_core.cli.main", "simulate", str(out), "--seed", str(seed_value), "--small",
                        "--quiet"], cwd=REPO, check=True, capture_output=True,
                       env={**os.environ, "OMP_NUM_THREADS": "1"})
    return out


if __name__ == "__main__":
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else "work_out/ui-platform")
    plat = start(folder)
    print(f"Georef UI at {plat.url}  (log in as {DEMO_EMAIL} / {DEMO_PASSWORD}); Ctrl-C stops", flush=True)
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        pass
    finally:
        stop(plat)
