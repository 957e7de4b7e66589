"""u-blox UBX decoding: synthetic streams (framing, RXM-RAWX / RXM-RAW / TIM-TM2, Galileo and BeiDou
navigation pages) and the real M8P logs of shared/data compared with their RTKLIB demo5 convbin RINEX."""

from __future__ import annotations

import dataclasses
import gzip
import math
import os
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.gnss.gnss_time import SECONDS_PER_WEEK, calendar_to_gps_time_s
from georef_core.gnss.ubx import decode_ubx_bytes, find_ubx_frames, read_ubx, ubx_signal_code

WEEK = 2021
T0_TOW = 401640.0   # 2018-10-04 15:34:00 GPST


# ============================================================================ stream builders
def fletcher(body: bytes) -> bytes:
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return bytes((a, b))


def ubx(cls: int, mid: int, payload: bytes) -> bytes:
    body = struct.pack("<BBH", cls, mid, len(payload)) + payload
    return b"\xb5\x62" + body + fletcher(body)


def rawx(week: int, tow: float, meas: list[dict], version: int = 1, leap: int = 18) -> bytes:
    out = struct.pack("<dHbBBBH", tow, week, leap, len(meas), 1, version, 0)
    for m in meas:
        out += struct.pack("<ddfBBBBHBBBBBB", m.get("pr", 2.2e7), m.get("cp", 1.1e8), m.get("do", -100.0),
                           m["gnss"], m["sv"], m.get("sig", 0), m.get("freq", 0), m.get("lock", 10000),
                           m.get("cno", 40), 5, m.get("cpstd", 1), 2, m.get("trk", 0x07), 0)
    return ubx(0x02, 0x15, out)


def rxm_raw(week: int, tow_ms: int, meas: list[dict]) -> bytes:
    out = struct.pack("<ihBB", tow_ms, week, len(meas), 0)
    for m in meas:
        out += struct.pack("<ddfBbbB", m.get("cp", 1.1e8), m.get("pr", 2.2e7), m.get("do", 50.0), m["sv"],
                           m.get("qi", 7), m.get("cno", 45), m.get("lli", 0))
    return ubx(0x02, 0x10, out)


def tim_tm2(flags: int, count: int, wn_r: int, tow_r_ms: int, sub_r_ns: int, wn_f: int, tow_f_ms: int,
            sub_f_ns: int, ch: int = 0, acc_ns: int = 20) -> bytes:
    return ubx(0x0D, 0x03, struct.pack("<BBHHHIIIII", ch, flags, count, wn_r, wn_f, tow_r_ms, sub_r_ns,
                                       tow_f_ms, sub_f_ns, acc_ns))


def nmea(body: str) -> bytes:
    cs = 0
    for ch in body.encode():
        cs ^= ch
    return f"${body}*{cs:02X}\r\n".encode()


def rtcm3_like(payload: bytes) -> bytes:
    """An RTCM 3 frame shape (preamble, length, payload, 3 CRC bytes); the CRC is not computed."""
    return bytes((0xD3, len(payload) >> 8 & 0x03, len(payload) & 0xFF)) + payload + b"\x11\x22\x33"


class Bits:
    """MSB-first bit writer (two's complement for negative values)."""

    def __init__(self) -> None:
        self.value = 0
        self.n = 0

    def add(self, v: int, n: int) -> "Bits":
        self.value = (self.value << n) | (v & ((1 << n) - 1))
        self.n += n
        return self


# ============================================================================ framing and errors
def test_frame_sync_skips_nmea_rtcm_corrupt_and_truncated_frames():
    t = WEEK * SECONDS_PER_WEEK
    good = [rawx(WEEK, T0_TOW + k, [{"gnss": 0, "sv": 5}]) for k in range(4)]
    corrupt = bytearray(good[1])
    corrupt[20] ^= 0xFF                                  # payload byte changed: checksum fails
    truncated = good[2][:30]                             # frame cut short, the next one follows at once
    junk = rtcm3_like(b"\x43\x50\xb5\x62\x77\x15\x40\x00" + bytes(range(40)))   # chance sync bytes inside
    stream = (nmea("GNRMC,153323.00,A,5316.82756,N,00903.47053,W,0.004,,041018,,,A") + good[0] + junk
              + bytes(corrupt) + truncated + good[3] + nmea("GNGGA,153323.00,,,,,0,00,,,M,,M,,") + good[2][:-1])
    frames = find_ubx_frames(stream)
    assert len(frames.start) == 2
    assert frames.msg_id.tolist() == [0x0215, 0x0215]
    assert frames.n_checksum_errors == 2           # the corrupt frame and the truncated one
    assert frames.n_truncated_at_end == 1
    log = decode_ubx_bytes(stream, "x.ubx")
    np.testing.assert_allclose(log.observations.gps_time_s, t + T0_TOW + np.array([0.0, 3.0]))
    assert log.bytes_skipped == len(stream) - len(good[0]) - len(good[3])
    assert log.checksum_errors == 2
    assert any("checksum" in w for w in log.warnings)
    assert any("truncated" in w for w in log.warnings)


def test_unknown_messages_are_skipped_silently():
    stream = ubx(0x0A, 0x09, bytes(60)) + rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 7}]) + ubx(0x01, 0x35, bytes(8))
    log = decode_ubx_bytes(stream)
    assert log.observations.n_epochs == 1
    assert log.warnings == []
    assert log.message_counts == {"RXM-RAWX": 1, "NAV-SAT": 1, "0x0A-0x09": 1}


def test_not_a_ubx_file_raises_input_file_error(tmp_path):
    p = tmp_path / "notes.ubx"
    p.write_bytes(nmea("GNGGA,153323.00,,,,,0,00,,,M,,M,,") * 50 + bytes(range(256)) * 4)
    with pytest.raises(InputFileError) as exc:
        read_ubx(p)
    assert "notes.ubx" in str(exc.value) and "no UBX frame" in str(exc.value)
    empty = tmp_path / "empty.ubx"
    empty.write_bytes(b"")
    with pytest.raises(InputFileError, match="empty.ubx"):
        read_ubx(empty)
    with pytest.raises(InputFileError, match="missing.ubx"):
        read_ubx(tmp_path / "missing.ubx")


