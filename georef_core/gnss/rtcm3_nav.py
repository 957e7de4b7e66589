"""Broadcast ephemerides from RTCM 3 messages into ``NavigationData`` (RTCM 10403.3 section 3.5.x):

* 1019 GPS and 1044 QZSS LNAV, 1042 BeiDou D1/D2, 1045 Galileo F/NAV, 1046 Galileo I/NAV ->
  ``KeplerEphemeris``;
* 1020 GLONASS -> ``GlonassEphemeris`` (frequency channel from DF040).

RTCM carries the navigation message's fields with their ICD scale factors and a week number (GPS and
QZSS: 10 bits; Galileo: 12-bit GST week; BeiDou: 13-bit BDT week; GLONASS: none). Every message is
dated by the stream time where it appears (the latest observation epoch before it): the broadcast
week is made whole in the cycle closest to that time and toe/toc are taken in that week (so a stale
record repeated by the receiver keeps its own date, as in RTKLIB), GLONASS tb and tk in the day
closest to the stream time, and the transmission time is that stream time (as RTKLIB does). Records
with an impossible orbit (placeholders such as an all-ones sqrt(A), seen in real DJI logs) are
dropped and named in the log's warnings. Ionosphere parameters are not part of these
messages: a stream-only PPK uses the base to remove the ionosphere (short baselines) or a navigation
file that carries them.
"""

from __future__ import annotations

import math

import numpy as np

from .gnss_time import SECONDS_PER_WEEK, resolve_tow_near
from .navigation import GlonassEphemeris, KeplerEphemeris, NavigationData
from .rtcm3 import BitReader
from .ubx_nav_decode import _GLONASS_FT_M, galileo_sisa_m, gps_ura_m

SC2RAD = math.pi
GST_WEEK_OFFSET = 1024
BDT_WEEK_OFFSET = 1356
BDT_TO_GPST_S = 14.0
GLONASS_UTC_OFFSET_S = 10800.0

# Galileo data source bits (RINEX 3 "data sources"): F/NAV E5a (1, 8), I/NAV E1-B + E5b-I (0, 2, 9)
GAL_FNAV_SOURCE = (1 << 1) | (1 << 8)
GAL_INAV_SOURCE = (1 << 0) | (1 << 2) | (1 << 9)


def ephemeris_week_time(msg_type: int, payload: bytes, now_gps_s: float) -> float | None:
    """The toe (gps_time_s) of an ephemeris message from its own week number; the 10-bit GPS/QZSS week
    is taken in the 1024-week cycle closest to ``now_gps_s``. None for a message without a week."""
    r = BitReader(payload)
    r.skip(12)
    if msg_type == 1019:
        r.skip(6)
        wn10 = r.u(10)
        r.skip(4 + 2 + 14 + 8 + 16 + 8 + 16 + 22 + 10 + 16 + 16 + 32 + 16 + 32 + 16 + 32)
        toe = r.u(16) * 16.0
        now_week = math.floor(now_gps_s / SECONDS_PER_WEEK)
        week = wn10 + 1024 * round((now_week - wn10) / 1024)
        if week > now_week + 1:
            week -= 1024
        return week * SECONDS_PER_WEEK + toe
    if msg_type == 1044:
        r.skip(4 + 16 + 8 + 16 + 22 + 8 + 16 + 16 + 32 + 16 + 32 + 16 + 32)
        toe = r.u(16) * 16.0
        r.skip(16 + 32 + 16 + 32 + 16 + 32 + 24 + 14 + 2)
        wn10 = r.u(10)
        now_week = math.floor(now_gps_s / SECONDS_PER_WEEK)
        week = wn10 + 1024 * round((now_week - wn10) / 1024)
        if week > now_week + 1:
            week -= 1024
        return week * SECONDS_PER_WEEK + toe
    if msg_type in (1045, 1046):
        r.skip(6)
        week = r.u(12) + GST_WEEK_OFFSET
        r.skip(10 + 8 + 14)
        toc = r.u(14) * 60.0
        return week * SECONDS_PER_WEEK + toc
    if msg_type == 1042:
        r.skip(6)
        week = r.u(13) + BDT_WEEK_OFFSET
        r.skip(4 + 14 + 5)
        toc = r.u(17) * 8.0
        return week * SECONDS_PER_WEEK + toc + BDT_TO_GPST_S
    return None


