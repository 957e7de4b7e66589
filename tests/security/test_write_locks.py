"""No database write lock held across slow work, and bounded work for what users send.

On the embedded SQLite shape a write transaction blocks every other writer (every login records its
attempt): completing an upload used to keep one open while it joined the parts, hashed them, recognised
the content and extracted archives (a crafted 70 KB UBX took 30-46 s in a pure-Python checksum loop), and
an ad-hoc volume kept one open while it computed (a 1,000,000-vertex polygon ran for 17 minutes while
every login answered 503). Here the slow part is held open on purpose (the science function waits) while
another user writes: the write must not wait. Against the real app on SQLite and PostgreSQL."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from ..backend.platform_helpers import Api, add_user, upload_bytes
from ..gnss.test_ubx import ubx

POINTS = (b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.0,3889231.0,80.0,control\n"
          b"T2,679478.0,3889241.0,79.9,check\n")
OUTLINE = {"type": "Polygon", "coordinates": [[[3, 3], [7, 3], [7, 7], [3, 7], [3, 3]]]}


@pytest.fixture(scope="module")
def world(platform):
    owner = f"owner-{platform.shape}@example.org"
    other = f"other-{platform.shape}@example.org"
    add_user(platform, owner)
    add_user(platform, other)
    a, b = Api(platform, owner), Api(platform, other)
    site = a.post("/api/v1/sites", json={"name": "Locks", "crs": "EPSG:32653"}).json()
    survey = a.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F1"}).json()
    return {"p": platform, "a": a, "b": b, "site": site["id"], "survey": survey["id"]}


class Gate:
    """Wraps a function so that each call waits (at most ``hold_s``) until the test opens the gate."""

    def __init__(self, fn, hold_s: float = 8.0):
        self.fn, self.hold_s = fn, hold_s
        self.entered, self.open = threading.Event(), threading.Event()

    def __call__(self, *a, **kw):
        self.entered.set()
        self.open.wait(self.hold_s)
        return self.fn(*a, **kw)


def _other_user_writes(world, name: str) -> float:
    t0 = time.monotonic()
    r = world["b"].post("/api/v1/sites", json={"name": name, "crs": "EPSG:32653"})
    dt = time.monotonic() - t0
    assert r.status_code == 201, r.text
    return dt


def _in_thread(fn):
    out = {}

    def run():
        try:
            out["result"] = fn()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            out["error"] = exc
    t = threading.Thread(target=run)
    t.start()
    return t, out


def test_completing_an_upload_holds_no_write_lock(world, monkeypatch):
    from backend.services import file_kinds

    gate = Gate(file_kinds.recognise)
    monkeypatch.setattr(file_kinds, "recognise", gate)
    t, out = _in_thread(lambda: upload_bytes(world["a"], world["survey"], "points.csv", POINTS, kind="points"))
    try:
        assert gate.entered.wait(20), "the upload never reached the content check"
        dt = _other_user_writes(world, "while an upload completes")
    finally:
        gate.open.set()
        t.join(30)
    assert "error" not in out, out
    assert out["result"].status_code == 200, out["result"].text
    assert dt < 1.5, f"another user's write waited {dt:.1f} s for the upload's content check"


def test_crafted_ubx_is_judged_in_bounded_time(world):
    """Sync bytes every 4 bytes behind one valid frame: every candidate announced a 25 kB frame whose
    checksum a Python loop summed (19 s for these 70 kB); the core's vectorised framing takes
    milliseconds. The same pattern without the valid frame is refused as unrecognised."""
    valid = ubx(0x01, 0x07, bytes(92))
    for data, ok in ((valid + b"\xb5\x62\xff\xff" * 17500, True), (b"\xb5\x62\xff\xff" * 17500, False)):
        t0 = time.monotonic()
        r = upload_bytes(world["a"], world["survey"], "crafted.ubx", data, kind="rover")
        dt = time.monotonic() - t0
        assert dt < 2.0, f"{dt:.1f} s to judge a 70 kB file"
        if ok:
            assert r.status_code == 200, r.text
            meta = [f for f in r.json()["result"]["files"]]
            assert meta and meta[0]["kind"] == "ubx"
        else:
            assert r.status_code == 422, r.text
            assert "crafted.ubx" in r.json()["detail"]


def test_ubx_scan_reads_rawx_times_and_marks(tmp_path):
    """The bounded scan reports what the old loop did: RXM-RAWX epochs and their span, TIM-TM2 marks,
    across the boundary of its 8 MB pieces."""
    from backend.services import file_kinds

    from ..gnss.test_ubx import rawx, tim_tm2

    frames = [rawx(2300, 100.0 + k, []) for k in range(5)] + [tim_tm2(0, 1, 2300, 100500, 0, 2300, 100600, 0)]
    data = b"".join(frames)
    filler = b"\x00" * (file_kinds.UBX_SCAN_BYTES - len(data) // 2)     # a frame straddles the piece boundary
    path = tmp_path / "log.ubx"
    path.write_bytes(data + filler + data)
    meta = file_kinds.recognise(path, "log.ubx").meta
    assert meta["rawx_epochs"] == 10 and meta["event_marks"] == 2 and meta["frames"] == 12, meta
    assert meta["first_gps_time_s"] == 2300 * 604800 + 100.0
    assert meta["last_gps_time_s"] == 2300 * 604800 + 104.0


def _dsm(path: Path) -> Path:
    """A 10 m x 10 m DSM (0.1 m cells, EPSG:32653 at the origin): ground at 10 m, a 2 m x 2 m block 1 m high."""
    import rasterio
    from rasterio.transform import from_origin

    z = np.full((100, 100), 10.0, dtype=np.float32)
    z[40:60, 40:60] = 11.0
    with rasterio.open(path, "w", driver="GTiff", width=100, height=100, count=1, dtype="float32",
                       crs="EPSG:32653", transform=from_origin(0, 10, 0.1, 0.1), nodata=-9999) as ds:
        ds.write(z, 1)
    return path


@pytest.fixture(scope="module")
def run_with_dsm(world, tmp_path_factory):
    from backend.models import Run, RunOutput
    from backend.storage import storage_for

    p = world["p"]
    # a run needs a survey with a file: this fixture does not rely on another test having uploaded one
    # (pytest-xdist may run that test in another process)
    assert upload_bytes(world["a"], world["survey"], "points.csv", POINTS, kind="points").status_code == 200
    r = world["a"].post(f"/api/v1/surveys/{world['survey']}/runs", json={"steps": ["gnss"]})
    assert r.status_code == 201, r.text
    run_id = r.json()["id"]
    dsm = _dsm(tmp_path_factory.mktemp("dsm") / "dsm.tif")
    sha, size = storage_for(p.settings).put_blob(dsm)
    with p.db().session() as s:
        s.add(RunOutput(run_id=run_id, step_name="dense", path="dense/dsm.tif", sha256=sha, size=size))
        s.get(Run, run_id).state = "succeeded"
    return run_id


def test_an_adhoc_volume_holds_no_write_lock(world, run_with_dsm, monkeypatch):
    import georef_core.steps.volumes as volumes_step

    gate = Gate(volumes_step.run_volumes)
    monkeypatch.setattr(volumes_step, "run_volumes", gate)
    t, out = _in_thread(lambda: world["a"].post(f"/api/v1/runs/{run_with_dsm}/volumes",
                                                json={"outline": OUTLINE, "base": "plane"}))
    try:
        assert gate.entered.wait(20), "the volume computation never started"
        dt = _other_user_writes(world, "while a volume is computed")
    finally:
        gate.open.set()
        t.join(30)
    assert "error" not in out, out
    r = out["result"]
    assert r.status_code == 200, r.text
    assert abs(r.json()["volume_m3"] - 4.0) < 0.2, r.json()
    assert dt < 1.5, f"another user's write waited {dt:.1f} s for a volume computation"


@pytest.mark.parametrize("outline, words", [
    ({"type": "Polygon", "coordinates": [[[i % 100, i // 100] for i in range(20_000)] + [[0, 0]]]}, "20001 vertices"),
    ({"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1]]] * 200}, "200 rings"),
    ({"type": "Polygon", "coordinates": [[[0, 0], [1e308, 0], [1e308, 1e308], [0, 0]]]}, "implausible"),
    ({"type": "Polygon", "coordinates": [[[0, 0], ["1", 0], [1, 1], [0, 0]]]}, "numbers"),
    ({"type": "Polygon", "coordinates": "[[0, 0]]"}, "list of rings"),
])
def test_outlines_are_bounded_and_checked(world, run_with_dsm, outline, words):
    """Too many vertices or rings, absurd coordinates, the wrong types: 422 naming the problem, quickly,
    for an ad-hoc volume and for a stockpile alike."""
    a = world["a"]
    for url, body in ((f"/api/v1/runs/{run_with_dsm}/volumes", {"outline": outline}),
                      (f"/api/v1/sites/{world['site']}/stockpiles", {"name": "P", "outline": outline})):
        t0 = time.monotonic()
        r = a.post(url, json=body)
        assert r.status_code == 422, (url, r.status_code, r.text[:300])
        assert words in r.json()["detail"], r.json()["detail"]
        assert time.monotonic() - t0 < 2
