"""Admission control: at most N requests inside the application at once per process, and at most R of
them reads (GET/HEAD).

Without it, a burst of requests all open their database session (authentication runs first) and then
wait for a worker thread while holding the connection: the pool runs dry and requests fail after the
pool timeout. Requests beyond the limit wait here, holding nothing, in arrival order. A request leaves the
limit when its response starts: streamed bodies (server-sent events, file downloads) do not count.

Reads have their own, lower limit: they are short and CPU-bound (a few milliseconds of Python and one or
two queries), so more of them at once only share the cores and the GIL and lengthen every one of them.
On the 2-core development machine with PostgreSQL, 200 readers at 1 request/s: p99 197 ms with 32 reads
at once per process, 73-95 ms with 8, 39-58 ms with 4 (docs/deploy.md). Writes (uploads stream their
chunks in) keep the general limit only, so slow uploads do not hold back readers."""

from __future__ import annotations

import asyncio
import errno
import json
import re

SAFE_METHODS = ("GET", "HEAD")


class ConcurrencyLimit:
    def __init__(self, app, limit: int, read_limit: int = 0):
        self.app = app
        self.limit = limit
        self.read_limit = read_limit
        self._sem: asyncio.Semaphore | None = None
        self._read_sem: asyncio.Semaphore | None = None

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or self.limit <= 0:
            await self.app(scope, receive, send)
            return
        if self._sem is None:
            self._sem = asyncio.Semaphore(self.limit)
            self._read_sem = asyncio.Semaphore(self.read_limit) if self.read_limit > 0 else None
        sems = [self._sem]
        if self._read_sem is not None and scope.get("method") in SAFE_METHODS:
            sems.insert(0, self._read_sem)
        for sem in sems:
            await sem.acquire()
        released = False

        def release():
            nonlocal released
            if not released:
                released = True
                for sem in sems:
                    sem.release()

        async def send_wrapper(message):
            if message["type"] == "http.response.start":
                release()
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            release()


# ------------------------------------------------------------------------------------------ request bodies

_UPLOAD_CHUNK_PATH = re.compile(r"^/api/v1/uploads/[^/]+/?$")
# a site's design surface file (LandXML / DXF / GeoTIFF) is sent whole: it may be as large as an upload chunk
_DESIGN_FILE_PATH = re.compile(r"^/api/v1/sites/[^/]+/design/file/?$")
MEMORY_BODY_BYTES = 1024 * 1024     # larger bodies (upload chunks) are spooled to a file while they arrive
SPOOLED_BODY_KEY = "georef.spooled_body"   # the ASGI scope's entry for a body spooled to a file (a _Body)


class RequestBodyGuard:
    """The request body is received in full *before* the request goes further (admission, database,
    authentication), against a deadline and a size limit.

    Without it a client that sends a request's headers and then its body one byte every few seconds holds
    an admission slot (ConcurrencyLimit is inside) for as long as it likes, and a write request holds the
    database's write lock while its body trickles in: 32 such connections froze the API for everyone.

    Deadline: the body must arrive within ``timeout_s`` plus one second per ``min_rate`` bytes received so
    far (a 64 MiB upload chunk may take as long as it keeps sending at min_rate; one byte every 5 s is cut
    off after timeout_s), else ``408 Request Timeout`` and the connection is closed. Size: a declared or
    received body longer than ``max_body`` (``max_chunk`` for an upload chunk, PUT /api/v1/uploads/{id})
    is answered ``413`` at once. A slow client waiting here holds one coroutine and its socket, nothing the
    other requests need. Bodies up to 1 MiB are kept in memory, larger ones spooled to a file in
    ``spool_dir`` (a full disk there: ``507``); the application then reads the body at disk speed."""

    def __init__(self, app, settings):
        self.app = app
        self.timeout_s = settings.request_body_timeout_s
        self.min_rate = settings.request_body_min_rate
        self.max_body = settings.max_request_body_bytes
        self.max_chunk = settings.max_chunk_bytes
        self.spool_dir = settings.resolved_work_dir() / "tmp"

    def _limit(self, scope) -> int:
        if scope.get("method") == "PUT" and (_UPLOAD_CHUNK_PATH.match(scope.get("path", ""))
                                             or _DESIGN_FILE_PATH.match(scope.get("path", ""))):
            return self.max_chunk
        return self.max_body

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = chunked = None
        for k, v in scope.get("headers", ()):
            if k == b"content-length":
                length = v
            elif k == b"transfer-encoding":
                chunked = v
        if length is not None:
            try:
                length = int(length)
            except ValueError:
                await _refuse(send, 400, "Content-Length is not a number")
                return
        if chunked is None and not length:            # HTTP/1.1: no Content-Length nor chunked: no body
            await self.app(scope, receive, send)
            return
        limit = self._limit(scope)
        if length is not None and length > limit:
            await _refuse(send, 413, f"request body of {length} bytes; at most {limit} bytes are accepted here")
            return
        body = _Body(self.spool_dir)
        try:
            outcome = await self._receive_body(receive, body, limit)
            if outcome == "disconnected":
                return
            if outcome is not None:
                await _refuse(send, *outcome)
                return
            if body.file is not None:
                # a spooled body: the route may take the file itself (request_body.body_in_temp_file)
                # instead of reading it back and writing it again (upload chunks: written once)
                scope[SPOOLED_BODY_KEY] = body
            await self.app(scope, body.replay(receive), send)
        finally:
            body.close()

    async def _receive_body(self, receive, body: "_Body", limit: int):
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        while True:
            left = t0 + self.timeout_s + body.size / self.min_rate - loop.time()
            if left <= 0:
                return _timeout(body.size, self.timeout_s, self.min_rate)
            try:
                message = await asyncio.wait_for(receive(), left)
            except asyncio.TimeoutError:
                return _timeout(body.size, self.timeout_s, self.min_rate)
            if message["type"] == "http.disconnect":
                return "disconnected"
            data = message.get("body", b"")
            if body.size + len(data) > limit:
                return 413, f"request body longer than {limit} bytes, the most accepted here"
            try:
                body.write(data)
            except OSError as exc:
                if exc.errno in (errno.ENOSPC, errno.EDQUOT):
                    return (507, "the server's disk is full: the request could not be received; nothing was "
                                 "stored. Retry later (the operator has been told by /health)")
                raise
            if not message.get("more_body", False):
                return None


