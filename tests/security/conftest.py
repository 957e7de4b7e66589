"""Security regression tests: the platform fixtures of tests/backend (a PostgreSQL + Redis platform and an
embedded SQLite one, each with a database of its own) and a few helpers shared by the modules here."""

from __future__ import annotations

import re
import subprocess
import tempfile
import threading
from http.server import BaseHTTPRequestHandler, HTTPServer
from pathlib import Path

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
    """The text a PDF draws, as poppler's pdftotext reads it (content-stream order, ``-raw``): an independent
    reader, not our own parse of ReportLab's streams (which missed page 1 now and then, with whatever the
    minute in the report's date made its compressed stream look like)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.pdf"
        path.write_bytes(pdf)
        done = subprocess.run(["pdftotext", "-raw", "-enc", "UTF-8", str(path), "-"], capture_output=True,
                              timeout=60)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    return done.stdout.decode("utf-8").replace("\f", "\n").rstrip("\n")


def has_image(pdf: bytes) -> bool:
    return re.search(rb"/Subtype\s*/Image", pdf) is not None
