"""The resident GNSS solver: a fork server for `georef gnss solve` (docs/gnss.md, "The resident solver").

It imports numpy, the kernels (ahead-of-time module or numba's) and the solve's modules once, then listens on
a Unix socket in the per-user run folder (solver_socket.py), named by the digest of the installation it
loaded. For each request it checks the peer's uid (SO_PEERCRED) and the digest, and fork()s a process that
takes the client's standard streams (passed as SCM_RIGHTS) as its 0/1/2, its working folder, umask and
environment, runs the ordinary CLI ``main(argv)`` and exits with its code, which goes back to the client.
Signals the client forwards (Ctrl-C) are sent to that process; a client that goes away gets its solve
ended. The solve process dies with the server (PR_SET_PDEATHSIG), so a client that falls back to solving
itself never races a half-finished one. The server exits after --idle-s without a request (default 900 s),
when its sources' digest changes (checked every 30 s), on SIGTERM and on a `stop` request.
"""

from __future__ import annotations

import argparse
import json
import os
import select
import selectors
import signal
import socket
import struct
import sys
import time
from pathlib import Path

from . import solver_socket as ss

DIGEST_CHECK_S = 30.0
REQUEST_TIMEOUT_S = 5.0
PR_SET_PDEATHSIG = 1


LAZY_IMPORTS = ("georef_core.gnss.rinex_obs", "georef_core.gnss.rinex_nav", "georef_core.gnss.ubx",
                "georef_core.gnss.rtcm3", "georef_core.gnss.receiver_equipment", "georef_core.gnss.dji_mrk",
                "georef_core.gnss.compressed_files", "georef_core.gnss.camera_events", "georef_core.gnss.rtcm3_nav",
                "georef_core.gnss.ubx_nav_decode", "georef_core.steps.flight_time", "numpy.ma", "hatanaka",
                "ncompress")


def warm_up_survey(folder) -> list[list[str]]:
    """Two tiny simulated solves (warmup.py's 20-epoch survey, RINEX 3 dual-frequency combined and RINEX 2
    single-frequency forward) that a spare process runs before it takes a request: `georef gnss solve`
    argument lists writing into `folder`."""
    from .. import warmup

    data = warmup._survey(folder)
    runs = []
    for version, extra in ((3, ["--freq", "l1+l2"]), (2, ["--freq", "l1", "--filter", "forward"])):
        rover, base, navs = data[version]
        runs.append(["gnss", "solve", str(rover), str(base), *map(str, navs), "--out",
                     str(folder / f"warm{version}.pos"), *extra])
    return runs


def preload() -> str:
    """Import (once, in the server) what every solve process would otherwise import: "aot" or "jit"."""
    from ..gnss import kernel_loader

    aot = kernel_loader.prefer_aot()
    import pyarrow  # noqa: F401
    import pyarrow.parquet  # noqa: F401

    from ..gnss import ppk
    from ..steps import gnss_solve  # noqa: F401
    from . import main

    import contextlib
    import importlib
    import io

    try:   # `--crs`: pyproj's import (~0.17 s) here, once; no CRS or transformer is built (PROJ's database is
        # first opened in the solve process that asks for one, never shared across a fork)
        import pyproj  # noqa: F401
        import pyproj.transformer  # noqa: F401
    except ImportError:
        pass
    main.keep_parser()   # the command-line parser is built once (below) and every solve process inherits it
    with contextlib.redirect_stdout(io.StringIO()):   # the parser: every command module is imported
        try:
            main.main(["gnss", "solve", "--help"])
        except SystemExit:
            pass
    for name in LAZY_IMPORTS:   # what a solve imports on its way (the readers of each input format, ...)
        try:
            importlib.import_module(name)
        except ImportError:
            pass
    if not aot:
        from .numba_start import trim_numba_start

        trim_numba_start()
    ppk._blas_controller()   # threadpoolctl's scan of the loaded BLAS libraries, once
    return "aot" if aot else "jit"


def _peer_uid(conn) -> int:
    creds = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    return struct.unpack("3i", creds)[1]


def peer_allowed(conn) -> bool:
    return _peer_uid(conn) == os.getuid()


