"""RINEX navigation reader: real files (counts, header values, time scales, decoding cross-checked with
georinex and RTKLIB demo5 through pyrtklib5), synthetic variants (RINEX 2 GLONASS, RINEX 3.05,
skipped systems, compression, duplicates) and error reporting."""

from __future__ import annotations

import gzip
import warnings
from pathlib import Path

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.gnss_time import calendar_to_gps_time_s
from georef_core.gnss.navigation import NavigationData
from georef_core.gnss.rinex_nav import read_rinex_nav

from .rtklib_cases import shared_gnss_dir

UNIX_MINUS_GPS_S = 315964800


DATA = shared_gnss_dir()
needs_data = pytest.mark.skipif(DATA is None, reason="shared GNSS data (/work/shared) not available")

EXPECTED_COUNTS = {
    "cssrlib_2021_265_car_kinematic/SEPT2650.21P": {"E": 253, "G": 49, "J": 19},
    "matrtklib_static_1m/base.nav": {"C": 32, "E": 67, "G": 13, "J": 3, "R": 19},
    "rtklib_gsi_0759_3040_static/07590920.05n": {"G": 162},
    "rtklib_gsi_0759_3040_static/30400920.05n": {"G": 164},
    "ublox_m8p_20181004_walk/base-20181004-1452.nav": {"G": 15, "J": 2, "R": 31},
    "ublox_m8p_20181004_walk/rover-20181004-1532.nav": {"G": 12, "R": 10},
}
# plausible sqrt(a) ranges (sqrt(m)) per system (E14/E18 are in eccentric orbits, e ~ 0.16)
SQRT_A_RANGE = {"G": (5100, 5200), "E": (5250, 5500), "J": (6400, 6600), "C": (5200, 6600)}


def _all_nav_files() -> list[Path]:
    """Every file in the data tree whose first line declares RINEX navigation data."""
    if DATA is None:
        return []
    out = []
    for p in sorted(DATA.rglob("*")):
        if not p.is_file() or p.stat().st_size == 0:
            continue
        with open(p, "rb") as fh:
            head = fh.readline(200).decode("latin-1")
        if "RINEX VERSION / TYPE" in head and head[20:21] in "NGH" and "OBS" not in head:
            out.append(p)
    return out


def _counts(nav: NavigationData) -> dict[str, int]:
    out: dict[str, int] = {}
    for recs in list(nav.kepler.values()) + list(nav.glonass.values()):
        for r in recs:
            out[r.sat_id[0]] = out.get(r.sat_id[0], 0) + 1
    return out


def _text(rel: str) -> str:
    assert DATA is not None
    return (DATA / rel).read_text(encoding="latin-1")


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="latin-1")
    return p


# --------------------------------------------------------------------------------------------------
# real files


@needs_data
def test_every_nav_file_in_data_tree_is_found_and_expected():
    found = {str(p.relative_to(DATA)) for p in _all_nav_files()}
    assert set(EXPECTED_COUNTS) <= found


@needs_data
@pytest.mark.parametrize("path", _all_nav_files(), ids=lambda p: p.name)
def test_parse_every_nav_file(path: Path):
    nav = read_rinex_nav(path)
    assert nav.n_records > 0
    assert nav.source_paths == [str(path)]
    for sat, recs in nav.kepler.items():
        assert sat[0] in "GEJC" and len(sat) == 3 and sat[1:].isdigit()
        toes = [r.toe_gps_s for r in recs]
        assert toes == sorted(toes)
        lo, hi = SQRT_A_RANGE[sat[0]]
        for r in recs:
            assert r.sat_id == sat
            assert lo < r.sqrt_a < hi
            assert 0.0 <= r.e < 0.2
            assert abs(r.toe_gps_s - r.toc_gps_s) <= 4 * 3600
            assert r.toe_gps_s % 1.0 == 0.0
            # (test satellites C56/C58 in base.nav carry a toe two days after their transmission)
            assert np.isnan(r.transmit_gps_s) or abs(r.transmit_gps_s - r.toe_gps_s) < 302400.0
    for sat, recs in nav.glonass.items():
        toes = [r.toe_gps_s for r in recs]
        assert toes == sorted(toes)
        for r in recs:
            assert 25.3e6 < np.linalg.norm(r.position_ecef_m) < 25.7e6
            assert 2.0e3 < np.linalg.norm(r.velocity_ecef_m_s) < 4.5e3   # ECEF (rotating) velocity
            assert -7 <= r.fcn <= 6
            assert abs(r.frame_time_gps_s - r.toe_gps_s) < 2 * 3600
            assert abs(r.tau_n_s) < 1e-2
    # no exact duplicates left
    for recs in nav.kepler.values():
        keys = [tuple(v for k, v in r.__dict__.items() if k != "transmit_gps_s") for r in recs]
        assert len(keys) == len(set(keys))