def test_gzip_log_is_read(tmp_path):
    p = tmp_path / "log.ubx.gz"
    p.write_bytes(gzip.compress(rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 7}])))
    assert read_ubx(p).observations.sat_ids == ["G07"]


def test_random_payloads_with_valid_checksums_do_not_crash():
    """Frames that pass the checksum but carry nonsense (wrong lengths, NaN times, bad words)."""
    import random

    rng = random.Random(3)
    ids = [(2, 0x15), (2, 0x10), (2, 0x13), (0x0D, 3), (0x0A, 4), (1, 6), (1, 7), (1, 1), (1, 0x20)]
    for it in range(300):
        parts = [rawx(WEEK, T0_TOW + it % 7, [{"gnss": 0, "sv": 5}])] if it % 2 else []
        for _ in range(rng.randint(1, 8)):
            cls, mid = rng.choice(ids)
            n = rng.choice([0, 1, 7, 8, 16, 24, 28, 40, 48, 52, 60, 92, rng.randint(0, 400)])
            payload = bytes(rng.getrandbits(8) for _ in range(n))
            if (cls, mid) == (2, 0x13) and n >= 8:
                payload = bytes([rng.choice([0, 2, 3, 5, 6]), rng.randint(0, 40), rng.randint(0, 8),
                                 rng.randint(0, 14), rng.randint(0, 12)]) + payload[5:]
            parts.append(ubx(cls, mid, payload))
        try:
            log = decode_ubx_bytes(b"".join(parts))
        except InputFileError:
            continue
        assert np.all(np.isfinite(log.observations.gps_time_s))


# ============================================================================ RXM-RAWX
def test_rawx_signals_units_and_validity_flags():
    meas = [
        {"gnss": 0, "sv": 5, "sig": 0, "pr": 20000000.123, "cp": 105000000.25, "do": -1234.5, "cno": 45},
        {"gnss": 0, "sv": 5, "sig": 3, "pr": 20000001.5, "cp": 81000000.75, "do": -950.25, "cno": 38},
        {"gnss": 2, "sv": 11, "sig": 0, "pr": 23000000.0, "cp": 120000000.5, "trk": 0x05},     # phase invalid
        {"gnss": 2, "sv": 11, "sig": 6, "pr": 23000002.0, "cp": 92000000.5, "trk": 0x03},     # half cycle not valid
        {"gnss": 3, "sv": 20, "sig": 0, "pr": 21000000.0, "cp": 110000000.0, "trk": 0x06},    # code invalid
        {"gnss": 3, "sv": 3, "sig": 0, "pr": 37000000.0, "cp": 190000000.25},                 # GEO: + half cycle
        {"gnss": 5, "sv": 2, "sig": 4, "pr": 36000000.0, "cp": 150000000.0},
        {"gnss": 6, "sv": 8, "sig": 0, "freq": 13, "pr": 19000000.0, "cp": 101000000.0},       # FCN +6
        {"gnss": 6, "sv": 255, "sig": 0, "freq": 7},                                            # unknown slot
        {"gnss": 1, "sv": 123, "sig": 0},                                                       # SBAS: not kept
        {"gnss": 0, "sv": 9, "sig": 0, "cp": 9.0e7, "cpstd": 15},                               # phase too noisy
    ]
    log = decode_ubx_bytes(rawx(WEEK, T0_TOW + 0.5, meas))
    o = log.observations
    assert o.sat_ids == ["G05", "G09", "R08", "E11", "J02", "C03", "C20"]
    assert set(o.obs_codes) == {f"{t}{s}" for s in ("1C", "2L", "2S", "7Q", "2I") for t in "CLDS"}
    np.testing.assert_allclose(o.gps_time_s, [WEEK * SECONDS_PER_WEEK + T0_TOW + 0.5])

    def get(sat: str, code: str) -> float:
        return o.values[0, o.sat_ids.index(sat), o.obs_codes.index(code)]

    def lli(sat: str, code: str) -> int:
        return int(o.lli[0, o.sat_ids.index(sat), o.obs_codes.index(code)])

    assert get("G05", "C1C") == 20000000.123 and get("G05", "L1C") == 105000000.25
    assert get("G05", "D1C") == -1234.5 and get("G05", "S1C") == 45
    assert o.ssi[0, 0, o.obs_codes.index("L1C")] == 7 and o.ssi[0, 0, o.obs_codes.index("L2L")] == 6
    assert get("G05", "C2L") == 20000001.5 and get("G05", "L2L") == 81000000.75
    assert math.isnan(get("E11", "L1C")) and get("E11", "C1C") == 23000000.0
    assert get("E11", "L7Q") == 92000000.5 and lli("E11", "L7Q") & 2
    assert math.isnan(get("C20", "C2I")) and get("C20", "L2I") == 110000000.0
    assert get("C03", "L2I") == 190000000.75
    assert get("J02", "C2S") == 36000000.0
    assert get("R08", "C1C") == 19000000.0 and o.header.glonass_fcn == {"R08": 6}
    assert math.isnan(get("G09", "L1C")) and not math.isnan(get("G09", "C1C"))
    assert lli("G05", "L1C") == 0          # first epoch, lock time > 0, half cycle valid and not subtracted
    assert ubx_signal_code(0, 4) == "2S" and ubx_signal_code(6, 2) == "2C" and ubx_signal_code(1, 0) is None


