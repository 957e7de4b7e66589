"""RTCM 3 decoding (georef_core.gnss.rtcm3, rtcm3_nav): the real Phantom 4 RTK raw log decoded by
RTKLIB demo5 (pyrtklib5's input_rtcm3, byte by byte) gives the same observations, and its ephemerides
the same satellite positions; framing survives foreign bytes, corrupt and truncated frames."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.ephemeris import ephemeris_states
from georef_core.gnss.rtcm3 import (_lock_ms_msm6, decode_rtcm3_bytes, find_rtcm3_frames, looks_like_rtcm3,
                                    read_rtcm3)
from .rtklib_cases import UNIX_MINUS_GPS_S, rtklib_decode_rtcm3, rtklib_gtime, rtklib_sat_id
from tests.shared_data import dji_auckland_dir

PPKRAW = dji_auckland_dir() / "100_0004_PPKRAW.bin"
needs_log = pytest.mark.skipif(not PPKRAW.is_file(), reason="shared DJI data not available")


@pytest.fixture(scope="module")
def rtk():
    return pytest.importorskip("pyrtklib5")


@pytest.fixture(scope="module")
def ours():
    return read_rtcm3(PPKRAW, slip_on_lock_gap=False)


@pytest.fixture(scope="module")
def theirs(rtk, ours):
    """RTKLIB's decoding of the same log: observation rows and the final navigation data."""
    rows, _, r = rtklib_decode_rtcm3(rtk, PPKRAW.read_bytes(), float(ours.observations.gps_time_s[0]))
    return rows, r.nav


@needs_log
def test_observations_match_rtklib(ours, theirs):
    """Every pseudorange, phase, Doppler and C/N0 RTKLIB decodes is ours to 1 um / 1 mHz (zero in RTKLIB
    is absent, NaN here); every slip RTKLIB flags on a valid phase is flagged here too, and the only
    extra flags are slips carried over epochs where the phase was missing."""
    rows, _ = theirs
    obs = ours.observations
    t_index = {round(t * 1e3): i for i, t in enumerate(obs.gps_time_s)}
    s_index = {s: i for i, s in enumerate(obs.sat_ids)}
    c_index = {c: i for i, c in enumerate(obs.obs_codes)}
    assert len(rows) > 100_000
    mismatches, extra_slips = [], 0
    for t, sat, code, p, l, d, snr, lli in rows:
        e, s = t_index[round(t * 1e3)], s_index[sat]
        v = obs.values[e, s]
        for kind, val, tol in (("C", p, 1e-6), ("L", l, 1e-6), ("D", d, 1e-3), ("S", snr, 1e-2)):
            mine = v[c_index[kind + code]]
            if (val == 0.0 and not np.isnan(mine)) or (val != 0.0 and not abs(mine - val) <= tol):
                mismatches.append((t, sat, kind + code, mine, val))
        if l != 0.0:
            my_lli = int(obs.lli[e, s, c_index["L" + code]]) & 1
            assert my_lli >= (lli & 1), (t, sat, code)          # no slip of RTKLIB's missed
            if my_lli > (lli & 1):
                assert e > 0 and np.isnan(obs.values[e - 1, s, c_index["L" + code]]), (t, sat, code)
                extra_slips += 1
    assert mismatches == []
    assert extra_slips < 0.01 * len(rows)
    # RTKLIB emits an epoch when the next begins: the log's last (complete) epoch is ours alone
    assert obs.n_epochs - len({r[0] for r in rows}) in (0, 1)
    assert set(obs.sat_ids) == {r[1] for r in rows}