class Rtcm3NavDecoder:
    """Collects the ephemeris messages of a stream (each issue once) into ``NavigationData``."""

    def __init__(self, leap_seconds: int):
        self.leap_seconds = leap_seconds
        self._kepler: dict[tuple, KeplerEphemeris] = {}
        self._glonass: dict[tuple, GlonassEphemeris] = {}
        self.counts: dict[int, int] = {}
        self.rejected: list[str] = []     # records with an impossible orbit, named

    def add(self, msg_type: int, payload: bytes, stream_gps_s: float) -> None:
        """Decode one ephemeris message dated by the stream time where it appears."""
        r = BitReader(payload)
        r.skip(12)
        if msg_type == 1019:
            eph = _gps_1019(r, stream_gps_s)
        elif msg_type == 1044:
            eph = _qzss_1044(r, stream_gps_s)
        elif msg_type in (1045, 1046):
            eph = _galileo_1045_1046(r, msg_type, stream_gps_s)
        elif msg_type == 1042:
            eph = _beidou_1042(r, stream_gps_s)
        elif msg_type == 1020:
            geph = _glonass_1020(r, stream_gps_s, self.leap_seconds)
            if geph is not None:
                self._glonass.setdefault((geph.sat_id, round(geph.toe_gps_s)), geph)
                self.counts[msg_type] = self.counts.get(msg_type, 0) + 1
            return
        else:
            return
        if eph is None:
            return
        if not plausible_orbit(eph):
            self.rejected.append(f"{eph.sat_id} (message {msg_type}, sqrt(A) {eph.sqrt_a:.3f}, e {eph.e:.4f})")
            return
        self._kepler.setdefault((eph.sat_id, round(eph.toe_gps_s), eph.iode, eph.data_source), eph)
        self.counts[msg_type] = self.counts.get(msg_type, 0) + 1

    def result(self, source_path: str = "") -> NavigationData:
        kepler: dict[str, list[KeplerEphemeris]] = {}
        for eph in self._kepler.values():
            kepler.setdefault(eph.sat_id, []).append(eph)
        glonass: dict[str, list[GlonassEphemeris]] = {}
        for geph in self._glonass.values():
            glonass.setdefault(geph.sat_id, []).append(geph)
        return NavigationData(
            kepler={s: sorted(v, key=lambda e: e.toe_gps_s) for s, v in sorted(kepler.items())},
            glonass={s: sorted(v, key=lambda e: e.toe_gps_s) for s, v in sorted(glonass.items())},
            source_paths=[source_path] if source_path else [])


# ----------------------------------------------------------------------------------------------- messages
def _week_near(week_field: int, cycle: int, near_gps_s: float) -> int:
    """A week number broadcast modulo ``cycle`` made whole, in the cycle closest to a time."""
    near_week = math.floor(near_gps_s / SECONDS_PER_WEEK)
    return week_field + cycle * round((near_week - week_field) / cycle)


def _in_message_week(toe_sow_s: float, week: int, stream_gps_s: float) -> float:
    """toe (or toc) in the message's own week: a stale record keeps its date (RTKLIB does the same),
    and a toe of the next week sent just before the roll-over is taken across it."""
    sow_now = stream_gps_s - math.floor(stream_gps_s / SECONDS_PER_WEEK) * SECONDS_PER_WEEK
    return resolve_tow_near(toe_sow_s, week * SECONDS_PER_WEEK + sow_now)


def plausible_orbit(eph: KeplerEphemeris) -> bool:
    """A semi-major axis of a GNSS orbit (MEO 25,500-30,000 km, IGSO/GEO about 42,164 km) and a small
    eccentricity; streams do carry placeholder records (e.g. all-ones sqrt(A)) that no filter should use."""
    a_m = eph.sqrt_a**2
    return 2.5e7 <= a_m <= 4.5e7 and 0.0 <= eph.e < 0.1

