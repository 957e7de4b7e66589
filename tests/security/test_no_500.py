"""Bad input answered 4xx, a full disk answered 507, never a 500 (the real app, SQLite and PostgreSQL).

Each case was a 500 before: a zip member whose name has a component over 255 bytes (ENAMETOOLONG while
extracting), a TIFF upload of 4-6 bytes (struct.error reading its header), `Range: bytes=<5000 digits>-` on
a download (Python refuses to convert more than 4300 digits), the same in an upload's Content-Range, and a
full disk during an upload (while /health still said storage ok). The full disk is made by the storage's
write failing with ENOSPC (the boundary where a full disk shows), and, where this machine lets the tests
mount a small tmpfs (root), by a real full file system."""

from __future__ import annotations

import errno
import hashlib
import io
import os
import subprocess
import zipfile
from pathlib import Path

import pytest

from ..backend.platform_helpers import Api, add_user, close_platform, make_platform, upload_bytes

POINTS = (b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.0,3889231.0,80.0,control\n"
          b"T2,679478.0,3889241.0,79.9,check\n")


@pytest.fixture(scope="module")
def world(platform):
    email = f"no500-{platform.shape}@example.org"
    add_user(platform, email)
    a = Api(platform, email)
    site = a.post("/api/v1/sites", json={"name": "No 500", "crs": "EPSG:32653"}).json()
    survey = a.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F1"}).json()
    return {"p": platform, "a": a, "site": site["id"], "survey": survey["id"]}


