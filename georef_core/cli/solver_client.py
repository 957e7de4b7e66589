"""The `georef gnss solve` client of the resident solver (solver_server.py): hands the command to the server
when one is listening and returns the solve's exit code, or None (the caller then solves in its own process,
as without a server). Standard library only: nothing here imports numpy (docs/gnss.md, "The resident solver").

Any failure of the server path (no server, a refusal, a server that dies before the exit code comes back, a
solve process killed by a signal other than the forwarded Ctrl-C) returns None: the command solves in this
process, with the same results. With no server listening, the first call starts one, detached, and solves
in its own process (it never waits for the server); the server waits for that first process to end before
it loads anything, so the two do not share the CPU.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import time

from . import solver_socket as ss

SIGNALS_FORWARDED = {signal.SIGINT: b"I", signal.SIGTERM: b"T", signal.SIGHUP: b"H"}


def switch() -> str:
    """"off" (GEOREF_GNSS_SERVER=0/off/no/false), "manual" (=manual: use a server started by `georef gnss
    server start`, start none) or "auto" (default)."""
    value = os.environ.get(ss.ENV_SWITCH, "").strip().lower()
    if value in ("0", "off", "no", "false"):
        return "off"
    return "manual" if value == "manual" else "auto"


def wants_server(argv: list[str]) -> bool:
    return (len(argv) >= 2 and argv[0] == "gnss" and argv[1] == "solve" and "--no-server" not in argv
            and "-h" not in argv and "--help" not in argv and switch() != "off")


def served_exit_code(argv: list[str]) -> int | None:
    """The exit code of `georef ARGV` run by the resident solver, or None: solve in this process."""
    if not wants_server(argv):
        return None
    try:
        for fd in (0, 1, 2):
            os.fstat(fd)
    except OSError:
        return None     # a closed standard stream: nothing to pass
    try:
        folder = ss.run_dir()
    except (ss.RunDirError, OSError) as exc:
        print(f"georef: warning: {exc}", file=sys.stderr)
        return None
    digest = ss.source_digest()
    sock = connect(folder, digest)
    if sock is None:
        if switch() == "auto" and not ss.failed_path(folder, digest).exists():
            start_server(folder, digest, wait_pid=os.getpid())
        return None
    with sock:
        return hand_over(sock, digest, argv)


def connect(folder, digest: str, timeout_s: float = 2.0):
    path = ss.socket_path(folder, digest)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.settimeout(timeout_s)
        ss.unix_address(path, sock.connect)
    except OSError:
        sock.close()
        return None
    return sock


def _request(digest: str, argv: list[str]) -> dict:
    mask = os.umask(0o022)
    os.umask(mask)
    streams = {name: [getattr(getattr(sys, name), "encoding", None) or "utf-8",
                      getattr(getattr(sys, name), "errors", None) or "strict"]
               for name in ("stdin", "stdout", "stderr")}
    return {"op": "solve", "protocol": ss.PROTOCOL, "digest": digest, "argv": list(argv), "cwd": os.getcwd(),
            "env": dict(os.environ), "umask": mask, "streams": streams, "nice": os.nice(0)}


def hand_over(sock, digest: str, argv: list[str], request: dict | None = None) -> int | None:
    """Send the request with fds 0-2, forward signals to the solve process, return its exit code (None:
    the server path failed before an exit code came back; the caller solves in its own process)."""
    buffer = bytearray()
    previous, interrupted = {}, []

    def forward(signum, frame):   # from before the request is sent: a Ctrl-C always reaches the solve
        interrupted.append(signum)
        try:
            sock.sendall(SIGNALS_FORWARDED[signum])
        except OSError:
            pass
    try:
        for signum in SIGNALS_FORWARDED:
            previous[signum] = signal.signal(signum, forward)
        try:
            socket.send_fds(sock, [ss.pack_request(request or _request(digest, argv))], [0, 1, 2])
            sock.settimeout(10.0)
            reply = ss.read_line(sock, buffer)
            if reply and "pid" in reply:
                sock.settimeout(None)
                reply = ss.read_line(sock, buffer)
        except (OSError, ValueError):
            reply = None
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if reply and reply.get("refused"):
        print(f"georef: note: the resident solver refused ({reply['refused']}); solving in this process",
              file=sys.stderr)
        reply = None
    if interrupted and not (reply and "exit" in reply):
        print("georef: interrupted", file=sys.stderr)
        return 128 + interrupted[0]
    if not reply or "exit" not in reply:
        print("georef: note: the resident solver ended before the solve did; solving in this process",
              file=sys.stderr)
        return None
    code = int(reply["exit"])
    if code >= 0:
        return code
    if -code in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) and reply.get("forwarded"):
        return 128 - code     # what a shell reports for a process ended by that signal
    print(f"georef: note: the resident solver's process ended by signal {-code}; solving in this process",
          file=sys.stderr)
    return None


# ------------------------------------------------------------------------------------------ server control

def start_server(folder, digest: str, wait_pid: int | None = None, idle_s: float | None = None) -> bool:
    """Start the server detached (its own session; output to its log in the run folder). False when one is
    already starting or running (it holds the lock)."""
    import fcntl

    lock = ss.lock_path(folder, digest)
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False   # a server holds it
    os.close(fd)       # released: the server takes it
    import subprocess

    code = ("import sys; sys.path.insert(0, sys.argv.pop(1)); from georef_core.cli.solver_server import main; "
            "sys.exit(main(sys.argv[1:]))")
    cmd = [sys.executable, "-c", code, str(ss.PACKAGE_DIR.parent), "--digest", digest]
    if wait_pid:
        cmd += ["--wait-pid", str(wait_pid)]
    if idle_s is not None:
        cmd += ["--idle-s", str(idle_s)]
    try:
        subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, close_fds=True, cwd="/")
    except OSError:
        return False
    return True


def ask(folder, digest: str, op: str, timeout_s: float = 5.0) -> dict | None:
    sock = connect(folder, digest, timeout_s)
    if sock is None:
        return None
    with sock:
        try:
            sock.sendall(ss.pack_request({"op": op, "protocol": ss.PROTOCOL, "digest": digest}))
            return ss.read_line(sock, bytearray())
        except (OSError, ValueError):
            return None


def cmd_server(args) -> int:
    """`georef gnss server start|stop|status`."""
    from ..errors import GeorefError

    try:
        folder = ss.run_dir()
    except (ss.RunDirError, OSError) as exc:
        raise GeorefError(str(exc)) from None
    digest = ss.source_digest()
    if args.action == "status":
        info = ask(folder, digest, "status")
        if args.json:
            print(json.dumps({"running": info is not None, "socket": str(ss.socket_path(folder, digest)),
                              **(info or {})}, indent=2))
        elif info is None:
            print(f"no resident GNSS solver for this installation ({ss.socket_path(folder, digest)})")
        else:
            print(f"resident GNSS solver: pid {info['pid']}, up {info['uptime_s']:.0f} s, {info['requests']} "
                  f"solve(s), {info['solving']} running, spare process {info.get('spare') or 'none'}, kernels "
                  f"{info['kernels']}, exits after "
                  f"{info['idle_s']:.0f} s idle; {ss.socket_path(folder, digest)}")
        return 0 if info is not None else 1
    if args.action == "stop":
        info = ask(folder, digest, "stop")
        print("stopped" if info else "no resident GNSS solver was running")
        return 0
    # start
    if ask(folder, digest, "status") is not None:
        print("already running")
        return 0
    start_server(folder, digest, idle_s=args.idle_s)
    if args.wait:
        deadline = time.monotonic() + args.wait
        while time.monotonic() < deadline:
            info = ask(folder, digest, "status")
            if info is not None:
                print(f"started: pid {info['pid']} ({info['kernels']} kernels)")
                return 0
            time.sleep(0.1)
        raise GeorefError(f"the resident solver did not answer within {args.wait:g} s; see "
                          f"{ss.log_path(folder, digest)}")
    print(f"starting (log: {ss.log_path(folder, digest)})")
    return 0