@needs_data
@pytest.mark.parametrize("rel", sorted(EXPECTED_COUNTS))
def test_record_counts_per_system(rel: str):
    assert _counts(read_rinex_nav(DATA / rel)) == EXPECTED_COUNTS[rel]


@pytest.fixture(scope="module")
def georinex_counts() -> dict[str, dict[str, int]]:
    gr = pytest.importorskip("georinex")
    out: dict[str, dict[str, int]] = {}
    for rel in EXPECTED_COUNTS:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ds = gr.load(DATA / rel)
        except Exception:  # georinex cannot read every variant; the comparison is then skipped
            continue
        bias = ds["SVclockBias"].values
        counts: dict[str, int] = {}
        for j, sv in enumerate(ds.sv.values):
            n = int(np.isfinite(bias[:, j]).sum())
            if n:
                counts[str(sv)[0]] = counts.get(str(sv)[0], 0) + n
        out[rel] = counts
    return out


@needs_data
@pytest.mark.parametrize("rel", sorted(EXPECTED_COUNTS))
def test_counts_match_georinex(rel: str, georinex_counts):
    if rel not in georinex_counts:
        pytest.skip("georinex cannot read this file")
    assert _counts(read_rinex_nav(DATA / rel)) == georinex_counts[rel]


@needs_data
def test_header_values():
    nav = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    np.testing.assert_array_equal(nav.iono_gps_alpha, [1.8626e-08, 2.2352e-08, -1.1921e-07, -5.9605e-08])
    np.testing.assert_array_equal(nav.iono_gps_beta, [1.2902e05, 1.6384e05, -1.9661e05, -2.6214e05])
    np.testing.assert_array_equal(nav.iono_gal, [1.6175e02, 6.6016e-01, 1.9379e-02])
    assert nav.iono_bds_alpha is None and nav.leap_seconds == 18

    nav2 = read_rinex_nav(DATA / "rtklib_gsi_0759_3040_static/07590920.05n")
    np.testing.assert_array_equal(nav2.iono_gps_alpha, [1.1180e-08, 1.4900e-08, -5.9600e-08, -5.9600e-08])
    np.testing.assert_array_equal(nav2.iono_gps_beta, [8.8060e04, 1.6380e04, -1.9660e05, -1.3110e05])
    assert nav2.leap_seconds == 13 and nav2.iono_gal is None

    nav3 = read_rinex_nav(DATA / "ublox_m8p_20181004_walk/base-20181004-1452.nav")   # '.1024D-07' style
    np.testing.assert_array_equal(nav3.iono_gps_alpha, [0.1024e-07, 0.7451e-08, -0.5960e-07, -0.5960e-07])
    assert nav3.leap_seconds is None