def _zip(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buf.getvalue()


def _problem(r, status: int, *words: str) -> dict:
    assert r.status_code == status, (r.status_code, r.text[:500])
    assert r.headers["content-type"].startswith("application/problem+json")
    body = r.json()
    for w in words:
        assert w in body["detail"], body["detail"]
    return body


@pytest.mark.parametrize("members, words", [
    ({"gcp/" + "p" * 300 + ".csv": POINTS}, ("longer than 255 bytes",)),
    ({"images/" + "\u00e9" * 130 + ".jpg": b"\xff\xd8\xff"}, ("longer than 255 bytes",)),       # 260 bytes in UTF-8
    ({"/".join(["d"] * 40) + "/points.csv": POINTS}, ("nested too deeply",)),
    ({"gcp/points.csv": POINTS, "gcp/points.csv/inner.csv": POINTS}, ("cannot be written",)),
])
def test_archive_member_names_the_file_system_refuses(world, members, words):
    r = upload_bytes(world["a"], world["survey"], "survey.zip", _zip(members), kind="archive")
    _problem(r, 422, "survey.zip", *words)


@pytest.mark.parametrize("data", [b"II*\x00", b"MM\x00*\x00", b"II*\x00\x08\x00"])
def test_tiff_cut_inside_its_header(world, data):
    r = upload_bytes(world["a"], world["survey"], "photo.tif", data)
    _problem(r, 422, "photo.tif", "TIFF", "header")


@pytest.fixture(scope="module")
def output(world):
    """A run with one stored output (a 3 kB file), as the worker records them."""
    from backend.models import RunOutput
    from backend.storage import storage_for

    p = world["p"]
    assert upload_bytes(world["a"], world["survey"], "points.csv", POINTS, kind="points").status_code == 200
    r = world["a"].post(f"/api/v1/surveys/{world['survey']}/runs", json={"steps": ["gnss"]})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    data = bytes(range(256)) * 12
    sha, size = storage_for(p.settings).put_blob_bytes(data)
    with p.db().session() as s:
        s.add(RunOutput(run_id=run_id, step_name="report", path="report/accuracy_report.pdf", sha256=sha, size=size))
    return run_id, data


@pytest.mark.parametrize("header", ["bytes=" + "9" * 5000 + "-", "bytes=0-" + "9" * 5000, "bytes=-" + "1" * 5000,
                                    "bytes=" + "1" * 19 + "-"])
def test_range_with_absurd_numbers(world, output, header):
    run_id, _ = output
    for url in (f"/api/v1/runs/{run_id}/results/report.pdf", f"/api/v1/runs/{run_id}/results/files/report/accuracy_report.pdf"):
        r = world["a"].get(url, headers={"Range": header})
        _problem(r, 416)
        assert r.headers["content-range"] == "bytes */3072"
    ok = world["a"].get(f"/api/v1/runs/{run_id}/results/report.pdf", headers={"Range": "bytes=10-19"})
    assert ok.status_code == 206 and ok.content == output[1][10:20]


def test_content_range_with_absurd_numbers(world):
    a = world["a"]
    up = a.post(f"/api/v1/surveys/{world['survey']}/uploads",
                json={"filename": "points.csv", "size": len(POINTS), "sha256": hashlib.sha256(POINTS).hexdigest()}).json()
    for header in ("bytes 0-" + "9" * 5000 + f"/{len(POINTS)}", "bytes " + "1" * 5000 + "-2/3"):
        r = a.put(f"/api/v1/uploads/{up['id']}", content=POINTS, headers={"Content-Range": header})
        _problem(r, 422, "Content-Range")


# ----------------------------------------------------------------------------------------------- full disk


class FullDisk:
    """The storage's writes fail with ENOSPC while ``on``."""

    def __init__(self, monkeypatch, storage):
        self.on = True
        self.storage = storage
        for name in ("put_file", "put_bytes"):
            real = getattr(storage, name)

            def failing(*a, _real=real, **kw):
                if self.on:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return _real(*a, **kw)
            monkeypatch.setattr(storage, name, failing)


def _create(a, survey_id: str, data: bytes, name: str = "points.csv") -> str:
    r = a.post(f"/api/v1/surveys/{survey_id}/uploads",
               json={"filename": name, "size": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _put(a, up: str, data: bytes, start: int, end: int):
    return a.put(f"/api/v1/uploads/{up}", content=data[start:end],
                 headers={"Content-Range": f"bytes {start}-{end - 1}/{len(data)}"})


def test_full_disk_during_an_upload_is_507_and_loses_nothing(world, monkeypatch):
    p, a = world["p"], world["a"]
    storage = p.app.state.storage
    # something stored before the disk fills up
    assert upload_bytes(a, world["survey"], "points.csv", POINTS, kind="points").status_code == 200
    before = a.get(f"/api/v1/surveys/{world['survey']}/files").json()
    data = POINTS.replace(b"T2", b"T3")
    up = _create(a, world["survey"], data)
    half = len(data) // 2
    assert _put(a, up, data, 0, half).status_code == 200
    full = FullDisk(monkeypatch, storage)
    # a chunk: 507 with a message, the upload still where it was
    body = _problem(_put(a, up, data, half, len(data)), 507, "storage is full")
    assert "retry" in body["detail"]
    assert a.get(f"/api/v1/uploads/{up}").json()["received_bytes"] == half
    # space comes back: the same chunk is accepted, the upload completes with the right bytes
    full.on = False
    assert _put(a, up, data, half, len(data)).status_code == 200
    # completion on a full disk: 507, the upload can be completed again later
    full.on = True
    _problem(a.post(f"/api/v1/uploads/{up}/complete"), 507, "storage is full")
    assert a.get(f"/api/v1/uploads/{up}").json()["state"] == "open"
    assert a.get(f"/api/v1/surveys/{world['survey']}/files").json() == before
    full.on = False
    r = a.post(f"/api/v1/uploads/{up}/complete")
    assert r.status_code == 200 and r.json()["state"] == "complete", r.text
    files = {f["path"]: f for f in a.get(f"/api/v1/surveys/{world['survey']}/files").json()}
    assert files["gcp/points.csv"]["sha256"] == hashlib.sha256(data).hexdigest()


def test_health_reports_a_full_storage(world, monkeypatch):
    p = world["p"]
    c = p.client()
    assert c.get("/api/v1/health").status_code == 200
    storage = p.app.state.storage
    if storage.free_bytes() is None:
        pytest.skip("the store cannot tell its free space")
    monkeypatch.setattr(storage, "free_bytes", lambda: 10 * 1024**2)      # under the 256 MiB minimum
    r = c.get("/api/v1/health")
    assert r.status_code == 503, r.text
    assert r.json()["checks"]["storage"] == "full"
    assert "storage" in r.json()["detail"]


# ----------------------------------------------------------------------------------------------- a real full disk


def _mount_tmpfs(path: Path, size: str) -> bool:
    if os.geteuid() != 0:
        return False
    path.mkdir(parents=True, exist_ok=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    return r.returncode == 0


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "disk"
    if not _mount_tmpfs(mnt, "2m"):
        pytest.skip("cannot mount a tmpfs here (needs root and mount permission)")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def test_a_really_full_disk(small_disk, tmp_path):
    """The storage folder on a 2 MiB tmpfs, filled up: an upload answers 507 and /health says storage full;
    once room is made, the same upload completes."""
    p = make_platform(tmp_path, "embedded", storage_dir=small_disk, min_free_storage_bytes=256 * 1024)
    try:
        add_user(p, "disk@example.org")
        a = Api(p, "disk@example.org")
        site = a.post("/api/v1/sites", json={"name": "Disk", "crs": "EPSG:32653"}).json()
        survey = a.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()["id"]
        assert p.client().get("/api/v1/health").status_code == 200
        filler = small_disk / "filler"
        with open(filler, "wb") as f:
            try:
                while True:
                    f.write(b"\0" * 65536)
            except OSError:
                pass
        data = POINTS + b"".join(b"P%d,679508.0,3889231.0,80.0,check\n" % i for i in range(6000))   # 200 kB
        up = _create(a, survey, data)
        _problem(_put(a, up, data, 0, len(data)), 507, "storage is full")
        h = p.client().get("/api/v1/health")
        assert h.status_code == 503 and h.json()["checks"]["storage"] == "full", h.text
        filler.unlink()
        assert _put(a, up, data, 0, len(data)).status_code == 200
        r = a.post(f"/api/v1/uploads/{up}/complete")
        assert r.status_code == 200 and r.json()["state"] == "complete", r.text
        assert p.client().get("/api/v1/health").status_code == 200
    finally:
        close_platform(p)


# ----------------------------------------------------------------------------------------------- bounded unpacking


def _rinex_obs_head() -> bytes:
    src = (Path(__file__).resolve().parents[1] / "data" / "rinex" / "3034265G_head5.21O").read_bytes()
    return b"".join(src.splitlines(keepends=True)[:120])


def test_a_unix_compress_bomb_is_refused_naming_the_file(world):
    """A valid RINEX header followed by 4 MB of spaces, Unix-compressed: 9 kB that unpack 450 times over (a
    crafted LZW stream reaches thousands). Before, the upload's epoch scan unpacked all of it onto the
    work disk, however much it was (a 512 MB .Z could unpack to terabytes); now the unpacking stops past
    200 times the packed size: 422 naming the file, in a fraction of a second."""
    import time

    ncompress = pytest.importorskip("ncompress")
    bomb = ncompress.compress(_rinex_obs_head() + b" " * 4_000_000 + b"\n")
    assert len(bomb) * 200 < 4_000_000
    t0 = time.monotonic()
    r = upload_bytes(world["a"], world["survey"], "base.21O.Z", bomb, kind="base")
    body = _problem(r, 422, "base.21O.Z", "decompression bomb", "200 times")
    assert time.monotonic() - t0 < 3, body
    # the same header with real epochs, packed the same way, is accepted (the bound is not in the way)
    ok = ncompress.compress(_rinex_obs_head())
    r = upload_bytes(world["a"], world["survey"], "base.21O.Z", ok, kind="base")
    assert r.status_code == 200, r.text


def test_unpacking_has_a_time_budget(tmp_path, monkeypatch):
    """The scan of a packed file also stops at its time budget (here 0 s): 422 naming the problem."""
    ncompress = pytest.importorskip("ncompress")
    from backend.services import file_kinds

    f = tmp_path / "rover.21O.Z"
    f.write_bytes(ncompress.compress(_rinex_obs_head() + b"\n" * 200_000))
    assert file_kinds.recognise(f).kind == "rinex-obs"
    monkeypatch.setattr(file_kinds, "SCAN_TIME_BUDGET_S", 0.0)
    with pytest.raises(file_kinds.UnrecognisedFile, match="took more than 0 s to unpack"):
        file_kinds.recognise(f)


def test_gzip_bombs_are_refused_by_the_upload_check_and_the_core_reader(tmp_path, monkeypatch):
    import gzip

    from backend.services import file_kinds
    from georef_core.errors import InputFileError
    from georef_core.gnss import compressed_files

    f = tmp_path / "rover.21O.gz"
    f.write_bytes(gzip.compress(_rinex_obs_head() + (b" " * 79 + b"\n") * 100_000, 9))   # 8 MB in ~9 kB
    with pytest.raises(file_kinds.UnrecognisedFile, match="decompression bomb"):
        file_kinds.recognise(f)
    monkeypatch.setattr(compressed_files, "MIN_UNPACK_CAP_BYTES", 1 << 20)
    with pytest.raises(InputFileError, match="decompression bomb"):
        compressed_files.read_bytes(f)


# ----------------------------------------------------------------------------------------------- chunks written once


def test_upload_chunks_are_written_once_and_assemble_byte_identical(world, monkeypatch):
    """A chunk's bytes are written once, where they arrive (spooled by core/limits.py), then renamed into the
    local store: before, they were spooled, copied to a second temporary file, then copied into the store.
    The file joined from its chunks is byte-identical to what was sent."""
    import random

    from backend.storage.base import blob_key
    from backend.storage.local import LocalStorage

    p, a = world["p"], world["a"]
    storage = p.app.state.storage
    if not isinstance(storage, LocalStorage):
        pytest.skip("a local store renames; others upload the received file")
    from backend.core import limits

    copied, taken = [], []
    real = storage._write_atomic
    monkeypatch.setattr(storage, "_write_atomic", lambda key, w: (copied.append(key), real(key, w))[1])
    real_take = limits._Body.take
    monkeypatch.setattr(limits._Body, "take", lambda self: (lambda got: (taken.append(got), got)[1])(real_take(self)))
    rng = random.Random(5)
    data = POINTS + b"".join(b"Q%d,%.3f,%.3f,%.3f,check\n" % (i, 679000 + rng.random() * 900, 3889000 + rng.random() * 900,
                                                            70 + rng.random() * 20) for i in range(30_000))
    assert 1100 * 1024 < len(data) < 2 * 1100 * 1024   # a chunk over 1 MiB (spooled to a file as it arrives), a small one
    r = upload_bytes(a, world["survey"], "points.csv", data, kind="points", chunk=1100 * 1024)
    assert r.status_code == 200 and r.json()["state"] == "complete", r.text
    assert not [k for k in copied if k.startswith("uploads/")], copied      # no chunk copied into the store
    assert [t for t in taken if t is not None], taken     # the spooled chunk's file itself went to the store
    sha = hashlib.sha256(data).hexdigest()
    assert r.json()["result"]["files"][0]["sha256"] == sha
    assert storage.read_bytes(blob_key(sha)) == data
    assert not list((p.settings.resolved_work_dir() / "tmp").glob("body-*"))   # no spooled body left behind


# ----------------------------------------------------------------------------------------------- bad data that ran anyway


@pytest.mark.parametrize("name, data, words", [
    ("points.csv", POINTS.replace(b"679478.0", b"1e308"), ("points.csv", "line 3", "not a place on Earth")),
    ("points.csv", POINTS.replace(b"80.0", b"-1e9"), ("points.csv", "line 2", "not a place on Earth")),
    ("events.csv", b"image,trigger_gps_time_s\nDJI_0001.JPG,1400000000.25\nDJI_0002.JPG,nan\n",
     ("events.csv", "line 3", "not a finite number")),
    ("events.csv", b"trigger_gps_time_s\n1400000000.25\ninf\n", ("events.csv", "line 3", "not a finite number")),
])
def test_absurd_numbers_are_refused_at_upload_naming_the_file(world, name, data, words):
    """1e308 coordinates gave a "succeeded" run with an empty residual table, NaN/inf trigger times failed
    later as "at least 3 control points are needed": both are now refused by the upload check (the core's
    own readers, so the steps refuse them the same way), naming the file and the line."""
    r = upload_bytes(world["a"], world["survey"], name, data)
    _problem(r, 422, *words)
