"""Scalar compiled (numba) versions of the models of frames.py and atmosphere.py, for per-epoch compiled code
(spp_kernels.py): ECEF -> geodetic, azimuth/elevation, Saastamoinen and modified Hopfield slant delays with
RTKLIB's standard atmosphere, the troposphere variance and the broadcast (Klobuchar) ionosphere. Same
formulas, same order of operations; tests/gnss/test_spp_kernels.py checks them against the vectorised ones."""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

from .atmosphere import ERR_SAAS_M, GPS_L1_HZ, TROPO_MAX_HEIGHT_M, TROPO_MIN_HEIGHT_M
from .constants import CLIGHT_M_S, WGS84_A_M, WGS84_E2

TROPO_OFF, TROPO_SAASTAMOINEN, TROPO_HOPFIELD = 0, 1, 2
TROPO_MODELS = {"off": TROPO_OFF, "saastamoinen": TROPO_SAASTAMOINEN, "hopfield": TROPO_HOPFIELD}
TROPO_OFF_VARIANCE_M2 = 9.0     # corrections.troposphere_delay_m with model "off"
IONO_OFF_VARIANCE_M2 = 25.0     # corrections.ionosphere_delay_m with model "off"


@njit(cache=True)
def geodetic(x, y, z):
    """ECEF (m) -> (lat rad, lon rad, h m), frames.ecef_to_geodetic."""
    r2 = x * x + y * y
    zk = z
    v = WGS84_A_M
    for _ in range(10):
        sinp = zk / np.sqrt(r2 + zk * zk)
        v = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sinp * sinp)
        zk = z + v * WGS84_E2 * sinp
    if r2 > 1e-12:
        lat = np.arctan(zk / np.sqrt(max(r2, 1e-300)))
        lon = np.arctan2(y, x)
    else:
        lat = np.pi / 2 if z > 0 else -np.pi / 2
        lon = 0.0
    return lat, lon, np.sqrt(r2 + zk * zk) - v


@njit(cache=True)
def enu_basis(lat, lon):
    """(sin lat, cos lat, sin lon, cos lon) of a receiver, for azimuth_elevation."""
    return np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)


@njit(cache=True)
def azimuth_elevation(basis, los):
    """Azimuth and elevation (rad) of the unit vector los (3,) seen at a receiver (enu_basis of its latitude and
    longitude), frames.azimuth_elevation_batch."""
    sl, cl, so, co = basis
    x, y, z = los[0], los[1], los[2]
    east = -so * x + co * y
    north = -sl * co * x - sl * so * y + cl * z
    up = cl * co * x + cl * so * y + sl * z
    return np.arctan2(east, north) % (2 * np.pi), np.arcsin(min(max(up, -1.0), 1.0))


@njit(cache=True)
def _standard_atmosphere(h, humidity):
    hgt = max(h, 0.0)
    pressure = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temperature = 15.0 - 6.5e-3 * hgt + 273.16
    e = 6.108 * humidity * np.exp((17.15 * temperature - 4684.0) / (temperature - 38.45))
    return pressure, temperature, e


@njit(cache=True)
def _saastamoinen_zenith(lat, h, humidity):
    """Zenith hydrostatic + wet delay (m), atmosphere.saastamoinen_zenith_m with the standard atmosphere."""
    p, t, e = _standard_atmosphere(h, humidity)
    hgt = max(h, 0.0)
    zhd = 0.0022768 * p / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hgt / 1e3)
    zwd = 0.002277 * (1255.0 / t + 0.05) * e
    return zhd + zwd


@njit(cache=True)
def _hopfield_layer(refractivity, layer_height_m, sin_el, cos2_el, radius_m):
    r = np.sqrt((radius_m + layer_height_m) ** 2 - radius_m**2 * cos2_el) - radius_m * sin_el
    a = -sin_el / layer_height_m
    b = -cos2_el / (2.0 * layer_height_m * radius_m)
    a2 = a * a
    coeffs = (1.0, 4.0 * a, 6.0 * a2 + 4.0 * b, 4.0 * a * (a2 + 3.0 * b), a2 * a2 + 12.0 * a2 * b + 6.0 * b * b,
              4.0 * a * b * (a2 + 3.0 * b), b * b * (6.0 * a2 + 4.0 * b), 4.0 * a * b**3, b**4)
    total = 0.0
    rk = 1.0
    k = 1
    for alpha in coeffs:
        rk = rk * r
        total = total + alpha * rk / k
        k += 1
    return 1e-6 * refractivity * total