@needs_data
def test_rinex3_beidou_iono_and_bds_leap_seconds(tmp_path):
    lines = _text("matrtklib_static_1m/base.nav").splitlines()
    k = next(i for i, s in enumerate(lines) if "LEAP SECONDS" in s)
    lines[k] = "     4     4  2185     7BDS".ljust(60) + "LEAP SECONDS"
    lines[k:k] = ["BDSA   1.1176E-08  2.9802E-08 -4.1723E-07  6.5565E-07       IONOSPHERIC CORR",
                  "BDSB   1.4131E+05 -5.2429E+05  1.6515E+06 -4.5875E+05       IONOSPHERIC CORR",
                  "QZSA   7.4506D-09 -2.2352D-08 -5.3644D-07 -6.5565D-07 T 01  IONOSPHERIC CORR"]
    nav = read_rinex_nav(_write(tmp_path, "bds.nav", "\n".join(lines) + "\n"))
    np.testing.assert_array_equal(nav.iono_bds_alpha, [1.1176e-08, 2.9802e-08, -4.1723e-07, 6.5565e-07])
    np.testing.assert_array_equal(nav.iono_bds_beta, [1.4131e05, -5.2429e05, 1.6515e06, -4.5875e05])
    assert nav.leap_seconds == 18      # BDT-UTC 4 s + 14 s
    ref = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    assert nav.glonass["R01"][0].toe_gps_s == ref.glonass["R01"][0].toe_gps_s


@needs_data
def test_time_scales():
    nav = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    g05 = nav.kepler["G05"][0]
    assert g05.toe_gps_s == 2320 * 604800 + 122400.0 == calendar_to_gps_time_s(2024, 6, 24, 10, 0, 0)
    assert g05.toc_gps_s == g05.toe_gps_s and g05.week == 2320 and g05.iode == 72 and g05.iodc == 72
    assert g05.transmit_gps_s == 2320 * 604800 + 115218.0
    assert g05.tgd_s == (-1.071020960808e-08, 0.0) and g05.fit_interval_h == 4.0
    e04 = [r for r in nav.kepler["E04"] if r.data_source == 517][0]
    assert e04.toe_gps_s == 2320 * 604800 + 115200.0 and e04.tgd_s == (-1.629814505577e-09, -2.328306436539e-09)
    assert e04.accuracy_m == 3.12
    # BeiDou: BDT epoch and BDT week/sow -> GPST (+14 s); BDS week 0 = GPS week 1356
    c01 = nav.kepler["C01"][0]
    assert c01.toc_gps_s == calendar_to_gps_time_s(2024, 6, 24, 8, 0, 14)
    assert c01.toe_gps_s == (964 + 1356) * 604800 + 115200.0 + 14.0
    assert c01.week == 964 and c01.toe_sow_s == 115200.0 and c01.tgd_s == (-4.9e-09, -1.0e-08)
    assert c01.iodc == 0 and c01.iode == 1
    # GLONASS: UTC epoch + leap seconds (header: 18); frame time = 115200 s of the UTC week
    r01 = nav.glonass["R01"][0]
    assert r01.toe_gps_s == calendar_to_gps_time_s(2024, 6, 24, 8, 15, 18)
    assert r01.frame_time_gps_s == calendar_to_gps_time_s(2024, 6, 24, 8, 0, 18)
    assert r01.tau_n_s == -8.934084326029e-05 and r01.gamma_n == 9.094947017729e-13 and r01.fcn == 1
    np.testing.assert_array_equal(r01.position_ecef_m, [-13736887.69531, -3309238.28125, 21242412.59766])
    # no LEAP SECONDS header line: table value (18 s in 2018)
    nav_u = read_rinex_nav(DATA / "ublox_m8p_20181004_walk/base-20181004-1452.nav")
    r23 = nav_u.glonass["R23"][0]
    assert r23.toe_gps_s == calendar_to_gps_time_s(2018, 10, 4, 14, 45, 18)
    assert r23.frame_time_gps_s == calendar_to_gps_time_s(2018, 10, 4, 14, 52, 48)   # 399150 % 86400 = 53550
    # RINEX 2, two-digit year, 'D' exponents
    nav2 = read_rinex_nav(DATA / "rtklib_gsi_0759_3040_static/07590920.05n")
    g01 = nav2.kepler["G01"][0]
    assert g01.toc_gps_s == calendar_to_gps_time_s(2005, 4, 2, 2, 0, 0) == 1316 * 604800 + 525600.0
    assert g01.af0_s == 3.966595977540e-04 and g01.transmit_gps_s == 1316 * 604800 + 519576.0


