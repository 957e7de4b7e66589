"""Physical constants, GNSS systems, carrier frequencies and the band convention.

Band convention (the same as RTKLIB demo5, so configurations carry over):
  band 0: GPS L1, GLONASS G1, Galileo E1, QZSS L1, BeiDou B1I (RINEX '2')
  band 1: GPS L2, GLONASS G2, Galileo E5b (RINEX '7'), QZSS L2, BeiDou B2I/B2b (RINEX '7')
  band 2: GPS L5, GLONASS G3, Galileo E5a (RINEX '5'), QZSS L5, BeiDou B3 (RINEX '6')
"""

from __future__ import annotations

CLIGHT_M_S = 299792458.0
OMEGA_EARTH_RAD_S = 7.2921151467e-5  # WGS84 / GPS ICD
WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)

GM_GPS_M3_S2 = 3.9860050e14
GM_GAL_M3_S2 = 3.986004418e14
GM_BDS_M3_S2 = 3.986004418e14
GM_GLO_M3_S2 = 3.9860044e14
OMEGA_EARTH_BDS_RAD_S = 7.292115e-5
OMEGA_EARTH_GLO_RAD_S = 7.292115e-5
GLO_A_M = 6378136.0
GLO_J2 = 1.0826257e-3

# Systems by their RINEX letter, and RTKLIB navsys bit masks.
SYSTEMS = ("G", "R", "E", "J", "C")
NAVSYS_BITS = {"G": 1, "S": 2, "R": 4, "E": 8, "J": 16, "C": 32, "I": 64}
SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "J": "QZSS", "C": "BeiDou", "S": "SBAS", "I": "NavIC"}

N_BANDS = 3

# Frequencies (Hz) per system and band; GLONASS FDMA: base + k * step.
FREQ_HZ = {
    "G": (1575.42e6, 1227.60e6, 1176.45e6),
    "J": (1575.42e6, 1227.60e6, 1176.45e6),
    "E": (1575.42e6, 1207.14e6, 1176.45e6),
    "C": (1561.098e6, 1207.14e6, 1268.52e6),
}
GLO_BASE_HZ = (1602.0e6, 1246.0e6, 1202.025e6)
GLO_STEP_HZ = (0.5625e6, 0.4375e6, 0.0)

# RINEX 3 frequency digit -> band index, per system.
RINEX_DIGIT_TO_BAND = {
    "G": {"1": 0, "2": 1, "5": 2},
    "R": {"1": 0, "2": 1, "3": 2},
    "E": {"1": 0, "7": 1, "5": 2},
    "J": {"1": 0, "2": 1, "5": 2},
    "C": {"2": 0, "1": 0, "7": 1, "6": 2},
}

# Tracking-code priority per system and band (first found wins), as RINEX attribute letters.
CODE_PRIORITY = {
    "G": ("CSLXPWYM", "PYWCMNDLSX", "IQX"),
    "R": ("CP", "PC", "IQX"),
    "E": ("CBXAZ", "IQX", "IQX"),
    "J": ("CSLXZ", "LXS", "IQX"),
    "C": ("IQX", "IQXDPZ", "IQX"),
}


def carrier_frequency_hz(sat_id: str, band: int, glonass_fcn: int | None = None) -> float:
    """Carrier frequency of a satellite's band; GLONASS needs its frequency channel number."""
    sys = sat_id[0]
    if sys == "R":
        if glonass_fcn is None:
            return float("nan")
        return GLO_BASE_HZ[band] + glonass_fcn * GLO_STEP_HZ[band]
    if sys == "C" and band == 0 and int(sat_id[1:]) <= 0:
        return float("nan")
    table = FREQ_HZ.get(sys)
    return float("nan") if table is None else table[band]


def wavelength_table_m(sat_ids: list[str], glonass_fcn: dict[str, int], n_bands: int = N_BANDS):
    """(S, n_bands) carrier wavelengths in metres; NaN where unknown (GLONASS without FCN, absent band)."""
    import numpy as np

    out = np.full((len(sat_ids), n_bands), np.nan)
    for i, sat in enumerate(sat_ids):
        for b in range(n_bands):
            f = carrier_frequency_hz(sat, b, glonass_fcn.get(sat))
            if f == f and f > 0:
                out[i, b] = CLIGHT_M_S / f
    return out
