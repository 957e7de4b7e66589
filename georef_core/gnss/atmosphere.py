"""Tropospheric and broadcast ionospheric delay models, vectorised over satellites.

Units: angles in radians, heights in metres (ellipsoidal, as RTKLIB uses them), pressures in hPa,
temperatures in kelvin, delays in metres, variances in m^2. Arguments broadcast against each other.

Models:
- Saastamoinen zenith delays with the standard atmosphere and a 1/cos(z) mapping, exactly as
  RTKLIB's ``tropmodel`` (Saastamoinen 1972, "Atmospheric correction for the troposphere and
  stratosphere in radio ranging of satellites").
- Modified Hopfield (Goad & Goodman 1974, "A modified Hopfield tropospheric refraction correction
  model"), in the form given by Hofmann-Wellenhof, Lichtenegger & Wasle, "GNSS" (2008), sect. 5.3.3.
- GPS broadcast ionosphere (Klobuchar 1987, "Ionospheric time-delay algorithm for single-frequency
  GPS users"; IS-GPS-200 20.3.3.5.2.5), as RTKLIB's ``ionmodel``.
"""

from __future__ import annotations

import numpy as np

from .constants import CLIGHT_M_S, WGS84_A_M

__all__ = [
    "ERR_BRDCI",
    "ERR_SAAS_M",
    "KLOBUCHAR_DEFAULT_ALPHA",
    "KLOBUCHAR_DEFAULT_BETA",
    "klobuchar_delay_m",
    "klobuchar_parameters",
    "klobuchar_variance_m2",
    "modified_hopfield_slant",
    "saastamoinen_zenith_and_slant",
    "saastamoinen_zenith_m",
    "standard_atmosphere",
    "tropo_variance_m2",
]

GPS_L1_HZ = 1575.42e6
# RTKLIB's validity range of the troposphere models (receiver height, m).
TROPO_MIN_HEIGHT_M = -100.0
TROPO_MAX_HEIGHT_M = 1.0e4
# RTKLIB error model: Saastamoinen residual (m at zenith, scaled by 1/(sin(el)+0.1)), and the
# broadcast ionosphere error as a fraction of the delay.
ERR_SAAS_M = 0.3
ERR_BRDCI = 0.5
# RTKLIB's fallback broadcast parameters (GPS, 2004/1/1), used when none are available.
KLOBUCHAR_DEFAULT_ALPHA = (0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06)
KLOBUCHAR_DEFAULT_BETA = (0.1167e06, -0.2294e06, -0.1311e06, 0.1049e07)


