"""Security regression tests: the platform fixtures of tests/backend (a PostgreSQL + Redis platform and an
embedded SQLite one, each with a database of its own) and a few helpers shared by the modules here."""

from __future__ import annotations

import base64
import re
import threading
import zlib
from http.server import BaseHTTPRequestHandler, HTTPServer

import pytest

from ..backend.conftest import pg_platform, platform, small_survey  # noqa: F401  (fixtures)


class Receiver:
    """An HTTP server on 127.0.0.1 (the only place the tests send traffic to) that records requests and
    answers `status` with a body the platform must never repeat."""

    BANNER = b"SECRET-INTERNAL-BANNER nginx/1.2.3 admin panel"

    def __init__(self, status: int = 200, headers: dict | None = None):
        self.status, self.headers, self.requests = status, headers or {}, []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
                outer.requests.append({"path": self.path, "headers": dict(self.headers), "body": body})
                self.send_response(outer.status)
                for k, v in outer.headers.items():
                    self.send_header(k, v)
                self.send_header("Content-Length", str(len(Receiver.BANNER)))
                self.end_headers()
                self.wfile.write(Receiver.BANNER)

            def log_message(self, *a):
                pass

        self.server = HTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_port
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture
def receiver():
    r = Receiver()
    yield r
    r.close()


def pdf_text(pdf: bytes) -> str:
    """The text a PDF written by ReportLab draws (its content streams inflated, the strings of the text
    operators joined per text object): enough to assert what a report shows."""
    out = []
    # each stream object's own dictionary ("N 0 obj << ... >> stream"): a search from any "<<" could start in
    # an earlier object (a font dictionary) and swallow the stream's /Filter
    for m in re.finditer(rb"\d+ \d+ obj\s*<<((?:(?!endobj).)*?)>>\s*stream\r?\n(.*?)endstream", pdf, re.S):
        dic, data = m.group(1), m.group(2).strip()
        try:
            if b"ASCII85Decode" in dic:
                data = base64.a85decode(data.removesuffix(b"~>"))
            if b"FlateDecode" in dic:
                data = zlib.decompress(data)
        except (ValueError, zlib.error):
            continue
        for bt in re.findall(rb"BT(.*?)ET", data, re.S):
            parts = re.findall(rb"\(((?:\\.|[^\\)])*)\)\s*Tj", bt)
            if parts:
                s = b"".join(parts)
                s = re.sub(rb"\\([()\\])", rb"\1", s)
                out.append(s.decode("latin1"))
    return "\n".join(out)


def has_image(pdf: bytes) -> bool:
    return re.search(rb"/Subtype\s*/Image", pdf) is not None
