"""The resident GNSS solver (georef_core/cli/solver_server.py and solver_client.py): the `georef gnss solve`
command handed to a running server gives the same bytes, exit codes and messages as the command solving
in its own process; a request for another installation is refused; the run folder must be private; Ctrl-C
reaches the solve; a server that dies mid-request leaves the command to solve in its own process."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from georef_core.cli import solver_client, solver_server
from georef_core.cli import solver_socket as ss

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
FILES = [str(DATA / "07590920.05o"), str(DATA / "30400920.05o"), str(DATA / "07590920.05n")]
# the `georef` command (main() with no argv: the console script's path, the server's client included)
GEOREF = [sys.executable, "-c", "import sys; from georef_core.cli.main import main; sys.exit(main())"]


def _env(run_dir: Path, switch: str) -> dict:
    return {**os.environ, ss.ENV_RUN_DIR: str(run_dir), ss.ENV_SWITCH: switch}


def georef(args, run_dir: Path, switch: str = "manual", cwd=None, **kw):
    return subprocess.run([*GEOREF, *args], capture_output=True, text=True, env=_env(run_dir, switch),
                          cwd=cwd, timeout=120, **kw)


_TREE_AT_START: dict[str, str] = {}   # run folder -> source digest when its server started (this process's view)


def status(run_dir: Path) -> dict:
    res = georef(["gnss", "server", "status", "--json"], run_dir)
    info = json.loads(res.stdout)
    if not info["running"] and str(run_dir) in _TREE_AT_START and ss.source_digest() != _TREE_AT_START[str(run_dir)]:
        # a georef_core file was edited while the test ran (a shared working tree): clients now look for the
        # server of the new sources, as they must; nothing to judge here
        pytest.skip("georef_core changed during the test: the server of the old sources is rightly not used")
    return info


def start_server(run_dir: Path) -> dict:
    _TREE_AT_START[str(run_dir)] = ss.source_digest()
    res = georef(["gnss", "server", "start", "--wait", "60", "--idle-s", "120"], run_dir)
    assert res.returncode == 0, res.stdout + res.stderr
    info = status(run_dir)
    assert info["running"], info
    return info


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("run")
    os.chmod(run_dir, 0o700)
    info = start_server(run_dir)
    yield run_dir
    georef(["gnss", "server", "stop"], run_dir)
    try:
        os.kill(info["pid"], signal.SIGTERM)
    except ProcessLookupError:
        pass


def test_served_solve_is_byte_identical_to_in_process(server, tmp_path):
    """Same .pos, Parquet files, stdout and stderr as the command solving in its own process, and the
    server did run it (its request count), in a spare process that had run the warm-up solves first."""
    n0 = _wait(lambda: _spare_ready(server), 300.0, server)["requests"]   # a warmed spare solves it (slow under load)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    served = georef(["gnss", "solve", *FILES, "--out", "t.pos"], server, cwd=tmp_path / "a")
    alone = georef(["gnss", "solve", *FILES, "--out", "t.pos"], server, switch="0", cwd=tmp_path / "b")
    assert served.returncode == alone.returncode == 0, served.stderr + alone.stderr
    assert status(server)["requests"] == n0 + 1
    assert served.stdout == alone.stdout and served.stderr == alone.stderr
    for name in ("t.pos", "t.parquet", "t_residuals.parquet"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert len((tmp_path / "a" / "t.pos").read_text().splitlines()) > 120


def test_client_imports_no_numpy(server, tmp_path):
    """The `georef` process that hands a solve over imports neither numpy nor the solve's modules."""
    probe = ("import atexit, sys; atexit.register(lambda: print('heavy:', sorted(m for m in sys.modules if m in "
             "('numpy', 'pyarrow', 'georef_core.gnss.ppk', 'georef_core.steps.gnss_solve'))));"
             "from georef_core.cli.main import main; sys.exit(main())")
    n0 = status(server)["requests"]
    res = subprocess.run([sys.executable, "-c", probe, "gnss", "solve", *FILES, "--out", str(tmp_path / "t.pos")],
                         capture_output=True, text=True, env=_env(server, "manual"), timeout=120)
    assert res.returncode == 0, res.stderr
    assert status(server)["requests"] == n0 + 1
    assert res.stdout.splitlines()[-1] == "heavy: []"


def test_bad_input_exit_code_and_message_pass_through(server, tmp_path):
    """A missing rover file (GeorefError: exit 2, `georef: error: ...`) and a bad option (argparse: exit 2,
    usage) come back from the server as they are in process."""
    n0 = status(server)["requests"]
    for args in (["gnss", "solve", str(tmp_path / "missing.obs"), *FILES[1:], "--out", str(tmp_path / "x.pos")],
                 ["gnss", "solve", *FILES, "--out", str(tmp_path / "x.pos"), "--mode", "sideways"]):
        served = georef(args, server)
        alone = georef(args, server, switch="0")
        assert served.returncode == alone.returncode == 2
        assert served.stderr == alone.stderr and served.stdout == alone.stdout
        assert "missing.obs" in served.stderr or "sideways" in served.stderr
    assert status(server)["requests"] == n0 + 2


def test_request_for_another_installation_is_refused(server, capsys):
    """A request whose source digest is not the server's is refused (nothing runs) and the client falls
    back to its own process (None)."""
    info = status(server)
    n0 = info["requests"]
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.connect(info["socket"])
    with sock:
        request = solver_client._request("0" * 64, ["gnss", "solve", *FILES, "--out", "/nonexistent/x.pos"])
        assert solver_client.hand_over(sock, "0" * 64, [], request=request) is None
    assert "refused" in capsys.readouterr().err
    assert status(server)["requests"] == n0


