"""The embedded server's HTTP/1.1 protocol: uvicorn's httptools protocol with a deadline and a size limit
on request headers (what nginx's client_header_timeout and large_client_header_buffers do in the
production shape).

uvicorn has neither: a connection that sends nothing, or its headers one byte at a time, stays open as
long as the client likes, and the headers it sends are kept in memory without a bound. Here a request's
headers must be complete within ``header_timeout_s`` of the connection being opened or of the request's
first byte (else ``408`` and the connection is closed) and total at most ``max_header_bytes`` (request
line and header fields; else ``431``). The request body's deadline is the application's
(core/limits.py RequestBodyGuard), so that it holds under any server."""

from __future__ import annotations

import logging
import time

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

log = logging.getLogger("georef.http")


class _OncePerInterval:
    """One log line per ``interval_s`` for a kind of refusal (with the count of those not logged since), so
    that a client repeating a refused request cannot fill the log: refusals are logged, never a traceback."""

    def __init__(self, interval_s: float = 10.0):
        self.interval_s = interval_s
        self.last: dict[str, float] = {}
        self.quiet: dict[str, int] = {}

    def __call__(self, kind: str, msg: str) -> bool:
        now = time.monotonic()
        if now - self.last.get(kind, -1e9) < self.interval_s:
            self.quiet[kind] = self.quiet.get(kind, 0) + 1
            return False
        more = self.quiet.pop(kind, 0)
        self.last[kind] = now
        log.warning(msg + (f" (and {more} more since the last such line)" if more else ""))
        return True


refusal_log = _OncePerInterval()


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    header_timeout_s: float = 10.0
    max_header_bytes: int = 64 * 1024

    def connection_made(self, transport) -> None:   # type: ignore[override]
        super().connection_made(transport)
        self._header_bytes = 0
        self._header_oversize = False
        self._header_timer = None
        if not isinstance(self.logger, _QuietWhenOversize):
            self.logger = _QuietWhenOversize(self, self.logger)
        self._arm_header_timer()

    def connection_lost(self, exc) -> None:
        self._cancel_header_timer()
        super().connection_lost(exc)

    # --- deadline
    def _arm_header_timer(self) -> None:
        if self._header_timer is None:
            self._header_timer = self.loop.call_later(self.header_timeout_s, self._headers_too_slow)

    def _cancel_header_timer(self) -> None:
        if getattr(self, "_header_timer", None) is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _headers_too_slow(self) -> None:
        self._header_timer = None
        if not self.transport.is_closing():
            client = (self.client or ("?",))[0]
            refusal_log("408", f"408: request headers not complete within {self.header_timeout_s:g} s (client "
                               f"{client}); connection closed")
            self._send_plain(408, "request headers not received in time")

    # --- parser callbacks
    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._header_bytes = 0
        self._arm_header_timer()      # the next request on a kept-alive connection: its own deadline

    def on_url(self, url: bytes) -> None:
        self._count(len(url))
        super().on_url(url)

    def on_header(self, name: bytes, value: bytes) -> None:
        self._count(len(name) + len(value) + 4)
        super().on_header(name, value)

    def on_headers_complete(self) -> None:
        self._cancel_header_timer()
        super().on_headers_complete()

    def _count(self, n: int) -> None:
        self._header_bytes += n
        if self._header_bytes > self.max_header_bytes:
            self._header_oversize = True
            raise ValueError("request headers too large")   # stops the parser (HttpParserCallbackError)

    def data_received(self, data: bytes) -> None:
        if not self._header_oversize:
            super().data_received(data)

    def send_400_response(self, msg: str) -> None:
        # uvicorn answers a parser error with 400; the parser stopped here because the headers were too large
        if self._header_oversize:
            client = (self.client or ("?",))[0]
            refusal_log("431", f"431: request headers over {self.max_header_bytes} bytes refused (client {client}); "
                               "connection closed")
            self._send_plain(431, f"request headers larger than {self.max_header_bytes} bytes")
            return
        super().send_400_response(msg)

    def _send_plain(self, status: int, msg: str) -> None:
        from http import HTTPStatus

        self._cancel_header_timer()
        body = msg.encode("ascii")
        head = (f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\ncontent-type: text/plain; charset=utf-8\r\n"
                f"content-length: {len(body)}\r\nconnection: close\r\n\r\n").encode("ascii")
        self.transport.write(head + body)
        self.transport.close()


class _QuietWhenOversize:
    """uvicorn's logger for one connection, without its "Invalid HTTP request received." warning when the
    parser was stopped by the header limit (send_400_response logs one line of its own instead)."""

    def __init__(self, proto: "GuardedHttpToolsProtocol", logger):
        self._proto, self._logger = proto, logger

    def warning(self, msg, *args, **kwargs):
        if not self._proto._header_oversize:
            self._logger.warning(msg, *args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._logger, name)


class SettingsHttpProtocol(GuardedHttpToolsProtocol):
    """The guarded protocol with the limits of the GEOREF_ settings, for uvicorn's command line (the
    production shape: ``uvicorn backend.main:app --http backend.core.http_protocol:SettingsHttpProtocol``,
    Dockerfile), so that the API is safe from slow and oversized headers without nginx in front too."""

    _configured = False

    def __init__(self, *args, **kwargs):
        cls = type(self)
        if not cls._configured:
            from .settings import get_settings

            settings = get_settings()
            cls.header_timeout_s = float(settings.request_header_timeout_s)
            cls.max_header_bytes = int(settings.max_request_header_bytes)
            cls._configured = True
            raise_open_files_limit()
        super().__init__(*args, **kwargs)


def raise_open_files_limit() -> None:
    """Each client connection is a file descriptor: the soft limit (often 1024) raised to the hard one, so
    that many idle or slow connections do not stop the server from accepting new ones."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        want = hard if hard != resource.RLIM_INFINITY else 65536
        if soft != resource.RLIM_INFINITY and soft < want:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
    except (ImportError, ValueError, OSError):
        pass


def guarded_protocol(settings) -> type[GuardedHttpToolsProtocol]:
    """The protocol class with the settings' limits (uvicorn takes a class, built per connection)."""
    return type("GeorefHttpProtocol", (GuardedHttpToolsProtocol,), {
        "header_timeout_s": float(settings.request_header_timeout_s),
        "max_header_bytes": int(settings.max_request_header_bytes)})
