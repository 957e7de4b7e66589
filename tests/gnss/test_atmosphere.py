"""Troposphere (Saastamoinen as RTKLIB, modified Hopfield) and broadcast ionosphere (Klobuchar) models,
compared with RTKLIB demo5 (pyrtklib5: tropmodel, ionmodel), hand-computed values and a numerical
ray integration."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from georef_core.gnss.atmosphere import (
    KLOBUCHAR_DEFAULT_ALPHA,
    KLOBUCHAR_DEFAULT_BETA,
    klobuchar_delay_m,
    klobuchar_variance_m2,
    modified_hopfield_slant,
    saastamoinen_zenith_and_slant,
    saastamoinen_zenith_m,
    standard_atmosphere,
    tropo_variance_m2,
)
from georef_core.gnss.constants import CLIGHT_M_S, WGS84_A_M

# Standard atmosphere at sea level (RTKLIB): 1013.25 hPa, 288.16 K, humidity 0.7 ->
# e = 6.108 * 0.7 * exp((17.15 * 288.16 - 4684) / (288.16 - 38.45)) = 12.0119104 hPa
E_SEA_LEVEL_HPA = 12.011910431975723
ZHD_45DEG_SEA_LEVEL_M = 0.0022768 * 1013.25  # cos(2 lat) = 0 at 45 deg: 2.3069676 m
ZWD_SEA_LEVEL_M = 0.002277 * (1255.0 / 288.16 + 0.05) * E_SEA_LEVEL_HPA  # 0.1204877 m


def _arr(p, values):
    out = p.Arr1Ddouble(len(values))
    for i, v in enumerate(values):
        out[i] = float(v)
    return out


# ---------------------------------------------------------------------------------------------------
# Saastamoinen


def test_saastamoinen_matches_rtklib_tropmodel():
    p = pytest.importorskip("pyrtklib5")
    rng = np.random.default_rng(1)
    n = 2000
    lat = rng.uniform(-np.pi / 2, np.pi / 2, n)
    lon = rng.uniform(-np.pi, np.pi, n)
    h = rng.uniform(-300.0, 11000.0, n)  # includes RTKLIB's out-of-range heights
    az = rng.uniform(0.0, 2 * np.pi, n)
    el = rng.uniform(-0.1, np.pi / 2, n)
    t0 = p.gpst2time(2200, 0.0)
    ref = np.array([p.tropmodel(t0, _arr(p, [lat[i], lon[i], h[i]]), _arr(p, [az[i], el[i]]), 0.7)
                    for i in range(n)])
    ours = saastamoinen_zenith_and_slant(lat, h, el)
    assert np.count_nonzero(ref == 0.0) > 100  # the edge cases are exercised
    np.testing.assert_array_equal(ours == 0.0, ref == 0.0)
    assert np.max(np.abs(ours - ref)) < 1e-4  # 0.1 mm (measured: 4e-8 m)


def test_saastamoinen_hand_computed_values():
    lat = np.radians(45.0)
    zhd, zwd = saastamoinen_zenith_m(lat, 0.0)
    assert float(zhd) == pytest.approx(ZHD_45DEG_SEA_LEVEL_M, abs=1e-9)
    assert float(zwd) == pytest.approx(ZWD_SEA_LEVEL_M, abs=1e-9)
    total = ZHD_45DEG_SEA_LEVEL_M + ZWD_SEA_LEVEL_M
    el = np.radians([90.0, 30.0, 10.0])
    np.testing.assert_allclose(saastamoinen_zenith_and_slant(lat, 0.0, el), total / np.sin(el), rtol=1e-12)
    # negative heights use the sea-level atmosphere; outside [-100 m, 10 km] and below the horizon: 0
    assert saastamoinen_zenith_and_slant(lat, -50.0, np.pi / 2) == pytest.approx(total)
    assert saastamoinen_zenith_and_slant(lat, -150.0, np.pi / 2) == 0.0
    assert saastamoinen_zenith_and_slant(lat, 10001.0, np.pi / 2) == 0.0
    np.testing.assert_array_equal(saastamoinen_zenith_and_slant(lat, 0.0, [0.0, -0.2]), [0.0, 0.0])
    # the latitude term: 1 - 0.00266 cos(2 lat) at the equator
    zhd_eq, _ = saastamoinen_zenith_m(0.0, 0.0)
    assert float(zhd_eq) == pytest.approx(0.0022768 * 1013.25 / (1 - 0.00266), abs=1e-9)


def test_saastamoinen_with_measured_meteorology():
    lat, h = np.radians(52.0), 300.0
    zhd, zwd = saastamoinen_zenith_m(lat, h, pressure_hpa=980.0, temperature_k=295.0, e_hpa=15.0)
    denom = 1.0 - 0.00266 * np.cos(2 * lat) - 0.00028 * 0.3
    assert float(zhd) == pytest.approx(0.0022768 * 980.0 / denom, abs=1e-12)
    assert float(zwd) == pytest.approx(0.002277 * (1255.0 / 295.0 + 0.05) * 15.0, abs=1e-12)
    # water vapour from the humidity at the given temperature; dry air has no wet delay
    _, zwd_h = saastamoinen_zenith_m(lat, h, humidity=0.5, temperature_k=295.0)
    e = 6.108 * 0.5 * np.exp((17.15 * 295.0 - 4684.0) / (295.0 - 38.45))
    assert float(zwd_h) == pytest.approx(0.002277 * (1255.0 / 295.0 + 0.05) * e, abs=1e-12)
    assert float(saastamoinen_zenith_m(lat, h, humidity=0.0)[1]) == 0.0
    slant = saastamoinen_zenith_and_slant(lat, h, np.radians(40.0), pressure_hpa=980.0, temperature_k=295.0,
                                          e_hpa=15.0)
    assert slant == pytest.approx(float(zhd + zwd) / np.sin(np.radians(40.0)))


def test_standard_atmosphere():
    p, t, e = standard_atmosphere([0.0, -20.0, 1000.0])
    np.testing.assert_allclose(p, [1013.25, 1013.25, 1013.25 * (1 - 2.2557e-2) ** 5.2568])
    np.testing.assert_allclose(t, [288.16, 288.16, 281.66])
    assert e[0] == pytest.approx(E_SEA_LEVEL_HPA)


# ---------------------------------------------------------------------------------------------------
# modified Hopfield


def _hopfield_ray_integral(h_m, el_rad, p_hpa, t_k, e_hpa, exact_geometry):
    """Straight-ray integral of the two quartic refractivity layers in a spherical atmosphere.

    The model's 9-term series integrates the height along the ray to second order in the distance s,
    h(s) ~ s sin(E) + s^2 cos^2(E) / (2 R); ``exact_geometry`` uses the exact sqrt instead.
    """
    radius = WGS84_A_M + h_m
    sin_e, cos_e = np.sin(el_rad), np.cos(el_rad)
    layers = ((77.64 * p_hpa / t_k, 40136.0 + 148.72 * (t_k - 273.16)),
              (-12.96 * e_hpa / t_k + 3.718e5 * e_hpa / t_k**2, 11000.0))
    total = 0.0
    for n0, top in layers:
        s_top = np.sqrt((radius + top) ** 2 - (radius * cos_e) ** 2) - radius * sin_e

        def refractivity(s, n0=n0, top=top):
            if exact_geometry:
                height = np.sqrt(radius**2 + s * s + 2 * radius * s * sin_e) - radius
            else:
                height = s * sin_e + s * s * cos_e**2 / (2 * radius)
            return n0 * ((top - height) / top) ** 4

        total += 1e-6 * quad(refractivity, 0.0, s_top, epsabs=1e-12, epsrel=1e-12, limit=200)[0]
    return total


@pytest.mark.parametrize("h_m", [0.0, 1500.0])
@pytest.mark.parametrize("el_deg", [3.0, 15.0, 45.0, 90.0])
def test_hopfield_matches_numerical_ray_integration(h_m, el_deg):
    p, t, e = (float(v) for v in standard_atmosphere(h_m))
    el = np.radians(el_deg)
    ours = float(modified_hopfield_slant(h_m, el))
    # the series is the exact integral of the model's ray-height approximation ...
    assert ours == pytest.approx(_hopfield_ray_integral(h_m, el, p, t, e, False), rel=1e-10)
    # ... which is within 0.04 % of the exact spherical geometry (1.2 cm at 3 deg elevation)
    assert ours == pytest.approx(_hopfield_ray_integral(h_m, el, p, t, e, True), rel=4e-4)


def test_hopfield_zenith_closed_form_and_defaults():
    p, t, e = 990.0, 285.0, 10.0
    h_dry = 40136.0 + 148.72 * (t - 273.16)
    expected = 1e-6 / 5 * (77.64 * p / t * h_dry + (-12.96 * e / t + 3.718e5 * e / t**2) * 11000.0)
    assert modified_hopfield_slant(200.0, np.pi / 2, p, t, e) == pytest.approx(expected, rel=1e-12)
    # defaults: the standard atmosphere, as for Saastamoinen
    h = np.array([0.0, 800.0, 2500.0])
    el = np.radians([20.0, 50.0, 80.0])
    ps, ts, es = standard_atmosphere(h)
    np.testing.assert_allclose(modified_hopfield_slant(h, el), modified_hopfield_slant(h, el, ps, ts, es),
                               rtol=1e-14)
    np.testing.assert_array_equal(modified_hopfield_slant([0.0, -150.0, 12000.0], [-0.1, 1.0, 1.0]), 0.0)


def test_hopfield_agrees_with_saastamoinen():
    """A few mm at zenith, ~1 cm at 30 deg; at 15 deg the flat 1/cos(z) mapping of RTKLIB's
    Saastamoinen (no Earth curvature, no B tan^2 z term) is ~1.5 % too large: ~0.1 m."""
    lat = np.radians(np.array([0.0, 30.0, 45.0, 60.0]))[:, None]
    h = np.array([0.0, 500.0, 1500.0, 3000.0])[None, :]

    def diff(el_deg):
        el = np.radians(el_deg)
        return np.abs(saastamoinen_zenith_and_slant(lat, h, el) - modified_hopfield_slant(h, el))

    assert np.max(diff(90.0)) < 0.010
    assert np.max(diff(30.0)) < 0.025
    assert np.max(diff(15.0)) < 0.15
    rel15 = diff(15.0) / saastamoinen_zenith_and_slant(lat, h, np.radians(15.0))
    assert np.max(rel15) < 0.02


# ---------------------------------------------------------------------------------------------------
# Klobuchar


@pytest.mark.parametrize("params", ["default", "custom", "zeros"])
def test_klobuchar_matches_rtklib_ionmodel(params):
    p = pytest.importorskip("pyrtklib5")
    rng = np.random.default_rng(2)
    n = 2000
    lat = rng.uniform(-np.pi / 2, np.pi / 2, n)
    lon = rng.uniform(-np.pi, np.pi, n)
    az = rng.uniform(0.0, 2 * np.pi, n)
    el = rng.uniform(-0.1, np.pi / 2, n)
    t = rng.uniform(1.0e9, 1.5e9, n)
    if params == "custom":
        alpha, beta = [1.2e-8, -7.5e-9, -6.0e-8, 1.2e-7], [1.1e5, -2.2e5, -1.3e5, 1.0e6]
    elif params == "zeros":
        alpha, beta = [0.0] * 4, [0.0] * 4
    else:
        alpha = beta = None
    ion = _arr(p, (alpha or [0.0] * 4) + (beta or [0.0] * 4))  # all zero -> RTKLIB's defaults
    ref = []
    for i in range(n):
        week = int(t[i] // 604800)
        ref.append(p.ionmodel(p.gpst2time(week, t[i] - week * 604800), ion, _arr(p, [lat[i], lon[i], 100.0]),
                              _arr(p, [az[i], el[i]])))
    ours = klobuchar_delay_m(t, lat, lon, az, el, alpha, beta)
    assert np.max(ref) > 10.0
    assert np.max(np.abs(ours - np.array(ref))) < 1e-3  # measured: 0 (same arithmetic)


def test_klobuchar_hand_computed_values():
    zenith_slant = 1.0 + 16.0 * 0.03**3
    # night: the constant 5 ns (local midnight at longitude 0)
    assert klobuchar_delay_m(0.0, 0.0, 0.0, 0.0, np.pi / 2) == pytest.approx(CLIGHT_M_S * 5e-9 * zenith_slant)
    # 14:00 local time: 5 ns + amplitude (alpha0 only, so the geomagnetic latitude does not matter;
    # azimuth 0 keeps the pierce point on the receiver's meridian)
    alpha, beta = [1e-8, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]  # period clamps to 72000 s
    peak = klobuchar_delay_m(50400.0, 0.3, 0.0, 0.0, np.pi / 2, alpha, beta)
    assert peak == pytest.approx(CLIGHT_M_S * 1.5e-8 * zenith_slant, rel=1e-12)
    x = np.pi / 4  # 9000 s later with the 72000 s period
    cosine = 1.0 - x * x / 2 + x**4 / 24
    later = klobuchar_delay_m(50400.0 + 9000.0, 0.3, 0.0, 0.0, np.pi / 2, alpha, beta)
    assert later == pytest.approx(CLIGHT_M_S * (5e-9 + 1e-8 * cosine) * zenith_slant, rel=1e-12)
    # local time follows the longitude (90 deg E is 6 h ahead); GPS seconds of any week are accepted
    east = klobuchar_delay_m(50400.0 - 21600.0 + 7 * 604800.0, 0.3, np.pi / 2, 0.0, np.pi / 2, alpha, beta)
    assert east == pytest.approx(peak, rel=1e-9)
    # other frequencies: (f1/f)^2; below the horizon or far below the ellipsoid: 0
    l2 = klobuchar_delay_m(50400.0, 0.3, 0.0, 0.0, np.pi / 2, alpha, beta, freq_hz=1227.60e6)
    assert l2 == pytest.approx(peak * (1575.42 / 1227.60) ** 2, rel=1e-12)
    assert klobuchar_delay_m(50400.0, 0.3, 0.0, 1.0, 0.0) == 0.0
    assert klobuchar_delay_m(50400.0, 0.3, 0.0, 1.0, 1.0, h_m=-2000.0) == 0.0
    # missing or all-zero parameters select RTKLIB's defaults
    args = (43000.0, 0.8, 0.2, 2.0, 0.4)
    default = klobuchar_delay_m(*args, KLOBUCHAR_DEFAULT_ALPHA, KLOBUCHAR_DEFAULT_BETA)
    assert klobuchar_delay_m(*args) == default
    assert klobuchar_delay_m(*args, np.zeros(4), np.zeros(4)) == default
    with pytest.raises(ValueError):
        klobuchar_delay_m(*args, [1e-8, 0.0], None)


def test_klobuchar_low_elevation_is_larger():
    el = np.radians([90.0, 45.0, 20.0, 5.0])
    d = klobuchar_delay_m(50400.0, np.radians(45.0), 0.0, 0.0, el)
    assert np.all(np.diff(d) > 0)
    assert d[-1] / d[0] == pytest.approx(1.0 + 16.0 * (0.53 - 5.0 / 180.0) ** 3, rel=0.25)


# ---------------------------------------------------------------------------------------------------
# error models and vectorisation


def test_error_variances():
    np.testing.assert_allclose(tropo_variance_m2([np.pi / 2, 0.0, np.radians(30.0)]),
                               [(0.3 / 1.1) ** 2, 9.0, (0.3 / 0.6) ** 2])
    np.testing.assert_allclose(klobuchar_variance_m2([2.0, 0.0]), [1.0, 0.0])


def test_vectorised_shapes():
    el = np.radians(np.linspace(5.0, 90.0, 12)).reshape(3, 4)
    assert saastamoinen_zenith_and_slant(0.7, 120.0, el).shape == (3, 4)
    assert modified_hopfield_slant(120.0, el).shape == (3, 4)
    assert tropo_variance_m2(el).shape == (3, 4)
    assert klobuchar_delay_m(1.3e9, 0.7, 0.2, el * 2, el).shape == (3, 4)
    lat = np.array([0.1, 0.7, 1.2])[:, None]
    out = saastamoinen_zenith_and_slant(lat, np.array([0.0, 10.0, 100.0, 1000.0]), el)
    for i in range(3):
        for j in range(4):
            assert out[i, j] == pytest.approx(float(saastamoinen_zenith_and_slant(lat[i, 0], [0.0, 10.0, 100.0,
                                                                                             1000.0][j], el[i, j])))
