"""Site calibration: the least-squares solution against a hand computation (the closed-form similarity about
the centroid and the inclined plane's normal equations written out), the file round trip, the inverse, and a
DSM carried onto the local grid."""

from __future__ import annotations

import math

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from georef_core.datums.site_calibration import (ControlPair, calibrate_raster, read_calibration,
                                                 read_control_pairs, solve_calibration)
from georef_core.dense.cog_writer import write_cog
from georef_core.errors import InputFileError, ProcessingError


def _four_points(seed=11):
    """Four control points: projected (E, N, h) and a local grid 1.7 deg rotated, 35 ppm scaled, shifted, with
    an inclined height datum, plus a few millimetres of survey noise (so the residuals are not zero)."""
    rng = np.random.default_rng(seed)
    E = 448_000.0 + np.array([12.0, 395.0, 410.0, 30.0])
    N = 5_412_000.0 + np.array([8.0, 22.0, 377.0, 402.0])
    h = np.array([101.2, 98.7, 104.9, 99.3])
    s, th = 1.000035, math.radians(1.7)
    e = 5000 + s * (math.cos(th) * (E - 448_000) - math.sin(th) * (N - 5_412_000)) + rng.normal(0, 0.006, 4)
    n = 8000 + s * (math.sin(th) * (E - 448_000) + math.cos(th) * (N - 5_412_000)) + rng.normal(0, 0.006, 4)
    H = h - 47.31 + 1.5e-4 * (N - 5_412_200) - 0.8e-4 * (E - 448_200) + rng.normal(0, 0.004, 4)
    return E, N, h, e, n, H


def test_calibration_reproduces_the_hand_computation():
    E, N, h, e, n, H = _four_points()
    pairs = [ControlPair(f"CP{k}", (E[k], N[k], h[k]), (e[k], n[k], H[k])) for k in range(4)]
    cal = solve_calibration(pairs, "EPSG:32631", "EPSG:5773", "quarry grid")

    # -- by hand: the similarity about the centroid in closed form
    E0, N0 = E.mean(), N.mean()
    dE, dN = E - E0, N - N0
    de, dn = e - e.mean(), n - n.mean()
    q = np.sum(dE ** 2 + dN ** 2)
    a = np.sum(dE * de + dN * dn) / q
    b = np.sum(dE * dn - dN * de) / q
    e_fit = e.mean() + a * dE - b * dN
    n_fit = n.mean() + b * dE + a * dN
    vE, vN = e - e_fit, n - n_fit
    s0 = math.sqrt((np.sum(vE ** 2) + np.sum(vN ** 2)) / (2 * 4 - 4))
    # -- by hand: the plane dz = c0 + c1 (N - N0) + c2 (E - E0), its 3-column design matrix written out
    dz = H - h
    B = np.array([[1.0, N[k] - N0, E[k] - E0] for k in range(4)])
    c = np.linalg.lstsq(B, dz, rcond=None)[0]
    vH = dz - B @ c

    assert cal.origin_source_m == pytest.approx((E0, N0), abs=1e-9)
    assert cal.a == pytest.approx(a, abs=1e-12) and cal.b == pytest.approx(b, abs=1e-12)
    assert cal.scale == pytest.approx(math.hypot(a, b), abs=1e-12)
    assert cal.rotation_rad == pytest.approx(math.atan2(b, a), abs=1e-12)
    assert (cal.c0_m, cal.slope_north, cal.slope_east) == pytest.approx(tuple(c), abs=1e-9)
    res = cal.residuals()
    assert np.max(np.abs([r["dE_m"] for r in res] - vE)) <= 1e-9
    assert np.max(np.abs([r["dN_m"] for r in res] - vN)) <= 1e-9
    assert np.max(np.abs([r["dH_m"] for r in res] - vH)) <= 1e-9
    assert cal.sigmas["sigma0_horizontal_m"] == pytest.approx(s0, rel=1e-9)
    assert cal.sigmas["a"] == pytest.approx(s0 / math.sqrt(q), rel=1e-9)         # var(a) = s0^2 / sum(d^2)
    assert cal.sigmas["shift_e_m"] == pytest.approx(s0 / 2.0, rel=1e-9)           # s0 / sqrt(4)
    st = cal.statistics()
    assert st["rms_vertical_m"] == pytest.approx(math.sqrt(np.mean(vH ** 2)), abs=1e-12)
    # the recovered parameters are the simulated ones within what 6 mm of noise on a 400 m site allows
    assert abs(cal.scale - 1.000035) < 3e-5 and abs(math.degrees(cal.rotation_rad) - 1.7) < 2e-3
    assert abs(cal.slope_north - 1.5e-4) < 5e-5 and abs(cal.slope_east + 0.8e-4) < 5e-5