def test_rawx_loss_of_lock_indicator():
    def epoch(k: int, lock: int, trk: int = 0x07, cp: float = 1.0e8) -> bytes:
        return rawx(WEEK, T0_TOW + k, [{"gnss": 0, "sv": 5, "lock": lock, "trk": trk, "cp": cp + k}])

    stream = (epoch(0, 5000) + epoch(1, 6000) + epoch(2, 1500)            # lock time decreased: slip
              + epoch(3, 0, trk=0x01) + epoch(4, 900)                     # lock 0 (no phase), carried to next
              + epoch(5, 1900, trk=0x0F) + epoch(6, 2900, trk=0x0F)       # half-cycle-subtracted flag set
              + epoch(7, 3900, trk=0x0B) + epoch(8, 4900, trk=0x0F)       # half cycle not valid -> bit 1
              + epoch(20, 9000, trk=0x0F))                                # 12 s gap but only 9 s of lock
    o = decode_ubx_bytes(stream).observations
    li = o.lli[:, 0, o.obs_codes.index("L1C")].tolist()
    assert li == [0, 0, 1, 0, 1, 1, 0, 2, 0, 1]
    o2 = decode_ubx_bytes(stream, slip_on_lock_gap=False).observations
    assert o2.lli[:, 0, o2.obs_codes.index("L1C")].tolist() == [0, 0, 1, 0, 1, 1, 0, 2, 0, 0]


def test_rawx_duplicate_and_unsorted_epochs():
    a = rawx(WEEK, T0_TOW + 1, [{"gnss": 0, "sv": 5, "pr": 1.0e7}])
    b = rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5, "pr": 2.0e7}])
    dup = rawx(WEEK, T0_TOW + 1, [{"gnss": 0, "sv": 5, "pr": 3.0e7}])
    log = decode_ubx_bytes(a + b + dup)
    o = log.observations
    np.testing.assert_allclose(o.gps_time_s - WEEK * SECONDS_PER_WEEK, [T0_TOW, T0_TOW + 1])
    np.testing.assert_allclose(o.values[:, 0, o.obs_codes.index("C1C")], [2.0e7, 1.0e7])
    assert any("duplicate" in w for w in log.warnings) and any("time order" in w for w in log.warnings)


# ============================================================================ RXM-RAW (u-blox 6)
def test_rxm_raw_gps_l1():
    stream = (rxm_raw(WEEK, 401640000, [{"sv": 3, "pr": 21000000.5, "cp": 110000000.25, "do": -250.5, "cno": 44},
                                        {"sv": 7, "qi": 4, "pr": 22000000.0},            # no phase (mesQI 4)
                                        {"sv": 12, "qi": 2},                               # nothing valid
                                        {"sv": 135, "pr": 38000000.0}])                    # SBAS: not kept
              + rxm_raw(WEEK, 401641000, [{"sv": 3, "cp": 110000100.0, "lli": 1}, {"sv": 7}]))
    log = decode_ubx_bytes(stream)
    o = log.observations
    assert o.sat_ids == ["G03", "G07", "G12"] and o.obs_codes == ["C1C", "L1C", "D1C", "S1C"]
    np.testing.assert_allclose(o.gps_time_s - WEEK * SECONDS_PER_WEEK, [401640.0, 401641.0])
    np.testing.assert_array_equal(o.values[0, 0], [21000000.5, 110000000.25, -250.5, 44])
    assert np.isnan(o.values[0, 1, 1]) and o.values[0, 1, 0] == 22000000.0
    assert np.isnan(o.values[0, 2, :3]).all()
    assert o.lli[1, 0, 1] == 1 and o.lli[0, 0, 1] == 0
    assert o.lli[1, 1, 1] == 1      # first valid phase of G07 follows mesQI 4 (< 6: lock likely lost)


# ============================================================================ TIM-TM2
def test_tim_tm2_events():
    rise, fall, valid, utc = 0x80, 0x04, 0x40, 0x10   # flag bits (timeBase 2 = UTC -> 0x10)
    gnss = 0x08
    stream = (rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5}], leap=18)
              + tim_tm2(rise | valid | gnss, 1, WEEK, 401650123, 456789, 0, 0, 0, ch=1)
              + tim_tm2(fall | valid | gnss, 1, WEEK, 401650123, 456789, WEEK, 401650223, 1000, ch=1)
              + tim_tm2(rise | valid | utc, 2, WEEK, 401651000, 500000, WEEK, 401650223, 1000, ch=1)
              + tim_tm2(rise | gnss, 3, WEEK, 401652000, 0, WEEK, 401650223, 1000))   # time not valid
    log = decode_ubx_bytes(stream, event_edge="rising")
    t0 = WEEK * SECONDS_PER_WEEK
    np.testing.assert_allclose(log.event_gps_time_s - t0, [401650.123456789, 401651.0005 + 18], atol=5e-7)
    np.testing.assert_allclose(log.event_falling_gps_time_s - t0, [401650.223001], atol=5e-7)
    assert log.event_channel.tolist() == [1, 1]
    np.testing.assert_allclose(log.event_accuracy_s, [2e-8, 2e-8])
    np.testing.assert_array_equal(log.observations.event_gps_time_s, log.event_gps_time_s)
    assert any("TIM-TM2" in w for w in log.warnings)
    # the default is the falling edge (hot-shoe contact closing to ground; the edge convbin writes)
    falling = decode_ubx_bytes(stream)
    np.testing.assert_array_equal(falling.event_gps_time_s, log.event_falling_gps_time_s)
    np.testing.assert_array_equal(falling.observations.event_gps_time_s, log.event_falling_gps_time_s)
    np.testing.assert_array_equal(decode_ubx_bytes(stream, event_edge="falling").event_gps_time_s,
                                  falling.event_gps_time_s)
    with pytest.raises(ValueError, match="event_edge"):
        decode_ubx_bytes(stream, event_edge="both")