@needs_data
def test_galileo_inav_and_fnav_records_are_kept():
    nav = read_rinex_nav(DATA / "cssrlib_2021_265_car_kinematic/SEPT2650.21P")
    sources = {r.data_source for recs in nav.kepler.values() for r in recs if r.sat_id[0] == "E"}
    assert sources == {258, 517}


@needs_data
def test_decoding_matches_rtklib():
    p = pytest.importorskip("pyrtklib5")
    sysmap = {"G": (p.SYS_GPS, 0), "E": (p.SYS_GAL, 0), "J": (p.SYS_QZS, 192), "C": (p.SYS_CMP, 0), "R": (p.SYS_GLO, 0)}
    for rel in EXPECTED_COUNTS:
        nav = read_rinex_nav(DATA / rel)
        rn = p.nav_t()
        assert p.readrnx(str(DATA / rel), 1, "", p.obs_t(), rn, p.sta_t()) == 1
        reph: dict = {}
        for i in range(rn.n):
            e = rn.eph[i]
            reph.setdefault((e.sat, e.toe.time - UNIX_MINUS_GPS_S + e.toe.sec, e.f0), []).append(e)
        rgeph = {(rn.geph[i].sat, rn.geph[i].toe.time - UNIX_MINUS_GPS_S): rn.geph[i] for i in range(rn.ng)}

        def same(e, r) -> bool:
            ok = ((e.toc.time - UNIX_MINUS_GPS_S + e.toc.sec) == r.toc_gps_s and e.toes == r.toe_sow_s
                  and e.week == r.week and e.iode == r.iode and e.svh == r.health and e.A == r.sqrt_a ** 2
                  and e.e == r.e and e.M0 == r.m0_rad and e.OMGd == r.omega_dot_rad_s and e.cis == r.cis_rad
                  and e.tgd[0] == r.tgd_s[0] and e.tgd[1] == r.tgd_s[1])
            if not np.isnan(r.transmit_gps_s):
                ok = ok and e.ttr.time - UNIX_MINUS_GPS_S + e.ttr.sec == r.transmit_gps_s
            if r.sat_id[0] == "E":
                ok = ok and e.code == r.data_source
            if r.sat_id[0] == "C":
                ok = ok and e.iodc == r.iodc
            return ok

        n_checked = 0
        for sat, recs in nav.kepler.items():
            s, off = sysmap[sat[0]]
            sn = p.satno(s, int(sat[1:]) + off)
            if sn == 0:   # this pyrtklib5 build stops at C46
                continue
            for r in recs:
                # (base.nav repeats some Galileo records with only the BGDs changed: any may match)
                assert any(same(e, r) for e in reph[(sn, r.toe_gps_s, r.af0_s)]), r
                n_checked += 1
        for sat, recs in nav.glonass.items():
            sn = p.satno(p.SYS_GLO, int(sat[1:]))
            for r in recs:
                g = rgeph[(sn, r.toe_gps_s)]
                assert g.tof.time - UNIX_MINUS_GPS_S == r.frame_time_gps_s
                assert g.taun == r.tau_n_s and g.gamn == r.gamma_n and g.frq == r.fcn and g.svh == r.health
                assert [g.pos[k] for k in range(3)] == list(r.position_ecef_m)
                assert [g.acc[k] for k in range(3)] == list(r.acceleration_ecef_m_s2)
                n_checked += 1
        assert n_checked > 0


# --------------------------------------------------------------------------------------------------
# synthetic variants built from the real files


def _v3_records(text: str, letter: str, nlines: int) -> list[list[str]]:
    lines = text.splitlines()
    body = lines[next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1:]
    return [body[i:i + nlines] for i, s in enumerate(body) if s.startswith(letter)]


