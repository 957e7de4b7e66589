"""The scalar compiled models used by the per-epoch single point positioning (atmosphere_kernels.py) give the
same values as the vectorised ones of frames.py / atmosphere.py / corrections.py (which are tested against
RTKLIB): same formulas, differences at round-off level only."""

from __future__ import annotations

import numpy as np
import pytest

from georef_core.gnss import atmosphere_kernels as ak
from georef_core.gnss.atmosphere import KLOBUCHAR_DEFAULT_ALPHA, KLOBUCHAR_DEFAULT_BETA, klobuchar_parameters
from georef_core.gnss.constants import CLIGHT_M_S
from georef_core.gnss.corrections import ionosphere_delay_m, troposphere_delay_m
from georef_core.gnss.frames import azimuth_elevation_batch, ecef_to_geodetic, geodetic_to_ecef_m
from georef_core.gnss.navigation import NavigationData

RNG = np.random.default_rng(7)
N = 400
LAT = RNG.uniform(-1.4, 1.4, N)
LON = RNG.uniform(-np.pi, np.pi, N)
H = RNG.uniform(-150.0, 11000.0, N)      # includes heights outside the models' validity range
EL = RNG.uniform(-0.2, np.pi / 2, N)     # includes negative elevations
AZ = RNG.uniform(0.0, 2 * np.pi, N)


def test_geodetic_and_azimuth_elevation():
    xyz = geodetic_to_ecef_m(LAT, LON, H)
    llh = ecef_to_geodetic(xyz)
    los = RNG.normal(size=(N, 3))
    los /= np.linalg.norm(los, axis=1, keepdims=True)
    az_ref, el_ref, _ = azimuth_elevation_batch(xyz, los[:, None, :])
    for i in range(N):
        lat, lon, h = ak.geodetic(*xyz[i])
        assert (lat, lon) == pytest.approx((llh[i, 0], llh[i, 1]), abs=1e-14)
        assert h == pytest.approx(llh[i, 2], abs=1e-8)
        az, el = ak.azimuth_elevation(ak.enu_basis(lat, lon), los[i])
        assert az == pytest.approx(az_ref[i, 0], abs=1e-12)
        assert el == pytest.approx(el_ref[i, 0], abs=1e-12)


@pytest.mark.parametrize("model", ["saastamoinen", "hopfield", "off"])
@pytest.mark.parametrize("humidity", [0.0, 0.7])
def test_troposphere(model, humidity):
    ref, ref_var = troposphere_delay_m(model, LAT, H, EL, humidity)
    for i in range(N):
        delay, var = ak.troposphere(ak.TROPO_MODELS[model], LAT[i], H[i], EL[i], humidity)
        assert delay == pytest.approx(ref[i], rel=1e-12, abs=1e-12)
        assert var == pytest.approx(ref_var[i], rel=1e-12)


@pytest.mark.parametrize("params", [(None, None), ((1.2e-8, 1.5e-8, -6e-8, -6e-8), (1e5, 1.2e5, -6.5e4, -3.3e5))])
def test_klobuchar(params):
    nav = NavigationData(iono_gps_alpha=None if params[0] is None else np.array(params[0]),
                         iono_gps_beta=None if params[1] is None else np.array(params[1]))
    alpha, beta = klobuchar_parameters(nav.iono_gps_alpha, nav.iono_gps_beta)
    if params[0] is None:
        assert np.array_equal(alpha, KLOBUCHAR_DEFAULT_ALPHA) and np.array_equal(beta, KLOBUCHAR_DEFAULT_BETA)
    t = 1.4e9 + RNG.uniform(0, 86400 * 7, N)
    lam = CLIGHT_M_S / RNG.choice([1575.42e6, 1227.60e6, 1602.5625e6, 1207.14e6], N)
    ref, _ = ionosphere_delay_m("broadcast", nav, t, LAT, LON, AZ, EL, lam)
    for i in range(N):
        delay = ak.klobuchar_l1_m(t[i], LAT[i], LON[i], AZ[i], EL[i], alpha, beta) * ak.ionosphere_scale(lam[i])
        assert delay == pytest.approx(ref[i], rel=1e-12, abs=1e-12)
