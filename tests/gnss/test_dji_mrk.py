"""DJI *_Timestamp.MRK reader: the real Phantom 4 RTK files of ../shared/data/dji (skipped when absent),
damaged copies of them, format variants, content recognition and joining flights."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.dji_mrk import (
    QUALITY_FIXED,
    QUALITY_NAMES,
    join_mrk,
    looks_like_mrk,
    parse_mrk_text,
    quality_name,
    read_mrk,
)
from georef_core.gnss.frames import ecef_to_geodetic


def _dji_dir() -> Path | None:
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared"
    for cand in (root / "data" / "dji", root / "dji"):
        if cand.is_dir():
            return cand
    return None


DJI = _dji_dir()
REAL = {  # file -> (exposures, GPS week)
    "p4rtk_auckland_2018/100_0004_Timestamp.MRK": (163, 2024),
    "p4rtk_mrk_samples/100_0067_Timestamp.MRK": (56, 2097),
    "p4rtk_mrk_samples/100_0001_Timestamp.MRK": (300, 2164),
}
AUCKLAND = "p4rtk_auckland_2018/100_0004_Timestamp.MRK"


def _real(name: str) -> Path:
    if DJI is None or not (DJI / name).is_file():
        pytest.skip(f"shared DJI data not available ({name}; set GEOREF_SHARED_DATA)")
    return DJI / name


def _line(i: int, sow: float, week: int = 2100, ned_mm=(10, -5, 190), lat=-36.4, lon=174.6, h=170.0,
          sigma=(0.01, 0.012, 0.02), q: int | None = 50) -> str:
    s = (f"{i}\t{sow:.6f}\t[{week}]\t{ned_mm[0]:6d},N\t{ned_mm[1]:6d},E\t{ned_mm[2]:6d},V\t"
         f"{lat:.8f},Lat\t{lon:.8f},Lon\t{h:.3f},Ellh")
    if sigma is not None:
        s += f"\t{sigma[0]:.6f}, {sigma[1]:.6f}, {sigma[2]:.6f}"
    if q is not None:
        s += f"\t{q},Q"
    return s


def _synthetic(n: int, t0: float, week: int = 2100, **kw) -> str:
    return "".join(_line(i + 1, t0 + 2.5 * i, week, lat=-36.4 + 1e-5 * i, **kw) + "\n" for i in range(n))


# ============================================================================ real files
@pytest.mark.parametrize("name", list(REAL))
def test_real_files(name):
    n, week = REAL[name]
    m = read_mrk(_real(name))
    assert len(m) == n and m.warnings == []
    assert np.array_equal(m.index, np.arange(1, n + 1))
    assert np.all(m.gps_week == week)
    assert np.all(np.diff(m.gps_time_s) > 0)
    assert np.all(m.seconds_of_week >= 0) and np.all(m.seconds_of_week < 604800)
    assert m.camera_offset_ned_m.shape == (n, 3) and np.all(np.abs(m.camera_offset_ned_m) <= 0.5)
    # the camera hangs under the antenna: V (down) is about +0.19 m on a Phantom 4 RTK
    assert np.all((m.camera_offset_ned_m[:, 2] > 0.15) & (m.camera_offset_ned_m[:, 2] < 0.21))
    assert np.all(m.quality == 16) and not m.rtk_fixed.any()
    assert m.sigma_ned_m.shape == (n, 3) and np.all((m.sigma_ned_m > 0.5) & (m.sigma_ned_m < 5))
    assert np.all(m.flight == 0) and m.flight_source_paths == [m.source_path]
    # ECEF consistent with lat/lon/h
    ecef = m.position_ecef_m()
    assert ecef.shape == (n, 3)
    assert np.all(np.abs(np.linalg.norm(ecef, axis=1) - 6.37e6) < 3e4)
    back = ecef_to_geodetic(ecef)
    assert np.allclose(np.degrees(back[:, 0]), m.lat_deg, atol=1e-9)
    assert np.allclose(np.degrees(back[:, 1]), m.lon_deg, atol=1e-9)
    assert np.allclose(back[:, 2], m.ellipsoidal_height_m, atol=1e-4)
    # rotated offsets keep their length
    assert np.allclose(np.linalg.norm(m.offset_ecef_m(), axis=1), np.linalg.norm(m.camera_offset_ned_m, axis=1))


def test_real_first_line_values():
    m = read_mrk(_real(AUCKLAND))
    assert m.gps_time_s[0] == pytest.approx(2024 * 604800 + 275295.301059, abs=1e-6)
    assert m.camera_offset_ned_m[0] == pytest.approx([-0.026, 0.019, 0.191])
    first = (m.lat_deg[0], m.lon_deg[0], m.ellipsoidal_height_m[0])
    assert first == pytest.approx((-36.41144502, 174.63075195, 170.415))
    assert m.sigma_ned_m[0] == pytest.approx([1.492559, 1.368525, 3.180128])
    assert 2.5 < np.median(np.diff(m.gps_time_s)) < 3.2   # one photo every ~2.8 s
    assert looks_like_mrk(_real(AUCKLAND).read_bytes()[:200])


def _damaged(tmp_path, line_no: int, old: str, new: str) -> Path:
    lines = _real(AUCKLAND).read_text().split("\n")
    assert old in lines[line_no - 1]
    lines[line_no - 1] = lines[line_no - 1].replace(old, new, 1)
    p = tmp_path / "damaged_Timestamp.MRK"
    p.write_text("\n".join(lines))
    return p


def test_damaged_truncated_field(tmp_path):
    p = _damaged(tmp_path, 5, "194,V", "19")
    with pytest.raises(InputFileError) as e:
        read_mrk(p)
    assert e.value.line == 5 and str(p) in str(e.value) and "'19'" in e.value.problem


def test_damaged_letter_in_number(tmp_path):
    p = _damaged(tmp_path, 12, "\t-36.4", "\t-36.O")
    with pytest.raises(InputFileError) as e:
        read_mrk(p)
    assert e.value.line == 12 and "latitude" in e.value.problem and "not a number" in e.value.problem


def test_damaged_time_backwards(tmp_path):
    lines = _real(AUCKLAND).read_text().split("\n")
    sow_40 = lines[39].split("\t")[1]
    p = _damaged(tmp_path, 41, lines[40].split("\t")[1], f"{float(sow_40) - 1.0:.6f}")
    with pytest.raises(InputFileError) as e:
        read_mrk(p)
    assert e.value.line == 41 and "not after" in e.value.problem and "line 40" in e.value.problem


def test_damaged_missing_quality_column(tmp_path):
    p = _damaged(tmp_path, 7, "\t16,Q", "")
    with pytest.raises(InputFileError) as e:
        read_mrk(p)
    assert e.value.line == 7 and "quality" in e.value.problem


# ============================================================================ synthetic variants
def test_tolerant_whitespace_crlf_blank_lines():
    clean = _synthetic(5, 1000.0)
    # tabs -> runs of spaces, trailing spaces, CRLF, blank lines, spaces inside the week brackets
    messy = "\r\n\r\n" + "\r\n\r\n".join(x.replace("\t", "   ") + "  " for x in clean.split("\n")[:-1])
    messy = messy.replace("[2100]", "[ 2100 ]") + "\r\n"
    a, b = parse_mrk_text(clean, "a"), parse_mrk_text(messy, "b")
    assert len(b) == 5 and b.warnings == []
    for name in ("gps_time_s", "camera_offset_ned_m", "lat_deg", "sigma_ned_m", "quality", "index"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_error_line_numbers_count_blank_lines():
    text = "\n\n" + _synthetic(3, 1000.0).replace("\t1002.500000\t", "\t1x02.500000\t")
    with pytest.raises(InputFileError) as e:
        parse_mrk_text(text, "x.MRK")
    assert e.value.line == 4 and "seconds of week" in e.value.problem


def test_variants_without_sigma_or_quality():
    m = parse_mrk_text(_synthetic(4, 500.0, sigma=None, q=None), "old.MRK")
    assert np.all(np.isnan(m.sigma_ned_m)) and np.all(m.quality == -1)
    m = parse_mrk_text(_synthetic(4, 500.0, q=None), "no_q.MRK")
    assert np.all(np.isfinite(m.sigma_ned_m)) and np.all(m.quality == -1)
    m = parse_mrk_text(_synthetic(4, 500.0, sigma=None), "no_sigma.MRK")
    assert np.all(np.isnan(m.sigma_ned_m)) and np.all(m.rtk_fixed)


def test_partial_last_line_is_dropped_with_warning():
    text = _synthetic(6, 1000.0)
    m = parse_mrk_text(text[:-25], "cut.MRK")   # the last line loses its end and its newline
    assert len(m) == 5 and len(m.warnings) == 1 and "line 6" in m.warnings[0] and "incomplete" in m.warnings[0]
    # the same damage on a terminated line is an error
    with pytest.raises(InputFileError) as e:
        parse_mrk_text(text[:-25] + "\n", "cut.MRK")
    assert e.value.line == 6


def test_week_rollover_and_week_jump():
    text = _line(1, 604798.0, 2100) + "\n" + _line(2, 0.5, 2101) + "\n"
    m = parse_mrk_text(text, "rollover.MRK")
    assert np.allclose(np.diff(m.gps_time_s), 2.5) and list(m.gps_week) == [2100, 2101]
    with pytest.raises(InputFileError) as e:
        parse_mrk_text(_line(1, 100.0, 2100) + "\n" + _line(2, 200.0, 2102) + "\n", "jump.MRK")
    assert e.value.line == 2 and "week" in e.value.problem


@pytest.mark.parametrize("text", ["", "\n\n  \r\n"])
def test_empty_file_raises(text, tmp_path):
    p = tmp_path / "empty_Timestamp.MRK"
    p.write_text(text)
    with pytest.raises(InputFileError, match="empty"):
        read_mrk(p)


def test_binary_file_raises(tmp_path):
    p = tmp_path / "x.MRK"
    p.write_bytes(b"\xb5\x62\x02\x15\x00\x00" * 10)
    with pytest.raises(InputFileError, match="binary"):
        read_mrk(p)


def test_camera_from_antenna_sign_convention():
    # 0.19 m down, 0.1 m north: the camera is 0.19 m lower and north of the antenna
    m = parse_mrk_text(_line(1, 1000.0, ned_mm=(100, 0, 190), lat=45.0, lon=10.0, h=100.0) + "\n", "s.MRK")
    assert m.camera_offset_ned_m[0] == pytest.approx([0.1, 0.0, 0.19])
    antenna = m.position_ecef_m()
    cam = ecef_to_geodetic(m.camera_ecef_from_antenna_m(antenna))[0]
    assert cam[2] == pytest.approx(100.0 - 0.19, abs=1e-6)
    assert (np.degrees(cam[0]) - 45.0) * 111_132.0 == pytest.approx(0.1, abs=1e-3)
    assert np.degrees(cam[1]) == pytest.approx(10.0, abs=1e-10)
    with pytest.raises(ValueError):
        m.camera_ecef_from_antenna_m(np.zeros((2, 3)))


def test_quality_names():
    assert QUALITY_NAMES[QUALITY_FIXED].startswith("RTK fixed") and "single" in QUALITY_NAMES[16]
    assert quality_name(34) == quality_name(40) and "float" in quality_name(40)
    assert "unknown" in quality_name(7)


# ============================================================================ recognition
def test_looks_like_mrk():
    assert looks_like_mrk(_synthetic(2, 10.0).encode())
    assert looks_like_mrk(b"\xef\xbb\xbf\r\n" + _synthetic(1, 10.0, sigma=None, q=None).replace("\t", "  ").encode())
    rinex = b"     3.04           OBSERVATION DATA    M                   RINEX VERSION / TYPE\n"
    csv = b"gps_time_s,lat,lon,h\n1300000000.0,-36.4,174.6,170.4\n"
    assert not looks_like_mrk(rinex) and not looks_like_mrk(csv)
    assert not looks_like_mrk(b"") and not looks_like_mrk(b"\n\n") and not looks_like_mrk(b"\xb5\x62\x01\x07")


# ============================================================================ joining flights
def test_join_two_flights_in_time_order():
    late = parse_mrk_text(_synthetic(3, 5000.0), "b_Timestamp.MRK")
    early = parse_mrk_text(_synthetic(4, 1000.0), "a_Timestamp.MRK")
    j = join_mrk([late, early])
    assert len(j) == 7 and np.all(np.diff(j.gps_time_s) > 0)
    assert list(j.flight) == [1, 1, 1, 1, 0, 0, 0]
    assert list(j.index) == [1, 2, 3, 4, 1, 2, 3]
    assert j.flight_source_paths == ["b_Timestamp.MRK", "a_Timestamp.MRK"]
    assert j.warnings == [] and len(j.flight_gaps) == 1
    g = j.flight_gaps[0]
    assert (g.before_flight, g.after_flight) == (1, 0)
    assert g.start_gps_time_s == pytest.approx(early.gps_time_s[-1]) and g.duration_s == pytest.approx(5000 - 1007.5)
    assert j.camera_offset_ned_m.shape == (7, 3) and j.position_ecef_m().shape == (7, 3)


def test_join_overlapping_flights_warns():
    a = parse_mrk_text(_synthetic(5, 1000.0), "a.MRK")
    b = parse_mrk_text(_synthetic(5, 1006.0), "b.MRK")
    j = join_mrk([a, b])
    assert np.all(np.diff(j.gps_time_s) >= 0) and j.flight_gaps == []
    assert len(j.warnings) == 1 and "a.MRK" in j.warnings[0] and "b.MRK" in j.warnings[0] and "overlap" in j.warnings[0]
    with pytest.raises(ValueError):
        join_mrk([])


def test_unterminated_last_line_with_bad_time_is_an_error():
    text = _synthetic(3, 1000.0) + _line(4, 900.0)   # complete fields, no newline, time going back
    with pytest.raises(InputFileError) as e:
        parse_mrk_text(text, "x.MRK")
    assert e.value.line == 4 and "not after" in e.value.problem