def _rinex2_glonass(text_v3: str) -> str:
    head = [
        "     2.11           G: GLONASS NAV DATA".ljust(60) + "RINEX VERSION / TYPE",
        "synthetic from base.nav".ljust(60) + "PGM / RUN BY / DATE",
        "".ljust(60) + "END OF HEADER",
    ]
    out = list(head)
    for rec in _v3_records(text_v3, "R", 4):
        first = rec[0]
        prn = int(first[1:3])
        y, mo, d, h, mi, s = first[4:23].split()
        frame = float(first[61:80].replace("D", "E")) % 86400.0
        out.append(f"{prn:2d} {int(y) % 100:02d} {int(mo):2d} {int(d):2d} {int(h):2d} {int(mi):2d}{float(s):5.1f}"
                   + first[23:61] + f"{frame:19.12E}".replace("E", "D"))
        out.extend("   " + line[4:] for line in rec[1:])
    return "\n".join(out) + "\n"


@needs_data
def test_rinex2_glonass_file(tmp_path):
    text = _text("matrtklib_static_1m/base.nav")
    p2 = _write(tmp_path, "base0760.24g", _rinex2_glonass(text))
    nav2 = read_rinex_nav(p2)
    nav3 = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    assert nav2.kepler == {}
    assert sorted(nav2.glonass) == sorted(nav3.glonass)
    for sat, recs in nav3.glonass.items():
        for a, b in zip(nav2.glonass[sat], recs, strict=True):
            assert a.toe_gps_s == b.toe_gps_s and a.frame_time_gps_s == b.frame_time_gps_s   # leap from table
            np.testing.assert_array_equal(a.position_ecef_m, b.position_ecef_m)
            np.testing.assert_array_equal(a.velocity_ecef_m_s, b.velocity_ecef_m_s)
            assert (a.tau_n_s, a.gamma_n, a.fcn, a.health, a.age_days) == (b.tau_n_s, b.gamma_n, b.fcn, b.health, b.age_days)
    pyrtklib5 = pytest.importorskip("pyrtklib5")
    rn = pyrtklib5.nav_t()
    assert pyrtklib5.readrnx(str(p2), 1, "", pyrtklib5.obs_t(), rn, pyrtklib5.sta_t()) == 1
    assert rn.ng == nav2.n_records
    assert sorted(rn.geph[i].toe.time - UNIX_MINUS_GPS_S for i in range(rn.ng)) == \
        sorted(r.toe_gps_s for recs in nav2.glonass.values() for r in recs)


@needs_data
def test_rinex305_glonass_five_line_records(tmp_path):
    lines = _text("matrtklib_static_1m/base.nav").splitlines()
    lines[0] = "     3.05" + lines[0][9:]
    out = []
    i = 0
    while i < len(lines):
        out.append(lines[i])
        if lines[i].startswith("R"):
            out.extend(lines[i + 1:i + 4])
            out.append("     1.790000000000E+02-2.793967723846E-09 2.000000000000E+00 0.000000000000E+00")
            i += 4
        else:
            i += 1
    nav = read_rinex_nav(_write(tmp_path, "v305.rnx", "\n".join(out) + "\n"))
    ref = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    assert _counts(nav) == _counts(ref)
    assert [r.toe_gps_s for r in nav.glonass["R01"]] == [r.toe_gps_s for r in ref.glonass["R01"]]
    assert nav.kepler["G05"][0] == ref.kepler["G05"][0]


@needs_data
def test_unknown_and_unused_systems_are_skipped(tmp_path):
    text = _text("matrtklib_static_1m/base.nav")
    g_record = _v3_records(text, "G05", 8)[0]
    extra = [
        "S23 2024 06 24 08 00 32 0.000000000000E+00 0.000000000000E+00 1.152320000000E+05",
        "     4.066404800000E+04 0.000000000000E+00 0.000000000000E+00 6.300000000000E+01",
        "     0.000000000000E+00 0.000000000000E+00 0.000000000000E+00 3.276700000000E+04",
        "     0.000000000000E+00 0.000000000000E+00 0.000000000000E+00 2.220000000000E+02",
    ] + ["I05" + g_record[0][3:]] + g_record[1:] + ["X01" + g_record[0][3:]] + g_record[1:3]
    lines = text.splitlines()
    k = next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1
    nav = read_rinex_nav(_write(tmp_path, "extra.nav", "\n".join(lines[:k] + extra + lines[k:]) + "\n"))
    assert _counts(nav) == EXPECTED_COUNTS["matrtklib_static_1m/base.nav"]