def test_run_folder_must_be_private_and_peer_same_user(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    monkeypatch.setenv(ss.ENV_RUN_DIR, str(run))
    assert ss.run_dir() == run and (run.stat().st_mode & 0o777) == 0o700
    os.chmod(run, 0o755)
    with pytest.raises(ss.RunDirError, match="open to other users"):
        ss.run_dir()
    # the command then solves in its own process, saying why
    monkeypatch.setenv(ss.ENV_SWITCH, "manual")
    assert solver_client.served_exit_code(["gnss", "solve", *FILES, "--out", "x.pos"]) is None
    assert "open to other users" in capsys.readouterr().err
    os.chmod(run, 0o700)
    link = tmp_path / "link"
    link.symlink_to(run)
    monkeypatch.setenv(ss.ENV_RUN_DIR, str(link))
    with pytest.raises(ss.RunDirError, match="symbolic link"):
        ss.run_dir()
    monkeypatch.setenv(ss.ENV_RUN_DIR, str(run))
    real_uid = os.getuid()
    monkeypatch.setattr(os, "getuid", lambda: real_uid + 1)
    with pytest.raises(ss.RunDirError, match="not by you"):
        ss.run_dir()
    # SO_PEERCRED: a connection from this user is allowed, one from another uid is not
    a, b = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    with a, b:
        assert not solver_server.peer_allowed(a)
        monkeypatch.setattr(os, "getuid", lambda: real_uid)
        assert solver_server.peer_allowed(a)
    # off switches
    monkeypatch.setenv(ss.ENV_SWITCH, "0")
    assert not solver_client.wants_server(["gnss", "solve", "r", "b", "--out", "x.pos"])
    monkeypatch.setenv(ss.ENV_SWITCH, "auto")
    assert not solver_client.wants_server(["gnss", "solve", "r", "b", "--out", "x.pos", "--no-server"])
    assert solver_client.wants_server(["gnss", "solve", "r", "b", "--out", "x.pos"])


def _spare_ready(run_dir: Path) -> dict | None:
    info = status(run_dir)
    return info if info.get("spare") == "ready" else None


def _wait(predicate, limit_s: float = 120.0, run_dir: Path | None = None):
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    logs = "".join(f"\n--- {p.name}\n{p.read_text(errors='replace')[-3000:]}"
                   for p in sorted(run_dir.glob("*.log"))) if run_dir is not None else ""
    raise AssertionError(f"timed out after {limit_s} s{logs}")


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] in ("Z", "X")
    except OSError:
        return True


def test_ctrl_c_reaches_the_solve_and_a_dying_server_falls_back(tmp_path):
    """The first solve starts the server itself (and solves in its own process). The .pos is a FIFO, so the solve blocks when it writes it. Ctrl-C to the client ends the served solve
    (exit 130, "georef: interrupted"). Then the server is killed while a served solve blocks: that solve dies
    with it and the command solves in its own process, writing the same bytes as a solve with no server."""
    run_dir = tmp_path / "run"
    run_dir.mkdir(mode=0o700)
    _TREE_AT_START[str(run_dir)] = ss.source_digest()
    ref = tmp_path / "ref" / "t.pos"
    ref.parent.mkdir()
    # automatic start: with no server listening the command solves in its own process and starts one
    assert georef(["gnss", "solve", *FILES, "--out", str(ref)], run_dir, switch="auto").returncode == 0
    info = _wait(lambda: _spare_ready(run_dir), 120.0, run_dir)
    assert info["requests"] == 0
    fifo = tmp_path / "t.pos"
    os.mkfifo(fifo)
    cmd = [*GEOREF, "gnss", "solve", *FILES, "--out", str(fifo)]

    client = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=_env(run_dir, "manual"))
    job = _wait(lambda: status(run_dir).get("jobs"))[0]
    client.send_signal(signal.SIGINT)
    out, err = client.communicate(timeout=60)
    assert client.returncode == 130 and "georef: interrupted" in err, err
    _wait(lambda: _gone(job))

    client = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=_env(run_dir, "manual"))
    job = _wait(lambda: status(run_dir).get("jobs"))[0]
    os.kill(info["pid"], signal.SIGKILL)
    _wait(lambda: _gone(job))   # the served solve died with its server, before it wrote anything
    got = {}
    reader = threading.Thread(target=lambda: got.update(data=fifo.read_bytes()), daemon=True)
    reader.start()
    out, err = client.communicate(timeout=120)
    reader.join(10)
    assert client.returncode == 0, err
    assert "solving in this process" in err
    assert got["data"] == ref.read_bytes()


def test_a_run_folder_deeper_than_an_af_unix_address(tmp_path):
    """A socket path longer than AF_UNIX's 107 bytes (a deep home or temporary folder: pytest-xdist's made the
    server of the test above fail to listen, silently, in CI) is bound and reached by its name from its folder."""
    run_dir = tmp_path / ("deep" * 20) / "run"
    run_dir.mkdir(parents=True, mode=0o700)
    run_dir.parent.chmod(0o700)
    assert len(os.fsencode(ss.socket_path(run_dir, ss.source_digest()))) > ss.SOCKET_PATH_MAX
    info = start_server(run_dir)
    out = tmp_path / "t.pos"
    res = georef(["gnss", "solve", *FILES, "--out", str(out)], run_dir)
    assert res.returncode == 0 and out.is_file(), res.stderr
    assert status(run_dir)["requests"] == info["requests"] + 1
    georef(["gnss", "server", "stop"], run_dir)