@njit(cache=True)
def _hopfield_slant(met, h, el):
    """atmosphere.modified_hopfield_slant; met = (dry refractivity, wet refractivity, dry layer height)."""
    n_dry, n_wet, h_dry = met
    sin_el = np.sin(el)
    cos2_el = 1.0 - sin_el * sin_el
    radius = WGS84_A_M + max(h, 0.0)
    return _hopfield_layer(n_dry, h_dry, sin_el, cos2_el, radius) + _hopfield_layer(n_wet, 11000.0, sin_el, cos2_el,
                                                                                     radius)


@njit(cache=True)
def troposphere_zenith(model, lat, h, humidity):
    """The receiver's part of the troposphere model, shared by its satellites: Saastamoinen (zenith delay, 0,
    0), modified Hopfield (dry and wet surface refractivities, dry layer height); NaN outside the models'
    height range [-100 m, 10 km] (delay 0)."""
    if model == TROPO_OFF or not (h >= TROPO_MIN_HEIGHT_M and h <= TROPO_MAX_HEIGHT_M):
        return np.nan, np.nan, np.nan
    if model == TROPO_HOPFIELD:
        p, t, e = _standard_atmosphere(h, humidity)
        return 77.64 * p / t, -12.96 * e / t + 3.718e5 * e / (t * t), 40136.0 + 148.72 * (t - 273.16)
    return _saastamoinen_zenith(lat, h, humidity), 0.0, 0.0


@njit(cache=True)
def troposphere_slant(model, zenith, h, el):
    """Slant delay (m) and its variance (m^2) at elevation el from troposphere_zenith's output,
    corrections.troposphere_delay_m."""
    if model == TROPO_OFF:
        return 0.0, TROPO_OFF_VARIANCE_M2
    var = (ERR_SAAS_M / (np.sin(el) + 0.1)) ** 2
    if not el > 0.0 or np.isnan(zenith[0]):
        return 0.0, var
    if model == TROPO_HOPFIELD:
        return _hopfield_slant(zenith, h, el), var
    return zenith[0] / np.sin(el), var


@njit(cache=True)
def troposphere(model, lat, h, el, humidity):
    """Slant delay (m) and its variance (m^2), corrections.troposphere_delay_m."""
    return troposphere_slant(model, troposphere_zenith(model, lat, h, humidity), h, el)


@njit(cache=True)
def klobuchar_l1_m(t, lat, lon, az, el, alpha, beta):
    """GPS L1 broadcast ionospheric delay (m), atmosphere.klobuchar_delay_m (alpha, beta: the 4 + 4
    coefficients actually used, defaults already substituted)."""
    if not el > 0.0:
        return 0.0
    el_sc = el / np.pi
    psi = 0.0137 / (el_sc + 0.11) - 0.022
    phi = min(max(lat / np.pi + psi * np.cos(az), -0.416), 0.416)
    lam = lon / np.pi + psi * np.sin(az) / np.cos(phi * np.pi)
    phi_m = phi + 0.064 * np.cos((lam - 1.617) * np.pi)
    local_time = np.mod(43200.0 * lam + np.mod(t, 604800.0), 86400.0)
    slant = 1.0 + 16.0 * (0.53 - el_sc) ** 3
    amp = alpha[0] + phi_m * (alpha[1] + phi_m * (alpha[2] + phi_m * alpha[3]))
    per = beta[0] + phi_m * (beta[1] + phi_m * (beta[2] + phi_m * beta[3]))
    amp = max(amp, 0.0)
    per = max(per, 72000.0)
    x = 2.0 * np.pi * (local_time - 50400.0) / per
    day = 5e-9 + amp * (1.0 + x * x * (-0.5 + x * x / 24.0))
    return CLIGHT_M_S * slant * (day if np.abs(x) < 1.57 else 5e-9)


@njit(cache=True)
def ionosphere_scale(wavelength_m):
    """Factor from the L1 delay to the delay at the frequency of `wavelength_m`: (f_L1 / f)^2."""
    return (GPS_L1_HZ / (CLIGHT_M_S / wavelength_m)) ** 2
