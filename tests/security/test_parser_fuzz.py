"""Seeded parser fuzz: small valid inputs of every format a user can hand the platform, mutated (bit
flips, bytes inserted, deleted, repeated, cut, digits replaced by absurd numbers, lines shuffled) with a
fixed seed, through the science library's readers (what the worker runs) and the upload's content check
(what the API runs).

Every failure must be the project's own error (georef_core.errors.GeorefError, an InputFileError naming the
file; the upload check's UnrecognisedFile), never a bare IndexError, struct.error, ValueError ... (a 500 in
the API, a traceback in the CLI, an "internal error" step), and no input may take over 2 s.
FUZZ_CASES (default 220 a format) scales the run; FUZZ_SEED changes the seed."""

from __future__ import annotations

import io
import json
import os
import random
import re
import time
from pathlib import Path

import numpy as np
import pytest

from georef_core.errors import GeorefError

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data"
CASES = int(os.environ.get("FUZZ_CASES", "220"))
SEED = int(os.environ.get("FUZZ_SEED", "20240623"))
MAX_S = 2.0


# ----------------------------------------------------------------------------------------------- seeds


def _lines(path: Path, n: int) -> bytes:
    return b"".join(path.read_bytes().splitlines(keepends=True)[:n])


def _rinex3_obs() -> bytes:
    return _lines(DATA / "rinex" / "3034265G_head5.21O", 120)


def _rinex2_obs() -> bytes:
    return _lines(DATA / "rinex" / "07590920_head20.05o", 80)


def _rinex2_nav() -> bytes:
    return _lines(DATA / "gnss" / "gsi_0759_3040" / "07590920.05n", 60)


def _rinex3_nav() -> bytes:
    return _lines(REPO / "georef_core" / "sim" / "data" / "base.nav", 58)      # the header and 6 records


def _ubx() -> bytes:
    from ..gnss.test_ubx import rawx, tim_tm2, ubx

    meas = [{"gnss": 0, "sv": sv, "sig": 0, "pr": 2.1e7 + sv * 1e5, "cp": 1.1e8 + sv * 1e6} for sv in (3, 7, 12)]
    meas += [{"gnss": 2, "sv": 5, "sig": 0}, {"gnss": 6, "sv": 4, "sig": 0, "freq": 9}]
    frames = [rawx(2300, 100.0 + k, meas) for k in range(4)]
    frames.insert(2, tim_tm2(0x01, 1, 2300, 101500, 250, 2300, 101600, 350))
    frames.insert(0, ubx(0x01, 0x07, bytes(92)))
    return b"".join(frames)


def _rtcm3() -> bytes:
    from georef_core.gnss.rinex_nav import read_rinex_nav
    from georef_core.gnss.rinex_obs import read_rinex_obs
    from georef_core.gnss.rtcm3_writer import encode_rtcm3

    obs = read_rinex_obs(DATA / "rinex" / "3034265G_head5.21O")
    nav = read_rinex_nav([REPO / "georef_core" / "sim" / "data" / "base.nav"])
    out = encode_rtcm3(obs, nav, station_ecef_m=obs.header.approx_position_ecef_m)
    return bytes(out.data)[:6000]


def _mrk() -> bytes:
    from ..gnss.test_dji_mrk import _synthetic

    return _synthetic(6, 345600.0).encode()


POINTS = (b"name,easting_m,northing_m,ellipsoidal_height_m,role\nT1,679508.012,3889231.5,80.25,control\n"
          b"T2,679478.0,3889241.25,79.9,check\nT3,679490.5,3889250.0,81.0,control\n")
GCP_LIST = (b"EPSG:32653\n679508.0 3889231.0 80.0 1012.5 733.25 IMG_0001.JPG T1\n"
            b"679478.0 3889241.0 79.9 455.0 1020.75 IMG_0002.JPG T2\n679490.5 3889250.0 81.0 600 800 IMG_0003.JPG T3\n")
GEOJSON = json.dumps({"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": "EPSG:32653"}},
                      "features": [{"type": "Feature", "properties": {"name": "pile A"},
                                    "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [10, 0], [10, 8], [0, 8],
                                                                                     [0, 0]]]}},
                                   {"type": "Feature", "properties": {"name": "pile B"},
                                    "geometry": {"type": "Polygon", "coordinates": [[[20, 0], [25, 0], [25, 5],
                                                                                     [20, 0]]]}}]}).encode()
EVENTS = b"gps_time_s,image\n1403870400.125,IMG_0001.JPG\n1403870401.625,IMG_0002.JPG\n1403870403.125,IMG_0003.JPG\n"


