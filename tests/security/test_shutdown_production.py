"""Stopping the production shape's worker and beat (docker-compose's own commands) leaves nothing behind.

The embedded server's stop is tested in test_shutdown.py. Here the services run as docker-compose runs them:
the `worker-heavy` service's command (a Celery prefork pool; the georef step goes to the heavy queue) and the
`beat` service's command, this venv's python, docker-compose's environment with a fresh PostgreSQL database
and a Redis database number of this test's own (127.0.0.1:5432 / 127.0.0.1:6379, as the other
production-shape tests use them; local object storage, not MinIO). A georef step (three tiny photos without
positions: it loads pycolmap in the pool child and fails fast) runs first, then SIGTERM goes to the worker's
main process and to beat (`docker compose stop`), or to the worker's whole process group.

Before the fix in worker/celery_app.py, pycolmap's glog failure handler replaced SIGTERM's handler: signalled
with its group, the pool child printed a native stack trace and died by SIGTERM (the `group` case fails on
that code; the `main` case does not: with a prefork pool pycolmap is loaded only in the child, and a warm
shutdown does not signal it)."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ..backend.platform_helpers import close_platform, have_postgres, have_redis, make_platform, wait_run
from .test_shutdown import _georef_run, _has_pycolmap, _procs, failing_georef_survey

REPO = Path(__file__).resolve().parents[2]
STACK_TRACE_WORDS = (b"Traceback", b"Fatal Python error", b"Stack (most recent call", b"*** SIGTERM",
                     b"stack trace", b"Aborted at")
STOP_BOUND_S = 20.0


def _compose_service(name: str) -> tuple[list[str], dict[str, str]]:
    """(command, environment) of a docker-compose service, ${VAR:-default} expanded as compose does."""
    import yaml

    sys.path.insert(0, str(REPO / "scripts"))
    try:
        from compose_local import expand
    finally:
        sys.path.pop(0)
    svc = yaml.safe_load((REPO / "docker-compose.yml").read_text())["services"][name]
    return [str(c) for c in svc["command"]], {k: expand(v) for k, v in (svc.get("environment") or {}).items()}


def _local_command(cmd: list[str], replace: dict[str, str]) -> list[str]:
    """The service's command with this venv's python in place of the `celery` script and the values of the
    options in `replace` (queue, schedule file) changed to this test's own."""
    assert cmd[0] == "celery", cmd
    out = [sys.executable, "-m", "celery"]
    args = cmd[1:]
    i = 0
    while i < len(args):
        out.append(args[i])
        if args[i] in replace:
            out.append(replace[args[i]])
            i += 1
        i += 1
    assert all(opt in args for opt in replace), (cmd, replace)
    return out


def _env(p, compose_env: dict[str, str]) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("GEOREF_")}
    env.update(compose_env)
    env.update({k: v for k, v in p.env.items() if k.startswith("GEOREF_")})   # database, broker, queues, data dir
    env.update({"GEOREF_STORAGE": "local", "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"})
    return env


def _group_and_children(pid: int) -> dict[int, tuple[int, int, str]]:
    """Every process in the process group `pid` leads, and every descendant of `pid`, wherever they are."""
    procs = _procs()
    out = {q: v for q, v in procs.items() if v[1] == pid}
    frontier = {pid}
    while frontier:
        kids = {q for q, v in procs.items() if v[0] in frontier and q not in out}
        out.update({q: procs[q] for q in kids})
        frontier = kids
    if pid in procs:
        out[pid] = procs[pid]
    return out


def _wait_for(log: Path, proc: subprocess.Popen, marker: bytes, timeout_s: float = 60) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if marker in log.read_bytes():
            return
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"{marker!r} not seen (exit {proc.poll()}):\n{log.read_text(errors='replace')[-3000:]}")


def _stop_and_check(proc: subprocess.Popen, log: Path, what: str, group: bool = False) -> float:
    """SIGTERM to the main process (`docker stop`), or to its whole process group (a service manager, a
    terminal's Ctrl-C); exit 0 in the bound, nothing of it left, no stack trace."""
    members = _group_and_children(proc.pid)
    start = log.stat().st_size
    t0 = time.monotonic()
    if group:
        os.killpg(proc.pid, signal.SIGTERM)
    else:
        os.kill(proc.pid, signal.SIGTERM)
    try:
        rc = proc.wait(timeout=STOP_BOUND_S)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the {what} did not stop in {STOP_BOUND_S} s:\n{log.read_text(errors='replace')[-3000:]}")
    took = time.monotonic() - t0
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and (set(members) | set(_group_and_children(proc.pid))) & set(_procs()):
        time.sleep(0.1)
    left = {q: v for q, v in _procs().items() if q in members or v[1] == proc.pid}
    tail = log.read_bytes()[start:]
    assert not left, f"still running after the {what} stopped: {left}"
    assert rc == 0, f"the {what} exited with {rc}:\n{tail[-3000:].decode(errors='replace')}"
    assert not any(w in tail for w in STACK_TRACE_WORDS), tail[-3000:].decode(errors="replace")
    return took