def read_request(conn, timeout_s: float | None = REQUEST_TIMEOUT_S) -> tuple[dict, list[int]]:
    """The request and the file descriptors passed with it."""
    conn.settimeout(timeout_s)
    data, fds, _, _ = socket.recv_fds(conn, 65536, 3)
    if len(data) < 4:
        raise ValueError("short request")
    n = ss.request_length(data)
    if n > 16 << 20:
        raise ValueError("request too large")
    body = bytearray(data[4:])
    while len(body) < n:
        chunk = conn.recv(min(65536, n - len(body)))
        if not chunk:
            raise ValueError("truncated request")
        body += chunk
    conn.settimeout(None)
    return json.loads(bytes(body)), list(fds)


def _send(conn, message: dict) -> None:
    try:
        conn.sendall(json.dumps(message).encode() + b"\n")
    except OSError:
        pass


def _die_with_parent(parent_pid: int) -> None:
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:
        os._exit(70)


def _reopen_streams(streams: dict) -> None:
    import io

    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        encoding, errors = streams.get(name) or ("utf-8", "strict")
        tty = os.isatty(fd)
        if name == "stdin":
            raw = io.open(fd, "rb", closefd=False)
            setattr(sys, name, io.TextIOWrapper(raw, encoding=encoding, errors=errors))
        else:
            raw = io.open(fd, "wb", closefd=False)
            setattr(sys, name, io.TextIOWrapper(raw, encoding=encoding, errors=errors,
                                                line_buffering=tty or name == "stderr"))