@needs_log
def test_log_contents_and_time(ours):
    """The log of 2018-10-24 (week 2024, as its MRK says): 5 Hz, four systems, dated from the Galileo
    ephemeris week; the same epochs when the date is given instead."""
    obs = ours.observations
    assert ours.time_reference.startswith("Galileo")
    assert obs.header.interval_s == 0.2
    assert int(obs.gps_time_s[0] // 604800) == 2024
    assert {s[0] for s in obs.sat_ids} == {"G", "R", "E", "C"}
    assert np.all(np.diff(obs.gps_time_s) > 0)
    assert ours.message_counts[1075] == 2342 and ours.message_counts[1019] == 7
    assert set(obs.header.glonass_fcn) >= {s for s in obs.sat_ids if s[0] == "R"}
    assert ours.station.arp_ecef_m is not None   # 1006 in the drone's stream
    given = decode_rtcm3_bytes(PPKRAW.read_bytes(), "x", approx_gps_time_s=float(obs.gps_time_s[0]) + 2 * 86400,
                               slip_on_lock_gap=False)
    assert given.time_reference == "given"
    np.testing.assert_array_equal(given.observations.gps_time_s, obs.gps_time_s)


@needs_log
def test_ephemerides_match_rtklib(ours, theirs, rtk):
    """Satellite positions and clocks of every decoded record agree with RTKLIB's eph2pos/geph2pos on
    RTKLIB's own decoding of the same messages (GPS, GLONASS; same toe, stale records included)."""
    _, rnav = theirs
    nav = ours.navigation
    def sat_of(n):
        return rtklib_sat_id(rtk, n)

    def gtime(t):
        return rtklib_gtime(rtk, t)

    # records keyed by satellite, toe within the week and issue: the weeks of stale records differ by one
    # (demo5 moves a toe more than half a week from the stream time by a week; here it keeps its message
    # week), which changes nothing in the orbit relative to toe
    kepler = {(sat_of(e.sat), e.toes, e.iode): e for e in (rnav.eph[i] for i in range(rnav.n)) if e.sat}
    glonass = {(sat_of(g.sat), g.toe.time - UNIX_MINUS_GPS_S + g.toe.sec): g
               for g in (rnav.geph[i] for i in range(rnav.ng)) if g.sat}
    checked = {"G": 0, "E": 0, "R": 0}
    worst_pos = worst_clk = 0.0
    for sat, recs in list(nav.kepler.items()) + list(nav.glonass.items()):
        for rec in recs:
            if sat[0] == "R":
                e, fn, span, their_toe = glonass[(sat, rec.toe_gps_s)], rtk.geph2pos, 1800.0, rec.toe_gps_s
            else:
                e, fn, span = kepler[(sat, rec.toe_sow_s, rec.iode)], rtk.eph2pos, 7200.0
                their_toe = e.toe.time - UNIX_MINUS_GPS_S + e.toe.sec
            offsets = np.linspace(-span, span, 7) + 0.25
            st = ephemeris_states([rec] * len(offsets), rec.toe_gps_s + offsets)
            for j, dt in enumerate(offsets):
                rs, dts, var = rtk.Arr1Ddouble(3), rtk.Arr1Ddouble(1), rtk.Arr1Ddouble(1)
                fn(gtime(their_toe + dt), e, rs, dts, var)
                worst_pos = max(worst_pos, float(np.linalg.norm(st.position_ecef_m[j] - [rs[0], rs[1], rs[2]])))
                worst_clk = max(worst_clk, abs(st.clock_bias_s[j] - dts[0]))
            checked[sat[0]] += 1
    # the log's seven Galileo 1045 records are placeholders (sqrt(A) = 4096, a 16,777 km orbit): dropped
    assert checked == {"G": 7, "E": 0, "R": 7}
    assert any("7 ephemeris record(s) with an impossible orbit" in w and "E14" in w for w in ours.warnings)
    stale = nav.kepler["G05"][0]
    assert stale.toe_gps_s < ours.observations.gps_time_s[0] - 4 * 604800   # a stale record keeps its old date
    assert worst_pos < 1e-3, worst_pos
    assert worst_clk < 1e-11, worst_clk


# ------------------------------------------------------------------------------------------------ framing
def _frame(payload: bytes) -> bytes:
    from georef_core.gnss.rtcm3 import _CRC24Q

    head = bytes([0xD3, len(payload) >> 8, len(payload) & 0xFF]) + payload
    crc = 0
    for b in head:
        crc = ((crc << 8) & 0xFFFFFF) ^ int(_CRC24Q[((crc >> 16) ^ b) & 0xFF])
    return head + crc.to_bytes(3, "big")


def _station_1005(x_m: float, y_m: float, z_m: float) -> bytes:
    bits = f"{1005:012b}{7:012b}{0:06b}1110"
    for v, tail in ((x_m, "00"), (y_m, "00"), (z_m, "")):
        bits += format(round(v * 1e4) & ((1 << 38) - 1), "038b") + tail
    bits += "0" * (-len(bits) % 8)
    return int(bits, 2).to_bytes(len(bits) // 8, "big")


def test_framing_skips_foreign_and_corrupt_bytes():
    payload = _station_1005(-3978241.958, 3382840.234, 3649900.853)
    good = _frame(payload)
    corrupt = bytearray(good)
    corrupt[10] ^= 0x40
    data = b"$GPGGA,foo*00\r\n" + good + b"\xb5\x62\x01\x07" + bytes(corrupt) + good + good[:-4]
    frames = find_rtcm3_frames(data)
    assert len(frames.start) == 2 and frames.msg_type.tolist() == [1005, 1005]
    assert frames.n_crc_errors == 1 and frames.n_truncated_at_end == 1
    with pytest.raises(InputFileError, match="station.rtcm3: .*no week number"):
        decode_rtcm3_bytes(data, "station.rtcm3")        # no ephemeris and no date given
    log = decode_rtcm3_bytes(data, "station.rtcm3", approx_gps_time_s=1.3e9)
    np.testing.assert_allclose(log.station.arp_ecef_m, [-3978241.958, 3382840.234, 3649900.853], atol=1e-4)
    assert log.observations.n_epochs == 0
    assert any("CRC" in w for w in log.warnings) and any("truncated" in w for w in log.warnings)


def test_not_rtcm_is_a_clear_error(tmp_path):
    for name, content, problem in (("empty.bin", b"", "empty"), ("text.bin", b"hello\n" * 100, "no RTCM 3 frame")):
        p = tmp_path / name
        p.write_bytes(content)
        with pytest.raises(InputFileError, match=problem) as exc:
            read_rtcm3(p)
        assert name in str(exc.value)
    assert not looks_like_rtcm3(b"hello\n" * 100)


@needs_log
def test_recognised_by_content_and_cut_log(tmp_path):
    data = PPKRAW.read_bytes()
    assert looks_like_rtcm3(data[:65536])
    assert looks_like_rtcm3(data[12345:12345 + 65536])       # starts mid-frame
    cut = tmp_path / "anything.dat"
    cut.write_bytes(data[: len(data) // 3])
    log = read_rtcm3(cut)
    assert 0.3 < log.observations.n_epochs / 2342 < 0.36
    assert any("truncated" in w for w in log.warnings)


def test_extended_lock_time_table():
    """DF407 (MSM6/7): exact below 64 ms, then piecewise with doubling steps (RTCM 10403.3 table 3.5-75)."""
    assert [_lock_ms_msm6(i) for i in (0, 63, 64, 95, 96, 128, 160, 704)] == [0, 63, 64, 126, 128, 256, 512, 67108864]
    vals = [_lock_ms_msm6(i) for i in range(705)]
    assert all(b > a for a, b in zip(vals, vals[1:]))
