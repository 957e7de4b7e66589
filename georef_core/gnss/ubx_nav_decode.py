"""Broadcast navigation messages from u-blox UBX-RXM-SFRBX (0x02 0x13) into ``NavigationData``.

One ``SfrbxNavDecoder`` is fed every SFRBX payload of a log in stream order, each with a reference
time (gps_time_s of the nearest receiver epoch) used to resolve week numbers and GLONASS days.

Decoded:
  * GPS and QZSS LNAV (L1 C/A): subframes 1-3 -> ``KeplerEphemeris``; GPS subframe 4 page 18 ->
    Klobuchar alpha/beta and GPS-UTC leap seconds. Every word's parity is checked (IS-GPS-200
    20.3.5); u-blox delivers words with the data bits already un-inverted and D29*/D30* in bits 31/30.
  * GLONASS L1/L2 OF strings 1-4 (+ 5) -> ``GlonassEphemeris`` (Hamming code checked and single
    errors corrected, ICD GLONASS 5.1 section 4.7); fcn from the SFRBX freqId.
  * Galileo I/NAV (E1-B / E5b-I) word types 1-5 -> ``KeplerEphemeris`` (CRC-24Q checked) and the
    NeQuick ai0..ai2 coefficients.
  * BeiDou D1 (MEO/IGSO, B1I) subframes 1-3 -> ``KeplerEphemeris`` and BDS Klobuchar (subframe 1).
    D2 (GEO satellites) is not decoded.

All times are gps_time_s (continuous GPS seconds since 1980-01-06); Galileo GST is GPS time with
week offset 1024, BDT is GPS time - 14 s with week offset 1356, GLONASS time is UTC(SU) + 3 h.
"""

from __future__ import annotations

import math
import struct
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from .gnss_time import SECONDS_PER_WEEK, resolve_tow_near
from .navigation import GlonassEphemeris, KeplerEphemeris, NavigationData

SC2RAD = math.pi  # semicircles to radians (IS-GPS-200 uses pi = 3.1415926535898)
GST_WEEK_OFFSET = 1024   # GPS week of GST week 0 (1999-08-22)
BDT_WEEK_OFFSET = 1356   # GPS week of BDT week 0 (2006-01-01)
BDT_TO_GPST_S = 14.0     # GPST = BDT + 14 s
GLONASS_UTC_OFFSET_S = 10800.0  # GLONASS time = UTC(SU) + 3 h

# u-blox gnssId values
UBX_GNSS_GPS, UBX_GNSS_SBAS, UBX_GNSS_GAL, UBX_GNSS_BDS = 0, 1, 2, 3
UBX_GNSS_IMES, UBX_GNSS_QZSS, UBX_GNSS_GLO = 4, 5, 6

_LNAV_PREAMBLE = 0x8B
_BDS_PREAMBLE = 0x712


# --------------------------------------------------------------------------- bit helpers
def _u(value: int, total: int, pos: int, n: int) -> int:
    """Unsigned field of ``n`` bits starting ``pos`` bits from the MSB of a ``total``-bit integer."""
    return (value >> (total - pos - n)) & ((1 << n) - 1)


def _s(value: int, total: int, pos: int, n: int) -> int:
    """Two's-complement signed field (see ``_u``)."""
    v = _u(value, total, pos, n)
    return v - (1 << n) if v >> (n - 1) else v


def _sm(value: int, lo_bit: int, n: int) -> int:
    """Sign-magnitude field (GLONASS) of ``n`` bits whose least significant bit is ICD bit ``lo_bit``
    (bits numbered from 1 at the end of the string, as in the GLONASS ICD)."""
    v = (value >> (lo_bit - 1)) & ((1 << n) - 1)
    mag = v & ((1 << (n - 1)) - 1)
    return -mag if v >> (n - 1) else mag


def _gu(value: int, lo_bit: int, n: int) -> int:
    """Unsigned GLONASS field by ICD bit number of its least significant bit."""
    return (value >> (lo_bit - 1)) & ((1 << n) - 1)


# --------------------------------------------------------------------------- accuracy tables
def gps_ura_m(index: int) -> float:
    """Nominal URA (m) of a GPS/QZSS/BDS URA index (IS-GPS-200 20.3.3.3.1.3); 8192 when unknown (15)."""
    if index < 0 or index >= 15:
        return 8192.0
    if index <= 6:
        return {0: 2.0, 1: 2.8, 2: 4.0, 3: 5.7, 4: 8.0, 5: 11.3, 6: 16.0}[index]
    return float(2 ** (index - 2))


def galileo_sisa_m(index: int) -> float:
    """Galileo SISA (m) from its 8-bit index (Galileo OS SIS ICD 5.1.11); 6144 for NAPA / spare."""
    if index < 50:
        return index * 0.01
    if index < 75:
        return 0.5 + (index - 50) * 0.02
    if index < 100:
        return 1.0 + (index - 75) * 0.04
    if index < 126:
        return 2.0 + (index - 100) * 0.16
    return 6144.0


