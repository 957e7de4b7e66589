"""Stored files served by the API (backend/api/responses.blob_response): whole, by one byte range, and
304 on a matching ETag, with the same bytes whether the file is small and local (read in one go), large and
local (streamed by FileResponse) or remote (streamed from the store)."""

from __future__ import annotations

import os

import pytest
from fastapi import FastAPI, Request
from fastapi.testclient import TestClient

from backend.api import responses
from backend.core.problems import install_problem_handlers
from backend.storage.local import LocalStorage


class _RemoteLike(LocalStorage):
    """A local store that hides its paths, so blob_response takes the streaming (object store) branch."""

    def local_path(self, key):
        return None


def _client(storage, sha256: str, size: int) -> TestClient:
    app = FastAPI()
    install_problem_handlers(app)

    @app.get("/f")
    def f(request: Request):
        return responses.blob_response(request, storage, sha256, size, "application/octet-stream", "f.bin")

    return TestClient(app)


@pytest.mark.parametrize("kind,size", [("local", 3000), ("local", responses.SMALL_FILE_BYTES + 5000),
                                       ("remote", 3000)])
def test_whole_ranges_and_etag(tmp_path, kind, size):
    storage = (LocalStorage if kind == "local" else _RemoteLike)(tmp_path / "store")
    data = os.urandom(size)
    sha, n = storage.put_blob_bytes(data)
    assert n == size
    c = _client(storage, sha, size)

    whole = c.get("/f")
    assert whole.status_code == 200 and whole.content == data
    assert whole.headers["content-disposition"] == 'attachment; filename="f.bin"'
    assert whole.headers["accept-ranges"] == "bytes"
    for header, lo, hi in [("bytes=100-299", 100, 300), ("bytes=2990-", 2990, size), ("bytes=-10", size - 10, size),
                           (f"bytes=5-{size + 100}", 5, size)]:
        part = c.get("/f", headers={"Range": header})
        assert part.status_code == 206, header
        assert part.content == data[lo:hi], header
        assert part.headers["content-range"] == f"bytes {lo}-{hi - 1}/{size}", header
    bad = c.get("/f", headers={"Range": f"bytes={size}-"})
    assert bad.status_code == 416 and bad.headers["content-range"] == f"bytes */{size}"
    assert bad.headers["content-type"].startswith("application/problem+json")
    assert c.get("/f", headers={"If-None-Match": whole.headers["etag"]}).status_code == 304