def _gps_1019(r: BitReader, stream_gps_s: float) -> KeplerEphemeris | None:
    prn = r.u(6)
    wn10 = r.u(10)
    ura = r.u(4)
    r.skip(2)                                    # code on L2
    idot = r.s(14) * 2.0**-43 * SC2RAD
    iode = r.u(8)
    toc = r.u(16) * 16.0
    af2 = r.s(8) * 2.0**-55
    af1 = r.s(16) * 2.0**-43
    af0 = r.s(22) * 2.0**-31
    iodc = r.u(10)
    crs = r.s(16) * 2.0**-5
    dn = r.s(16) * 2.0**-43 * SC2RAD
    m0 = r.s(32) * 2.0**-31 * SC2RAD
    cuc = r.s(16) * 2.0**-29
    e = r.u(32) * 2.0**-33
    cus = r.s(16) * 2.0**-29
    sqrt_a = r.u(32) * 2.0**-19
    toe = r.u(16) * 16.0
    cic = r.s(16) * 2.0**-29
    omega0 = r.s(32) * 2.0**-31 * SC2RAD
    cis = r.s(16) * 2.0**-29
    i0 = r.s(32) * 2.0**-31 * SC2RAD
    crc = r.s(16) * 2.0**-5
    omega = r.s(32) * 2.0**-31 * SC2RAD
    omega_dot = r.s(24) * 2.0**-43 * SC2RAD
    tgd = r.s(8) * 2.0**-31
    health = r.u(6)
    r.skip(1)                                    # L2 P data flag
    fit = r.u(1)
    if not 1 <= prn <= 32:
        return None
    toe_gps = _in_message_week(toe, _week_near(wn10, 1024, stream_gps_s), stream_gps_s)
    toc_gps = resolve_tow_near(toc, toe_gps)
    return KeplerEphemeris(
        sat_id=f"G{prn:02d}", toe_gps_s=toe_gps, toc_gps_s=toc_gps, af0_s=af0, af1_s_s=af1, af2_s_s2=af2,
        sqrt_a=sqrt_a, e=e, i0_rad=i0, omega0_rad=omega0, omega_rad=omega, m0_rad=m0, delta_n_rad_s=dn,
        idot_rad_s=idot, omega_dot_rad_s=omega_dot, cuc_rad=cuc, cus_rad=cus, crc_m=crc, crs_m=crs, cic_rad=cic,
        cis_rad=cis, toe_sow_s=toe, week=int(math.floor(toe_gps / SECONDS_PER_WEEK)), iode=iode, iodc=iodc,
        tgd_s=(tgd, 0.0), accuracy_m=gps_ura_m(ura), health=health, fit_interval_h=6.0 if fit else 4.0,
        transmit_gps_s=stream_gps_s, data_source=0)


def _qzss_1044(r: BitReader, stream_gps_s: float) -> KeplerEphemeris | None:
    prn = r.u(4)
    toc = r.u(16) * 16.0
    af2 = r.s(8) * 2.0**-55
    af1 = r.s(16) * 2.0**-43
    af0 = r.s(22) * 2.0**-31
    iode = r.u(8)
    crs = r.s(16) * 2.0**-5
    dn = r.s(16) * 2.0**-43 * SC2RAD
    m0 = r.s(32) * 2.0**-31 * SC2RAD
    cuc = r.s(16) * 2.0**-29
    e = r.u(32) * 2.0**-33
    cus = r.s(16) * 2.0**-29
    sqrt_a = r.u(32) * 2.0**-19
    toe = r.u(16) * 16.0
    cic = r.s(16) * 2.0**-29
    omega0 = r.s(32) * 2.0**-31 * SC2RAD
    cis = r.s(16) * 2.0**-29
    i0 = r.s(32) * 2.0**-31 * SC2RAD
    crc = r.s(16) * 2.0**-5
    omega = r.s(32) * 2.0**-31 * SC2RAD
    omega_dot = r.s(24) * 2.0**-43 * SC2RAD
    idot = r.s(14) * 2.0**-43 * SC2RAD
    r.skip(2)                                    # codes on L2
    wn10 = r.u(10)
    ura = r.u(4)
    health = r.u(6)
    tgd = r.s(8) * 2.0**-31
    iodc = r.u(10)
    fit = r.u(1)
    if not 1 <= prn <= 10:
        return None
    toe_gps = _in_message_week(toe, _week_near(wn10, 1024, stream_gps_s), stream_gps_s)
    toc_gps = resolve_tow_near(toc, toe_gps)
    return KeplerEphemeris(
        sat_id=f"J{prn:02d}", toe_gps_s=toe_gps, toc_gps_s=toc_gps, af0_s=af0, af1_s_s=af1, af2_s_s2=af2,
        sqrt_a=sqrt_a, e=e, i0_rad=i0, omega0_rad=omega0, omega_rad=omega, m0_rad=m0, delta_n_rad_s=dn,
        idot_rad_s=idot, omega_dot_rad_s=omega_dot, cuc_rad=cuc, cus_rad=cus, crc_m=crc, crs_m=crs, cic_rad=cic,
        cis_rad=cis, toe_sow_s=toe, week=int(math.floor(toe_gps / SECONDS_PER_WEEK)), iode=iode, iodc=iodc,
        tgd_s=(tgd, 0.0), accuracy_m=gps_ura_m(ura), health=health, fit_interval_h=4.0 if fit else 2.0,
        transmit_gps_s=stream_gps_s, data_source=0)


