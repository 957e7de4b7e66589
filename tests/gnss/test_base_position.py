"""Base position: from the RINEX header (the marker plus ANTENNA: DELTA H/E/N), and the order of sources
when there is none (--base-pos > RINEX header > averaged single-point solution of the base log > the
receiver's own fixes of a UBX log), with the robust average of single-point epochs."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from georef_core.errors import ProcessingError
from georef_core.gnss.frames import ecef_to_enu_rotation, ecef_to_geodetic, geodetic_to_ecef_m
from georef_core.gnss.observations import ReceiverHeader
from georef_core.gnss.ppk import RECEIVER_FIX_SIGMA_ENU_M, SPP_COMMON_SIGMA_ENU_M, _base_position, solve
from georef_core.gnss.rinex_nav import read_rinex_nav
from georef_core.gnss.rinex_obs import read_rinex_obs
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.gnss.spp import average_spp_positions

from .rtklib_cases import shared_gnss_dir

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"


def test_header_antenna_delta_moves_the_solution_with_the_base():
    rover = read_rinex_obs(DATA / "07590920.05o")
    nav = read_rinex_nav(DATA / "07590920.05n")
    opts = RtkOptions(mode="static", filter_direction="forward", systems=("G",))
    base = read_rinex_obs(DATA / "30400920.05o")
    ref = solve(rover, base, nav, opts)
    base.header.antenna_delta_hen_m = np.array([1.5, 0.2, -0.1])
    moved = solve(rover, base, nav, opts)
    assert any("antenna delta" in w for w in moved.warnings)
    fixed = (ref.status == 1) & (moved.status == 1)
    assert fixed.sum() > 100
    lat, lon, _ = ecef_to_geodetic(ref.position_ecef_m[fixed][-1])
    shift = (moved.position_ecef_m[fixed] - ref.position_ecef_m[fixed]) @ ecef_to_enu_rotation(lat, lon).T
    # the rover follows the base antenna by the same ENU offset; the 1.5 m higher base also sees ~0.5 mm
    # less hydrostatic delay at zenith (more at 15 degrees), which moves the solution by ~1.5 mm vertically
    assert np.allclose(shift, [0.2, -0.1, 1.5], atol=0.002)


# ============================================================================ base position sources

SITE = geodetic_to_ecef_m(np.radians(53.28045), np.radians(-9.05784), 66.8)


def _synthetic_spp_epochs(seed: int = 1, n: int = 1800, step_s: float = 2.0, n_outliers: int = 40):
    """Static receiver: formal covariances ENU sigma (1.0, 1.2, 2.5) m x a per-epoch factor 0.7-1.5 (the
    actual noise is 0.6 of it, as SPP covariances are pessimistic per epoch), a time-correlated part
    (first-order Gauss-Markov, 120 s, 0.5 m per axis), and outliers 30-60 m off with small covariances."""
    rng = np.random.default_rng(seed)
    t = 1.3e9 + step_s * np.arange(n)
    lat, lon, _ = ecef_to_geodetic(SITE)
    rot = ecef_to_enu_rotation(lat, lon)
    factor = rng.uniform(0.7, 1.5, n)
    cov_enu = np.einsum("e,ij->eij", factor**2, np.diag([1.0, 1.2, 2.5]) ** 2)
    white = 0.6 * np.sqrt(np.einsum("eii->ei", cov_enu)) * rng.standard_normal((n, 3))
    phi = np.exp(-step_s / 120.0)
    slow = np.zeros((n, 3))
    for k in range(1, n):
        slow[k] = phi * slow[k - 1] + 0.5 * np.sqrt(1 - phi**2) * rng.standard_normal(3)
    err_enu = white + slow
    bad = rng.choice(n, n_outliers, replace=False)
    err_enu[bad] += rng.uniform(30.0, 60.0, (n_outliers, 1)) * rng.choice([-1.0, 1.0], (n_outliers, 3))
    cov_enu[bad] *= 0.05
    pos = SITE + err_enu @ rot
    cov = np.einsum("ji,ejk,kl->eil", rot, cov_enu, rot)
    return t, pos, cov, bad, err_enu, rot


def test_average_spp_positions_rejects_outliers_and_states_honest_sigmas():
    t, pos, cov, bad, err_enu, rot = _synthetic_spp_epochs()
    valid = np.ones(len(t), dtype=bool)
    valid[5] = False
    pos[7] = np.nan                                     # an epoch without a solution
    avg = average_spp_positions(t, pos, cov, valid)
    assert avg.n_epochs == len(t) - 2
    kept = np.ones(len(t), dtype=bool)
    kept[[5, 7]] = False
    # every outlier is dropped (their small covariances would otherwise pull the weighted mean by metres),
    # and few good epochs (chi-square 99.9 % with the variance factor from the median)
    assert avg.n_rejected >= len(bad) and avg.n_rejected <= len(bad) + 0.01 * len(t)
    assert not avg.used[bad].any() and not avg.used[[5, 7]].any() and avg.used.sum() == avg.n_used
    err = rot @ (avg.position_ecef_m - SITE)
    assert np.all(np.abs(err) < 3.5 * avg.sigma_mean_enu_m), (err, avg.sigma_mean_enu_m)
    assert np.linalg.norm(err) < 0.5
    good = kept.copy()
    good[bad] = False
    np.testing.assert_allclose(avg.scatter_enu_m, np.std(err_enu[good], axis=0), rtol=0.1)
    # 3598 s of epochs: 12 independent 300 s blocks; sigma of the mean = scatter / sqrt(12), far above the
    # formal sigma of 1758 "independent" epochs
    assert avg.n_independent == 12 and avg.block_s == 300.0
    np.testing.assert_allclose(avg.sigma_mean_enu_m, avg.scatter_enu_m / np.sqrt(12), rtol=1e-9)
    assert np.all(avg.formal_sigma_mean_enu_m < 0.3 * avg.sigma_mean_enu_m)
    np.testing.assert_allclose(np.sqrt(np.diag(rot @ avg.covariance_ecef_m2 @ rot.T)), avg.sigma_mean_enu_m)
    assert 0.2 < avg.variance_factor < 0.6              # the synthetic noise is 0.6 sigma (+ the slow part)
    assert avg.span_s == pytest.approx(t[-1] - t[0])


def test_average_spp_positions_edge_cases():
    t, pos, cov, _, _, _ = _synthetic_spp_epochs(n=20, n_outliers=0)
    assert average_spp_positions(t, pos, cov, np.zeros(20, dtype=bool)) is None
    one = average_spp_positions(t[:1], pos[:1], cov[:1])
    np.testing.assert_allclose(one.position_ecef_m, pos[0])
    assert one.n_used == 1 and one.n_independent == 1
    np.testing.assert_allclose(one.sigma_mean_enu_m, one.formal_sigma_mean_enu_m)
    singular = cov.copy()
    singular[3] = 0.0                                   # no usable covariance: the epoch is left out
    assert average_spp_positions(t, pos, singular).n_epochs == 19
    short = average_spp_positions(t, pos, cov)          # 38 s: one block, sigma of the mean = the scatter
    assert short.n_independent == 1
    np.testing.assert_allclose(short.sigma_mean_enu_m, np.maximum(short.scatter_enu_m,
                                                                  short.formal_sigma_mean_enu_m))


def _fake_base(header: ReceiverHeader, t, path: str = "base-x.ubx"):
    return SimpleNamespace(header=header, source_path=path, gps_time_s=t)


def test_base_position_source_order_and_notes():
    t, pos, cov, _, _, _ = _synthetic_spp_epochs(n=600, n_outliers=5)
    spp = SimpleNamespace(position_ecef_m=pos, covariance_ecef_m2=cov, valid=np.ones(len(t), dtype=bool))
    fixes = SITE + np.array([3.0, -2.0, 12.0])
    opts = RtkOptions()
    # a UBX base: the receiver's fixes are not a header position; the averaged single-point solution wins
    ubx_header = ReceiverHeader(approx_position_ecef_m=fixes, approx_position_source="receiver-fixes")
    p, notes, basis = _base_position(_fake_base(ubx_header, t), opts, spp)
    assert np.linalg.norm(p - SITE) < 1.0
    (note,) = notes
    # its stated uncertainty: the sigma of the mean and the broadcast models' common error, in quadrature
    avg = average_spp_positions(t, pos, cov)
    assert basis["source"] == "averaged-single-point" and "not surveyed" in basis["text"]
    np.testing.assert_allclose(basis["sigma_enu_m"], np.hypot(avg.sigma_mean_enu_m, SPP_COMMON_SIGMA_ENU_M), atol=1e-3)
    assert "averaged single-point" in note and "base-x.ubx" in note and "RINEX header" not in note.split(";")[1]
    assert "sigma of the mean" in note and "Scatter of single epochs" in note and "formal" in note
    assert "independent 300 s blocks" in note and "metre-level" in note and "receiver's own fixes" in note
    # no single-point solution: the receiver's own fixes, named as such
    p, (note,), basis = _base_position(_fake_base(ubx_header, t), opts, None)
    np.testing.assert_allclose(p, fixes)
    assert "receiver's own navigation fixes" in note and "base-x.ubx" in note
    assert basis["source"] == "receiver-fixes" and basis["sigma_enu_m"] == list(RECEIVER_FIX_SIGMA_ENU_M)
    # --base-pos first, silently
    given = SITE + np.array([0.1, 0.2, 0.3])
    p, notes, basis = _base_position(_fake_base(ubx_header, t), RtkOptions(base_position_ecef_m=tuple(given)), spp)
    np.testing.assert_allclose(p, given)
    assert notes == [] and basis["source"] == "given" and basis["sigma_enu_m"] is None
    # a RINEX header (the field unset, as the RINEX reader leaves it) comes before the single-point solution
    rinex_header = ReceiverHeader(approx_position_ecef_m=fixes, rinex_version=3.04)
    p, (note,), basis = _base_position(_fake_base(rinex_header, t, "base.obs"), opts, spp)
    np.testing.assert_allclose(p, fixes)
    assert note == "base position taken from the RINEX header of base.obs"
    assert basis["source"] == "rinex-header" and basis["sigma_enu_m"] is None and "surveyed" in basis["text"]
    rtcm_header = ReceiverHeader(approx_position_ecef_m=fixes, rinex_version=None, approx_position_source="rtcm-station")
    p, (note,), _ = _base_position(_fake_base(rtcm_header, t, "base.rtcm3"), opts, spp)
    np.testing.assert_allclose(p, fixes)
    assert "RTCM 3 1005/1006" in note and "base.rtcm3" in note
    # a position from a header of unstated origin (older readers): used as before
    p, (note,), _ = _base_position(_fake_base(ReceiverHeader(approx_position_ecef_m=fixes), t), opts, spp)
    np.testing.assert_allclose(p, fixes)
    assert note == "base position taken from the header of base-x.ubx"
    # nothing at all
    with pytest.raises(ProcessingError, match="give --base-pos"):
        _base_position(_fake_base(ReceiverHeader(), t), opts, None)


def test_rinex_base_without_header_position_uses_the_averaged_single_point_solution():
    """GSI 3040 without its APPROX POSITION: the base log's averaged single-point position (120 epochs,
    30 s, GPS L1) lies 0.8 m from the header's station coordinates. The single-point solution starts from
    the rover's (from the Earth's centre the SPP kernel divided by zero: this fallback never ran)."""
    from georef_core.gnss.ppk import prepare

    rover = read_rinex_obs(DATA / "07590920.05o")
    nav = read_rinex_nav(DATA / "07590920.05n")
    base = read_rinex_obs(DATA / "30400920.05o")
    opts = RtkOptions(mode="static", filter_direction="forward", systems=("G",))
    header_pos = base.header.approx_position_ecef_m.copy()
    _, _, pos, (note,), _, _ = prepare(rover, base, nav, opts)
    np.testing.assert_array_equal(pos, header_pos)
    assert note == f"base position taken from the RINEX header of {base.source_path}"
    base.header.approx_position_ecef_m = None
    _, _, pos, (note,), _, _ = prepare(rover, base, nav, opts)
    assert np.linalg.norm(pos - header_pos) < 2.0
    assert "averaged single-point position" in note and base.source_path in note and "sigma of the mean" in note


def _walk_dir():
    root = shared_gnss_dir()
    walk = root / "ublox_m8p_20181004_walk" if root is not None else None
    return walk if walk is not None and (walk / "base-20181004-1452.ubx.gz").is_file() else None


WALK = _walk_dir()
# the author's base coordinates (dataset README; ellipsoidal height, as RTKLIB's -l takes it)
WALK_BASE_LLH = (53.280449957, -9.057836328, 66.8)


@pytest.mark.skipif(WALK is None, reason="shared u-blox M8P walk data not available")
def test_ubx_base_position_is_the_averaged_single_point_solution():
    """Measured (2026-11, 882 RXM-RAWX epochs of the lossy base log over 61 min): the averaged single-point
    position is 2.8 m from the author's coordinates (E/N/U -0.3/+0.2/-2.8 m; stated sigma of the mean
    0.35/0.43/0.76 m, so the height error is ~3.7 sigma: broadcast-ionosphere errors do not average out),
    the receiver's own fixes (its 128 s survey-in mean) 5.3 m, convbin's header (one epoch's single-point
    position) 8.0 m, and the averaged position 5.9 m from convbin's header."""
    from georef_core.gnss.ppk import prepare
    from georef_core.gnss.ubx import read_ubx

    rover = read_ubx(WALK / "rover-20181004-1532.ubx.gz")
    base = read_ubx(WALK / "base-20181004-1452.ubx.gz")
    assert base.observations.header.approx_position_source == "receiver-fixes"
    nav = rover.navigation.merge(base.navigation)
    _, _, base_pos, notes, _, _ = prepare(rover.observations, base.observations, nav, RtkOptions())
    (note,) = notes
    assert "single-point" in note and "base-20181004-1452.ubx.gz" in note and "RINEX header of" not in note
    ref = geodetic_to_ecef_m(*np.radians(WALK_BASE_LLH[:2]), WALK_BASE_LLH[2])
    convbin = None
    for line in (WALK / "base-20181004-1452.obs").read_text().splitlines()[:30]:
        if "APPROX POSITION XYZ" in line:
            convbin = np.array([float(v) for v in line[:42].split()])
    fixes = base.observations.header.approx_position_ecef_m
    d_ref, d_convbin = np.linalg.norm(base_pos - ref), np.linalg.norm(base_pos - convbin)
    assert d_ref < 4.0 and d_convbin < 8.0, (d_ref, d_convbin)
    assert d_ref < np.linalg.norm(fixes - ref) and d_ref < np.linalg.norm(convbin - ref)
    # with --base-pos the log's positions are not used
    _, _, given, notes, _, _ = prepare(rover.observations, base.observations, nav,
                                       RtkOptions(base_position_ecef_m=tuple(ref)))
    np.testing.assert_allclose(given, ref)
    assert notes == []