@needs_data
def test_gzip_and_duplicates_and_merge(tmp_path):
    src = DATA / "rtklib_gsi_0759_3040_static/07590920.05n"
    gz = tmp_path / "07590920.05n.gz"
    gz.write_bytes(gzip.compress(src.read_bytes()))
    plain = read_rinex_nav(src)
    assert _counts(read_rinex_nav(gz)) == _counts(plain)
    # the same file twice, and a record repeated inside one file: no new records
    assert _counts(read_rinex_nav([src, gz])) == _counts(plain)
    lines = src.read_text(encoding="latin-1").splitlines()
    k = next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1
    repeated = lines[k:k + 8]
    repeated[7] = "    5.195000000000D+05"   # other transmission time, same content
    nav_dup = read_rinex_nav(_write(tmp_path, "dup.05n", "\n".join(lines + lines[k:k + 8] + repeated) + "\n"))
    assert _counts(nav_dup) == _counts(plain)
    # two stations' files: union
    other = DATA / "rtklib_gsi_0759_3040_static/30400920.05n"
    merged = read_rinex_nav([src, other])
    one, two = read_rinex_nav(other), plain
    keys = lambda n: {(s, r.toe_gps_s, r.iode) for s, recs in n.kepler.items() for r in recs}  # noqa: E731
    assert keys(merged) == keys(one) | keys(two)
    assert merged.source_paths == [str(src), str(other)]
    assert merged.leap_seconds == 13


@needs_data
def test_columns_not_respected_fall_back_to_free_format(tmp_path):
    text = _text("matrtklib_static_1m/base.nav")
    lines = text.splitlines()
    i = next(i for i, s in enumerate(lines) if s.startswith("G05"))
    # second line of G05: values shifted by one column, single spaces
    vals = lines[i + 1][4:].replace("E", "e")
    nums = [vals[k:k + 19].strip() for k in range(0, 76, 19)]
    lines[i + 1] = "   " + " ".join(nums)
    nav = read_rinex_nav(_write(tmp_path, "shifted.nav", "\n".join(lines) + "\n"))
    ref = read_rinex_nav(DATA / "matrtklib_static_1m/base.nav")
    assert nav.kepler["G05"][0] == ref.kepler["G05"][0]


# --------------------------------------------------------------------------------------------------
# errors


def _expect_error(path: Path, fragment: str, line: int | None = None) -> InputFileError:
    with pytest.raises(InputFileError) as info:
        read_rinex_nav(path)
    err = info.value
    assert err.path == str(path)
    assert fragment in err.problem, err.problem
    if line is not None:
        assert err.line == line, str(err)
    return err


@needs_data
def test_observation_file_is_rejected():
    _expect_error(DATA / "rtklib_gsi_0759_3040_static/07590920.05o", "observation file", line=1)


def test_not_a_rinex_file(tmp_path):
    _expect_error(_write(tmp_path, "notes.nav", "hello\nworld\n"), "not a RINEX file", line=1)
    _expect_error(_write(tmp_path, "empty.nav", ""), "empty file")
    _expect_error(tmp_path / "missing.nav", "not found")
    _expect_error(_write(tmp_path, "clk.clk", "     3.00           C                                       RINEX VERSION / TYPE\n"),
                  "clock file")
    _expect_error(_write(tmp_path, "v4.rnx", "     4.00           N: GNSS NAV DATA    M: MIXED            RINEX VERSION / TYPE\n"),
                  "not supported")