_GLONASS_FT_M = (1.0, 2.0, 2.5, 4.0, 5.0, 7.0, 10.0, 12.0, 14.0, 16.0, 32.0, 64.0, 128.0, 256.0, 512.0, 8192.0)


# --------------------------------------------------------------------------- GPS LNAV parity
def _lnav_parity(data24: int, d29: int, d30: int) -> int:
    """The six parity bits D25..D30 of a GPS LNAV word (IS-GPS-200 table 20-XIV) from its 24 source
    data bits d1..d24 (d1 = MSB) and the last two parity bits of the previous word."""
    par = 0
    for k, mask in enumerate(_LNAV_PARITY_MASKS):
        bit = (d29 if k in (0, 2, 5) else d30) ^ ((data24 & mask).bit_count() & 1)
        par = (par << 1) | bit
    return par


def _lnav_mask(bits: tuple[int, ...]) -> int:
    return sum(1 << (24 - b) for b in bits)


_LNAV_PARITY_MASKS = tuple(_lnav_mask(b) for b in (
    (1, 2, 3, 5, 6, 10, 11, 12, 13, 14, 17, 18, 20, 23),
    (2, 3, 4, 6, 7, 11, 12, 13, 14, 15, 18, 19, 21, 24),
    (1, 3, 4, 5, 7, 8, 12, 13, 14, 15, 16, 19, 20, 22),
    (2, 4, 5, 6, 8, 9, 13, 14, 15, 16, 17, 20, 21, 23),
    (1, 3, 5, 6, 7, 9, 10, 14, 15, 16, 17, 18, 21, 22, 24),
    (3, 5, 6, 8, 9, 10, 11, 13, 15, 19, 22, 23, 24),
))


def lnav_words_to_subframe(words: tuple[int, ...] | list[int]) -> int | None:
    """Ten SFRBX words of a GPS/QZSS L1 C/A subframe -> the 240 source data bits (parity removed),
    or None when the parity fails.

    u-blox delivers each 30-bit word in bits 29..0 with the data bits already corrected for D30*
    (so they are the source bits d1..d24) and D29*/D30* of the parity equations in bits 31/30.
    Streams that carry the words exactly as transmitted (data inverted when the previous word's
    D30 is 1, bits 31/30 unused) are accepted too.
    """
    # u-blox convention: every word is self-contained.
    out = 0
    ok = True
    for w in words:
        data = (w >> 6) & 0xFFFFFF
        if _lnav_parity(data, (w >> 31) & 1, (w >> 30) & 1) != (w & 0x3F):
            ok = False
            break
        out = (out << 24) | data
    if ok:
        return out
    # As transmitted (IS-GPS-200): D29*/D30* from the previous word; word 1 follows word 10 of the
    # previous subframe whose last two parity bits are 0 by design.
    out = 0
    d29 = d30 = 0
    for w in words:
        raw = (w >> 6) & 0xFFFFFF
        data = raw ^ 0xFFFFFF if d30 else raw
        if _lnav_parity(data, d29, d30) != (w & 0x3F):
            return None
        out = (out << 24) | data
        d29, d30 = (w >> 1) & 1, w & 1
    return out


# --------------------------------------------------------------------------- GLONASS Hamming
def _glonass_hamming_tables() -> tuple[list[int], dict[int, int]]:
    """Masks (over the 85-bit string, bit k of the ICD at integer bit k-1) of the check sums C1..C7,
    and the Hamming syndrome -> ICD bit number map used for single-error correction."""
    masks = [1 << j for j in range(7)]   # check bit beta_j (ICD bit j+1) belongs to C_{j+1}
    syndrome_to_bit: dict[int, int] = {}
    for c in range(3, 85):
        if c & (c - 1) == 0:
            continue
        k = c + 8 - math.ceil(math.log2(c))   # ICD bit number carried by Hamming position c
        syndrome_to_bit[c] = k
        for j in range(7):
            if c >> j & 1:
                masks[j] |= 1 << (k - 1)
    return masks, syndrome_to_bit


_GLO_HAMMING_MASKS, _GLO_SYNDROME_TO_BIT = _glonass_hamming_tables()
_GLO_ALL_BITS = (1 << 85) - 1