def run_child(request: dict, fds: list[int], server_pid: int, close: list) -> None:
    """In the forked process: become the client's `georef` process and run the CLI; never returns."""
    code = 70
    try:
        _die_with_parent(server_pid)
        for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGCHLD):
            signal.signal(signum, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for obj in close:
            try:
                obj.close() if hasattr(obj, "close") else os.close(obj)
            except OSError:
                pass
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
        for fd in fds:
            if fd > 2:
                os.close(fd)
        os.chdir(request["cwd"])
        os.umask(int(request["umask"]))
        lower = int(request.get("nice", 0)) - os.nice(0)
        if lower > 0:   # `nice georef gnss solve`: the solve runs as nice as its command (never less nice)
            os.nice(lower)
        os.environ.clear()
        os.environ.update(request["env"])
        time.tzset()
        _reopen_streams(request.get("streams") or {})
        sys.argv = ["georef", *request["argv"]]
        from .main import main

        try:
            result = main(list(request["argv"]))
            code = int(result or 0)
        except SystemExit as exc:
            if exc.code is None:
                code = 0
            elif isinstance(exc.code, int):
                code = exc.code
            else:
                print(exc.code, file=sys.stderr)
                code = 1
        except KeyboardInterrupt:
            print("georef: interrupted", file=sys.stderr)
            code = 130
        except BaseException:   # noqa: BLE001 - as Python's own top level: traceback, exit 1
            import traceback

            traceback.print_exc()
            code = 1
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:   # noqa: BLE001 - the process ends here
                pass
        os._exit(code)


def run_spare(pair, warm_runs: list[list[str]], server_pid: int, close: list) -> None:
    """A spare solve process: runs the warm-up solves (first-call costs and the first touch of its memory
    are paid before a request, not during one), says b"R", waits for a request and its descriptors on
    `pair`, then is that request's process (run_child). Never returns."""
    import warnings

    try:
        _die_with_parent(server_pid)
        for obj in close:
            try:
                obj.close() if hasattr(obj, "close") else os.close(obj)
            except OSError:
                pass
        saved = list(warnings.filters)
        from .main import main

        for argv in warm_runs:
            try:
                main(list(argv))
            except BaseException:   # noqa: BLE001 - a warm-up only
                pass
        warnings.resetwarnings()   # what the warm-up warned about is said again to the user's solve
        warnings.filters[:] = saved
        for stream in (sys.stdout, sys.stderr):
            stream.flush()
        pair.sendall(b"R")
        request, fds = read_request(pair, timeout_s=None)
    except BaseException:   # noqa: BLE001 - no request (the server went away or stopped it)
        os._exit(0)
    run_child(request, fds, server_pid, [pair])


class Server:
    def __init__(self, folder, digest: str, idle_s: float, log):
        self.folder, self.digest, self.idle_s, self.log = folder, digest, idle_s, log
        self.own_digest = ss.source_digest()   # what this process sees at start; a change later: exit
        self.path = ss.socket_path(folder, digest)
        self.sel = selectors.DefaultSelector()
        self.listener = None
        self.jobs: dict[int, dict] = {}     # pid -> {"conn", "pidfd", "forwarded"}
        self.requests = 0
        self.started = time.monotonic()
        self.last_activity = time.monotonic()
        self.mode = ""
        self.stopping = False
        self.lock_fd = -1
        self.wake_r = self.wake_w = -1
        self.warm_runs: list[list[str]] = []
        self.spare = None          # {"pid", "pair", "pidfd", "ready"}: a warmed process waiting for a request
        self.spare_failures = 0

    def say(self, text: str) -> None:
        print(f"{time.strftime('%Y-%m-%dT%H:%M:%S')} [{os.getpid()}] {text}", file=self.log, flush=True)

    def bind(self) -> None:
        try:
            os.unlink(self.path)   # we hold the lock: a socket file there is a dead server's
        except FileNotFoundError:
            pass
        self.listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            ss.unix_address(self.path, self.listener.bind)
        finally:
            os.umask(old)
        self.listener.listen(16)
        self.listener.setblocking(False)
        self.sel.register(self.listener, selectors.EVENT_READ, ("accept", None))
        self.wake_r, self.wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        signal.set_wakeup_fd(self.wake_w, warn_on_full_buffer=False)
        self.sel.register(self.wake_r, selectors.EVENT_READ, ("wake", None))

    def serve(self) -> int:
        last_check = time.monotonic()
        while not self.stopping:
            now = time.monotonic()
            if not self.jobs and now - self.last_activity > self.idle_s:
                self.say(f"idle {self.idle_s:.0f} s: exiting")
                break
            if now - last_check > DIGEST_CHECK_S:
                last_check = now
                if ss.source_digest() != self.own_digest:
                    self.say("the installation changed (source digest): exiting")
                    break
            for key, _ in self.sel.select(timeout=min(DIGEST_CHECK_S, max(0.1, self.idle_s))):
                what, pid = key.data
                if what == "accept":
                    self.accept()
                elif what == "conn":
                    self.client_event(pid)
                elif what == "exit":
                    self.reap(pid)
                elif what == "spare":
                    self.spare_event(pid)
                elif what == "wake":   # a signal arrived (SIGTERM sets self.stopping)
                    try:
                        os.read(key.fd, 512)
                    except OSError:
                        pass
        self.shutdown()
        return 0

    def accept(self) -> None:
        try:
            conn, _ = self.listener.accept()
        except BlockingIOError:
            return
        self.last_activity = time.monotonic()
        conn.setblocking(True)
        fds: list[int] = []
        try:
            if not peer_allowed(conn):
                self.say(f"refused a connection from uid {_peer_uid(conn)}")
                _send(conn, {"refused": "another user's process"})
                conn.close()
                return
            request, fds = read_request(conn)
            if request.get("protocol") != ss.PROTOCOL or request.get("digest") != self.digest:
                self.say("refused a request for another installation (digest)")
                _send(conn, {"refused": "this server runs another version of georef (source digest differs)"})
                raise ValueError("stale")
            op = request.get("op")
            if op == "status":
                _send(conn, {"pid": os.getpid(), "uptime_s": time.monotonic() - self.started,
                             "requests": self.requests, "solving": len(self.jobs), "kernels": self.mode,
                             "idle_s": self.idle_s, "jobs": sorted(self.jobs),
                             "spare": None if self.spare is None else ("ready" if self.spare["ready"] else "warming")})
                raise ValueError("done")
            if op == "stop":
                _send(conn, {"stopping": True, "pid": os.getpid()})
                self.say("stop requested")
                self.stopping = True
                raise ValueError("done")
            if op != "solve" or len(fds) != 3:
                _send(conn, {"refused": f"bad request ({op!r}, {len(fds)} descriptors)"})
                raise ValueError("bad")
        except (OSError, ValueError):
            for fd in fds:
                os.close(fd)
            conn.close()
            return
        self.start_job(conn, request, fds)

    def _fds_to_close(self, *extra) -> list:
        """What a forked process must not keep: the server's sockets, log, lock, other jobs' connections."""
        close = [self.listener, self.log, self.lock_fd, self.wake_r, self.wake_w, *extra,
                 *(j["conn"] for j in self.jobs.values() if j["conn"] is not None),
                 *(j["pidfd"] for j in self.jobs.values())]
        if self.spare is not None:
            close += [self.spare["pair"], self.spare["pidfd"]]
        return close

    def _fork(self, child) -> int:
        for stream in (sys.stdout, sys.stderr, self.log):
            stream.flush()
        pid = os.fork()
        if pid == 0:
            signal.set_wakeup_fd(-1)
            self.sel.close()
            child()
        return pid

    def start_spare(self) -> None:
        """Fork a spare solve process (run_spare) when none is there, nothing runs, and spares work."""
        if self.spare is not None or self.jobs or self.stopping or not self.warm_runs or self.spare_failures >= 3:
            return
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        server_pid = os.getpid()
        close = self._fds_to_close(ours)
        pid = self._fork(lambda: run_spare(theirs, self.warm_runs, server_pid, close))
        theirs.close()
        pidfd = os.pidfd_open(pid)
        self.spare = {"pid": pid, "pair": ours, "pidfd": pidfd, "ready": False}
        self.sel.register(ours, selectors.EVENT_READ, ("spare", pid))
        self.sel.register(pidfd, selectors.EVENT_READ, ("exit", pid))

    def spare_event(self, pid: int) -> None:
        spare = self.spare
        try:
            data = spare["pair"].recv(16)
        except OSError:
            data = b""
        self.sel.unregister(spare["pair"])
        if data == b"R":
            spare["ready"] = True
        # else: the spare is ending; its exit is reaped through its pidfd

    def start_job(self, conn, request: dict, fds: list[int]) -> None:
        self.requests += 1
        spare, self.spare = self.spare, None
        pid = None
        if spare is not None and spare["ready"]:
            try:
                socket.send_fds(spare["pair"], [ss.pack_request(request)], fds)
                pid, pidfd = spare["pid"], spare["pidfd"]
            except OSError:
                pass
            spare["pair"].close()
            if pid is None:
                self._kill(spare["pid"], signal.SIGKILL)   # reaped through its pidfd, as a spare that failed
                self.spare = spare
        elif spare is not None:   # still warming up: left to finish, used by a later request
            self.spare = spare
        if pid is None:
            server_pid = os.getpid()
            close = self._fds_to_close(conn)
            pid = self._fork(lambda: run_child(request, fds, server_pid, close))
            pidfd = os.pidfd_open(pid)
            self.sel.register(pidfd, selectors.EVENT_READ, ("exit", pid))
        for fd in fds:
            os.close(fd)
        self.jobs[pid] = {"conn": conn, "pidfd": pidfd, "forwarded": False, "t0": time.monotonic(),
                          "warm": spare is not None and pid == spare["pid"]}
        self.sel.register(conn, selectors.EVENT_READ, ("conn", pid))
        _send(conn, {"pid": pid})
        self.say(f"solve {self.requests}: pid {pid} ({'warmed spare' if self.jobs[pid]['warm'] else 'forked'}): "
                 f"{' '.join(request['argv'])[:300]}")

    def client_event(self, pid: int) -> None:
        job = self.jobs[pid]
        try:
            data = job["conn"].recv(64)
        except OSError:
            data = b""
        signum = {b"I": signal.SIGINT, b"T": signal.SIGTERM, b"H": signal.SIGHUP}
        if not data:   # the client is gone: its solve is not wanted any more
            self.sel.unregister(job["conn"])
            job["conn"].close()
            job["conn"] = None
            self._kill(pid, signal.SIGTERM)
            return
        for byte in data:
            s = signum.get(bytes([byte]))
            if s is not None:
                job["forwarded"] = True
                self._kill(pid, s)

    @staticmethod
    def _kill(pid: int, signum) -> None:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass

    def reap(self, pid: int) -> None:
        if self.spare is not None and pid == self.spare["pid"]:   # a spare that ended before any request
            spare, self.spare = self.spare, None
            self.sel.unregister(spare["pidfd"])
            os.close(spare["pidfd"])
            try:
                self.sel.unregister(spare["pair"])
            except (KeyError, ValueError):
                pass
            spare["pair"].close()
            _, status, _ = os.wait4(pid, 0)
            self.spare_failures += 1
            self.say(f"spare pid {pid} ended before a request (status {status}); failures {self.spare_failures}")
            return
        job = self.jobs.pop(pid)
        self.sel.unregister(job["pidfd"])
        os.close(job["pidfd"])
        try:
            _, status, usage = os.wait4(pid, 0)
            code = os.waitstatus_to_exitcode(status)
        except ChildProcessError:
            code, usage = 70, None
        cpu_s = (usage.ru_utime + usage.ru_stime) if usage else 0.0
        self.say(f"pid {pid}: exit {code}, {time.monotonic() - job['t0']:.2f} s, CPU {cpu_s:.2f} s")
        if job["conn"] is not None:
            self.sel.unregister(job["conn"])
            _send(job["conn"], {"exit": code, "forwarded": job["forwarded"], "cpu_s": cpu_s})
            job["conn"].close()
        self.last_activity = time.monotonic()
        self.start_spare()

    def shutdown(self) -> None:
        if self.spare is not None:
            self._kill(self.spare["pid"], signal.SIGKILL)
            try:
                os.wait4(self.spare["pid"], 0)
            except ChildProcessError:
                pass
            self.spare = None
        try:
            if self.listener is not None:
                self.listener.close()
                os.unlink(self.path)
        except OSError:
            pass
        for pid in list(self.jobs):   # a stop while solves run: let them finish, their clients get the code
            try:
                _, status, _ = os.wait4(pid, 0)
            except ChildProcessError:
                continue
            job = self.jobs.pop(pid)
            if job["conn"] is not None:
                _send(job["conn"], {"exit": os.waitstatus_to_exitcode(status), "forwarded": job["forwarded"]})
                job["conn"].close()


def _wait_for_exit(pid: int, limit_s: float) -> None:
    """Until process `pid` (the solve that started this server) has ended, at most limit_s."""
    try:
        fd = os.pidfd_open(pid)
    except OSError:
        return
    try:
        select.select([fd], [], [], limit_s)
    finally:
        os.close(fd)


def main(argv: list[str] | None = None) -> int:
    import fcntl

    ap = argparse.ArgumentParser(prog="georef-gnss-server")
    ap.add_argument("--digest", required=True, help="the installation digest the clients compute")
    ap.add_argument("--idle-s", type=float, default=float(os.environ.get("GEOREF_GNSS_SERVER_IDLE_S", 900)))
    ap.add_argument("--wait-pid", type=int, help="load nothing before this process has ended (the first solve)")
    args = ap.parse_args(argv)
    folder = ss.run_dir()
    lock_fd = os.open(ss.lock_path(folder, args.digest), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return 0   # another server for this installation is starting or running
    os.set_inheritable(lock_fd, False)
    log = open(ss.log_path(folder, args.digest), "w", encoding="utf-8")
    os.chmod(log.name, 0o600)
    server = Server(folder, args.digest, args.idle_s, log)
    server.lock_fd = lock_fd
    server.say(f"starting for {ss.PACKAGE_DIR} (digest {args.digest[:24]}), python {sys.executable}")
    if args.wait_pid:
        _wait_for_exit(args.wait_pid, 120.0)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        server.mode = preload()
    except Exception as exc:   # noqa: BLE001 - no server then: every solve runs in its own process
        server.say(f"cannot load the solver: {type(exc).__name__}: {exc}")
        ss.failed_path(folder, args.digest).write_text(f"{type(exc).__name__}: {exc}\n", encoding="utf-8")
        return 1   # and no automatic start for this installation again (solver_client.start_server)
    import gc
    import shutil
    import tempfile

    warm_dir = Path(tempfile.mkdtemp(prefix="georef-gnss-warm-"))
    try:
        server.warm_runs = warm_up_survey(warm_dir)
    except Exception as exc:   # noqa: BLE001 - no spare processes then: each solve is forked cold
        server.say(f"no warm-up survey ({type(exc).__name__}: {exc}); solves are forked without a warm-up")
    gc.collect()
    gc.freeze()   # what is loaded stays out of the collector's sight: a solve process does not touch (copy) it
    server.say(f"loaded ({server.mode} kernels) in {time.perf_counter() - t0:.2f} s, CPU "
               f"{time.process_time() - c0:.2f} s")
    signal.signal(signal.SIGTERM, lambda *a: setattr(server, "stopping", True))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        server.bind()
    except OSError as exc:   # said in the log: the clients then solve in their own processes
        server.say(f"cannot listen on {server.path}: {exc}")
        shutil.rmtree(warm_dir, ignore_errors=True)
        return 1
    server.say(f"listening on {server.path}")
    server.start_spare()
    try:
        return server.serve()
    finally:
        shutil.rmtree(warm_dir, ignore_errors=True)
        server.say("stopped")