@needs_data
def test_header_and_record_errors(tmp_path):
    text = _text("matrtklib_static_1m/base.nav")
    lines = text.splitlines()
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s)
    # no END OF HEADER
    _expect_error(_write(tmp_path, "nohead.nav", "\n".join(lines[:end]) + "\n"), "END OF HEADER")
    # file cut in the middle of the last record
    cut = _write(tmp_path, "cut.nav", "\n".join(lines[:-3]) + "\n")
    last_start = max(i for i, s in enumerate(lines) if s[:1].strip())
    _expect_error(cut, "truncated", line=last_start + 1)
    # a record missing one line in the middle of the file (G06: 7 lines)
    g06 = next(i for i, s in enumerate(lines) if s.startswith("G06"))
    missing = lines[:g06 + 3] + lines[g06 + 4:]
    _expect_error(_write(tmp_path, "hole.nav", "\n".join(missing) + "\n"), "truncated", line=g06 + 1)
    # garbage number
    bad = list(lines)
    bad[g06 + 2] = bad[g06 + 2][:23] + "  1.23X56789012E-05" + bad[g06 + 2][42:]
    _expect_error(_write(tmp_path, "garbage.nav", "\n".join(bad) + "\n"), "unreadable number", line=g06 + 3)
    bad = list(lines)
    bad[g06 + 2] = bad[g06 + 2][:23] + "  1.2.3456789012345" + bad[g06 + 2][42:]
    _expect_error(_write(tmp_path, "garbage2.nav", "\n".join(bad) + "\n"), "unreadable number", line=g06 + 3)
    # invalid epoch
    bad = list(lines)
    bad[g06] = "G06 2024 02 30 08 00 00" + bad[g06][23:]
    _expect_error(_write(tmp_path, "epoch.nav", "\n".join(bad) + "\n"), "invalid epoch", line=g06 + 1)
    # continuation line with no record line before it
    orphan = lines[:end + 1] + lines[end + 2:]
    _expect_error(_write(tmp_path, "orphan.nav", "\n".join(orphan) + "\n"), "continuation line", line=end + 2)
    # a list with one bad file names that file
    good = DATA / "matrtklib_static_1m/base.nav"
    with pytest.raises(InputFileError) as info:
        read_rinex_nav([good, tmp_path / "garbage.nav"])
    assert info.value.path == str(tmp_path / "garbage.nav")


def test_compiled_field_reader_is_bit_identical_to_float():
    """rinex_nav_kernels: every well-formed field equals Python's float() (hence strtod, RTKLIB) bit for bit,
    whether read by the compiled fast path or left to float(); a malformed field hands the record back."""
    from georef_core.gnss.rinex_nav_kernels import fill_hard_fields, record_fields

    rng = np.random.default_rng(7)
    mant = rng.uniform(-9.999, 9.999, 400)
    expo = rng.integers(-30, 12, 400)
    def fortran(v: float) -> str:             # 0.123456789012D-03: mantissa in [0.1, 1)
        e = int(np.floor(np.log10(abs(v)))) + 1
        return f"{v / 10.0**e:.12f}D{e:+03d}"

    styles = [lambda v: f"{v:19.12E}".replace("E", "D"),                          # 1.234567890123D-04
              lambda v: fortran(v).replace("0.", ".").replace("D", "d"),          # -.123456789012d-03
              fortran,                                                            # -0.123456789012D-03
              lambda v: f"{abs(v) * 1e15:016.0f}"[:16] + "D-9",                   # 16 digits, no point
              lambda v: ""]                                                       # blank
    texts = [styles[k % 5](mant[k] * 10.0 ** expo[k]).rjust(19) for k in range(400)]
    assert all(len(t) == 19 for t in texts)
    # records of 8 lines: 3 fields on the first line (after a 22-column epoch), 4 on the next seven
    lines, per_rec = [], 31
    n_rec = len(texts) // per_rec
    for r in range(n_rec):
        f = texts[r * per_rec:(r + 1) * per_rec]
        lines.append(" 1 05  4  2  2  0  0.0" + "".join(f[:3]))
        for m in range(7):
            lines.append("   " + "".join(f[3 + 4 * m:7 + 4 * m]))
    lines.append(" 2 05  4  2  2  0  0.0 1.0D+00 1.2D-0X" + " " * 10)   # malformed exponent
    lines += ["   " + " 0.0D+00" * 4] * 7
    lens = np.array([len(s) for s in lines], dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(lens[:-1] + 1))).astype(np.int64)
    buf = np.frombuffer("\n".join(lines).encode(), dtype=np.uint8)
    rec_line = np.arange(n_rec + 1, dtype=np.int64) * 8
    values, ok, hard = record_fields(buf, starts, lens, rec_line, np.full(n_rec + 1, 8, np.int64), 22, 3, 31)
    fill_hard_fields(values, buf, hard)
    assert ok[:n_rec].all() and not ok[n_rec]
    assert 0 < len(hard) < n_rec * per_rec          # both paths were taken
    expected = np.array([float(t.replace("D", "E").replace("d", "e")) if t.strip() else 0.0
                         for t in texts[:n_rec * per_rec]]).reshape(n_rec, per_rec)
    assert np.array_equal(values[:n_rec], expected)  # bit-identical, signs of zeros aside


