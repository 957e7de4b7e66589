"""Stopping the embedded server after a georef step stops every child cleanly.

Before: pycolmap (imported by the georef step) replaced the worker's SIGTERM handler with glog's, so the
worker printed a native stack trace and died at once instead of shutting down warmly, and when the server
itself was killed the worker's embedded Celery beat child was left running with parent 1. The real
server (python -m backend.serve_embedded, with its worker and beat) is started, a georef step is run (on a
survey of three tiny photos without positions: it loads pycolmap and fails fast), and the server is stopped: by SIGTERM
(a service manager, Ctrl-C), then, started again, by SIGKILL (a crash: the worker learns of it through
PR_SET_PDEATHSIG)."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from ..backend.platform_helpers import Api, add_user, close_platform, make_platform, upload_bytes, wait_run, worker_env
from .slow_clients import Server

POINTS = (b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.0,3889231.0,80.0,control\n"
          b"T2,679478.0,3889241.0,79.9,check\n")
STACK_TRACE_WORDS = (b"*** SIGTERM", b"stack trace", b"Traceback", b"Aborted at")


def failing_georef_survey(p, email: str) -> tuple[Api, str]:
    """A user, a site and a survey on platform ``p`` whose georef step starts, loads pycolmap and fails (a
    control point and photos without positions); (the user's Api, the survey id)."""
    add_user(p, email)
    a = Api(p, email)
    s = a.post("/api/v1/sites", json={"name": "Stop", "crs": "EPSG:32653"}).json()
    survey = a.post(f"/api/v1/sites/{s['id']}/surveys", json={"name": "F"}).json()["id"]
    assert upload_bytes(a, survey, "points.csv", POINTS, kind="points").status_code == 200
    for i in range(3):
        assert upload_bytes(a, survey, f"IMG_{i}.jpg", _jpeg(i), kind="image").status_code == 200
    return a, survey


def _jpeg(seed: int) -> bytes:
    import io

    import numpy as np
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(seed).integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(buf, "JPEG")
    return buf.getvalue()


def _procs() -> dict[int, tuple[int, int, str]]:
    """pid -> (ppid, pgid, command line) of every process."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if fields[0] == "Z":
            continue
        out[int(d.name)] = (int(fields[1]), int(fields[2]), cmd)
    return out


def _log_size(data_dir: Path) -> int:
    log = data_dir / "worker.log"
    return log.stat().st_size if log.exists() else 0


def _worker_pid(data_dir: Path, offset: int, timeout_s: float = 60) -> int:
    log = data_dir / "worker.log"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if log.exists() and b" ready." in log.read_bytes()[offset:]:
            for pid, (_ppid, pgid, cmd) in _procs().items():
                if "celery" in cmd and str(data_dir) in cmd and pid == pgid:
                    return pid
        time.sleep(0.2)
    raise AssertionError(f"the worker did not start:\n{log.read_text()[-3000:] if log.exists() else ''}")


def _has_pycolmap(pid: int) -> bool:
    try:
        return "pycolmap" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def _georef_run(p, a, survey: str) -> str:
    """A run whose georef step is queued (its gnss step marked done: the survey has no GNSS data, and the
    georef step is what loads pycolmap); queued before the server starts, so that no step runs early."""
    from sqlalchemy import update

    from backend.core.queue import send_step
    from backend.models import RunStep

    r = a.post(f"/api/v1/surveys/{survey}/runs", json={"steps": ["georef"]})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    with p.db().session() as s:
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == "gnss").values(state="skipped"))
        s.execute(update(RunStep).where(RunStep.run_id == run_id, RunStep.name == "georef").values(state="queued"))
    send_step(p.settings, run_id, "georef")
    return run_id


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    if not Path("/proc/self/stat").exists():
        pytest.skip("needs Linux /proc")
    tmp = tmp_path_factory.mktemp("shutdown")
    p = make_platform(tmp, "embedded")
    a, survey = failing_georef_survey(p, "stop@example.org")
    yield p, a, survey, tmp
    close_platform(p)


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL], ids=["sigterm", "sigkill"])
def test_stopping_the_server_after_a_georef_step_leaves_nothing_behind(site, how):
    p, a, survey, tmp = site
    run_id = _georef_run(p, a, survey)
    offset = _log_size(p.data_dir)
    server = Server(worker_env(p), p.data_dir, tmp / f"server-{how.name}.log", worker=True)
    try:
        worker = _worker_pid(p.data_dir, offset)
        done = wait_run(a, run_id, timeout_s=60)
        georef = next(s for s in done["step_details"] if s["name"] == "georef")
        assert georef["state"] in ("failed", "succeeded"), [(s["name"], s["state"], s.get("error")) for s in done["step_details"]]
        assert _has_pycolmap(worker), "the georef step ran in the worker: pycolmap is loaded there"
        group = [pid for pid, (_pp, pgid, _c) in _procs().items() if pgid == worker]
        assert len(group) >= 2, "the worker and its embedded beat"
        log_start = (p.data_dir / "worker.log").stat().st_size
        os.kill(server.proc.pid, how)
        server.proc.wait(timeout=40)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(pid in _procs() for pid in group):
            time.sleep(0.2)
        left = {pid: _procs()[pid] for pid in group if pid in _procs()}
        assert not left, f"still running after the server stopped: {left}"
        orphans = {pid: v for pid, v in _procs().items() if v[0] == 1 and str(p.data_dir) in v[2]}
        assert not orphans, f"orphaned children: {orphans}"
        with open(p.data_dir / "worker.log", "rb") as f:
            f.seek(log_start)
            tail = f.read()
        assert not any(w in tail for w in STACK_TRACE_WORDS), tail[-3000:].decode(errors="replace")
        assert b"Warm shutdown" in tail, tail[-2000:].decode(errors="replace")
    finally:
        server.stop()
        for pid, (_pp, _pg, cmd) in _procs().items():      # never leave a process behind, even on failure
            if str(p.data_dir) in cmd:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
