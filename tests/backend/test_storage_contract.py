"""The storage contract, on both implementations: local disk (the embedded shape) and S3 (the production
shape). The S3 store talks HTTP to moto's S3 server started on the loopback: MinIO, which docker-compose
runs, needs Docker, which this machine cannot run (docs/deploy.md); the boto3 client, the requests on the
wire and our S3Storage code are the real ones.

What the platform relies on: whole-object atomic writes, exists/size, byte ranges (resumable downloads,
HTTP Range), fetch to a local file, content-addressed blobs stored once, deletes by key and by prefix (an
upload's chunks), and a bucket created on first use."""

from __future__ import annotations

import hashlib
import socket

import pytest

from backend.storage.base import blob_key
from backend.storage.local import LocalStorage


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def s3_endpoint():
    from moto.server import ThreadedMotoServer

    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    yield f"http://127.0.0.1:{port}"
    server.stop()


@pytest.fixture(params=["local", "s3"])
def store(request, tmp_path):
    if request.param == "local":
        return LocalStorage(tmp_path / "store")
    from backend.storage.s3 import S3Storage

    endpoint = request.getfixturevalue("s3_endpoint")
    bucket = f"georef-test-{request.node.name.split('[')[0][-20:].replace('_', '-')}-{tmp_path.name[-6:]}".lower()
    return S3Storage(bucket, endpoint_url=endpoint, access_key_id="test", secret_access_key="test-secret")


def test_objects_round_trip_with_ranges(store, tmp_path):
    data = bytes(range(256)) * 5000                        # 1.28 MB: several read chunks
    assert not store.exists("a/b/c.bin") and store.size("a/b/c.bin") is None
    store.put_bytes("a/b/c.bin", data)
    assert store.exists("a/b/c.bin") and store.size("a/b/c.bin") == len(data)
    assert store.read_bytes("a/b/c.bin") == data
    assert b"".join(store.iter_bytes("a/b/c.bin", 1000, 1_100_000, chunk=65536)) == data[1000:1_100_000]
    assert b"".join(store.iter_bytes("a/b/c.bin", len(data) - 10)) == data[-10:]
    dest = tmp_path / "out" / "c.bin"
    store.fetch("a/b/c.bin", dest)
    assert dest.read_bytes() == data and not dest.with_name("c.bin.part").exists()
    # overwrite replaces the whole object
    store.put_bytes("a/b/c.bin", b"short")
    assert store.read_bytes("a/b/c.bin") == b"short" and store.size("a/b/c.bin") == 5


def test_files_are_stored_once_by_content(store, tmp_path):
    f1, f2 = tmp_path / "one.jpg", tmp_path / "two.jpg"
    payload = b"\xff\xd8" + bytes(range(256)) * 36_000       # 9.2 MB: boto3 uploads it in parts (8 MB threshold)
    f1.write_bytes(payload)
    f2.write_bytes(payload)
    sha, size = store.put_blob(f1)
    assert sha == hashlib.sha256(payload).hexdigest() and size == len(payload)
    assert store.put_blob(f2) == (sha, size)                  # same content: same key, not stored twice
    assert store.read_bytes(blob_key(sha)) == payload


def test_deletes_by_key_and_by_prefix(store):
    for k in range(3):
        store.put_bytes(f"uploads/u1/{k * 100}", b"x" * (k + 1))
    store.put_bytes("uploads/u2/0", b"keep")
    store.delete("uploads/u1/0")
    assert not store.exists("uploads/u1/0") and store.exists("uploads/u1/100")
    store.delete_prefix("uploads/u1/")
    assert not store.exists("uploads/u1/100") and not store.exists("uploads/u1/200")
    assert store.read_bytes("uploads/u2/0") == b"keep"        # another upload's chunks are untouched


def test_s3_bucket_is_created_on_first_use(s3_endpoint):
    import boto3

    from backend.storage.s3 import S3Storage

    client = boto3.client("s3", endpoint_url=s3_endpoint, region_name="us-east-1", aws_access_key_id="test",
                          aws_secret_access_key="test-secret")
    assert "georef-fresh" not in [b["Name"] for b in client.list_buckets()["Buckets"]]
    store = S3Storage("georef-fresh", endpoint_url=s3_endpoint, access_key_id="test", secret_access_key="test-secret")
    store.check()
    assert "georef-fresh" in [b["Name"] for b in client.list_buckets()["Buckets"]]
    store.put_bytes("k", b"v")
    assert client.get_object(Bucket="georef-fresh", Key="k")["Body"].read() == b"v"