def _galileo_1045_1046(r: BitReader, msg_type: int, stream_gps_s: float) -> KeplerEphemeris | None:
    prn = r.u(6)
    gst_week = r.u(12)
    iod = r.u(10)
    sisa = r.u(8)
    idot = r.s(14) * 2.0**-43 * SC2RAD
    toc = r.u(14) * 60.0
    af2 = r.s(6) * 2.0**-59
    af1 = r.s(21) * 2.0**-46
    af0 = r.s(31) * 2.0**-34
    crs = r.s(16) * 2.0**-5
    dn = r.s(16) * 2.0**-43 * SC2RAD
    m0 = r.s(32) * 2.0**-31 * SC2RAD
    cuc = r.s(16) * 2.0**-29
    e = r.u(32) * 2.0**-33
    cus = r.s(16) * 2.0**-29
    sqrt_a = r.u(32) * 2.0**-19
    toe = r.u(14) * 60.0
    cic = r.s(16) * 2.0**-29
    omega0 = r.s(32) * 2.0**-31 * SC2RAD
    cis = r.s(16) * 2.0**-29
    i0 = r.s(32) * 2.0**-31 * SC2RAD
    crc = r.s(16) * 2.0**-5
    omega = r.s(32) * 2.0**-31 * SC2RAD
    omega_dot = r.s(24) * 2.0**-43 * SC2RAD
    bgd_e5a = r.s(10) * 2.0**-32
    if msg_type == 1045:
        e5a_hs, e5a_dvs = r.u(2), r.u(1)
        health = (e5a_hs << 4) | (e5a_dvs << 3)
        tgd = (bgd_e5a, 0.0)
        source = GAL_FNAV_SOURCE
    else:
        bgd_e5b = r.s(10) * 2.0**-32
        e5b_hs, e5b_dvs, e1b_hs, e1b_dvs = r.u(2), r.u(1), r.u(2), r.u(1)
        health = (e5b_hs << 7) | (e5b_dvs << 6) | (e1b_hs << 1) | e1b_dvs
        tgd = (bgd_e5a, bgd_e5b)
        source = GAL_INAV_SOURCE
    if not 1 <= prn <= 36:
        return None
    week = _week_near(gst_week + GST_WEEK_OFFSET, 4096, stream_gps_s)
    toe_gps = _in_message_week(toe, week, stream_gps_s)
    toc_gps = resolve_tow_near(toc, toe_gps)
    return KeplerEphemeris(
        sat_id=f"E{prn:02d}", toe_gps_s=toe_gps, toc_gps_s=toc_gps, af0_s=af0, af1_s_s=af1, af2_s_s2=af2,
        sqrt_a=sqrt_a, e=e, i0_rad=i0, omega0_rad=omega0, omega_rad=omega, m0_rad=m0, delta_n_rad_s=dn,
        idot_rad_s=idot, omega_dot_rad_s=omega_dot, cuc_rad=cuc, cus_rad=cus, crc_m=crc, crs_m=crs, cic_rad=cic,
        cis_rad=cis, toe_sow_s=toe, week=int(math.floor(toe_gps / SECONDS_PER_WEEK)), iode=iod, iodc=iod,
        tgd_s=tgd, accuracy_m=galileo_sisa_m(sisa), health=health, fit_interval_h=0.0,
        transmit_gps_s=stream_gps_s, data_source=source)