def test_tim_tm2_utc_time_base_and_sub_millisecond_field():
    """One hot-shoe pulse, 3 ms long, as a u-blox 8 reports it in the UTC time base (flags 0x75 for the
    falling edge, 0xF1 for the rising one, as in the M8P walk log): towSubMs is in nanoseconds, UTC gets
    the leap seconds of RXM-RAWX (here 18 s, convbin: utc2gpst), and each edge is reported once."""
    stream = (rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5}], leap=18)
              + tim_tm2(0x75, 7, 0, 0, 0, WEEK, 401609113, 958620, ch=1, acc_ns=25)
              + tim_tm2(0xF1, 8, WEEK, 401609117, 1234, WEEK, 401609113, 958620, ch=1, acc_ns=25))
    t0 = WEEK * SECONDS_PER_WEEK
    log = decode_ubx_bytes(stream)
    # (float64 GPS seconds resolve 0.24 us at this date)
    np.testing.assert_allclose(log.event_gps_time_s - t0, [401609.11395862 + 18], atol=3e-7)
    np.testing.assert_allclose(log.event_rising_gps_time_s - t0, [401609.117001234 + 18], atol=3e-7)
    np.testing.assert_allclose(log.event_rising_gps_time_s - log.event_falling_gps_time_s, [0.004 - 957386e-9],
                               atol=3e-7)
    assert log.warnings == []


def nav_sol(week: int, itow_ms: int, xyz_m, fix: int = 3, flags: int = 0x0D) -> bytes:
    x, y, z = (int(round(v * 100)) for v in xyz_m)
    return ubx(0x01, 0x06, struct.pack("<IihBBiiiIiiiIHBBI", itow_ms, 0, week, fix, flags, x, y, z, 170, 0, 0, 0,
                                       10, 150, 0, 12, 0))


def test_receiver_fixes_are_marked_as_such_not_as_a_header_position():
    """The median of the receiver's own fixes is kept as an approximate position (a starting point), with
    its source: a base log's ppk._base_position then prefers an averaged single-point solution to it."""
    xyz = np.array([3774088.2, -601663.1, 5089317.1])
    stream = b"".join(rawx(WEEK, T0_TOW + k, [{"gnss": 0, "sv": 5}]) + nav_sol(WEEK, int((T0_TOW + k) * 1000),
                                                                              xyz + [0.0, 0.0, k - 1.0])
                      for k in range(3))
    hdr = decode_ubx_bytes(stream).observations.header
    np.testing.assert_allclose(hdr.approx_position_ecef_m, xyz, atol=0.006)
    assert hdr.approx_position_source == "receiver-fixes" and hdr.rinex_version is None
    bare = decode_ubx_bytes(rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5}])).observations.header
    assert bare.approx_position_ecef_m is None and bare.approx_position_source == ""


# ============================================================================ Galileo I/NAV, BeiDou D1 (synthetic)
def _crc24q_bits(value: int, nbits: int) -> int:
    """Bitwise CRC-24Q of an nbits-long message (independent of the library's table version)."""
    crc = 0
    for k in range(nbits - 1, -1, -1):
        bit = (value >> k) & 1
        top = (crc >> 23) & 1
        crc = ((crc << 1) & 0xFFFFFF)
        if top ^ bit:
            crc ^= 0x864CFB
    return crc


def _gal_sfrbx(sv: int, word128: int) -> bytes:
    even = Bits().add(0, 1).add(0, 1).add(word128 >> 16, 112).add(0, 6).add(0, 8)       # 128 bits
    odd_head = Bits().add(1, 1).add(0, 1).add(word128 & 0xFFFF, 16).add(0, 40).add(0, 22).add(0, 2)   # 82 bits
    crc = _crc24q_bits(((even.value >> 14) << 82) | odd_head.value, 196)
    odd = Bits().add(odd_head.value, 82).add(crc, 24).add(0, 8).add(0, 6).add(0, 8)
    page = (even.value << 128) | odd.value
    words = [(page >> (32 * (7 - k))) & 0xFFFFFFFF for k in range(8)]
    return ubx(0x02, 0x13, struct.pack("<8B", 2, sv, 1, 0, 8, 3, 2, 0) + struct.pack("<8I", *words))


GAL_RAW = dict(iod=77, toe=int(T0_TOW + 600) // 60, m0=-123456789, e=1234567, sqrta=2921130000, omega0=987654321,
               i0=654321987, omega=-456789123, idot=-1234, omega_dot=-5000, delta_n=12000, cuc=-300, cus=4000,
               crc=5000, crs=-600, sisa=107, cic=-40, cis=25, toc=int(T0_TOW + 600) // 60, af0=-12345678,
               af1=-20000, af2=3, ai0=123, ai1=-45, ai2=67, bgd_a=-10, bgd_b=-12, hs=0, wn=WEEK - 1024,
               tow=int(T0_TOW + 30))


def _gal_words(r: dict, sv: int) -> list[int]:
    w1 = (Bits().add(1, 6).add(r["iod"], 10).add(r["toe"], 14).add(r["m0"], 32).add(r["e"], 32).add(r["sqrta"], 32)
          .add(0, 2))
    w2 = (Bits().add(2, 6).add(r["iod"], 10).add(r["omega0"], 32).add(r["i0"], 32).add(r["omega"], 32)
          .add(r["idot"], 14).add(0, 2))
    w3 = (Bits().add(3, 6).add(r["iod"], 10).add(r["omega_dot"], 24).add(r["delta_n"], 16).add(r["cuc"], 16)
          .add(r["cus"], 16).add(r["crc"], 16).add(r["crs"], 16).add(r["sisa"], 8))
    w4 = (Bits().add(4, 6).add(r["iod"], 10).add(sv, 6).add(r["cic"], 16).add(r["cis"], 16).add(r["toc"], 14)
          .add(r["af0"], 31).add(r["af1"], 21).add(r["af2"], 6).add(0, 2))
    w5 = (Bits().add(5, 6).add(r["ai0"], 11).add(r["ai1"], 11).add(r["ai2"], 14).add(0, 5).add(r["bgd_a"], 10)
          .add(r["bgd_b"], 10).add(0, 2).add(0, 2).add(0, 1).add(0, 1).add(r["wn"], 12).add(r["tow"], 20).add(0, 23))
    w6 = (Bits().add(6, 6).add(-3, 32).add(-2, 24).add(18, 8).add(72, 8).add(r["wn"] & 0xFF, 8).add(137, 8)
          .add(7, 3).add(18, 8).add(r["tow"] + 2, 20).add(0, 3))     # UTC parameters (only RTKLIB needs them)
    for w in (w1, w2, w3, w4, w5, w6):
        assert w.n == 128
    return [w.value for w in (w1, w2, w3, w4, w5, w6)]