def _jpeg_exif_xmp() -> bytes:
    """A small JPEG with EXIF (camera, time, GPS) and a DJI XMP packet, as the simulator writes them."""
    import tempfile

    from PIL import Image

    from georef_core.sim.dji_flight import insert_xmp, xmp_packet

    img = Image.fromarray(np.random.default_rng(1).integers(0, 255, (24, 32, 3), dtype=np.uint8))
    exif = Image.Exif()
    exif[271], exif[272] = "DJI", "FC6310R"
    exif[306] = "2024:06:24 10:00:00"
    ifd = exif.get_ifd(0x8825)
    ifd.update({1: "N", 2: (36.0, 12.0, 30.5), 3: "E", 4: (140.0, 5.0, 10.25), 6: 120.5})
    sub = exif.get_ifd(0x8769)
    sub.update({36867: "2024:06:24 10:00:00", 37521: "123", 37386: 8.8})
    buf = io.BytesIO()
    img.save(buf, "JPEG", exif=exif.tobytes())
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "x.jpg"
        p.write_bytes(buf.getvalue())
        insert_xmp(p, xmp_packet({"GpsLatitude": "36.20847200", "GpsLongtitude": "140.08618000",
                                  "AbsoluteAltitude": "+120.500", "RelativeAltitude": "+60.200",
                                  "GimbalPitchDegree": "-90.00", "GimbalYawDegree": "+12.50",
                                  "CalibratedFocalLength": "3666.666", "RtkFlag": "50", "RtkStdLon": "0.01200",
                                  "RtkStdLat": "0.01100", "RtkStdHgt": "0.02100",
                                  "DewarpData": "2020-01-01;3678.7,3677.9,10.5,-8.2,-0.27,0.11,0.0,0.0,-0.03"}))
        return p.read_bytes()


# ----------------------------------------------------------------------------------------------- readers


def _read_rinex_obs(path):
    from georef_core.gnss.rinex_obs import read_rinex_obs
    return read_rinex_obs(path)


def _read_rinex_nav(path):
    from georef_core.gnss.rinex_nav import read_rinex_nav
    return read_rinex_nav([path])


def _read_ubx(path):
    from georef_core.gnss.ubx import read_ubx
    return read_ubx(path)


def _read_rtcm3(path):
    from georef_core.gnss.rtcm3 import read_rtcm3
    return read_rtcm3(path, approx_gps_time_s=1403870400.0)


def _read_mrk(path):
    from georef_core.gnss.dji_mrk import read_mrk
    return read_mrk(path)


def _read_points(path):
    from georef_core.adjustment.control_points import read_points_csv
    return read_points_csv(path, "EPSG:32653")


def _read_gcp_list(path):
    from georef_core.adjustment.control_points import read_gcp_list
    return read_gcp_list(path)


def _read_geojson(path):
    from georef_core.volumes.polygons import read_polygons
    return read_polygons(path)


def _read_events(path):
    from georef_core.gnss.camera_events import read_event_csv
    return read_event_csv(path)


def _read_image(path):
    from georef_core.photo.dji_xmp import read_dji_xmp
    from georef_core.photo.images import read_image_info
    return read_image_info(path, warn=False), read_dji_xmp(path)


FORMATS = {
    # name: (seed maker, core reader, file name)
    "rinex3-obs": (_rinex3_obs, _read_rinex_obs, "rover.21O"),
    "rinex2-obs": (_rinex2_obs, _read_rinex_obs, "base.05o"),
    "rinex2-nav": (_rinex2_nav, _read_rinex_nav, "brdc.05n"),
    "rinex3-nav": (_rinex3_nav, _read_rinex_nav, "base.nav"),
    "ubx": (_ubx, _read_ubx, "rover.ubx"),
    "rtcm3": (_rtcm3, _read_rtcm3, "flight_PPKRAW.bin"),
    "dji-mrk": (_mrk, _read_mrk, "100_0001_Timestamp.MRK"),
    "points": (lambda: POINTS, _read_points, "points.csv"),
    "gcp-list": (lambda: GCP_LIST, _read_gcp_list, "gcp_list.txt"),
    "geojson": (lambda: GEOJSON, _read_geojson, "piles.geojson"),
    "events": (lambda: EVENTS, _read_events, "events.csv"),
    "exif-xmp": (_jpeg_exif_xmp, _read_image, "DJI_0001.JPG"),
}


# ----------------------------------------------------------------------------------------------- mutations

_ABSURD = [b"99999999999999999999999999", b"-1", b"0", b"1e308", b"-1e308", b"nan", b"inf", b"13", b"25", b"32",
           b"60", b"4294967296", b"9" * 400, b"", b"\x00", b"\xff\xff\xff\xff"]