def _beidou_1042(r: BitReader, stream_gps_s: float) -> KeplerEphemeris | None:
    prn = r.u(6)
    bdt_week = r.u(13)
    urai = r.u(4)
    idot = r.s(14) * 2.0**-43 * SC2RAD
    aode = r.u(5)
    toc = r.u(17) * 8.0
    a2 = r.s(11) * 2.0**-66
    a1 = r.s(22) * 2.0**-50
    a0 = r.s(24) * 2.0**-33
    aodc = r.u(5)
    crs = r.s(18) * 2.0**-6
    dn = r.s(16) * 2.0**-43 * SC2RAD
    m0 = r.s(32) * 2.0**-31 * SC2RAD
    cuc = r.s(18) * 2.0**-31
    e = r.u(32) * 2.0**-33
    cus = r.s(18) * 2.0**-31
    sqrt_a = r.u(32) * 2.0**-19
    toe = r.u(17) * 8.0
    cic = r.s(18) * 2.0**-31
    omega0 = r.s(32) * 2.0**-31 * SC2RAD
    cis = r.s(18) * 2.0**-31
    i0 = r.s(32) * 2.0**-31 * SC2RAD
    crc = r.s(18) * 2.0**-6
    omega = r.s(32) * 2.0**-31 * SC2RAD
    omega_dot = r.s(24) * 2.0**-43 * SC2RAD
    tgd1 = r.s(10) * 1e-10
    tgd2 = r.s(10) * 1e-10
    health = r.u(1)
    if not 1 <= prn <= 63:
        return None
    week = _week_near(bdt_week + BDT_WEEK_OFFSET, 8192, stream_gps_s)
    toe_bdt = _in_message_week(toe, week, stream_gps_s - BDT_TO_GPST_S)
    toc_bdt = resolve_tow_near(toc, toe_bdt)
    toe_gps = toe_bdt + BDT_TO_GPST_S
    return KeplerEphemeris(
        sat_id=f"C{prn:02d}", toe_gps_s=toe_gps, toc_gps_s=toc_bdt + BDT_TO_GPST_S, af0_s=a0, af1_s_s=a1,
        af2_s_s2=a2, sqrt_a=sqrt_a, e=e, i0_rad=i0, omega0_rad=omega0, omega_rad=omega, m0_rad=m0, delta_n_rad_s=dn,
        idot_rad_s=idot, omega_dot_rad_s=omega_dot, cuc_rad=cuc, cus_rad=cus, crc_m=crc, crs_m=crs, cic_rad=cic,
        cis_rad=cis, toe_sow_s=toe, week=int(math.floor(toe_bdt / SECONDS_PER_WEEK)) - BDT_WEEK_OFFSET,
        iode=aode, iodc=aodc, tgd_s=(tgd1, tgd2), accuracy_m=gps_ura_m(urai), health=health, fit_interval_h=0.0,
        transmit_gps_s=stream_gps_s, data_source=0)


def _glonass_day_time(t_moscow_of_day_s: float, ref_gps_s: float, leap_s: int) -> float:
    """A Moscow time of day turned into gps_time_s, on the day closest to ``ref_gps_s``."""
    ref_moscow = ref_gps_s - leap_s + GLONASS_UTC_OFFSET_S
    t = math.floor(ref_moscow / 86400.0) * 86400.0 + t_moscow_of_day_s
    if t - ref_moscow > 43200.0:
        t -= 86400.0
    elif t - ref_moscow < -43200.0:
        t += 86400.0
    return t - GLONASS_UTC_OFFSET_S + leap_s


def _glonass_1020(r: BitReader, stream_gps_s: float, leap_s: int) -> GlonassEphemeris | None:
    slot = r.u(6)
    fcn_field = r.u(5)
    r.skip(1 + 1 + 2)                            # almanac health, health availability, P1
    tk_h, tk_m, tk_30 = r.u(5), r.u(6), r.u(1)
    bn_msb = r.u(1)
    r.skip(1)                                    # P2
    tb = r.u(7)
    km = 1000.0
    vel, pos, acc = np.zeros(3), np.zeros(3), np.zeros(3)
    for k in range(3):
        vel[k] = r.sm(24) * 2.0**-20 * km
        pos[k] = r.sm(27) * 2.0**-11 * km
        acc[k] = r.sm(5) * 2.0**-30 * km
    r.skip(1)                                    # P3
    gamma = r.sm(11) * 2.0**-40
    r.skip(2)                                    # P
    ln = r.u(1)
    tau = r.sm(22) * 2.0**-30
    r.skip(5)                                    # delta tau_n
    age = r.u(5)
    r.skip(1)                                    # P4
    ft = r.u(4)
    if not 1 <= slot <= 24 or fcn_field > 13:
        return None
    toe = _glonass_day_time(tb * 900.0, stream_gps_s, leap_s)
    tof = _glonass_day_time(tk_h * 3600.0 + tk_m * 60.0 + tk_30 * 30.0, stream_gps_s, leap_s)
    return GlonassEphemeris(
        sat_id=f"R{slot:02d}", toe_gps_s=toe, frame_time_gps_s=tof, position_ecef_m=pos, velocity_ecef_m_s=vel,
        acceleration_ecef_m_s2=acc, tau_n_s=tau, gamma_n=gamma, fcn=fcn_field - 7, health=(ln << 3) | bn_msb,
        age_days=age, accuracy_m=_GLONASS_FT_M[ft])