def _bds_sfrbx(sv: int, info224: int) -> bytes:
    words = [((info224 >> 198) << 4)] + [((info224 >> (176 - 22 * k)) & 0x3FFFFF) << 8 for k in range(9)]
    return ubx(0x02, 0x13, struct.pack("<8B", 3, sv, 0, 0, 10, 4, 2, 0) + struct.pack("<10I", *words))


BDS_RAW = dict(sow=int(T0_TOW - 14) // 6 * 6, wn=WEEK - 1356, toe=int(T0_TOW + 1800) // 8, aodc=1, aode=2, urai=2,
               tgd1=55, tgd2=-31, a0=-1234567, a1=-23456, a2=5, delta_n=9000, cuc=-70000, m0=1234567890,
               e=23456789, cus=80000, crc=-90000, crs=100000, sqrta=2818620000, i0=700000000, cic=-5000,
               omega_dot=-300000, cis=6000, idot=-700, omega0=-1500000000, omega=600000000)


def _bds_subframes(r: dict) -> list[int]:
    def head(fid: int, sow: int) -> Bits:
        return Bits().add(0x712, 11).add(0, 4).add(fid, 3).add(sow, 20)

    f1 = (head(1, r["sow"]).add(0, 1).add(r["aodc"], 5).add(r["urai"], 4).add(r["wn"], 13).add(r["toe"], 17)
          .add(r["tgd1"], 10).add(r["tgd2"], 10).add(0, 64).add(r["a2"], 11).add(r["a0"], 24).add(r["a1"], 22)
          .add(r["aode"], 5))
    f2 = (head(2, r["sow"] + 6).add(r["delta_n"], 16).add(r["cuc"], 18).add(r["m0"], 32).add(r["e"], 32)
          .add(r["cus"], 18).add(r["crc"], 18).add(r["crs"], 18).add(r["sqrta"], 32).add(r["toe"] >> 15, 2))
    f3 = (head(3, r["sow"] + 12).add(r["toe"] & 0x7FFF, 15).add(r["i0"], 32).add(r["cic"], 18).add(r["omega_dot"], 24)
          .add(r["cis"], 18).add(r["idot"], 14).add(r["omega0"], 32).add(r["omega"], 32).add(0, 1))
    for f in (f1, f2, f3):
        assert f.n == 224
    return [f.value for f in (f1, f2, f3)]


def _nav_stream() -> bytes:
    stream = rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5}])
    words = _gal_words(GAL_RAW, 11)
    stream += b"".join(_gal_sfrbx(11, w) for w in words[5:] + words[:5])   # RTKLIB decodes at type 5
    stream += b"".join(_bds_sfrbx(23, f) for f in _bds_subframes(BDS_RAW))
    return stream


def test_galileo_inav_and_beidou_d1_decoding():
    nav = decode_ubx_bytes(_nav_stream()).navigation
    r = GAL_RAW
    (gal,) = nav.kepler["E11"]
    t0 = (WEEK) * SECONDS_PER_WEEK
    assert gal.toe_gps_s == t0 + r["toe"] * 60 and gal.toe_sow_s == r["toe"] * 60 and gal.week == WEEK
    assert gal.transmit_gps_s == t0 + r["tow"] and gal.iode == 77 and gal.data_source == 513
    assert gal.m0_rad == r["m0"] * 2.0**-31 * math.pi and gal.e == r["e"] * 2.0**-33
    assert gal.sqrt_a == r["sqrta"] * 2.0**-19 and gal.omega_rad == r["omega"] * 2.0**-31 * math.pi
    assert gal.idot_rad_s == r["idot"] * 2.0**-43 * math.pi and gal.crs_m == r["crs"] * 2.0**-5
    assert gal.af0_s == r["af0"] * 2.0**-34 and gal.af1_s_s == r["af1"] * 2.0**-46 and gal.af2_s_s2 == 3 * 2.0**-59
    assert gal.tgd_s == (-10 * 2.0**-32, -12 * 2.0**-32) and gal.accuracy_m == pytest.approx(3.12)
    np.testing.assert_allclose(nav.iono_gal, [123 / 4, -45 / 256, 67 / 32768])
    b = BDS_RAW
    (bds,) = nav.kepler["C23"]
    toe_bdt = (b["wn"] + 1356) * SECONDS_PER_WEEK + b["toe"] * 8
    assert bds.toe_gps_s == toe_bdt + 14 and bds.toc_gps_s == toe_bdt + 14
    assert bds.week == b["wn"] and bds.toe_sow_s == b["toe"] * 8 and bds.iode == 2 and bds.iodc == 1
    assert bds.sqrt_a == b["sqrta"] * 2.0**-19 and bds.m0_rad == b["m0"] * 2.0**-31 * math.pi
    assert bds.omega0_rad == b["omega0"] * 2.0**-31 * math.pi and bds.crc_m == b["crc"] * 2.0**-6
    assert bds.af0_s == b["a0"] * 2.0**-33 and bds.af1_s_s == b["a1"] * 2.0**-50 and bds.af2_s_s2 == 5 * 2.0**-66
    assert bds.tgd_s == pytest.approx((5.5e-9, -3.1e-9)) and bds.accuracy_m == 4.0