def _timeout(received: int, timeout_s: float, min_rate: int) -> tuple[int, str]:
    return 408, (f"request body not received in time ({received} bytes arrived; a body must arrive within "
                 f"{timeout_s:g} s plus 1 s per {min_rate} bytes): send it at once, at a steady rate")


class _Body:
    """A request body being received: in memory, or in a spool file (a named file of ``spool_dir``) past
    MEMORY_BODY_BYTES. ``take()`` hands the spool file over (it is then the taker's to move or remove)."""

    def __init__(self, spool_dir):
        self.spool_dir = spool_dir
        self.parts: list[bytes] = []
        self.size = 0
        self.file = None
        self.path = None
        self.taken = False
        self.read_started = False

    def write(self, data: bytes) -> None:
        if not data:
            return
        if self.file is None and self.size + len(data) > MEMORY_BODY_BYTES:
            import os
            import tempfile
            from pathlib import Path

            self.spool_dir.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(dir=self.spool_dir, prefix="body-")
            self.path = Path(name)
            self.file = os.fdopen(fd, "w+b")
            for p in self.parts:
                self.file.write(p)
            self.parts = []
        if self.file is not None:
            self.file.write(data)
        else:
            self.parts.append(data)
        self.size += len(data)

    def take(self):
        """The spool file's path, its bytes all written, for the caller to keep (rename) or remove; None
        when the body is not in a file or was already read or taken."""
        if self.file is None or self.taken or self.read_started:
            return None
        self.file.flush()
        self.taken = True
        return self.path

    def replay(self, receive):
        """An ASGI receive that gives the stored body, then hands over to the connection's own (which
        tells the application when the client goes away)."""
        state = {"done": False}
        if self.file is not None:
            self.file.flush()
            self.file.seek(0)

        async def replayed():
            if state["done"]:
                return await receive()
            if self.file is None:
                state["done"] = True
                return {"type": "http.request", "body": b"".join(self.parts), "more_body": False}
            if self.taken:
                raise RuntimeError("the request body was taken as a file")
            self.read_started = True
            data = self.file.read(MEMORY_BODY_BYTES)
            more = self.file.tell() < self.size
            if not more:
                state["done"] = True
            return {"type": "http.request", "body": data, "more_body": more}

        return replayed

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None
            if not self.taken:
                self.path.unlink(missing_ok=True)
        self.parts = []


async def _refuse(send, status: int, detail: str) -> None:
    """A problem+json answer from outside the application (its body not read: the connection closes)."""
    from http import HTTPStatus

    title = HTTPStatus(status).phrase
    body = json.dumps({"type": "https://georef.example/problems/" + title.lower().replace(" ", "-"),
                       "title": title, "status": status, "detail": detail}).encode()
    await send({"type": "http.response.start", "status": status, "headers": [
        (b"content-type", b"application/problem+json"), (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"), (b"x-content-type-options", b"nosniff"), (b"x-frame-options", b"DENY"),
        (b"referrer-policy", b"same-origin")]})
    await send({"type": "http.response.body", "body": body})