def _kill_all(proc: subprocess.Popen | None) -> None:
    if proc is None:
        return
    for q in _group_and_children(proc.pid):
        try:
            os.kill(q, signal.SIGKILL)
        except ProcessLookupError:
            pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        pass


@pytest.fixture(scope="module")
def production(tmp_path_factory):
    if not Path("/proc/self/stat").exists():
        pytest.skip("needs Linux /proc")
    if not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed for the production shape")
    tmp = tmp_path_factory.mktemp("shutdown-production")
    # queues of this test's own (the Redis db number is shared with other tests of the same process group)
    p = make_platform(tmp, "postgres", queue=f"stop-{os.getpid()}")
    try:
        a, survey = failing_georef_survey(p, "stop-prod@example.org")
        yield p, a, survey, tmp
    finally:
        close_platform(p)


def _start(p, service: str, replace: dict[str, str], log: Path) -> subprocess.Popen:
    cmd, compose_env = _compose_service(service)
    cmd = _local_command(cmd, replace)
    with open(log, "wb") as f:
        return subprocess.Popen(cmd, cwd=REPO, env=_env(p, compose_env), stdout=f, stderr=subprocess.STDOUT,
                                start_new_session=True)


@pytest.mark.parametrize("to", ["main", "group"])
def test_production_worker_and_beat_stop_cleanly_after_a_georef_step(production, to):
    """`main`: `docker compose stop` (SIGTERM to each service's main process: the heavy worker and beat);
    `group`: a service manager or a terminal's Ctrl-C signalling the worker's whole process group, pool child
    included (the child's handler was pycolmap's: a native stack trace, the child killed by SIGTERM)."""
    p, a, survey, tmp = production
    cmd, _ = _compose_service("worker-heavy")
    assert "--pool" not in cmd and "-B" not in cmd, "docker-compose's heavy worker: the prefork pool, no embedded beat"
    run_id = _georef_run(p, a, survey)
    worker = beat = None
    try:
        worker = _start(p, "worker-heavy", {"-Q": p.env["GEOREF_HEAVY_QUEUE"], "-n": f"heavy-{os.getpid()}@%h"},
                        tmp / f"worker-heavy-{to}.log")
        if to == "main":        # beat is a service of its own in docker-compose
            beat = _start(p, "beat", {"-s": str(tmp / "beat-schedule")}, tmp / "beat.log")
        _wait_for(tmp / f"worker-heavy-{to}.log", worker, b" ready.")
        done = wait_run(a, run_id, timeout_s=60)
        georef = next(s for s in done["step_details"] if s["name"] == "georef")
        assert georef["state"] in ("failed", "succeeded"), [(s["name"], s["state"], s.get("error")) for s in done["step_details"]]
        children = [q for q, v in _procs().items() if v[0] == worker.pid]
        assert children, "the prefork pool has a child process"
        assert any(_has_pycolmap(q) for q in children), "the georef step ran in a pool child: pycolmap is loaded there"
        took = _stop_and_check(worker, tmp / f"worker-heavy-{to}.log", "worker", group=to == "group")
        out = (tmp / f"worker-heavy-{to}.log").read_bytes()
        assert b"Warm shutdown" in out, out[-2000:].decode(errors="replace")
        print(f"worker warm shutdown (SIGTERM to {to}) in {took:.1f} s")
        if beat is not None:
            _wait_for(tmp / "beat.log", beat, b"beat: Starting...")
            took = _stop_and_check(beat, tmp / "beat.log", "beat")
            print(f"beat stopped in {took:.1f} s")
    finally:
        _kill_all(worker)
        _kill_all(beat)


def test_local_command_keeps_compose_arguments():
    """The command run above is docker-compose's, option for option, bar the replaced values."""
    cmd, _env_ = _compose_service("worker-heavy")
    local = _local_command(cmd, {"-Q": "q"})
    assert local[:3] == [sys.executable, "-m", "celery"]
    assert shlex.join(local[3:]) == shlex.join(cmd[1:]).replace("-Q heavy", "-Q q")