def test_file_round_trip_inverse_and_errors(tmp_path):
    E, N, h, e, n, H = _four_points()
    pairs = [ControlPair(f"CP{k}", (E[k], N[k], h[k]), (e[k], n[k], H[k]), "hv" if k else "h") for k in range(4)]
    cal = solve_calibration(pairs, "EPSG:32631", "EPSG:5773")
    assert cal.vertical_model == "inclined plane" and cal.residuals()[0]["dH_m"] is None
    back = read_calibration(cal.write(tmp_path / "cal.json"))
    x = np.array([448_100.0, 448_350.5]), np.array([5_412_050.0, 5_412_390.2]), np.array([100.0, 120.0])
    assert np.max(np.abs(np.array(back.to_local(*x)) - np.array(cal.to_local(*x)))) < 1e-9
    assert np.max(np.abs(np.array(cal.to_source(*cal.to_local(*x))) - np.array(x))) < 1e-8
    assert back.residuals() == cal.residuals()
    two = [ControlPair(p.name, p.source_m, p.local_m, "v") for p in pairs[:2]] + pairs[2:]
    with pytest.raises(ProcessingError, match="at least 3 horizontal"):
        solve_calibration(two)
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "georef-site-calibration", "version": 1, "horizontal": {}}')
    with pytest.raises(InputFileError, match="bad.json.*malformed"):
        read_calibration(bad)
    csv = tmp_path / "pairs.csv"
    csv.write_text("name,easting_m,northing_m,height_m,local_e_m,local_n_m\nA,1,2,3,4,5\n")
    with pytest.raises(InputFileError, match="pairs.csv.*local_h_m"):
        read_control_pairs(csv)


def test_dsm_onto_the_local_grid(tmp_path):
    """A planar DSM carried onto the local grid: bilinear resampling of a plane is exact, so every output
    cell must equal the plane at the cell's projected position plus the vertical adjustment."""
    E, N, h, e, n, H = _four_points()
    cal = solve_calibration([ControlPair(f"CP{k}", (E[k], N[k], h[k]), (e[k], n[k], H[k])) for k in range(4)])
    tr = from_origin(448_000.0, 5_412_420.0, 2.0, 2.0)
    rows, cols = np.mgrid[0:210, 0:215] + 0.5
    x, y = tr.c + 2.0 * cols, tr.f - 2.0 * rows

    def plane(px, py):
        return 100.0 + 0.01 * (px - 448_000.0) - 0.02 * (py - 5_412_000.0)

    write_cog(tmp_path / "dsm.tif", plane(x, y).astype(np.float64), tr, 32631, nodata=-9999.0)
    out = calibrate_raster(cal, tmp_path / "dsm.tif", tmp_path / "dsm_local.tif")
    with rasterio.open(tmp_path / "dsm_local.tif") as src:
        z = src.read(1)
        t = src.transform
        assert src.crs is not None and "site" in src.crs.to_wkt().lower()
    r, c = np.nonzero(z != -9999.0)
    le, ln = t.c + t.a * (c + 0.5), t.f + t.e * (r + 0.5)
    Es, Ns = cal.to_source(le, ln)
    want = plane(Es, Ns) + cal.height_shift_m(Es, Ns)
    assert out["valid_cells"] > 0.9 * 210 * 215
    assert np.max(np.abs(z[r, c] - want)) < 1e-4
