"""Tests of georef_core.gnss.rinex_obs: RINEX 2/3 observation reading and writing.

Real files come from ../shared/data/gnss (or env GEOREF_SHARED_DATA); tests that need them skip when absent.
Small fixtures in tests/data/rinex (MIT/BSD, see PROVENANCE.txt) and handcrafted texts cover the rest.
georinex, the peer reader, is used as the reference for values (it is slow on RINEX 3: small files only).
"""

from __future__ import annotations

import gzip
import json
import os
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.gnss_time import calendar_to_gps_time_s
from georef_core.gnss.observations import RawObservations, ReceiverHeader
from georef_core.gnss.rinex_obs import (
    RINEX2_TO_RINEX3,
    RinexTruncatedWarning,
    read_rinex_obs,
    write_rinex2_obs,
    write_rinex3_obs,
)

FIXTURES = Path(__file__).resolve().parents[1] / "data" / "rinex"
GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")


def _shared_gnss_dir() -> Path | None:
    candidates = []
    env = os.environ.get("GEOREF_SHARED_DATA")
    if env:
        candidates += [Path(env) / "data" / "gnss", Path(env) / "gnss", Path(env)]
    candidates.append(Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gnss")
    for c in candidates:
        if (c / "rinex_summary.jsonl").is_file():
            return c
    return None


SHARED_GNSS = _shared_gnss_dir()
SUMMARY = ([json.loads(x) for x in (SHARED_GNSS / "rinex_summary.jsonl").read_text().splitlines() if x.strip()]
           if SHARED_GNSS else [])


@pytest.fixture
def gnss_dir() -> Path:
    if SHARED_GNSS is None:
        pytest.skip("shared real data (../shared/data/gnss) not found; set GEOREF_SHARED_DATA")
    return SHARED_GNSS


def _georinex():
    return pytest.importorskip("georinex")


# ------------------------------------------------------------------------------------------------------------
# helpers to compose RINEX text
# ------------------------------------------------------------------------------------------------------------

def hl(content: str, label: str) -> str:
    return f"{content:<60}{label:<20}"


def f16(v: float | None, lli: int | None = None, ssi: int | None = None) -> str:
    """One observation field: F14.3 value, LLI, SSI (blank where None)."""
    val = " " * 14 if v is None else f"{v:14.3f}"
    return val + (" " if lli is None else str(lli)) + (" " if ssi is None else str(ssi))


def rinex3_header(types: dict[str, list[str]], version: str = "3.04", extra: list[str] | None = None,
                  time_system: str = "GPS", xyz: tuple[float, float, float] = (1000.0, 2000.0, 3000.0)) -> list[str]:
    lines = [hl(f"{version:>9}{'':11}{'OBSERVATION DATA':<20}{'M':<20}", "RINEX VERSION / TYPE"),
             hl("test", "PGM / RUN BY / DATE"),
             hl("MARK", "MARKER NAME"),
             hl(f"{'123':<20}{'RECV TYPE':<20}{'1.0':<20}", "REC # / TYPE / VERS"),
             hl(f"{'9':<20}{'ANT_TYPE        NONE':<20}", "ANT # / TYPE"),
             hl("".join(f"{x:14.4f}" for x in xyz), "APPROX POSITION XYZ"),
             hl(f"{1.234:14.4f}{0.1:14.4f}{-0.2:14.4f}", "ANTENNA: DELTA H/E/N")]
    for sys, codes in types.items():
        for i in range(0, len(codes), 13):
            lead = f"{sys}  {len(codes):3d}" if i == 0 else " " * 6
            lines.append(hl(lead + "".join(f" {c:<3}" for c in codes[i:i + 13]), "SYS / # / OBS TYPES"))
    lines.append(hl(f"{1.0:10.3f}", "INTERVAL"))
    lines.append(hl(f"{2021:6d}{9:6d}{22:6d}{6:6d}{30:6d}{0.0:13.7f}     {time_system}", "TIME OF FIRST OBS"))
    lines += extra or []
    lines.append(hl("", "END OF HEADER"))
    return lines


def epoch3(sec: float, n: int, flag: int = 0, minute: int = 30) -> str:
    return f"> 2021 09 22 06 {minute:02d}{sec:11.7f}  {flag:1d}{n:3d}"


def rinex2_header(types: list[str], sys: str = "M (MIXED)", version: str = "2.11", extra: list[str] | None = None,
                  time_system: str = "GPS") -> list[str]:
    lines = [hl(f"{version:>9}{'':11}{'OBSERVATION DATA':<20}{sys:<20}", "RINEX VERSION / TYPE"),
             hl("test", "PGM / RUN BY / DATE"),
             hl("MARK2", "MARKER NAME"),
             hl(f"{'1':<20}{'RX2':<20}{'2.0':<20}", "REC # / TYPE / VERS"),
             hl(f"{'1':<20}{'ANT2':<20}", "ANT # / TYPE"),
             hl(f"{1.0:14.4f}{2.0:14.4f}{3.0:14.4f}", "APPROX POSITION XYZ"),
             hl(f"{0.5:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"),
             hl(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2")]
    for i in range(0, len(types), 9):
        lead = f"{len(types):6d}" if i == 0 else " " * 6
        lines.append(hl(lead + "".join(f"    {t:<2}" for t in types[i:i + 9]), "# / TYPES OF OBSERV"))
    lines.append(hl(f"{2005:6d}{4:6d}{2:6d}{0:6d}{0:6d}{0.0:13.7f}     {time_system}", "TIME OF FIRST OBS"))
    lines += extra or []
    lines.append(hl("", "END OF HEADER"))
    return lines


def epoch2(sec: float, sats: list[str], flag: int = 0, minute: int = 0) -> list[str]:
    head = f" 05  4  2  0 {minute:2d}{sec:11.7f}  {flag:1d}{len(sats):3d}"
    out = [head + "".join(sats[:12])]
    for i in range(12, len(sats), 12):
        out.append(" " * 32 + "".join(sats[i:i + 12]))
    return out


def record2(fields: list[str]) -> list[str]:
    """A RINEX 2 satellite record: 5 fields per line."""
    return ["".join(fields[i:i + 5]).rstrip() for i in range(0, max(len(fields), 1), 5)]


def write_text(path: Path, lines: list[str]) -> Path:
    path.write_text("\n".join(lines) + "\n", encoding="latin-1")
    return path


def col(raw: RawObservations, sat: str, code: str) -> np.ndarray:
    return raw.values[:, raw.sat_ids.index(sat), raw.obs_codes.index(code)]


def to_gps_s(times: np.ndarray) -> np.ndarray:
    return (times.astype("datetime64[ns]") - GPS_EPOCH).astype(np.int64) / 1e9


# ------------------------------------------------------------------------------------------------------------
# comparison with the peer reader georinex
# ------------------------------------------------------------------------------------------------------------

def assert_matches_georinex(raw: RawObservations, path: Path, rinex2: bool) -> int:
    """Every georinex value (0 read as missing), LLI and SSI equals ours; returns the number of values compared."""
    gr = _georinex()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = gr.load(path, useindicators=True)
    # georinex truncates epoch seconds to the millisecond below (it reads '30.0050000' as 30.004 s)
    assert np.allclose(to_gps_s(ds.time.values), raw.gps_time_s, atol=1.5e-3, rtol=0)
    svs = [str(s) for s in ds.sv.values]
    n = 0
    for var in ds.data_vars:
        if var.endswith(("lli", "ssi")):
            continue
        for i, sv in enumerate(svs):
            code = RINEX2_TO_RINEX3.get(sv[0], {}).get(var) if rinex2 else var
            g = ds[var].values[:, i].astype(float)
            g[g == 0] = np.nan
            if code is None or sv not in raw.sat_ids or code not in raw.obs_codes:
                assert np.isnan(g).all(), (var, sv)
                continue
            k, s = raw.obs_codes.index(code), raw.sat_ids.index(sv)
            ours = raw.values[:, s, k]
            np.testing.assert_array_equal(np.isnan(ours), np.isnan(g), err_msg=f"{sv} {var}")
            ok = ~np.isnan(g)
            np.testing.assert_allclose(ours[ok], g[ok], rtol=0, atol=5e-4, err_msg=f"{sv} {var}")
            for ind, arr in (("lli", raw.lli), ("ssi", raw.ssi)):
                if var + ind in ds:
                    gi = np.nan_to_num(ds[var + ind].values[:, i].astype(float))[ok]
                    np.testing.assert_array_equal(arr[:, s, k][ok], gi, err_msg=f"{sv} {var}{ind}")
            n += int(ok.sum())
    return n


# ------------------------------------------------------------------------------------------------------------
# real files
# ------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("entry", SUMMARY or [None], ids=[e["path"] for e in SUMMARY] or ["no-shared-data"])
def test_real_file_matches_summary(entry, gnss_dir):
    raw = read_rinex_obs(gnss_dir / entry["path"])
    assert raw.n_epochs == entry["epochs"]
    assert raw.values.shape == (raw.n_epochs, len(raw.sat_ids), len(raw.obs_codes))
    assert raw.lli.dtype == np.uint8 and raw.ssi.dtype == np.uint8
    assert np.all(np.diff(raw.gps_time_s) > 0)
    first, last = to_gps_s(np.array([entry["first"], entry["last"]], dtype="datetime64[ns]"))
    assert abs(raw.gps_time_s[0] - first) < 1e-6 and abs(raw.gps_time_s[-1] - last) < 1e-6
    assert raw.gps_time_s[-1] - raw.gps_time_s[0] == pytest.approx(entry["span_s"], abs=1e-6)
    has = ~np.isnan(raw.values).all(axis=2)
    systems = sorted({s[0] for s in raw.sat_ids})
    assert systems == sorted(entry["nsat_per_sys"])
    for sys in systems:
        sel = [i for i, s in enumerate(raw.sat_ids) if s[0] == sys]
        assert len(sel) == entry["nsat_per_sys"][sys]
        assert int(has[:, sel].sum()) == entry["sat_obs_per_sys"][sys]
        # every signal of the summary is there (RINEX 2 types renamed to RINEX 3 codes)
        for sig in entry["signals_present"][sys]:
            name = sig.split(":")[0]
            code = RINEX2_TO_RINEX3[sys][name] if len(name) == 2 else name
            assert code in raw.obs_codes
            assert not np.isnan(raw.values[:, sel, raw.obs_codes.index(code)]).all()
    np.testing.assert_allclose(raw.header.approx_position_ecef_m, entry["xyz"], atol=1e-4)
    assert raw.header.rinex_version == pytest.approx(entry["version"])
    if "interval_hdr" in entry:
        assert raw.header.interval_s == entry["interval_hdr"]
    if entry.get("receiver", " / ").strip(" /"):
        assert raw.header.receiver_type == entry["receiver"].split(" / ")[0].strip()
    assert raw.header.antenna_type == entry.get("antenna", "").strip()


def test_every_shared_observation_file_loads(gnss_dir):
    files = [p for p in sorted(gnss_dir.rglob("*")) if p.is_file()
             and (p.suffix.lower() == ".obs" or (len(p.suffix) == 4 and p.suffix[-1] in "oO"))]
    assert len(files) >= 8
    for p in files:
        raw = read_rinex_obs(p)
        assert raw.n_epochs > 0 and len(raw.sat_ids) > 0
        sys_r = [s for s in raw.sat_ids if s[0] == "R"]
        assert all(s in raw.header.glonass_fcn for s in sys_r)


def test_gsi_rinex210_matches_georinex(gnss_dir):
    path = gnss_dir / "rtklib_gsi_0759_3040_static" / "07590920.05o"
    raw = read_rinex_obs(path)
    assert raw.obs_codes == ["L1C", "C1C", "L2W", "C2W"]
    n = assert_matches_georinex(raw, path, rinex2=True)
    assert n == 3740
    # spot check of the first record: ' 05  4  2  0  0  0.0000000  0  8G 3...' G03 L1 C1 L2 P2, L2 LLI 4 (AS)
    assert col(raw, "G03", "L1C")[0] == 55923622.160
    assert col(raw, "G03", "C1C")[0] == 24767686.375
    assert col(raw, "G03", "L2W")[0] == 43647388.242
    assert raw.lli[0, raw.sat_ids.index("G03"), raw.obs_codes.index("L2W")] == 4


def test_ublox_rover_events(gnss_dir):
    raw = read_rinex_obs(gnss_dir / "ublox_m8p_20181004_walk" / "rover-20181004-1532.obs")
    ev = raw.event_gps_time_s
    assert len(ev) == 318
    assert np.all(np.diff(ev) > 0)
    assert raw.gps_time_s[0] < ev[0] and ev[-1] < raw.gps_time_s[-1]
    assert not np.isin(ev, raw.gps_time_s).any()
    # '> 2018 10 04 15 33 47.1139586  5  0'
    assert ev[0] == pytest.approx(calendar_to_gps_time_s(2018, 10, 4, 15, 33, 47.1139586), abs=1e-6)
    assert set(raw.epoch_flags) == {0}


@pytest.mark.parametrize("name", ["rtklib_gsi_0759_3040_static/07590920.05n",
                                  "cssrlib_2021_265_car_kinematic/SEPT2650.21P", "matrtklib_static_1m/base.nav"])
def test_shared_navigation_files_are_rejected(gnss_dir, name):
    with pytest.raises(InputFileError, match="navigation file, not an observation file") as exc:
        read_rinex_obs(gnss_dir / name)
    assert name.split("/")[1] in str(exc.value)


# ------------------------------------------------------------------------------------------------------------
# fixtures (always available) against georinex
# ------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, n_epochs, systems", [
    ("SEPT265G_head10.21O", 10, "GEJ"),
    ("3034265G_head5.21O", 5, "GEJ"),
    ("matrtklib_base_head4.obs", 4, "GREJC"),
])
def test_rinex3_fixtures_match_georinex(name, n_epochs, systems):
    path = FIXTURES / name
    raw = read_rinex_obs(path)
    assert raw.n_epochs == n_epochs
    assert {s[0] for s in raw.sat_ids} == set(systems)
    assert assert_matches_georinex(raw, path, rinex2=False) > 500


def test_rinex3_fixture_spot_values():
    raw = read_rinex_obs(FIXTURES / "SEPT265G_head10.21O")
    # 'E02  28187222.822 4                        25.625 ...' : C1C with SSI 4, L1C blank, S1C
    assert col(raw, "E02", "C1C")[0] == 28187222.822
    assert raw.ssi[0, raw.sat_ids.index("E02"), raw.obs_codes.index("C1C")] == 4
    assert np.isnan(col(raw, "E02", "L1C")[0])
    assert col(raw, "E02", "S1C")[0] == 25.625
    assert col(raw, "G05", "L1C")[0] == 111634716.537
    hdr = raw.header
    assert (hdr.marker_name, hdr.receiver_type, hdr.antenna_type) == ("SEPT", "SEPT MOSAIC-X5", "JAVRINGANT_DM   JVDM")
    assert hdr.interval_s == 1.0 and hdr.rinex_version == 3.04
    glo = read_rinex_obs(FIXTURES / "matrtklib_base_head4.obs")
    assert glo.header.glonass_fcn == {"R01": 1, "R02": -4, "R03": 5, "R11": 0, "R12": -1, "R13": -2, "R17": 4,
                                      "R18": -3, "R24": 2}
    assert "X1" in glo.obs_codes and "C2I" in glo.obs_codes


def test_rinex2_fixture_matches_georinex():
    path = FIXTURES / "07590920_head20.05o"
    raw = read_rinex_obs(path)
    assert raw.n_epochs == 20
    assert assert_matches_georinex(raw, path, rinex2=True) > 500


# ------------------------------------------------------------------------------------------------------------
# field decoding
# ------------------------------------------------------------------------------------------------------------

def test_field_decoding_is_exact(tmp_path):
    """Random F14.3 values (both signs, all magnitudes) decode bit-identically to Python's float()."""
    rng = np.random.default_rng(7)
    n_sat, n_codes, n_ep = 30, 13, 40
    mags = 10.0 ** rng.integers(-3, 10, size=(n_ep, n_sat, n_codes))
    vals = np.round(rng.uniform(-1, 1, size=mags.shape) * mags, 3)
    vals = np.clip(vals, -999999999.999, 9999999999.999)
    vals[rng.random(vals.shape) < 0.1] = np.nan
    lli = rng.integers(0, 10, vals.shape)
    ssi = rng.integers(0, 10, vals.shape)
    codes = ["C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "D2W", "S2W", "C5Q", "L5Q", "D5Q", "S5Q", "C1W"]
    lines = rinex3_header({"G": codes})
    expected = {}
    for e in range(n_ep):
        lines.append(epoch3(float(e), n_sat))
        for s in range(n_sat):
            fields = []
            for k in range(n_codes):
                v = vals[e, s, k]
                text = f16(None) if np.isnan(v) else f16(v, lli[e, s, k] or None, ssi[e, s, k] or None)
                fields.append(text)
                ref = float(text[:14]) if text[:14].strip() else 0.0
                present = ref != 0.0
                expected[e, s, k] = (ref if present else np.nan, int(lli[e, s, k]) if present else 0,
                                     int(ssi[e, s, k]) if present else 0)
            lines.append(f"G{s + 1:02d}" + "".join(fields))
    raw = read_rinex_obs(write_text(tmp_path / "exact.rnx", lines))
    ref = np.array([expected[e, s, k][0] for e in range(n_ep) for s in range(n_sat) for k in range(n_codes)])
    np.testing.assert_array_equal(raw.values.reshape(-1), ref)
    ref_lli = np.array([expected[e, s, k][1] for e in range(n_ep) for s in range(n_sat) for k in range(n_codes)])
    ref_ssi = np.array([expected[e, s, k][2] for e in range(n_ep) for s in range(n_sat) for k in range(n_codes)])
    np.testing.assert_array_equal(raw.lli.reshape(-1), ref_lli)
    np.testing.assert_array_equal(raw.ssi.reshape(-1), ref_ssi)


def test_fields_outside_f14_3_layout(tmp_path):
    """Other decimals and exponents are still numbers (slow path); 0.000 and blanks are missing."""
    values = ["1.2345678E+07", "12345.12345", "-0.5", "0.000", "1.5D+02", ".250"]
    fields = [f"{x:>14}" + ("1 " if x == ".250" else "  ") for x in values]
    lines = rinex3_header({"G": ["C1C", "L1C", "D1C", "S1C", "C2W", "L2W"]})
    lines += [epoch3(0.0, 1), "G01" + "".join(fields)]
    raw = read_rinex_obs(write_text(tmp_path / "odd.rnx", lines))
    got = raw.values[0, 0]
    np.testing.assert_array_equal(got, [12345678.0, 12345.12345, -0.5, np.nan, 150.0, 0.25])
    assert raw.lli[0, 0, 5] == 1


# ------------------------------------------------------------------------------------------------------------
# RINEX 2 and RINEX 3 features on handcrafted files
# ------------------------------------------------------------------------------------------------------------

def test_rinex2_mixed_features(tmp_path):
    types = ["C1", "L1", "D1", "S1", "P1", "P2", "L2", "D2", "S2", "C5"]     # 10 types: 2 header and 2 data lines
    sats = [f"G{p:2d}" for p in range(1, 10)] + [" 10", "R01", "R02", "E11", "S20", "T01"]   # 15: 2 sat lines
    lines = rinex2_header(types)
    lines += epoch2(0.0, sats)
    for j in range(len(sats)):
        base = 2.0e7 + j
        lines += record2([f16(base + 0.001 * t, ssi=7 if t == 1 else None) for t in range(len(types) - 1)]
                         + [f16(None)])
    lines.append(" 05  4  2  0  0 15.0000000  5  0")                          # event
    lines.append("                            4  2")                          # header records
    lines.append(hl("a comment", "COMMENT"))
    lines.append(hl(f"{1.5:14.4f}{0.0:14.4f}{0.0:14.4f}", "ANTENNA: DELTA H/E/N"))
    lines += epoch2(25.0, ["G01"], flag=6)                                      # cycle slip record: skipped
    lines += record2([f16(1.0)] * len(types))
    lines += epoch2(30.0, ["G01", "R01"], flag=1)
    lines += record2([f16(21.5, lli=1)] + [f16(None)] * (len(types) - 1))
    lines += record2([f16(None)] * 5 + [f16(22.125), f16(33.5)] + [f16(None)] * 3)
    lines.append("                            3  1")
    lines.append(hl("NEWSITE", "MARKER NAME"))
    lines += epoch2(0.0, ["E11"], minute=1)
    lines += record2([f16(None)] * 9 + [f16(123.456)])
    raw = read_rinex_obs(write_text(tmp_path / "mixed.05o", lines))

    assert raw.n_epochs == 3
    np.testing.assert_array_equal(raw.epoch_flags, [0, 1, 0])
    t0 = calendar_to_gps_time_s(2005, 4, 2, 0, 0, 0.0)
    np.testing.assert_allclose(raw.gps_time_s - t0, [0.0, 30.0, 60.0])
    np.testing.assert_allclose(raw.event_gps_time_s - t0, [15.0])
    assert raw.sat_ids == [f"G{p:02d}" for p in range(1, 11)] + ["R01", "R02", "E11", "S20"]  # T01 dropped
    for code in ("C1C", "L1C", "D1C", "S1C", "C1W", "C2W", "L2W", "D2W", "S2W", "C5X",   # GPS
                 "C1P", "C2P", "L2P", "D2P", "S2P",                                        # GLONASS
                 "C1X", "L1X", "D1X", "S1X", "C5X"):                                       # Galileo
        assert code in raw.obs_codes, code
    assert col(raw, "G10", "C1C")[0] == 2.0e7 + 9                # ' 10': blank system is GPS
    assert col(raw, "G03", "L2W")[0] == 2.0e7 + 2 + 0.006
    assert col(raw, "R02", "C2P")[0] == 2.0e7 + 11 + 0.005       # GLONASS P2
    assert col(raw, "E11", "C1X")[0] == 2.0e7 + 12
    assert col(raw, "S20", "L1C")[0] == 2.0e7 + 13 + 0.001
    assert raw.ssi[0, raw.sat_ids.index("G05"), raw.obs_codes.index("L1C")] == 7
    assert col(raw, "G01", "C1C")[1] == 21.5 and raw.lli[1, 0, raw.obs_codes.index("C1C")] == 1
    assert col(raw, "R01", "C2P")[1] == 22.125 and col(raw, "R01", "L2P")[1] == 33.5
    assert np.isnan(col(raw, "G02", "C1C")[1])
    assert col(raw, "E11", "C5X")[2] == 123.456
    assert raw.header.marker_name == "NEWSITE"                   # flag 3 header record applied
    np.testing.assert_allclose(raw.header.antenna_delta_hen_m, [1.5, 0, 0])   # flag 4 header record applied


def test_rinex2_type_change_mid_file(tmp_path):
    lines = rinex2_header(["C1", "L1"], sys="G (GPS)", version="2.10")
    lines += epoch2(0.0, ["G01"]) + record2([f16(1.0), f16(2.0)])
    lines.append("                            4  1")
    lines.append(hl(f"{3:6d}    P2    C1    L2", "# / TYPES OF OBSERV"))
    lines += epoch2(1.0, ["G01"]) + record2([f16(3.0), f16(4.0), f16(5.0)])
    raw = read_rinex_obs(write_text(tmp_path / "change.05o", lines))
    assert raw.obs_codes == ["C1C", "L1C", "C2W", "L2W"]
    np.testing.assert_array_equal(raw.values[:, 0, :], [[1.0, 2.0, np.nan, np.nan], [4.0, np.nan, 3.0, 5.0]])


def test_rinex3_features(tmp_path):
    g_codes = ["C1C", "L1C", "D1C", "S1C", "C1W", "C2W", "L2W", "D2W", "S2W", "C2L", "L2L", "D2L", "S2L", "C5Q",
               "L5Q"]                                                             # 15 codes: continuation line
    extra = [hl("G  100   1 S1C", "SYS / SCALE FACTOR"),
             hl("  2 R05 -4 R12  3", "GLONASS SLOT / FRQ #")]
    lines = rinex3_header({"G": g_codes, "C": ["C1I", "L1I"], "R": ["C1C"]}, version="3.02", extra=extra,
                          time_system="BDT", xyz=(0.0, 0.0, 0.0))
    lines += [epoch3(0.0, 3),
              "G 5" + "".join(f16(1000.0 + k) for k in range(15)),
              "C07" + f16(3.0e7) + f16(1.5e8, lli=1, ssi=6),
              "R05" + f16(2.2e7)]
    lines += [epoch3(0.5, 0, flag=5)]                                             # event, RINEX 3 style
    lines += [epoch3(0.7, 2, flag=4), hl("G    2 L1C C1C", "SYS / # / OBS TYPES"), hl("x", "COMMENT")]
    lines += [epoch3(0.8, 1, flag=6), "G05" + f16(9.0)]                           # cycle slip: skipped
    lines += [epoch3(1.0, 1, flag=1), "G05" + f16(7.0) + f16(8.0)]
    raw = read_rinex_obs(write_text(tmp_path / "f302.rnx", lines))
    assert raw.sat_ids == ["G05", "R05", "C07"]
    assert raw.obs_codes == g_codes + ["C2I", "L2I"]                             # 3.02 BeiDou B1I C1I -> C2I
    np.testing.assert_array_equal(raw.values[0, 0, :15], [1000.0 + k for k in range(15)][:3] + [10.03]
                                  + [1000.0 + k for k in range(4, 15)])          # S1C scaled by 1/100
    assert col(raw, "C07", "L2I")[0] == 1.5e8
    assert raw.lli[0, 2, raw.obs_codes.index("L2I")] == 1 and raw.ssi[0, 2, raw.obs_codes.index("L2I")] == 6
    assert col(raw, "R05", "C1C")[0] == 2.2e7
    np.testing.assert_array_equal(raw.values[1, 0, :2], [8.0, 7.0])             # new layout: L1C C1C
    assert np.isnan(raw.values[1, 0, 2:]).all()
    np.testing.assert_array_equal(raw.epoch_flags, [0, 1])
    t0 = calendar_to_gps_time_s(2021, 9, 22, 6, 30, 0.0) + 14.0                 # BDT -> GPST
    np.testing.assert_allclose(raw.gps_time_s - t0, [0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(raw.event_gps_time_s - t0, [0.5], atol=1e-9)
    hdr = raw.header
    assert hdr.approx_position_ecef_m is None
    assert hdr.glonass_fcn == {"R05": -4, "R12": 3}
    assert (hdr.marker_name, hdr.receiver_type, hdr.antenna_type) == ("MARK", "RECV TYPE", "ANT_TYPE        NONE")
    np.testing.assert_allclose(hdr.antenna_delta_hen_m, [1.234, 0.1, -0.2])
    assert hdr.interval_s == 1.0 and hdr.rinex_version == 3.02


@pytest.mark.parametrize("time_system, offset_s", [("GPS", 0.0), ("GAL", 0.0), ("QZS", 0.0), ("BDT", 14.0),
                                                   ("GLO", 18.0), ("UTC", 18.0)])
def test_time_systems(tmp_path, time_system, offset_s):
    lines = rinex3_header({"G": ["C1C"]}, time_system=time_system)
    lines += [epoch3(0.0, 1), "G01" + f16(2.0e7)]
    raw = read_rinex_obs(write_text(tmp_path / f"{time_system}.rnx", lines))
    assert raw.gps_time_s[0] == pytest.approx(calendar_to_gps_time_s(2021, 9, 22, 6, 30, 0.0) + offset_s, abs=1e-9)


def test_rinex4_is_read(tmp_path):
    lines = rinex3_header({"E": ["C1C", "L1C"]}, version="4.01")
    lines += [epoch3(0.0, 1), "E01" + f16(2.0e7) + f16(1.0e8)]
    raw = read_rinex_obs(write_text(tmp_path / "v4.rnx", lines))
    assert raw.values[0, 0].tolist() == [2.0e7, 1.0e8] and raw.header.rinex_version == 4.01


def test_crlf_line_ends(tmp_path):
    lines = rinex3_header({"G": ["C1C", "L1C"]}) + [epoch3(0.0, 1), "G01" + f16(2.0e7) + f16(1.0e8)]
    path = tmp_path / "crlf.rnx"
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    assert read_rinex_obs(path).values[0, 0].tolist() == [2.0e7, 1.0e8]


# ------------------------------------------------------------------------------------------------------------
# writers: round trips and the peer reader
# ------------------------------------------------------------------------------------------------------------

SIGNALS = {
    "G": ["C1C", "L1C", "D1C", "S1C", "C1W", "C2W", "L2W", "D2W", "S2W", "C2X", "C5X", "L5X"],
    "R": ["C1C", "L1C", "D1C", "S1C", "C1P", "C2P", "L2P", "C2C"],
    "E": ["C1X", "L1X", "D1X", "S1X", "C5X", "L5X", "C7X", "L7X", "C8X", "L8X"],
    "J": ["C1C", "L1C", "C2X", "L2X", "C5X", "L5X"],
    "C": ["C2I", "L2I", "C7I", "L7I", "C6I", "L6I"],
    "S": ["C1C", "L1C", "S1C", "C5X", "L5X"],
}
SATS = {"G": [1, 5, 12, 30], "R": [1, 7, 24], "E": [2, 11, 36], "J": [2], "C": [6, 19, 45], "S": [20, 23]}


def synthetic_raw(n_epochs: int = 30, systems: str = "GREJCS", seed: int = 3) -> RawObservations:
    """Observations of every kind: gaps, LLI/SSI digits, flag-1 epochs and events around and on epochs."""
    rng = np.random.default_rng(seed)
    sats = [f"{s}{p:02d}" for s in systems for p in SATS[s]]
    codes: list[str] = []
    for s in systems:
        codes += [c for c in SIGNALS[s] if c not in codes]
    shape = (n_epochs, len(sats), len(codes))
    values = np.full(shape, np.nan)
    for j, sat in enumerate(sats):
        for c in SIGNALS[sat[0]]:
            k = codes.index(c)
            base = {"C": 2.2e7, "L": 1.1e8, "D": -2500.0, "S": 45.0}[c[0]]
            values[:, j, k] = np.round(base + rng.uniform(1, 1000, n_epochs), 3)
    values[rng.random(shape) < 0.1] = np.nan
    values[n_epochs // 2, 0, :] = np.nan                          # one satellite absent at one epoch
    lli = np.where(rng.random(shape) < 0.2, rng.integers(1, 8, shape), 0).astype(np.uint8)
    ssi = rng.integers(0, 10, shape).astype(np.uint8)
    lli[np.isnan(values)] = 0
    ssi[np.isnan(values)] = 0
    t = calendar_to_gps_time_s(2024, 6, 24, 8, 20, 0.0) + np.arange(n_epochs) * 0.1
    flags = np.zeros(n_epochs, np.uint8)
    flags[n_epochs // 3] = 1
    events = np.array([t[0] - 0.05, t[1], t[2] + 0.0234567, t[-1] + 0.5])
    header = ReceiverHeader(marker_name="UAV1", receiver_type="SIM RX", antenna_type="SIMANT          NONE",
                            approx_position_ecef_m=np.array([-3817680.727, 3562839.5216, 3650159.2407]),
                            antenna_delta_hen_m=np.array([0.1234, 0.0, -0.05]), interval_s=0.1,
                            glonass_fcn={f"R{p:02d}": p % 13 - 7 for p in SATS["R"]} if "R" in systems else {})
    return RawObservations("synthetic", t, sats, codes, values, lli, ssi, header, events, flags)


def assert_same_observations(back: RawObservations, raw: RawObservations, code_map=None) -> None:
    """back holds every value, LLI and SSI of raw (codes renamed by code_map[sys]); other columns are empty."""
    np.testing.assert_allclose(back.gps_time_s, raw.gps_time_s, atol=1e-6, rtol=0)
    np.testing.assert_allclose(back.event_gps_time_s, np.sort(raw.event_gps_time_s), atol=1e-6, rtol=0)
    np.testing.assert_array_equal(back.epoch_flags, raw.epoch_flags)
    assert back.sat_ids == raw.sat_ids
    for s, sat in enumerate(raw.sat_ids):
        seen = set()
        for k, code in enumerate(raw.obs_codes):
            name = code_map[sat[0]].get(code, code) if code_map else code
            if np.isnan(raw.values[:, s, k]).all():
                continue
            kb = back.obs_codes.index(name)
            seen.add(kb)
            np.testing.assert_allclose(back.values[:, s, kb], raw.values[:, s, k], atol=1e-3, rtol=0,
                                       err_msg=f"{sat} {code}")
            np.testing.assert_array_equal(back.lli[:, s, kb], raw.lli[:, s, k], err_msg=f"{sat} {code} LLI")
            np.testing.assert_array_equal(back.ssi[:, s, kb], raw.ssi[:, s, k], err_msg=f"{sat} {code} SSI")
        others = [kb for kb in range(len(back.obs_codes)) if kb not in seen]
        assert np.isnan(back.values[:, s, others]).all()


def assert_same_header(back: ReceiverHeader, ref: ReceiverHeader, glonass: bool = True) -> None:
    assert (back.marker_name, back.receiver_type, back.antenna_type) == \
        (ref.marker_name, ref.receiver_type, ref.antenna_type)
    np.testing.assert_allclose(back.approx_position_ecef_m, ref.approx_position_ecef_m, atol=1e-4)
    np.testing.assert_allclose(back.antenna_delta_hen_m, ref.antenna_delta_hen_m, atol=1e-4)
    assert back.interval_s == ref.interval_s
    if glonass:
        assert back.glonass_fcn == ref.glonass_fcn


def test_rinex3_round_trip(tmp_path):
    raw = synthetic_raw()
    path = tmp_path / "rt.rnx"
    write_rinex3_obs(path, raw, program="georef-test")
    back = read_rinex_obs(path)
    assert back.obs_codes == raw.obs_codes
    np.testing.assert_array_equal(back.values, raw.values)        # values were already F14.3-exact
    np.testing.assert_array_equal(back.lli, raw.lli)
    np.testing.assert_array_equal(back.ssi, raw.ssi)
    assert_same_observations(back, raw)
    assert_same_header(back.header, raw.header)
    assert back.header.rinex_version == 3.04
    text = path.read_text()
    assert "georef-test" in text.splitlines()[1]
    event_lines = [x for x in text.splitlines() if x.startswith(">") and x[31] == "5"]
    assert len(event_lines) == 4 and all(x.endswith("  5  0") for x in event_lines)
    lines = text.splitlines()
    assert lines.index(event_lines[0]) < lines.index(next(x for x in lines if x.startswith("> ") and x[31] == "0"))


def test_rinex3_writer_rounds_to_mm_and_drops_absent_systems(tmp_path):
    raw = synthetic_raw(n_epochs=5, systems="GE")
    raw.values = raw.values + 0.00049                               # rounding to 3 decimals
    path = tmp_path / "mm.rnx"
    write_rinex3_obs(path, raw)
    back = read_rinex_obs(path)
    assert_same_observations(back, raw)
    assert "SYS / # / OBS TYPES" in path.read_text() and "\nR " not in path.read_text()


def test_rinex2_round_trip(tmp_path):
    raw = synthetic_raw(systems="GRES")
    path = tmp_path / "rt.24o"
    write_rinex2_obs(path, raw)
    back = read_rinex_obs(path)
    assert back.header.rinex_version == 2.11
    assert_same_observations(back, raw)
    assert_same_header(back.header, raw.header, glonass=False)      # RINEX 2.11 has no GLONASS slot/FCN record
    assert back.header.glonass_fcn == {}


def test_rinex2_writer_renames_and_drops(tmp_path):
    raw = synthetic_raw(systems="GRJC")
    raw.obs_codes = [{"C2X": "C2L", "C5X": "C5Q"}.get(c, c) for c in raw.obs_codes]   # GPS L2C(L), L5 Q
    path = tmp_path / "drop.24o"
    with pytest.warns(UserWarning, match=r"cannot hold systems \['C', 'J'\]"):
        write_rinex2_obs(path, raw)
    back = read_rinex_obs(path)
    assert {s[0] for s in back.sat_ids} == {"G", "R"}
    keep = [i for i, s in enumerate(raw.sat_ids) if s[0] in "GR"]
    sub = RawObservations(raw.source_path, raw.gps_time_s, [raw.sat_ids[i] for i in keep], raw.obs_codes,
                          raw.values[:, keep], raw.lli[:, keep], raw.ssi[:, keep], raw.header, raw.event_gps_time_s,
                          raw.epoch_flags)
    assert_same_observations(back, sub, code_map={"G": {"C2L": "C2X", "C5Q": "C5X", "L5X": "L5X"}, "R": {}})


@pytest.mark.parametrize("version", [3, 2])
def test_written_files_load_in_georinex(tmp_path, version):
    raw = synthetic_raw(n_epochs=8, systems="GRES" if version == 2 else "GREJCS")
    path = tmp_path / ("w.rnx" if version == 3 else "w.24o")
    (write_rinex3_obs if version == 3 else write_rinex2_obs)(path, raw)
    back = read_rinex_obs(path)
    assert assert_matches_georinex(back, path, rinex2=version == 2) > 200


def test_writer_rejects_bad_input(tmp_path):
    raw = synthetic_raw(n_epochs=3, systems="G")
    raw.values[0, 0, 0] = 2.0e10
    with pytest.raises(ValueError, match="F14.3"):
        write_rinex3_obs(tmp_path / "x.rnx", raw)
    raw = synthetic_raw(n_epochs=3, systems="G")
    raw.lli = raw.lli[:, :1]
    with pytest.raises(ValueError, match="shape"):
        write_rinex2_obs(tmp_path / "x.obs", raw)


# ------------------------------------------------------------------------------------------------------------
# packings: gzip, Unix compress, Hatanaka
# ------------------------------------------------------------------------------------------------------------

def _pack(data: bytes, how: str) -> bytes:
    if how == "gz":
        return gzip.compress(data)
    if how == "Z":
        ncompress = pytest.importorskip("ncompress", reason="no Unix-compress writer (pip install ncompress)")
        return ncompress.compress(data)
    hatanaka = pytest.importorskip("hatanaka")
    return hatanaka.compress(data, compression="none" if how == "crx" else "gz")


@pytest.mark.parametrize("how, suffix3, suffix2", [("gz", ".21O.gz", ".05o.gz"), ("Z", ".21O.Z", ".05o.Z"),
                                                    ("crx", ".crx", ".05d"), ("crx.gz", ".crx.gz", ".05d.gz")])
def test_packed_files_read_like_plain(tmp_path, how, suffix3, suffix2):
    for name, suffix in (("SEPT265G_head10.21O", suffix3), ("07590920_head20.05o", suffix2)):
        plain = read_rinex_obs(FIXTURES / name)
        packed = tmp_path / (name.split(".")[0] + suffix)
        packed.write_bytes(_pack((FIXTURES / name).read_bytes(), how))
        back = read_rinex_obs(packed)
        assert back.sat_ids == plain.sat_ids and back.obs_codes == plain.obs_codes
        np.testing.assert_array_equal(back.gps_time_s, plain.gps_time_s)
        np.testing.assert_array_equal(back.values, plain.values)
        np.testing.assert_array_equal(back.lli, plain.lli)
        np.testing.assert_array_equal(back.ssi, plain.ssi)


# ------------------------------------------------------------------------------------------------------------
# errors: always InputFileError naming the file (and the line where it applies)
# ------------------------------------------------------------------------------------------------------------

def _good_rinex3(n_epochs: int = 3) -> list[str]:
    lines = rinex3_header({"G": ["C1C", "L1C"]})
    for e in range(n_epochs):
        lines += [epoch3(float(e), 2), "G01" + f16(2.0e7 + e) + f16(1.0e8), "G02" + f16(2.1e7) + f16(1.1e8)]
    return lines


def _raises(path: Path, match: str, line: int | None = None) -> InputFileError:
    with pytest.raises(InputFileError, match=match) as exc:
        read_rinex_obs(path)
    assert str(path) in str(exc.value)
    if line is not None:
        assert exc.value.line == line and f"line {line}" in str(exc.value)
    return exc.value


def test_missing_and_empty_files(tmp_path):
    _raises(tmp_path / "nope.obs", "not found")
    (tmp_path / "empty.obs").write_bytes(b"")
    _raises(tmp_path / "empty.obs", "empty")
    (tmp_path / "blank.obs").write_text("\n   \n\n")
    _raises(tmp_path / "blank.obs", "empty")


def test_wrong_file_types(tmp_path):
    nav = tmp_path / "brdc.rnx"
    write_text(nav, [hl(f"{'3.04':>9}{'':11}{'N: GNSS NAV DATA':<20}{'M: MIXED':<20}", "RINEX VERSION / TYPE"),
                     hl("", "END OF HEADER")])
    _raises(nav, "navigation file, not an observation file", 1)
    met = tmp_path / "x.05m"
    write_text(met, [hl(f"{'2.11':>9}{'':11}{'METEOROLOGICAL DATA':<20}", "RINEX VERSION / TYPE")])
    _raises(met, "meteorological file")
    text = tmp_path / "notes.txt"
    text.write_text("hello\nthis is not RINEX\n" * 20)
    _raises(text, "not a RINEX file", 1)
    binary = tmp_path / "log.ubx"
    binary.write_bytes(bytes(range(256)) * 50)
    _raises(binary, "binary")
    rng = np.random.default_rng(0)
    noise = tmp_path / "noise.obs"
    noise.write_bytes(rng.integers(1, 256, 5000, dtype=np.uint8).tobytes())
    _raises(noise, "not a RINEX file")


@pytest.mark.parametrize("version", ["1.00", "3.10", "5.00"])
def test_unsupported_version(tmp_path, version):
    lines = _good_rinex3()
    lines[0] = hl(f"{version:>9}{'':11}{'OBSERVATION DATA':<20}{'M':<20}", "RINEX VERSION / TYPE")
    _raises(write_text(tmp_path / "v.obs", lines), "unsupported RINEX version", 1)


def test_garbage_in_numeric_fields(tmp_path):
    lines = _good_rinex3()
    lines[-4] = "G01" + "  2x000001.000  " + f16(1.0e8)                       # line numbers are 1-based
    _raises(write_text(tmp_path / "g1.obs", lines), "not a number", len(lines) - 3)
    lines = _good_rinex3()
    lines[-1] = "G02" + f16(2.1e7) + "  110000000.000X"
    _raises(write_text(tmp_path / "g2.obs", lines), "LLI/SSI", len(lines))
    lines = _good_rinex3()
    lines[-2] = "G01" + f16(2.1e7)[2:] + f16(1.0e8)                             # column shift
    _raises(write_text(tmp_path / "g3.obs", lines), "observation field", len(lines) - 1)
    lines = _good_rinex3()
    lines[-3] = "> 2021 09 22 06 30 x2.0000000  0  2"
    _raises(write_text(tmp_path / "g4.obs", lines), "malformed epoch time", len(lines) - 2)
    lines = _good_rinex3()
    lines[-3] = "> 2021 13 22 06 30  2.0000000  0  2"
    _raises(write_text(tmp_path / "g4b.obs", lines), "impossible epoch date", len(lines) - 2)
    lines = _good_rinex3()
    lines[-2] = "G0A" + f16(2.1e7) + f16(1.0e8)
    _raises(write_text(tmp_path / "g5.obs", lines), "satellite identifier", len(lines) - 1)
    # RINEX 2: an error on the second line of a satellite record is reported on that line
    types = ["C1", "L1", "D1", "S1", "P1", "P2"]
    lines = rinex2_header(types, sys="G (GPS)") + epoch2(0.0, ["G01", "G02"])
    lines += record2([f16(1.0)] * 6) + record2([f16(1.0)] * 5 + ["  bad         "])
    _raises(write_text(tmp_path / "g6.05o", lines), "not a number", len(lines))


def test_structural_errors(tmp_path):
    lines = _good_rinex3()
    del lines[-4]                                                              # epoch 2 lacks a satellite
    _raises(write_text(tmp_path / "short.obs", lines), "announces more satellites than it has", len(lines) - 2)
    lines = [x for x in _good_rinex3() if "END OF HEADER" not in x]
    _raises(write_text(tmp_path / "noend.obs", lines), "END OF HEADER")
    lines = _good_rinex3()
    idx = next(i for i, x in enumerate(lines) if "SYS / # / OBS TYPES" in x)
    lines[idx] = hl("G    3 C1C L1C", "SYS / # / OBS TYPES")
    _raises(write_text(tmp_path / "count.obs", lines), "announces 3 observation types but lists 2", idx + 1)
    lines = _good_rinex3()
    lines[-1] = "E02" + f16(2.1e7)
    _raises(write_text(tmp_path / "sys.obs", lines), "no 'SYS / # / OBS TYPES'", len(lines))
    lines = _good_rinex3(0)
    _raises(write_text(tmp_path / "header_only.obs", lines), "no \\(complete\\) observation epoch")
    lines = _good_rinex3()
    lines.insert(-3, epoch3(2.5, 0, flag=8))
    _raises(write_text(tmp_path / "flag.obs", lines), "unknown epoch flag", len(lines) - 3)


def _warns_truncated(path: Path, line: int) -> RawObservations:
    with pytest.warns(RinexTruncatedWarning) as rec:
        raw = read_rinex_obs(path)
    msg = str(rec[0].message)
    assert str(path) in msg and f"line {line}" in msg
    return raw


def test_truncated_tail_keeps_complete_epochs(tmp_path):
    lines = _good_rinex3(4)
    raw = _warns_truncated(write_text(tmp_path / "t1.obs", lines[:-1]), len(lines) - 2)   # missing a line
    assert raw.n_epochs == 3
    np.testing.assert_array_equal(col(raw, "G01", "C1C"), [2.0e7, 2.0e7 + 1, 2.0e7 + 2])
    path = tmp_path / "t2.obs"                                                 # cut inside the last value
    path.write_text("\n".join(lines)[:-12])
    assert _warns_truncated(path, len(lines) - 2).n_epochs == 3
    path = tmp_path / "t3.obs"                                                 # cut inside the epoch line
    path.write_text("\n".join(lines[:-3]) + "\n> 2021 09 22 0")
    assert _warns_truncated(path, len(lines) - 2).n_epochs == 3
    path = tmp_path / "t4.obs"                                                 # only an incomplete epoch
    path.write_text("\n".join(lines[:lines.index(epoch3(0.0, 2)) + 2]) + "\n")
    with pytest.warns(RinexTruncatedWarning), pytest.raises(InputFileError, match="no \\(complete\\)"):
        read_rinex_obs(path)
    types = ["C1", "L1", "D1", "S1", "P1", "P2"]                               # RINEX 2, 2 lines per record
    lines = rinex2_header(types, sys="G (GPS)")
    for e in range(3):
        lines += epoch2(float(e), ["G01", "G02"]) + record2([f16(1.0 + e)] * 6) + record2([f16(2.0)] * 6)
    raw = _warns_truncated(write_text(tmp_path / "t5.05o", lines[:-1]), len(lines) - 4)
    assert raw.n_epochs == 2


# ------------------------------------------------------------------------------------------------------------
# speed
# ------------------------------------------------------------------------------------------------------------

def test_parse_speed_well_under_0_2_s_per_mb(tmp_path):
    """A 10 Hz multi-GNSS file of a few MB parses at well under 0.2 s/MB (typically ~0.03 s/MB)."""
    raw = synthetic_raw(n_epochs=3000, seed=11)
    path = tmp_path / "speed.rnx"
    write_rinex3_obs(path, raw)
    mb = path.stat().st_size / 1e6
    assert mb > 3
    best = min(_timed(lambda: read_rinex_obs(path)) for _ in range(3))
    assert best / mb < 0.2, f"{best / mb:.3f} s/MB"


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _read_both_ways(path, monkeypatch):
    """read_rinex_obs with the compiled epoch scan and with the Python scan alone: (result or error text,
    warnings) for each."""
    import georef_core.gnss.rinex_obs as ro

    compiled = ro._scan_rinex2
    out = []
    for scan in (compiled, lambda p, lines, i, state, spans=None: compiled(p, lines, i, state, None)):
        monkeypatch.setattr(ro, "_scan_rinex2", scan)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                got = ro.read_rinex_obs(path)
            except InputFileError as e:
                got = str(e)
        out.append((got, [str(w.message) for w in caught]))
    return out


def test_rinex2_compiled_scan_matches_python_scan_on_damaged_files(tmp_path, monkeypatch):
    """The compiled scan walks regular epochs and leaves every other record to the Python scan, which
    reports the errors: on 150 seeded random damages of a real RINEX 2 file (lines deleted, duplicated or
    cut, characters and epoch flags changed, blank lines, event records and carriage returns inserted) the
    two give the same observations, the same warnings and the same errors."""
    import random

    src = (Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040" / "07590920.05o").read_bytes()
    lines = src.split(b"\n")
    first_data = next(i for i, line in enumerate(lines) if b"END OF HEADER" in line) + 1
    rng = random.Random(20261122)
    outcomes = {"read": 0, "error": 0}
    for trial in range(150):
        damaged = list(lines)
        for _ in range(rng.randint(1, 3)):
            k = rng.randint(first_data, len(damaged) - 1)
            line = damaged[k]
            what = rng.choice(["delete", "char", "cut", "blank", "event", "duplicate", "flag", "cr"])
            if what == "delete":
                del damaged[k]
            elif what == "char" and line:
                c = rng.randrange(len(line))
                damaged[k] = line[:c] + bytes([rng.choice(b" 0123456789.-xG>R")]) + line[c + 1:]
            elif what == "cut":
                damaged = damaged[:k] + [line[:rng.randrange(len(line) + 1)]]
            elif what == "blank":
                damaged.insert(k, b"   ")
            elif what == "event":
                damaged.insert(k, b" 05  4  2  0  0 30.0000000  5  0")
            elif what == "duplicate":
                damaged.insert(k, line)
            elif what == "flag" and len(line) > 28:
                damaged[k] = line[:28] + bytes([rng.choice(b"0123456 x")]) + line[29:]
            elif what == "cr":
                damaged[k] = line + b"\r"
        path = tmp_path / f"damaged{trial}.05o"
        path.write_bytes(b"\n".join(damaged))
        (a, warn_a), (b, warn_b) = _read_both_ways(path, monkeypatch)
        assert warn_a == warn_b, trial
        if isinstance(a, str) or isinstance(b, str):
            assert a == b, trial
            outcomes["error"] += 1
            continue
        outcomes["read"] += 1
        assert a.sat_ids == b.sat_ids and a.obs_codes == b.obs_codes, trial
        np.testing.assert_array_equal(a.gps_time_s, b.gps_time_s)
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.lli, b.lli)
        np.testing.assert_array_equal(a.ssi, b.ssi)
        np.testing.assert_array_equal(a.epoch_flags, b.epoch_flags)
        np.testing.assert_array_equal(a.event_gps_time_s, b.event_gps_time_s)
    assert outcomes["read"] > 25 and outcomes["error"] > 25    # both kinds of outcome were exercised (50, 100)


def test_unix_compress_head_is_unpacked_alone_and_corruption_is_named(tmp_path):
    """A .Z file: recognising it unpacks only its head (a file whose tail is corrupt is still recognised;
    reading it whole names the corruption and the file), and the head is byte-identical to the plain file's."""
    from georef_core.gnss.compressed_files import read_bytes, read_head_bytes
    from georef_core.gnss.input_files import sniff_kind

    plain = (FIXTURES / "SEPT265G_head10.21O").read_bytes() * 8
    packed = _pack(plain, "Z")
    bad = tmp_path / "cut.21O.Z"
    bad.write_bytes(packed[: len(packed) // 2] + b"\xff" * 64)     # garbage from the middle on
    assert read_head_bytes(bad, 4096) == plain[:4096]
    assert sniff_kind(bad) == "rinex-obs"
    with pytest.raises(InputFileError, match=r"Unix-compress \(\.Z\) data is truncated or corrupt") as exc:
        read_bytes(bad)
    assert "cut.21O.Z" in str(exc.value)
    good = tmp_path / "ok.21O.Z"
    good.write_bytes(packed)
    assert read_bytes(good) == plain and read_head_bytes(good, 100) == plain[:100]