def mutate(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 3, 8))):
        op = rng.randrange(9)
        n = len(b)
        if n == 0:
            b += bytes([rng.randrange(256)])
            continue
        i = rng.randrange(n)
        if op == 0:                                      # flip a bit
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1:                                    # a random byte
            b[i] = rng.randrange(256)
        elif op == 2:                                    # delete a run
            del b[i:i + rng.randrange(1, 64)]
        elif op == 3:                                    # insert random bytes
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
        elif op == 4:                                    # repeat a run
            j = min(n, i + rng.randrange(1, 200))
            b[i:i] = b[i:j] * rng.randrange(1, 4)
        elif op == 5:                                    # cut the file
            del b[rng.randrange(n):]
        elif op == 6:                                    # a number replaced by an absurd one
            nums = list(re.finditer(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?", bytes(b)))
            if nums:
                m = rng.choice(nums)
                b[m.start():m.end()] = rng.choice(_ABSURD)
        elif op == 7:                                    # two lines swapped
            lines = bytes(b).splitlines(keepends=True)
            if len(lines) > 2:
                x, y = rng.randrange(len(lines)), rng.randrange(len(lines))
                lines[x], lines[y] = lines[y], lines[x]
                b = bytearray(b"".join(lines))
        else:                                            # a 16-bit field of a binary frame set to its maximum
            if n > 2:
                b[i:i + 2] = b"\xff\xff"
    return bytes(b)


# ----------------------------------------------------------------------------------------------- the test


@pytest.fixture(scope="module")
def seeds():
    out = {}
    for name, (make, read, fname) in FORMATS.items():
        data = make()
        assert data, name
        out[name] = data
    return out


def _check(fn, path: Path, allowed: tuple, what: str, failures: list, slow: list, data: bytes) -> None:
    t0 = time.perf_counter()
    try:
        fn(path)
    except allowed:
        pass
    except Exception as exc:    # noqa: BLE001 - what the test is looking for
        failures.append((what, f"{type(exc).__name__}: {str(exc)[:160]}", data))
    dt = time.perf_counter() - t0
    if dt > MAX_S:
        slow.append((what, round(dt, 2), data))


@pytest.mark.parametrize("name", list(FORMATS))
def test_mutated_inputs_fail_with_the_projects_errors(name, seeds, tmp_path):
    from backend.services.file_kinds import UnrecognisedFile, recognise

    make, read, fname = FORMATS[name]
    seed = seeds[name]
    path = tmp_path / fname
    path.write_bytes(seed)
    read(path)                                   # the seed itself is valid
    recognise(path, fname)
    rng = random.Random(f"{SEED}-{name}")
    failures: list = []
    slow: list = []
    t_start = time.perf_counter()
    for k in range(CASES):
        data = mutate(seed, rng)
        path.write_bytes(data)
        _check(read, path, (GeorefError,), f"{name} #{k} core", failures, slow, data)
        _check(lambda p: recognise(p, fname), path, (UnrecognisedFile,), f"{name} #{k} upload", failures, slow, data)
    total = time.perf_counter() - t_start
    if failures:
        kinds = {}
        for what, err, data in failures:
            kinds.setdefault(err.split(":")[0] + " " + what.split()[-1], (what, err, data[:120]))
        pytest.fail(f"{len(failures)} of {2 * CASES} inputs failed with a foreign error; one of each kind:\n"
                    + "\n".join(f"  {w}: {e}\n    input starts {d!r}" for w, e, d in kinds.values()))
    assert not slow, f"inputs over {MAX_S} s: {[(w, t) for w, t, _ in slow]}"
    assert total < 30, f"{2 * CASES} inputs took {total:.1f} s"


def test_the_issues_36_byte_ubx_gives_the_clis_error_not_a_traceback(tmp_path, capsys):
    """Sync bytes and no valid frame (find_ubx_frames raised IndexError; the CLI printed a traceback)."""
    from georef_core.cli.main import main
    from georef_core.errors import InputFileError
    from georef_core.gnss.ubx import find_ubx_frames, read_ubx

    data = b"\xb5\x62\x02\x15" + bytes(range(32))
    assert len(data) == 36
    f = tmp_path / "rover.ubx"
    f.write_bytes(data)
    find_ubx_frames(np.frombuffer(data, np.uint8))
    with pytest.raises(InputFileError):
        read_ubx(f)
    nav = DATA / "rinex" / "3034265G_head5.21O"
    rc = main(["gnss", "solve", str(f), str(nav), str(nav), "--out", str(tmp_path / "x.pos")])
    err = capsys.readouterr().err
    assert rc == 2 and str(f) in err and "Traceback" not in err, err