def test_galileo_crc_error_rejected():
    pages = [_gal_sfrbx(11, w) for w in _gal_words(GAL_RAW, 11)]
    bad = bytearray(pages[2])
    bad[20] ^= 0x10                       # a data bit of word type 3; re-frame so only the CRC catches it
    body = bytes(bad[2:-2])
    pages[2] = b"\xb5\x62" + body + fletcher(body)
    log = decode_ubx_bytes(rawx(WEEK, T0_TOW, [{"gnss": 0, "sv": 5}]) + b"".join(pages))
    assert "E11" not in log.navigation.kepler and log.nav_stats["galileo_crc_error"] == 1


def test_galileo_beidou_agree_with_rtklib():
    """The same synthetic pages decoded by RTKLIB demo5 (pyrtklib5): an independent check of bit positions."""
    p = pytest.importorskip("pyrtklib5")
    raw = p.raw_t()
    p.init_raw(raw, p.STRFMT_UBX)
    for byte in _nav_stream():
        p.input_ubx(raw, byte)
    nav = decode_ubx_bytes(_nav_stream()).navigation
    for sat, sys_, prn in (("E11", p.SYS_GAL, 11), ("C23", p.SYS_CMP, 23)):
        ref = raw.nav.eph[p.satno(sys_, prn) - 1]
        mine = nav.kepler[sat][0]
        assert ref.A == pytest.approx(mine.sqrt_a**2, rel=1e-15)
        for a, b in (("e", "e"), ("i0", "i0_rad"), ("OMG0", "omega0_rad"), ("omg", "omega_rad"), ("M0", "m0_rad"),
                     ("deln", "delta_n_rad_s"), ("OMGd", "omega_dot_rad_s"), ("idot", "idot_rad_s"),
                     ("cuc", "cuc_rad"), ("cus", "cus_rad"), ("crc", "crc_m"), ("crs", "crs_m"), ("cic", "cic_rad"),
                     ("cis", "cis_rad"), ("f0", "af0_s"), ("f1", "af1_s_s"), ("f2", "af2_s_s2"), ("toes", "toe_sow_s")):
            assert getattr(ref, a) == pytest.approx(getattr(mine, b), rel=1e-13, abs=1e-25), (sat, a)
        assert ref.toe.time + ref.toe.sec - 315964800 == pytest.approx(mine.toe_gps_s)
        assert ref.week == mine.week


