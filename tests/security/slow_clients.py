"""Helpers shared by the slow-client tests and bench/slow_clients.py: the embedded server started as
`make run` starts it (python -m backend.serve_embedded, here without the demo and the worker) on a free
loopback port, and clients that send their request's headers and then its body one byte at a time."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`python -m backend.serve_embedded --no-demo [--no-worker]` on 127.0.0.1 with the given environment."""

    def __init__(self, env: dict, data_dir: Path, log: Path, timeout_s: float = 60, worker: bool = False):
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {**env, "GEOREF_COOKIE_SECURE": "false", "PYTHONPATH": str(REPO) + os.pathsep + env.get("PYTHONPATH", "")}
        self.log = log
        self._f = open(log, "wb")
        cmd = [sys.executable, "-m", "backend.serve_embedded", "--no-demo", "--port", str(self.port), "--data-dir",
               str(data_dir)] + ([] if worker else ["--no-worker"])
        self.proc = subprocess.Popen(cmd,
                                     cwd=REPO, env=env, stdout=self._f, stderr=subprocess.STDOUT,
                                     start_new_session=True)
        import httpx

        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited:\n{log.read_text()[-3000:]}")
            try:
                if httpx.get(self.url + "/api/v1/health", timeout=2).status_code in (200, 503):
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"server not answering in {timeout_s} s:\n{log.read_text()[-3000:]}")

    def stop(self) -> None:
        import signal

        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
        self._f.close()


class SlowClients:
    """``n`` connections that each send a request's head and then trickle one byte every ``interval_s``
    seconds, and ``n_idle`` that send nothing, from one background thread; each one's answer (status line,
    b"closed" or b"reset") and when it came (seconds after all connected) are recorded.

    By default the head is a request's headers announcing ``body_len`` bytes and the trickle its body, never
    the last byte (a slow body); ``slow_headers`` makes clients that never finish their headers."""

    def __init__(self, port: int, n: int, method: str = "POST", path: str = "/api/v1/auth/login",
                 body_len: int = 64, interval_s: float = 1.0, headers: dict | None = None, n_idle: int = 0,
                 head: bytes | None = None, trickle: bytes = b" ", trickle_max: int | None = None):
        self.port, self.n, self.n_idle, self.interval_s = port, n, n_idle, interval_s
        extra = "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
        self.head = head if head is not None else (
            f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
            f"Content-Length: {body_len}\r\n{extra}\r\n").encode()
        self.trickle = trickle
        # never the last byte of a body: the request stays incomplete
        self.trickle_max = (body_len - 1) if head is None else trickle_max
        self.socks: list[socket.socket] = []
        self.answers: dict[int, tuple[float, bytes]] = {}
        self.connected_at = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @classmethod
    def slow_headers(cls, port: int, n: int, n_idle: int = 0, interval_s: float = 0.5) -> "SlowClients":
        """Clients that send a request line and then one header byte every ``interval_s`` (never the end of
        the headers), and ``n_idle`` silent ones."""
        return cls(port, n, interval_s=interval_s, n_idle=n_idle,
                   head=b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Slow: ", trickle=b"a")

    def start(self) -> "SlowClients":
        for i in range(self.n + self.n_idle):
            s = socket.create_connection(("127.0.0.1", self.port), timeout=5)
            if i < self.n:
                s.sendall(self.head)
            s.setblocking(False)
            self.socks.append(s)
        self.connected_at = time.monotonic()
        self._thread.start()
        return self

    def _run(self) -> None:
        sent = 0
        while not self._stop.is_set():
            for i, s in enumerate(self.socks):
                if i in self.answers:
                    continue
                try:
                    data = s.recv(4096)
                    if data:
                        self.answers[i] = (time.monotonic() - self.connected_at, data.split(b"\r\n", 1)[0])
                        continue
                    self.answers[i] = (time.monotonic() - self.connected_at, b"closed")
                    continue
                except BlockingIOError:
                    pass
                except OSError:
                    self.answers[i] = (time.monotonic() - self.connected_at, b"reset")
                    continue
                if i < self.n and (self.trickle_max is None or sent < self.trickle_max):
                    try:
                        s.send(self.trickle)
                    except OSError:
                        pass
            sent += 1
            self._stop.wait(self.interval_s)

    def wait_answers(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and len(self.answers) < len(self.socks):
            time.sleep(0.1)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for s in self.socks:
            try:
                s.close()
            except OSError:
                pass
