"""Atmospheric delay models applied to observations, chosen by the options (troposphere, ionosphere)."""

from __future__ import annotations

import numpy as np

from .atmosphere import klobuchar_delay_m, modified_hopfield_slant, saastamoinen_zenith_and_slant, tropo_variance_m2
from .constants import CLIGHT_M_S, FREQ_HZ
from .navigation import NavigationData

L1_HZ = FREQ_HZ["G"][0]


def troposphere_delay_m(model: str, lat_rad, h_m, el_rad, humidity: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """Slant tropospheric delay (m) and its variance (m^2) for the chosen model. ``humidity`` (0..1) sets the
    standard atmosphere's water vapour; 0 gives the hydrostatic delay alone."""
    el = np.asarray(el_rad, dtype=float)
    if model == "off":
        return np.zeros_like(el), np.full_like(el, 9.0)  # ~3 m uncertainty when uncorrected
    lat_b, h_b, el_b = np.broadcast_arrays(np.asarray(lat_rad, float), np.asarray(h_m, float), el)
    if model == "hopfield":
        delay = modified_hopfield_slant(h_b, el_b, humidity=humidity)
    else:
        delay = saastamoinen_zenith_and_slant(lat_b, h_b, el_b, humidity=humidity)
    return np.asarray(delay, dtype=float), np.asarray(tropo_variance_m2(el_b), dtype=float)


def ionosphere_delay_m(model: str, nav: NavigationData, gps_time_s, lat_rad, lon_rad, az_rad, el_rad,
                       wavelength_m) -> tuple[np.ndarray, np.ndarray]:
    """Code ionospheric delay (m, positive; the phase advance is its negative) and variance (m^2)
    at each signal's frequency, from the GPS broadcast Klobuchar model."""
    el = np.asarray(el_rad, dtype=float)
    if model == "off":
        return np.zeros_like(el), np.full_like(el, 25.0)
    t, lat, lon, az, el_b = np.broadcast_arrays(np.asarray(gps_time_s, float), np.asarray(lat_rad, float),
                                                np.asarray(lon_rad, float), np.asarray(az_rad, float), el)
    l1 = np.asarray(klobuchar_delay_m(t, lat, lon, az, el_b, nav.iono_gps_alpha, nav.iono_gps_beta, L1_HZ), dtype=float)
    freq = CLIGHT_M_S / np.asarray(wavelength_m, dtype=float)
    delay = l1 * (L1_HZ / freq) ** 2
    return delay, (0.5 * delay) ** 2