# --------------------------------------------------------------------------------------------------
# time window


@needs_data
@pytest.mark.parametrize("rel", sorted(EXPECTED_COUNTS))
def test_record_epochs_read_in_bulk_match_the_line_parser(rel: str):
    """The window's epochs come from the fixed columns of the byte buffer, all records at once: equal to
    the line parser's epoch (whole seconds) for every record of every real file, RINEX 2 and 3."""
    from georef_core.gnss.rinex_nav import (_epoch_seconds, _line_buffer, _parse_epoch, _parse_header,
                                            _record_epochs_s, _record_spans)

    path = DATA / rel
    lines = _text(rel).splitlines()
    header = _parse_header(lines, path)
    v3 = header.version >= 3.0
    buf, starts, lens = _line_buffer(lines)
    rec_line = np.array([sp[1] for sp in _record_spans(lines, header, path, buf, starts, lens)])
    epoch_s, readable = _record_epochs_s(buf, starts, lens, rec_line, v3)
    assert readable.all()
    expect = [np.floor(_epoch_seconds(_parse_epoch(lines[i][4:23] if v3 else lines[i][3:22], v3, path, i + 1)))
              for i in rec_line]
    np.testing.assert_array_equal(epoch_s, expect)


@needs_data
def test_time_window_reads_only_the_records_near_the_observations():
    """A daily GPS file read for one hour of observations keeps the records within 3 h of it (2 h of
    ephemeris validity + 1 h), the same ephemerides as a full read, and reports how many it skipped and
    the span of all of them."""
    rel = "rtklib_gsi_0759_3040_static/07590920.05n"
    full = read_rinex_nav(DATA / rel)
    t0 = calendar_to_gps_time_s(2005, 4, 2, 12, 0, 0.0)
    window = read_rinex_nav(DATA / rel, (t0, t0 + 3600.0))
    margin = 3 * 3600.0 + 1.0
    n_full, n_window = full.n_records, window.n_records
    assert 0 < n_window < 0.6 * n_full and window.records_outside_window == n_full - n_window
    for sat, recs in full.kepler.items():
        near = [r for r in recs if t0 - margin <= r.toc_gps_s <= t0 + 3600.0 + margin]
        assert [(r.toe_gps_s, r.iode, r.sqrt_a) for r in window.kepler.get(sat, [])] == \
            [(r.toe_gps_s, r.iode, r.sqrt_a) for r in near]
    lo, hi = window.record_span_gps_s
    assert lo <= min(r.toc_gps_s for recs in full.kepler.values() for r in recs) + 1.0
    assert hi >= max(r.toc_gps_s for recs in full.kepler.values() for r in recs) - 1.0


def test_unreadable_epoch_is_still_reported_with_a_window(tmp_path):
    """A record whose epoch the bulk reader cannot read is kept, so the line parser reports it."""
    text = (Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040" / "07590920.05n").read_text()
    lines = text.splitlines()
    body = next(i for i, line in enumerate(lines) if "END OF HEADER" in line) + 1
    lines[body] = lines[body][:6] + "xx" + lines[body][8:]
    bad = _write(tmp_path, "bad.05n", "\n".join(lines) + "\n")
    t0 = calendar_to_gps_time_s(2005, 4, 2, 12, 0, 0.0)
    with pytest.raises(InputFileError, match="epoch") as err:
        read_rinex_nav(bad, (t0, t0 + 3600.0))
    assert err.value.line == body + 1