def standard_atmosphere(h_m, humidity=0.7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pressure (hPa), temperature (K) and water-vapour pressure (hPa) of RTKLIB's standard atmosphere.

    Heights below 0 are taken as 0 (as RTKLIB does). ``humidity`` is relative (0..1).
    """
    hgt = np.maximum(np.asarray(h_m, dtype=float), 0.0)
    pressure = 1013.25 * (1.0 - 2.2557e-5 * hgt) ** 5.2568
    temperature = 15.0 - 6.5e-3 * hgt + 273.16
    return pressure, temperature, _water_vapour_hpa(temperature, humidity)


def _water_vapour_hpa(temperature_k, humidity) -> np.ndarray:
    """Partial pressure of water vapour (hPa) from temperature (K) and relative humidity (RTKLIB)."""
    t = np.asarray(temperature_k, dtype=float)
    return 6.108 * np.asarray(humidity, dtype=float) * np.exp((17.15 * t - 4684.0) / (t - 38.45))


def _surface_met(h_m, humidity, pressure_hpa, temperature_k, e_hpa):
    """Fill the meteorological values not given with the standard atmosphere at h_m."""
    p_std, t_std, _ = standard_atmosphere(h_m, humidity)
    p = p_std if pressure_hpa is None else np.asarray(pressure_hpa, dtype=float)
    t = t_std if temperature_k is None else np.asarray(temperature_k, dtype=float)
    e = _water_vapour_hpa(t, humidity) if e_hpa is None else np.asarray(e_hpa, dtype=float)
    return p, t, e


def saastamoinen_zenith_m(
    lat_rad, h_m, humidity=0.7, pressure_hpa=None, temperature_k=None, e_hpa=None
) -> tuple[np.ndarray, np.ndarray]:
    """Saastamoinen zenith hydrostatic and wet delays (m), RTKLIB's formulas.

    Meteorological values not given come from the standard atmosphere at ``h_m`` (heights below 0
    taken as 0). Heights outside [-100 m, 10 km] give 0, as in RTKLIB.
    """
    lat, h = np.broadcast_arrays(np.asarray(lat_rad, dtype=float), np.asarray(h_m, dtype=float))
    p, t, e = _surface_met(h, humidity, pressure_hpa, temperature_k, e_hpa)
    hgt = np.maximum(h, 0.0)
    zhd = 0.0022768 * p / (1.0 - 0.00266 * np.cos(2.0 * lat) - 0.00028 * hgt / 1e3)
    zwd = 0.002277 * (1255.0 / t + 0.05) * e
    valid = (h >= TROPO_MIN_HEIGHT_M) & (h <= TROPO_MAX_HEIGHT_M)
    return np.where(valid, zhd, 0.0), np.where(valid, zwd, 0.0)


def saastamoinen_zenith_and_slant(
    lat_rad, h_m, el_rad, humidity=0.7, pressure_hpa=None, temperature_k=None, e_hpa=None
) -> np.ndarray:
    """Slant tropospheric delay (m): Saastamoinen zenith delays mapped with 1/cos(z), as RTKLIB's
    ``tropmodel`` (RTKLIB calls it with humidity 0.7).

    Args:
        lat_rad: geodetic latitude (rad).
        h_m: ellipsoidal height (m); outside [-100 m, 10 km] the delay is 0.
        el_rad: elevation (rad); at or below 0 the delay is 0.
        humidity: relative humidity 0..1 (used for the water vapour when ``e_hpa`` is not given).
        pressure_hpa, temperature_k, e_hpa: measured surface values; standard atmosphere if None.

    Returns:
        Slant delay (m), broadcast shape of the inputs.
    """
    el = np.asarray(el_rad, dtype=float)
    zhd, zwd = saastamoinen_zenith_m(lat_rad, h_m, humidity, pressure_hpa, temperature_k, e_hpa)
    zhd, zwd, el = np.broadcast_arrays(zhd, zwd, el)
    positive = el > 0.0
    cos_z = np.where(positive, np.sin(el), 1.0)  # cos(pi/2 - el)
    return np.where(positive, (zhd + zwd) / cos_z, 0.0)


def _hopfield_layer(refractivity, layer_height_m, sin_el, cos2_el, radius_m):
    """One layer of the modified Hopfield model: 1e-6 N0 sum_k alpha_k r^k / k (m)."""
    r = np.sqrt((radius_m + layer_height_m) ** 2 - radius_m**2 * cos2_el) - radius_m * sin_el
    a = -sin_el / layer_height_m
    b = -cos2_el / (2.0 * layer_height_m * radius_m)
    a2 = a * a
    coeffs = (
        1.0,
        4.0 * a,
        6.0 * a2 + 4.0 * b,
        4.0 * a * (a2 + 3.0 * b),
        a2 * a2 + 12.0 * a2 * b + 6.0 * b * b,
        4.0 * a * b * (a2 + 3.0 * b),
        b * b * (6.0 * a2 + 4.0 * b),
        4.0 * a * b**3,
        b**4,
    )
    total = np.zeros_like(r)
    rk = np.ones_like(r)
    for k, alpha in enumerate(coeffs, start=1):
        rk = rk * r
        total = total + alpha * rk / k
    return 1e-6 * refractivity * total


def modified_hopfield_slant(
    h_m, el_rad, pressure_hpa=None, temperature_k=None, e_hpa=None, humidity=0.7
) -> np.ndarray:
    """Slant tropospheric delay (m) of the modified Hopfield model (Goad & Goodman 1974).

    Surface refractivities N_d = 77.64 p/T and N_w = -12.96 e/T + 3.718e5 e/T^2, layer heights
    above the station h_d = 40136 + 148.72 (T - 273.16) m and h_w = 11000 m, integrated along the
    ray in a spherical atmosphere of radius (WGS84 a + h) at the station; the sum of the 9-term
    series is exact for the quartic refractivity profile. Meteorological values not given come from
    the same standard atmosphere as saastamoinen_zenith_and_slant. Delay 0 at elevations <= 0 and
    for heights outside [-100 m, 10 km].
    """
    h, el = np.broadcast_arrays(np.asarray(h_m, dtype=float), np.asarray(el_rad, dtype=float))
    p, t, e = _surface_met(h, humidity, pressure_hpa, temperature_k, e_hpa)
    p, t, e, h, el = np.broadcast_arrays(p, t, e, h, el)
    positive = el > 0.0
    sin_el = np.where(positive, np.sin(el), 1.0)
    cos2_el = 1.0 - sin_el * sin_el
    radius = WGS84_A_M + np.maximum(h, 0.0)
    n_dry = 77.64 * p / t
    n_wet = -12.96 * e / t + 3.718e5 * e / (t * t)
    h_dry = 40136.0 + 148.72 * (t - 273.16)
    h_wet = 11000.0
    delay = _hopfield_layer(n_dry, h_dry, sin_el, cos2_el, radius) + _hopfield_layer(
        n_wet, h_wet, sin_el, cos2_el, radius
    )
    valid = positive & (h >= TROPO_MIN_HEIGHT_M) & (h <= TROPO_MAX_HEIGHT_M)
    return np.where(valid, delay, 0.0)


def tropo_variance_m2(el_rad) -> np.ndarray:
    """Variance (m^2) of the modelled tropospheric delay, RTKLIB's ``(ERR_SAAS / (sin(el) + 0.1))^2``
    with ERR_SAAS = 0.3 m (about 0.07 m^2 at zenith, 2.5 m^2 at the horizon)."""
    el = np.asarray(el_rad, dtype=float)
    return (ERR_SAAS_M / (np.sin(el) + 0.1)) ** 2


def _params(values, default) -> np.ndarray:
    if values is None:
        return np.asarray(default, dtype=float)
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.size != 4:
        raise ValueError(f"Klobuchar alpha/beta need 4 values, got {v.size}")
    return v


def klobuchar_parameters(alpha, beta) -> tuple[np.ndarray, np.ndarray]:
    """The 4 + 4 Klobuchar coefficients to use: RTKLIB's default set when none are given or all are zero."""
    alpha_v = _params(alpha, KLOBUCHAR_DEFAULT_ALPHA)
    beta_v = _params(beta, KLOBUCHAR_DEFAULT_BETA)
    if not np.any(alpha_v) and not np.any(beta_v):
        alpha_v = np.asarray(KLOBUCHAR_DEFAULT_ALPHA, dtype=float)
        beta_v = np.asarray(KLOBUCHAR_DEFAULT_BETA, dtype=float)
    return alpha_v, beta_v


def klobuchar_delay_m(
    gps_time_s, lat_rad, lon_rad, az_rad, el_rad, alpha=None, beta=None, freq_hz=GPS_L1_HZ, h_m=None
) -> np.ndarray:
    """Ionospheric group delay (m, positive) of the GPS broadcast (Klobuchar) model, RTKLIB's ``ionmodel``.

    Args:
        gps_time_s: GPS time (s); any epoch of GPS seconds works (only the time of day matters).
        lat_rad, lon_rad: receiver geodetic latitude and longitude (rad).
        az_rad, el_rad: satellite azimuth and elevation (rad); delay 0 at elevations <= 0.
        alpha, beta: the 4 + 4 broadcast coefficients (s, s/semicircle^n and s, s/semicircle^n).
            None, or all eight zero, selects RTKLIB's default set (as RTKLIB does).
        freq_hz: carrier frequency; the L1 delay is scaled by (f_L1 / f)^2.
        h_m: receiver height (m), optional; below -1000 m the delay is 0 (as in RTKLIB).

    Returns:
        Delay (m) at ``freq_hz``; the carrier phase is advanced by the same amount.
    """
    alpha_v, beta_v = klobuchar_parameters(alpha, beta)
    t, lat, lon, az, el = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (gps_time_s, lat_rad, lon_rad, az_rad, el_rad))
    )
    el_sc = el / np.pi  # semicircles
    psi = 0.0137 / (el_sc + 0.11) - 0.022  # earth-centred angle (semicircles)
    phi = np.clip(lat / np.pi + psi * np.cos(az), -0.416, 0.416)  # sub-ionospheric latitude
    lam = lon / np.pi + psi * np.sin(az) / np.cos(phi * np.pi)  # sub-ionospheric longitude
    phi_m = phi + 0.064 * np.cos((lam - 1.617) * np.pi)  # geomagnetic latitude
    local_time = np.mod(43200.0 * lam + np.mod(t, 604800.0), 86400.0)
    slant = 1.0 + 16.0 * (0.53 - el_sc) ** 3
    amp = alpha_v[0] + phi_m * (alpha_v[1] + phi_m * (alpha_v[2] + phi_m * alpha_v[3]))
    per = beta_v[0] + phi_m * (beta_v[1] + phi_m * (beta_v[2] + phi_m * beta_v[3]))
    amp = np.maximum(amp, 0.0)
    per = np.maximum(per, 72000.0)
    x = 2.0 * np.pi * (local_time - 50400.0) / per
    day = 5e-9 + amp * (1.0 + x * x * (-0.5 + x * x / 24.0))
    delay_l1 = CLIGHT_M_S * slant * np.where(np.abs(x) < 1.57, day, 5e-9)
    delay_l1 = np.where(el > 0.0, delay_l1, 0.0)
    if h_m is not None:
        delay_l1 = np.where(np.asarray(h_m, dtype=float) >= -1e3, delay_l1, 0.0)
    scale = (GPS_L1_HZ / np.asarray(freq_hz, dtype=float)) ** 2
    return delay_l1 * scale


def klobuchar_variance_m2(delay_m) -> np.ndarray:
    """Variance (m^2) of a broadcast-model ionospheric delay: RTKLIB's ``(ERR_BRDCI * delay)^2``,
    ERR_BRDCI = 0.5."""
    return (ERR_BRDCI * np.asarray(delay_m, dtype=float)) ** 2