def glonass_check_string(string85: int) -> int | None:
    """Hamming check of an 85-bit GLONASS string (ICD bit k at integer bit k-1). Returns the string,
    corrected when it had a single error in a data bit, or None when uncorrectable."""
    syndrome = 0
    for j, mask in enumerate(_GLO_HAMMING_MASKS):
        syndrome |= ((string85 & mask).bit_count() & 1) << j
    total = (string85 & _GLO_ALL_BITS).bit_count() & 1
    if syndrome == 0 and total == 0:
        return string85
    n_set = syndrome.bit_count()
    if total == 1 and n_set == 1:
        return string85               # single error in a check bit: data are fine
    if total == 1 and n_set >= 2:
        k = _GLO_SYNDROME_TO_BIT.get(syndrome)
        if k is not None and 9 <= k <= 85:
            return string85 ^ (1 << (k - 1))
    return None


# --------------------------------------------------------------------------- Galileo CRC-24Q
def _crc24q_table() -> list[int]:
    table = []
    for i in range(256):
        c = i << 16
        for _ in range(8):
            c <<= 1
            if c & 0x1000000:
                c ^= 0x1864CFB
        table.append(c & 0xFFFFFF)
    return table


_CRC24Q_TABLE = _crc24q_table()


def crc24q(data: bytes) -> int:
    """CRC-24Q (polynomial 0x1864CFB, initial value 0) used by Galileo I/NAV and RTCM 3."""
    crc = 0
    for b in data:
        crc = ((crc << 8) & 0xFFFFFF) ^ _CRC24Q_TABLE[(crc >> 16) ^ b]
    return crc


# --------------------------------------------------------------------------- per-satellite state
@dataclass
class _LnavState:
    subframes: dict[int, tuple[int, float]] = field(default_factory=dict)  # id -> (240 bits, ref time)
    last_key: tuple | None = None


@dataclass
class _GloState:
    strings: dict[int, tuple[int, int, int, float]] = field(default_factory=dict)  # m -> (bits, superframe, frame, t)
    last_toe: float | None = None


@dataclass
class _GalState:
    words: dict[int, tuple[int, float]] = field(default_factory=dict)   # type -> (128 bits, ref time)
    last_key: tuple | None = None


@dataclass
class _BdsState:
    subframes: dict[int, tuple[int, float]] = field(default_factory=dict)  # id -> (224 info bits, ref time)
    last_key: tuple | None = None


def _sat_id(letter: str, prn: int) -> str:
    return f"{letter}{prn:02d}"


