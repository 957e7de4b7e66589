"""Static checks of the production shape's files (docker-compose.yml, Dockerfile) against the code they
start. This machine has the Docker client but no daemon, so the stack itself is not run here
(docs/deploy.md); these checks catch the drift that would only show on a server: a misspelt GEOREF_
variable (the settings ignore unknown ones), a queue no worker consumes, a module path that moved, a
health check on a route that does not exist, a file the image build cannot copy."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
SERVICES = {"postgres", "redis", "minio", "api", "worker", "beat", "frontend"}


def _expand(value: str) -> str:
    """${VAR:-default} -> default (what compose substitutes when VAR is unset)."""
    return re.sub(r"\$\{[A-Z0-9_]+:-([^}]*)\}", r"\1", str(value))


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def _georef_env(compose: dict) -> dict[str, str]:
    env = {}
    for svc in compose["services"].values():
        for k, v in (svc.get("environment") or {}).items():
            if k.startswith("GEOREF_"):
                env[k] = _expand(v)
    return env


def test_compose_has_the_production_services(compose):
    assert SERVICES <= set(compose["services"])
    for name in ("api", "worker", "worker-heavy", "beat"):
        svc = compose["services"][name]
        assert svc["image"] == "georef:latest" and svc["build"] == "."
        assert {"postgres", "redis", "minio"} <= set(svc["depends_on"])


def test_every_georef_variable_is_a_setting_and_the_settings_validate(compose, monkeypatch):
    from backend.core.settings import Settings

    env = _georef_env(compose)
    fields = {f"GEOREF_{name.upper()}" for name in Settings.model_fields}
    unknown = sorted(set(env) - fields)
    assert not unknown, f"docker-compose.yml sets variables the settings ignore: {unknown}"
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    s = Settings(_env_file=None)
    assert s.storage == "s3" and s.s3_endpoint_url == "http://minio:9000" and s.s3_bucket
    assert s.resolved_database_url().startswith("postgresql+psycopg://") and "@postgres:5432/" in s.database_url
    assert s.broker_url.startswith("redis://redis:6379")


def test_workers_consume_the_queues_the_api_sends_to(compose):
    from backend.core.settings import Settings

    s = Settings(_env_file=None)
    consumed = set()
    for name in ("worker", "worker-heavy"):
        cmd = compose["services"][name]["command"]
        assert cmd[:3] == ["celery", "-A", "worker.celery_app"]
        consumed |= set(cmd[cmd.index("-Q") + 1].split(","))
    assert {s.default_queue, s.heavy_queue} <= consumed
    beat = compose["services"]["beat"]["command"]
    assert beat[:4] == ["celery", "-A", "worker.celery_app", "beat"]
    import worker.celery_app as celery_module

    assert celery_module.app.main and celery_module.app.conf.beat_schedule


def test_api_image_command_and_health_check_match_the_app(compose):
    from backend.main import app

    dockerfile = (REPO / "Dockerfile").read_text()
    for src in re.findall(r"^COPY\s+(.+?)\s+\S+$", dockerfile, flags=re.M):
        for part in shlex.split(src):
            assert (REPO / part).exists(), f"Dockerfile copies {part}, which is not in the repository"
    cmd = re.search(r'^CMD \["sh", "-c", "(.+)"\]$', dockerfile, flags=re.M).group(1)
    assert "python -m backend.db.migrate" in cmd and "uvicorn backend.main:app" in cmd and "--port 8000" in cmd
    health = compose["services"]["api"]["healthcheck"]["test"]
    url = next(t for t in health if t.startswith("http://"))
    assert url.startswith("http://127.0.0.1:8000/")
    path = url.split(":8000", 1)[1]
    assert path in app.openapi()["paths"]
    nginx = compose["configs"]["nginx_conf"]["content"]
    assert "proxy_pass http://api:8000" in nginx
    # one upload chunk must pass the proxy
    from backend.core.settings import Settings

    limit_mb = int(re.search(r"client_max_body_size (\d+)m", nginx).group(1))
    assert limit_mb * 1024**2 > Settings(_env_file=None).max_chunk_bytes


def test_frontend_service_serves_the_built_ui(compose):
    import json

    mounts = compose["services"]["frontend"]["volumes"]
    dist = [m.split(":")[1] for m in mounts if m.startswith("./frontend/dist:")]
    assert dist
    # nginx serves the folder the UI is mounted in: its compiled-in default root differs between builds
    # (the official image's is /etc/nginx/html), so the server block must name it (found by docker compose up)
    nginx = compose["configs"]["nginx_conf"]["content"]
    assert re.search(r"^\s*root\s+" + re.escape(dist[0]) + r"\s*;", nginx, re.M), nginx
    scripts = json.loads((REPO / "frontend" / "package.json").read_text())["scripts"]
    assert "build" in scripts
    assert "frontend/dist" in (REPO / "docs" / "deploy.md").read_text() or "npm run build" in (
        REPO / "docs" / "deploy.md").read_text()