# ============================================================================ speed
def _synthetic_10hz_log(minutes: float = 20.0, n_sat: int = 30) -> bytes:
    """RXM-RAWX at 10 Hz with n_sat signals per epoch, plus NMEA between epochs."""
    n_ep = int(minutes * 600)
    rng = np.random.default_rng(1)
    meas = np.zeros(n_sat, dtype=[("pr", "<f8"), ("cp", "<f8"), ("do", "<f4"), ("gnss", "u1"), ("sv", "u1"),
                                  ("sig", "u1"), ("freq", "u1"), ("lock", "<u2"), ("cno", "u1"), ("prs", "u1"),
                                  ("cps", "u1"), ("dos", "u1"), ("trk", "u1"), ("res", "u1")])
    meas["gnss"] = np.repeat([0, 6, 2], n_sat // 3 + 1)[:n_sat]
    meas["sv"] = np.arange(n_sat) % 24 + 1
    meas["freq"] = 7
    meas["trk"] = 7
    meas["cno"] = 40
    meas["cps"] = 1
    nm = nmea("GNGGA,153323.00,5316.82756,N,00903.47053,W,1,12,0.74,9.1,M,56.0,M,,")
    parts = []
    for k in range(n_ep):
        meas["pr"] = 2.2e7 + rng.normal(size=n_sat)
        meas["cp"] = 1.1e8 + k
        meas["lock"] = min(100 * k, 64500)
        body = struct.pack("<BBH", 0x02, 0x15, 16 + 32 * n_sat) + struct.pack(
            "<dHbBBBH", T0_TOW + 0.1 * k, WEEK, 18, n_sat, 1, 1, 0) + meas.tobytes()
        b = np.frombuffer(body, np.uint8)
        ck_a = int(b.sum()) & 0xFF
        ck_b = int(np.sum(b.astype(np.int64) * np.arange(len(b), 0, -1))) & 0xFF
        parts.append(b"\xb5\x62" + body + bytes((ck_a, ck_b)) + nm)
    return b"".join(parts)


def test_decoding_speed_20_min_10_hz():
    data = _synthetic_10hz_log()
    t0 = time.perf_counter()
    log = decode_ubx_bytes(data)
    dt = time.perf_counter() - t0
    assert log.observations.n_epochs == 12000 and len(log.observations.sat_ids) == 30
    assert dt < 5.0, f"{len(data) / 1e6:.1f} MB decoded in {dt:.2f} s"


# ============================================================================ real data vs RTKLIB convbin
def _walk_dir() -> Path | None:
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else Path(__file__).resolve().parents[2].parent / "shared"
    for cand in (root / "data" / "gnss", root / "gnss", root):
        if (cand / "ublox_m8p_20181004_walk").is_dir():
            return cand / "ublox_m8p_20181004_walk"
    return None


WALK = _walk_dir()
needs_walk = pytest.mark.skipif(WALK is None, reason="shared u-blox M8P data (/work/shared) not available")


def _parse_rinex3_obs(path: Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """Minimal RINEX 3 observation reader: epoch times, event (flag 5) times and
    {(epoch index, sat, code): (value, lli)}."""
    lines = path.read_text().splitlines()
    types: dict[str, list[str]] = {}
    i = 0
    while "END OF HEADER" not in lines[i]:
        if "SYS / # / OBS TYPES" in lines[i]:
            types[lines[i][0]] = lines[i][7:60].split()
        i += 1
    i += 1
    epochs, events, recs = [], [], {}
    while i < len(lines):
        ln = lines[i]
        t = calendar_to_gps_time_s(int(ln[2:6]), int(ln[7:9]), int(ln[10:12]), int(ln[13:15]), int(ln[16:18]),
                                   float(ln[19:29]))
        flag, n = int(ln[31]), int(ln[32:35])
        if flag == 5:
            events.append(t)
        else:
            epochs.append(t)
            for sat_line in lines[i + 1:i + 1 + n]:
                sat = sat_line[:3]
                for k, code in enumerate(types[sat[0]]):
                    f = sat_line[3 + 16 * k: 19 + 16 * k]
                    v, flag_lli = f[:14].strip(), f[14:15].strip()
                    if v:
                        recs[(len(epochs) - 1, sat, code)] = (float(v), int(flag_lli) if flag_lli else 0)
        i += 1 + n
    return np.array(epochs), np.array(events), recs


def _compare_with_convbin(name: str, slip_on_lock_gap: bool):
    log = read_ubx(WALK / f"{name}.ubx.gz", slip_on_lock_gap=slip_on_lock_gap)
    epochs, events, recs = _parse_rinex3_obs(WALK / f"{name}.obs")
    o = log.observations
    e_map = np.searchsorted(o.gps_time_s, epochs)
    np.testing.assert_allclose(o.gps_time_s[e_map], epochs, atol=1e-7)
    col = {c: k for k, c in enumerate(o.obs_codes)}
    sat = {s: k for k, s in enumerate(o.sat_ids)}
    tol = {"C": 1e-3, "L": 1e-3, "D": 1e-3, "S": 0.0}
    worst = dict.fromkeys("CLDS", 0.0)
    lli_pairs = []
    for (e, s, code), (v, lli) in recs.items():
        mine = o.values[e_map[e], sat[s], col[code]]
        d = abs(mine - v)
        assert d <= tol[code[0]] + 1e-9, (name, e, s, code, v, mine)
        worst[code[0]] = max(worst[code[0]], d)
        if code[0] == "L":
            lli_pairs.append((lli, int(o.lli[e_map[e], sat[s], col[code]])))
    n_values = np.count_nonzero(~np.isnan(o.values[e_map]))
    assert n_values == len(recs)          # no value the RINEX lacks, none missing
    return log, epochs, events, np.array(lli_pairs), worst


@needs_walk
def test_rover_observations_match_convbin():
    log, epochs, events, lli, worst = _compare_with_convbin("rover-20181004-1532", slip_on_lock_gap=False)
    assert log.observations.n_epochs == len(epochs) == 1180
    assert log.warnings == []
    np.testing.assert_array_equal(lli[:, 1], lli[:, 0])        # identical LLI to demo5
    # with the lock-time-versus-gap test: every convbin flag kept, a few more slips (re-locks)
    _, _, _, lli_gap, _ = _compare_with_convbin("rover-20181004-1532", slip_on_lock_gap=True)
    assert np.all((lli_gap[:, 1] & lli_gap[:, 0]) == lli_gap[:, 0])
    assert np.all((lli_gap[:, 1] ^ lli_gap[:, 0]) <= 1) and np.count_nonzero(lli_gap[:, 1] != lli_gap[:, 0]) < 60
    assert worst["C"] <= 5e-4 + 1e-9 and worst["L"] <= 5e-4 + 1e-9
    # time marks: convbin writes the falling edges as event epochs, and so do we by default
    np.testing.assert_allclose(log.event_gps_time_s, events, atol=1e-6)
    assert len(log.event_gps_time_s) == 318 and np.all(np.diff(log.event_gps_time_s) > 1.5)
    assert log.observations.header.glonass_fcn["R10"] == -7 and log.observations.header.interval_s == 1.0


@needs_walk
def test_tim_tm2_edges_against_convbin_rinex_events():
    """The walk rover's EXTINT input carries a ~0.5 Hz square wave (not a camera): 318 falling and 317
    rising edges, UTC time base. convbin's 318 event epochs (flag 5) are the falling edges, leap seconds
    added: ours agree to the RINEX print resolution (0.1 us; 0.24 us with float64 GPS seconds). The rising
    edges lie a half period (0.93-1.06 s) from them: the ~1 s difference of the old rising-edge default."""
    log = read_ubx(WALK / "rover-20181004-1532.ubx.gz")
    _, events, _ = _parse_rinex3_obs(WALK / "rover-20181004-1532.obs")
    if len(events) == 0:
        pytest.skip("the converted rover RINEX has no event records")
    fall, rise = log.event_falling_gps_time_s, log.event_rising_gps_time_s
    assert log.message_counts["TIM-TM2"] == len(fall) + len(rise) == 635
    assert len(events) == len(fall) == 318
    assert np.max(np.abs(fall - events)) < 1e-6
    np.testing.assert_array_equal(log.event_gps_time_s, fall)          # the default edge
    assert set(log.event_channel.tolist()) == {1}
    # the rising edge after each falling one (the low half of the wave) and before it (the high half)
    k = np.searchsorted(rise, events)
    after = rise[k[k < len(rise)]] - events[k < len(rise)]
    before = events[k > 0] - rise[k[k > 0] - 1]
    low, high = after[after < 1.5], before[before < 1.5]               # one 131 s gap in the signal
    assert len(low) >= 300 and len(high) >= 300
    assert 0.9 < low.min() and low.max() < 1.1 and 0.9 < high.min() and high.max() < 1.1
    rising = read_ubx(WALK / "rover-20181004-1532.ubx.gz", event_edge="rising")
    np.testing.assert_array_equal(rising.event_gps_time_s, rise)
    np.testing.assert_array_equal(rising.observations.event_gps_time_s, rise)


@needs_walk
def test_lossy_base_log_resyncs_and_matches_convbin():
    """The base log mixes UBX and RTCM 3 and loses bytes: every convbin epoch is found with the same
    values, and more epochs are recovered (convbin loses the frames swallowed by a corrupt length)."""
    log, epochs, _, _, _ = _compare_with_convbin("base-20181004-1452", slip_on_lock_gap=True)
    assert log.observations.n_epochs > len(epochs) == 763
    assert log.checksum_errors > 100 and any("checksum" in w for w in log.warnings)
    assert log.bytes_skipped > 0.3 * log.bytes_total
    assert log.message_counts["RXM-RAWX"] == log.observations.n_epochs


def _eph_compare(name: str) -> dict[str, float]:
    from georef_core.gnss.ephemeris import ephemeris_states
    from georef_core.gnss.rinex_nav import read_rinex_nav

    nav = read_ubx(WALK / f"{name}.ubx.gz").navigation
    ref = read_rinex_nav(WALK / f"{name}.nav")
    worst = {"rel": 0.0, "pos": 0.0, "clk": 0.0, "glo_pos": 0.0}
    for sat, recs in ref.kepler.items():
        for r in recs:
            (m,) = [x for x in nav.kepler[sat] if x.iode == r.iode and abs(x.toe_gps_s - r.toe_gps_s) < 1.0]
            for f in ("sqrt_a", "e", "i0_rad", "omega0_rad", "omega_rad", "m0_rad", "delta_n_rad_s", "idot_rad_s",
                      "omega_dot_rad_s", "cuc_rad", "cus_rad", "crc_m", "crs_m", "cic_rad", "cis_rad", "af0_s",
                      "af1_s_s", "af2_s_s2"):
                a, b = getattr(r, f), getattr(m, f)
                worst["rel"] = max(worst["rel"], abs(a - b) / max(abs(a), 1e-30))
            assert (m.toc_gps_s, m.week, m.iodc, m.health, m.toe_sow_s) == (r.toc_gps_s, r.week, r.iodc, r.health,
                                                                            r.toe_sow_s)
            assert m.accuracy_m == r.accuracy_m and m.tgd_s[0] == pytest.approx(r.tgd_s[0], rel=1e-10)
            assert m.fit_interval_h == r.fit_interval_h
            t = r.toe_gps_s + np.array([0.0, -3600.0, 3600.0])
            s1, s2 = ephemeris_states([r] * 3, t), ephemeris_states([m] * 3, t)
            worst["pos"] = max(worst["pos"], float(np.abs(s1.position_ecef_m - s2.position_ecef_m).max()))
            worst["clk"] = max(worst["clk"], float(np.abs(s1.clock_bias_s - s2.clock_bias_s).max()))
    for sat, recs in ref.glonass.items():
        for r in recs:
            (m,) = [x for x in nav.glonass[sat] if abs(x.toe_gps_s - r.toe_gps_s) < 1.0]
            np.testing.assert_allclose(m.position_ecef_m, r.position_ecef_m, atol=1e-4)
            np.testing.assert_allclose(m.velocity_ecef_m_s, r.velocity_ecef_m_s, atol=1e-8)
            np.testing.assert_allclose(m.acceleration_ecef_m_s2, r.acceleration_ecef_m_s2, atol=1e-12)
            assert m.tau_n_s == pytest.approx(r.tau_n_s, rel=1e-10) and m.gamma_n == pytest.approx(r.gamma_n, rel=1e-10)
            assert (m.fcn, m.health, m.age_days) == (r.fcn, r.health, r.age_days)
            t = r.toe_gps_s + np.array([-900.0, 0.0, 900.0])
            s1, s2 = ephemeris_states([r] * 3, t), ephemeris_states([m] * 3, t)
            worst["glo_pos"] = max(worst["glo_pos"], float(np.abs(s1.position_ecef_m - s2.position_ecef_m).max()))
    np.testing.assert_allclose(nav.iono_gps_alpha, ref.iono_gps_alpha, rtol=1e-3)
    np.testing.assert_allclose(nav.iono_gps_beta, ref.iono_gps_beta, rtol=1e-3)
    assert nav.leap_seconds == 18
    return worst


@needs_walk
@pytest.mark.parametrize("name", ["rover-20181004-1532", "base-20181004-1452"])
def test_ephemerides_match_convbin_nav(name):
    worst = _eph_compare(name)
    assert worst["rel"] < 1e-10            # RINEX prints 12 significant digits
    assert worst["pos"] < 0.01 and worst["glo_pos"] < 0.01
    assert worst["clk"] < 1e-12


@needs_walk
def test_rover_log_speed():
    data = gzip.decompress((WALK / "rover-20181004-1532.ubx.gz").read_bytes())
    t0 = time.perf_counter()
    decode_ubx_bytes(data)
    assert time.perf_counter() - t0 < 3.0


def test_ubxlog_fields_are_documented():
    from georef_core.gnss.ubx import UbxLog

    names = {f.name for f in dataclasses.fields(UbxLog)}
    assert {"observations", "navigation", "event_gps_time_s", "warnings"} <= names


@needs_walk
def test_event_edge_reaches_the_solution_from_the_cli():
    """`georef gnss solve --event-edge rising` (GNSS setting event_edge): the camera events of a UBX rover
    are its rising TIM-TM2 edges; the default is the falling one."""
    from georef_core.cli.gnss_commands import options_from_args, register
    import argparse

    from georef_core.gnss.input_files import load_observations

    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="c"))
    args = parser.parse_args(["gnss", "solve", "r", "b", "--out", "x.pos", "--event-edge", "rising"])
    opts, _ = options_from_args(args)
    assert opts.ubx_event_edge == "rising"
    log = read_ubx(WALK / "rover-20181004-1532.ubx.gz")
    rising = load_observations(WALK / "rover-20181004-1532.ubx.gz", event_edge=opts.ubx_event_edge).observations
    np.testing.assert_array_equal(rising.event_gps_time_s, log.event_rising_gps_time_s)
    falling = load_observations(WALK / "rover-20181004-1532.ubx.gz").observations
    np.testing.assert_array_equal(falling.event_gps_time_s, log.event_falling_gps_time_s)
    from georef_core.steps.contract import get_spec

    assert get_spec("gnss").validate({"event_edge": "rising"}) == {"event_edge": "rising"}