class SfrbxNavDecoder:
    """Stateful decoder of UBX-RXM-SFRBX payloads; call ``add`` in stream order, then ``result``."""

    def __init__(self, leap_seconds: int):
        self.leap_seconds = int(leap_seconds)   # GPS - UTC (s) used for GLONASS time conversion
        self.stats: Counter[str] = Counter()
        self._kepler: dict[str, list[KeplerEphemeris]] = {}
        self._glonass: dict[str, list[GlonassEphemeris]] = {}
        self._lnav: dict[str, _LnavState] = {}
        self._glo: dict[tuple[int, int], _GloState] = {}
        self._gal: dict[tuple[str, int], _GalState] = {}
        self._bds: dict[str, _BdsState] = {}
        self.iono_gps_alpha: np.ndarray | None = None
        self.iono_gps_beta: np.ndarray | None = None
        self.iono_gal: np.ndarray | None = None
        self.iono_bds_alpha: np.ndarray | None = None
        self.iono_bds_beta: np.ndarray | None = None
        self.nav_leap_seconds: int | None = None

    # ------------------------------------------------------------------ entry point
    def add(self, payload: bytes, ref_gps_s: float) -> None:
        """Decode one SFRBX payload (without the UBX header/checksum); ``ref_gps_s`` is the receiver
        time (gps_time_s) of the nearest measurement epoch, used to resolve weeks and days."""
        if len(payload) < 8:
            self.stats["sfrbx_short"] += 1
            return
        gnss, sv, sig, freq_id, n_words = payload[0], payload[1], payload[2], payload[3], payload[4]
        if len(payload) < 8 + 4 * n_words:
            self.stats["sfrbx_short"] += 1
            return
        words = struct.unpack_from(f"<{n_words}I", payload, 8)
        if gnss == UBX_GNSS_GPS or gnss == UBX_GNSS_QZSS:
            if sig != 0 or n_words != 10:      # L2C / L5 CNAV, QZSS L1S: not decoded
                self.stats["sfrbx_other_signal"] += 1
                return
            self._add_lnav("G" if gnss == UBX_GNSS_GPS else "J", sv, words, ref_gps_s)
        elif gnss == UBX_GNSS_GLO:
            if n_words < 4:
                self.stats["sfrbx_short"] += 1
                return
            self._add_glonass(sv, freq_id, words, ref_gps_s)
        elif gnss == UBX_GNSS_GAL:
            if n_words < 8:
                self.stats["sfrbx_other_signal"] += 1
                return
            self._add_galileo(sv, sig, words, ref_gps_s)
        elif gnss == UBX_GNSS_BDS:
            if n_words != 10 or sig not in (0, 1):   # B1I D1/D2 only
                self.stats["sfrbx_other_signal"] += 1
                return
            self._add_beidou(sv, words, ref_gps_s)
        else:
            self.stats["sfrbx_other_system"] += 1

    def result(self, source_path: str = "") -> NavigationData:
        nav = NavigationData(
            kepler={s: sorted(v, key=lambda e: e.toe_gps_s) for s, v in sorted(self._kepler.items())},
            glonass={s: sorted(v, key=lambda e: e.toe_gps_s) for s, v in sorted(self._glonass.items())},
            iono_gps_alpha=self.iono_gps_alpha, iono_gps_beta=self.iono_gps_beta, iono_gal=self.iono_gal,
            iono_bds_alpha=self.iono_bds_alpha, iono_bds_beta=self.iono_bds_beta,
            leap_seconds=self.nav_leap_seconds,
            source_paths=[source_path] if source_path else [])
        return nav

    # ------------------------------------------------------------------ GPS / QZSS LNAV
    def _add_lnav(self, letter: str, sv: int, words: tuple[int, ...], ref: float) -> None:
        if not (1 <= sv <= (32 if letter == "G" else 10)):
            self.stats["sfrbx_bad_svid"] += 1
            return
        if (words[0] >> 22) & 0xFF != _LNAV_PREAMBLE:
            self.stats["lnav_preamble_error"] += 1
            return
        bits = lnav_words_to_subframe(words)
        if bits is None:
            self.stats["lnav_parity_error"] += 1
            return
        sf_id = _u(bits, 240, 43, 3)
        if not 1 <= sf_id <= 5:
            self.stats["lnav_subframe_id_error"] += 1
            return
        self.stats["lnav_subframes"] += 1
        sat = _sat_id(letter, sv)
        if sf_id <= 3:
            st = self._lnav.setdefault(sat, _LnavState())
            st.subframes[sf_id] = (bits, ref)
            if len(st.subframes) == 3:
                self._try_lnav_ephemeris(sat, st)
        elif sf_id == 4 and letter == "G" and _u(bits, 240, 50, 6) == 56:
            self._decode_gps_page18(bits, ref)

    def _try_lnav_ephemeris(self, sat: str, st: _LnavState) -> None:
        (sf1, t1), (sf2, t2), (sf3, t3) = st.subframes[1], st.subframes[2], st.subframes[3]
        if max(t1, t2, t3) - min(t1, t2, t3) > 7200.0:
            return
        iodc = (_u(sf1, 240, 70, 2) << 8) | _u(sf1, 240, 168, 8)
        iode2 = _u(sf2, 240, 48, 8)
        iode3 = _u(sf3, 240, 216, 8)
        if iode2 != iode3 or iode2 != (iodc & 0xFF):
            return   # subframes of different issues: wait for a matching set
        tow1 = _u(sf1, 240, 24, 17) * 6.0
        wn10 = _u(sf1, 240, 48, 10)
        toc = _u(sf1, 240, 176, 16) * 16.0
        toe = _u(sf2, 240, 216, 16) * 16.0
        key = (iodc, iode2, toe, toc)
        if key == st.last_key:
            return
        # full week: the 10-bit week number closest to the reference time, then the transmit time
        ref_week = math.floor(t1 / SECONDS_PER_WEEK)
        week = wn10 + 1024 * round((ref_week - wn10) / 1024)
        ttr = resolve_tow_near(tow1, week * SECONDS_PER_WEEK + 302400.0)
        toe_gps = resolve_tow_near(toe, ttr)
        toc_gps = resolve_tow_near(toc, ttr)
        tgd_raw = _s(sf1, 240, 160, 8)
        fit_flag = _u(sf2, 240, 232, 1)
        is_gps = sat[0] == "G"
        eph = KeplerEphemeris(
            sat_id=sat, toe_gps_s=toe_gps, toc_gps_s=toc_gps,
            af0_s=_s(sf1, 240, 216, 22) * 2.0**-31,
            af1_s_s=_s(sf1, 240, 200, 16) * 2.0**-43,
            af2_s_s2=_s(sf1, 240, 192, 8) * 2.0**-55,
            sqrt_a=_u(sf2, 240, 184, 32) * 2.0**-19,
            e=_u(sf2, 240, 136, 32) * 2.0**-33,
            i0_rad=_s(sf3, 240, 112, 32) * 2.0**-31 * SC2RAD,
            omega0_rad=_s(sf3, 240, 64, 32) * 2.0**-31 * SC2RAD,
            omega_rad=_s(sf3, 240, 160, 32) * 2.0**-31 * SC2RAD,
            m0_rad=_s(sf2, 240, 88, 32) * 2.0**-31 * SC2RAD,
            delta_n_rad_s=_s(sf2, 240, 72, 16) * 2.0**-43 * SC2RAD,
            idot_rad_s=_s(sf3, 240, 224, 14) * 2.0**-43 * SC2RAD,
            omega_dot_rad_s=_s(sf3, 240, 192, 24) * 2.0**-43 * SC2RAD,
            cuc_rad=_s(sf2, 240, 120, 16) * 2.0**-29,
            cus_rad=_s(sf2, 240, 168, 16) * 2.0**-29,
            crc_m=_s(sf3, 240, 144, 16) * 2.0**-5,
            crs_m=_s(sf2, 240, 56, 16) * 2.0**-5,
            cic_rad=_s(sf3, 240, 48, 16) * 2.0**-29,
            cis_rad=_s(sf3, 240, 96, 16) * 2.0**-29,
            toe_sow_s=toe,
            week=int(math.floor(toe_gps / SECONDS_PER_WEEK)),
            iode=iode2, iodc=iodc,
            tgd_s=(0.0 if tgd_raw == -128 else tgd_raw * 2.0**-31, 0.0),
            accuracy_m=gps_ura_m(_u(sf1, 240, 60, 4)),
            health=_u(sf1, 240, 64, 6),
            fit_interval_h=(6.0 if fit_flag else 4.0) if is_gps else (4.0 if fit_flag else 2.0),
            transmit_gps_s=ttr,
            data_source=0)
        st.last_key = key
        self._kepler.setdefault(sat, []).append(eph)
        self.stats["ephemerides_" + sat[0]] += 1

    def _decode_gps_page18(self, bits: int, ref: float) -> None:
        self.iono_gps_alpha = np.array([
            _s(bits, 240, 56, 8) * 2.0**-30, _s(bits, 240, 64, 8) * 2.0**-27,
            _s(bits, 240, 72, 8) * 2.0**-24, _s(bits, 240, 80, 8) * 2.0**-24])
        self.iono_gps_beta = np.array([
            _s(bits, 240, 88, 8) * 2.0**11, _s(bits, 240, 96, 8) * 2.0**14,
            _s(bits, 240, 104, 8) * 2.0**16, _s(bits, 240, 112, 8) * 2.0**16])
        dt_ls = _s(bits, 240, 192, 8)
        wn_lsf8 = _u(bits, 240, 200, 8)
        dn = _u(bits, 240, 208, 8)
        dt_lsf = _s(bits, 240, 216, 8)
        # leap second in effect at the reference time (the future value once its date has passed)
        ref_week = math.floor(ref / SECONDS_PER_WEEK)
        wn_lsf = ref_week + ((wn_lsf8 - ref_week) % 256 + 128) % 256 - 128
        t_lsf = wn_lsf * SECONDS_PER_WEEK + dn * 86400.0
        self.nav_leap_seconds = dt_lsf if (dt_lsf != dt_ls and 1 <= dn <= 7 and ref >= t_lsf) else dt_ls
        self.stats["gps_iono_utc"] += 1

    # ------------------------------------------------------------------ GLONASS
    def _add_glonass(self, sv: int, freq_id: int, words: tuple[int, ...], ref: float) -> None:
        big = (words[0] << 96) | (words[1] << 64) | (words[2] << 32) | words[3]
        string = glonass_check_string(big >> 43)
        if string is None:
            self.stats["glonass_hamming_error"] += 1
            return
        m = _gu(string, 81, 4)
        superframe, frame = words[3] >> 16, words[3] & 0xFF
        self.stats["glonass_strings"] += 1
        if not 1 <= m <= 5:
            return
        st = self._glo.setdefault((sv, freq_id), _GloState())
        st.strings[m] = (string, superframe, frame, ref)
        if m == 5:
            return
        if not all(k in st.strings for k in (1, 2, 3, 4)):
            return
        parts = [st.strings[k] for k in (1, 2, 3, 4)]
        # Strings 1-4 repeat in every 30 s frame; like RTKLIB, those of different frames of one
        # superframe (2.5 min) are combined, but only within one 15-minute slot of the day, as the
        # immediate data (tb intervals of 30, 45 or 60 min) can only change at such a boundary.
        times = [p[3] for p in parts]
        if max(times) - min(times) > 150.0:
            return
        if parts[0][1] and len({p[1] for p in parts}) != 1:
            return
        if len({math.floor((t - self.leap_seconds) / 900.0) for t in times}) != 1:
            return
        self._decode_glonass(sv, freq_id, [p[0] for p in parts], ref)

    def _glonass_day_time(self, t_moscow_of_day_s: float, ref: float) -> float:
        """A Moscow time of day (s) turned into gps_time_s, taking the day closest to ``ref``."""
        ref_moscow = ref - self.leap_seconds + GLONASS_UTC_OFFSET_S
        day0 = math.floor(ref_moscow / 86400.0) * 86400.0
        t = day0 + t_moscow_of_day_s
        if t - ref_moscow > 43200.0:
            t -= 86400.0
        elif t - ref_moscow < -43200.0:
            t += 86400.0
        return t - GLONASS_UTC_OFFSET_S + self.leap_seconds

    def _decode_glonass(self, sv: int, freq_id: int, s: list[int], ref: float) -> None:
        s1, s2, s3, s4 = s
        slot = _gu(s4, 11, 5)
        prn = sv if 1 <= sv <= 32 else slot
        if not 1 <= prn <= 32:
            self.stats["glonass_bad_slot"] += 1
            return
        tb = _gu(s2, 70, 7)
        toe = self._glonass_day_time(tb * 900.0, ref)
        st = self._glo[(sv, freq_id)]
        if st.last_toe is not None and abs(st.last_toe - toe) < 1.0:
            return
        tk_s = _gu(s1, 72, 5) * 3600.0 + _gu(s1, 66, 6) * 60.0 + _gu(s1, 65, 1) * 30.0
        tof = self._glonass_day_time(tk_s, ref)
        km = 1000.0
        pos = np.array([_sm(s, 9, 27) for s in (s1, s2, s3)], dtype=float) * 2.0**-11 * km
        vel = np.array([_sm(s, 41, 24) for s in (s1, s2, s3)], dtype=float) * 2.0**-20 * km
        acc = np.array([_sm(s, 36, 5) for s in (s1, s2, s3)], dtype=float) * 2.0**-30 * km
        bn_msb = _gu(s2, 80, 1)
        ln = _gu(s3, 65, 1)
        fcn = freq_id - 7 if freq_id <= 13 else 0
        eph = GlonassEphemeris(
            sat_id=_sat_id("R", prn), toe_gps_s=toe, frame_time_gps_s=tof,
            position_ecef_m=pos, velocity_ecef_m_s=vel, acceleration_ecef_m_s2=acc,
            tau_n_s=_sm(s4, 59, 22) * 2.0**-30, gamma_n=_sm(s3, 69, 11) * 2.0**-40,
            fcn=fcn, health=(ln << 3) | bn_msb, age_days=_gu(s4, 49, 5),
            accuracy_m=_GLONASS_FT_M[_gu(s4, 30, 4)])
        st.last_toe = toe
        self._glonass.setdefault(eph.sat_id, []).append(eph)
        self.stats["ephemerides_R"] += 1

    # ------------------------------------------------------------------ Galileo I/NAV
    def _add_galileo(self, sv: int, sig: int, words: tuple[int, ...], ref: float) -> None:
        if not 1 <= sv <= 36:
            self.stats["sfrbx_bad_svid"] += 1
            return
        big = 0
        for w in words[:8]:
            big = (big << 32) | w
        even_odd_1, alert_1 = _u(big, 256, 0, 1), _u(big, 256, 1, 1)
        even_odd_2, alert_2 = _u(big, 256, 128, 1), _u(big, 256, 129, 1)
        if even_odd_1 != 0 or even_odd_2 != 1:
            self.stats["galileo_page_error"] += 1
            return
        if alert_1 or alert_2:
            return
        crc_bits = (_u(big, 256, 0, 114) << 82) | _u(big, 256, 128, 82)   # 196 bits
        if crc24q(crc_bits.to_bytes(25, "big")) != _u(big, 256, 210, 24):
            self.stats["galileo_crc_error"] += 1
            return
        word = (_u(big, 256, 2, 112) << 16) | _u(big, 256, 130, 16)   # 128-bit I/NAV word
        wtype = _u(word, 128, 0, 6)
        self.stats["galileo_words"] += 1
        if not 1 <= wtype <= 5:
            return
        sat = _sat_id("E", sv)
        signal = 1 if sig in (5, 6) else 0          # 0: E1-B, 1: E5b-I
        st = self._gal.setdefault((sat, signal), _GalState())
        st.words[wtype] = (word, ref)
        if wtype == 5:
            self.iono_gal = np.array([_u(word, 128, 6, 11) * 2.0**-2, _s(word, 128, 17, 11) * 2.0**-8,
                                      _s(word, 128, 28, 14) * 2.0**-15])
        if all(k in st.words for k in (1, 2, 3, 4, 5)):
            self._try_galileo_ephemeris(sat, signal, st)

    def _try_galileo_ephemeris(self, sat: str, signal: int, st: _GalState) -> None:
        w = {k: st.words[k][0] for k in range(1, 6)}
        times = [st.words[k][1] for k in range(1, 6)]
        if max(times) - min(times) > 7200.0:
            return
        iods = {_u(w[k], 128, 6, 10) for k in (1, 2, 3, 4)}
        if len(iods) != 1:
            return
        iod = iods.pop()
        if _u(w[4], 128, 16, 6) != int(sat[1:]):
            self.stats["galileo_svid_mismatch"] += 1
            return
        toe = _u(w[1], 128, 16, 14) * 60.0
        toc = _u(w[4], 128, 54, 14) * 60.0
        key = (iod, toe, toc)
        if key == st.last_key:
            return
        gst_week = _u(w[5], 128, 73, 12)
        tow = _u(w[5], 128, 85, 20)
        ref = max(times)
        ref_week = math.floor(ref / SECONDS_PER_WEEK)
        week = gst_week + GST_WEEK_OFFSET
        week += 4096 * round((ref_week - week) / 4096)         # 12-bit GST week roll-over
        ttr = week * SECONDS_PER_WEEK + tow
        toe_gps = resolve_tow_near(toe, ttr)
        toc_gps = resolve_tow_near(toc, ttr)
        e5b_hs, e1b_hs = _u(w[5], 128, 67, 2), _u(w[5], 128, 69, 2)
        e5b_dvs, e1b_dvs = _u(w[5], 128, 71, 1), _u(w[5], 128, 72, 1)
        eph = KeplerEphemeris(
            sat_id=sat, toe_gps_s=toe_gps, toc_gps_s=toc_gps,
            af0_s=_s(w[4], 128, 68, 31) * 2.0**-34,
            af1_s_s=_s(w[4], 128, 99, 21) * 2.0**-46,
            af2_s_s2=_s(w[4], 128, 120, 6) * 2.0**-59,
            sqrt_a=_u(w[1], 128, 94, 32) * 2.0**-19,
            e=_u(w[1], 128, 62, 32) * 2.0**-33,
            i0_rad=_s(w[2], 128, 48, 32) * 2.0**-31 * SC2RAD,
            omega0_rad=_s(w[2], 128, 16, 32) * 2.0**-31 * SC2RAD,
            omega_rad=_s(w[2], 128, 80, 32) * 2.0**-31 * SC2RAD,
            m0_rad=_s(w[1], 128, 30, 32) * 2.0**-31 * SC2RAD,
            delta_n_rad_s=_s(w[3], 128, 40, 16) * 2.0**-43 * SC2RAD,
            idot_rad_s=_s(w[2], 128, 112, 14) * 2.0**-43 * SC2RAD,
            omega_dot_rad_s=_s(w[3], 128, 16, 24) * 2.0**-43 * SC2RAD,
            cuc_rad=_s(w[3], 128, 56, 16) * 2.0**-29,
            cus_rad=_s(w[3], 128, 72, 16) * 2.0**-29,
            crc_m=_s(w[3], 128, 88, 16) * 2.0**-5,
            crs_m=_s(w[3], 128, 104, 16) * 2.0**-5,
            cic_rad=_s(w[4], 128, 22, 16) * 2.0**-29,
            cis_rad=_s(w[4], 128, 38, 16) * 2.0**-29,
            toe_sow_s=toe,
            week=int(math.floor(toe_gps / SECONDS_PER_WEEK)),
            iode=iod, iodc=iod,
            tgd_s=(_s(w[5], 128, 47, 10) * 2.0**-32, _s(w[5], 128, 57, 10) * 2.0**-32),
            accuracy_m=galileo_sisa_m(_u(w[3], 128, 120, 8)),
            health=(e5b_hs << 7) | (e5b_dvs << 6) | (e1b_hs << 1) | e1b_dvs,
            fit_interval_h=0.0,
            transmit_gps_s=ttr,
            data_source=(1 if signal == 0 else 4) | (1 << 9))   # I/NAV E1-B or E5b-I; af for E5b/E1
        st.last_key = key
        recs = self._kepler.setdefault(sat, [])
        if any(r.iode == iod and abs(r.toe_gps_s - toe_gps) < 1.0 for r in recs):
            return   # the same issue already decoded from the other I/NAV signal
        recs.append(eph)
        self.stats["ephemerides_E"] += 1

    # ------------------------------------------------------------------ BeiDou D1
    def _add_beidou(self, sv: int, words: tuple[int, ...], ref: float) -> None:
        if not 1 <= sv <= 63:
            self.stats["sfrbx_bad_svid"] += 1
            return
        # info bits without the BCH parity: word 1 carries 26, words 2-10 carry 22 each (224 bits)
        info = (words[0] >> 4) & 0x3FFFFFF
        for w in words[1:]:
            info = (info << 22) | ((w >> 8) & 0x3FFFFF)
        pre = _u(info, 224, 0, 11)
        if pre != _BDS_PREAMBLE:
            if pre == (~_BDS_PREAMBLE & 0x7FF):     # polarity not resolved: invert everything
                info ^= (1 << 224) - 1
            else:
                self.stats["bds_preamble_error"] += 1
                return
        if sv <= 5 or sv >= 59:
            self.stats["bds_d2_not_decoded"] += 1
            return
        sf_id = _u(info, 224, 15, 3)
        if not 1 <= sf_id <= 5:
            self.stats["bds_subframe_id_error"] += 1
            return
        self.stats["bds_subframes"] += 1
        if sf_id > 3:
            return
        sat = _sat_id("C", sv)
        st = self._bds.setdefault(sat, _BdsState())
        st.subframes[sf_id] = (info, ref)
        if sf_id == 1:
            self.iono_bds_alpha = np.array([
                _s(info, 224, 98, 8) * 2.0**-30, _s(info, 224, 106, 8) * 2.0**-27,
                _s(info, 224, 114, 8) * 2.0**-24, _s(info, 224, 122, 8) * 2.0**-24])
            self.iono_bds_beta = np.array([
                _s(info, 224, 130, 8) * 2.0**11, _s(info, 224, 138, 8) * 2.0**14,
                _s(info, 224, 146, 8) * 2.0**16, _s(info, 224, 154, 8) * 2.0**16])
        if len(st.subframes) == 3:
            self._try_beidou_ephemeris(sat, st)

    def _try_beidou_ephemeris(self, sat: str, st: _BdsState) -> None:
        f1, f2, f3 = (st.subframes[k][0] for k in (1, 2, 3))
        sow1, sow2, sow3 = (_u(f, 224, 18, 20) for f in (f1, f2, f3))
        if sow2 != sow1 + 6 or sow3 != sow2 + 6:
            return                       # not one frame
        toc = _u(f1, 224, 61, 17) * 8.0
        toe = ((_u(f2, 224, 222, 2) << 15) | _u(f3, 224, 38, 15)) * 8.0
        if toc != toe:
            return
        wn = _u(f1, 224, 48, 13)
        aode = _u(f1, 224, 219, 5)
        key = (toe, aode, wn)
        if key == st.last_key:
            return
        ttr = (wn + BDT_WEEK_OFFSET) * SECONDS_PER_WEEK + sow1 + BDT_TO_GPST_S
        toe_bdt = resolve_tow_near(toe, ttr - BDT_TO_GPST_S)   # BDT seconds since GPS epoch
        toe_gps = toe_bdt + BDT_TO_GPST_S
        eph = KeplerEphemeris(
            sat_id=sat, toe_gps_s=toe_gps, toc_gps_s=toe_gps,
            af0_s=_s(f1, 224, 173, 24) * 2.0**-33,
            af1_s_s=_s(f1, 224, 197, 22) * 2.0**-50,
            af2_s_s2=_s(f1, 224, 162, 11) * 2.0**-66,
            sqrt_a=_u(f2, 224, 190, 32) * 2.0**-19,
            e=_u(f2, 224, 104, 32) * 2.0**-33,
            i0_rad=_s(f3, 224, 53, 32) * 2.0**-31 * SC2RAD,
            omega0_rad=_s(f3, 224, 159, 32) * 2.0**-31 * SC2RAD,
            omega_rad=_s(f3, 224, 191, 32) * 2.0**-31 * SC2RAD,
            m0_rad=_s(f2, 224, 72, 32) * 2.0**-31 * SC2RAD,
            delta_n_rad_s=_s(f2, 224, 38, 16) * 2.0**-43 * SC2RAD,
            idot_rad_s=_s(f3, 224, 145, 14) * 2.0**-43 * SC2RAD,
            omega_dot_rad_s=_s(f3, 224, 103, 24) * 2.0**-43 * SC2RAD,
            cuc_rad=_s(f2, 224, 54, 18) * 2.0**-31,
            cus_rad=_s(f2, 224, 136, 18) * 2.0**-31,
            crc_m=_s(f2, 224, 154, 18) * 2.0**-6,
            crs_m=_s(f2, 224, 172, 18) * 2.0**-6,
            cic_rad=_s(f3, 224, 85, 18) * 2.0**-31,
            cis_rad=_s(f3, 224, 127, 18) * 2.0**-31,
            toe_sow_s=toe,
            week=int(math.floor(toe_bdt / SECONDS_PER_WEEK)) - BDT_WEEK_OFFSET,
            iode=aode, iodc=_u(f1, 224, 39, 5),
            tgd_s=(_s(f1, 224, 78, 10) * 1e-10, _s(f1, 224, 88, 10) * 1e-10),
            accuracy_m=gps_ura_m(_u(f1, 224, 44, 4)),
            health=_u(f1, 224, 38, 1),
            fit_interval_h=0.0,
            transmit_gps_s=ttr,
            data_source=0)
        st.last_key = key
        self._kepler.setdefault(sat, []).append(eph)
        self.stats["ephemerides_C"] += 1
