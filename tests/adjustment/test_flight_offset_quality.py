"""The per-flight offsets' prior from the positions' own quality (docs/dji.md, "The per-flight prior from the RTK
quality"): each flight's fixed and not-fixed exposures get their own offset, whose sigma is the larger of the
default and the median of the exposures' sigmas (RtkStd of the photos, the PPK's). Synthetic two-flight block with
known truth (make_block, no images): flight 1 fixed, flight 2 RTK float whose error is mostly a bias common to the
flight (as a float solution's is). The rule makes the camera centres' and check points' covariances honest where the
default prior (1 cm / 1.5 cm for every flight) leaves them far too small."""

import numpy as np
import pytest

from georef_core.adjustment.bundle_adjustment import BundleOptions, adjust, flight_offset_prior_cov
from georef_core.adjustment.camera_model import free_mask
from georef_core.steps.georef import GeorefOptions, ImageGnss, flight_offset_groups, flight_offset_prior
from tests.adjustment.test_flight_offsets import anees, two_flight_block

DEFAULT_SIGMA_ENU_M = np.array([0.01, 0.01, 0.015])      # flight_offset_sigma_m's default (1 cm, 1.5 cm)
FLOAT_SIGMA_ENU_M = np.array([0.06, 0.06, 0.10])         # the float flight's stated per-exposure sigmas


def float_flight_case(seed: int, rule: bool, n_control: int = 0, float_bias_m=None, float_white_m: float = 0.01,
                      fixed_offset_m=(0.01, -0.01, 0.015), per_line: int = 8, n_points: int = 500,
                      vce_groups: bool = False) -> dict:
    """Two flights of make_block: flight 1 RTK fixed (4 mm noise, stated 4 mm) shifted by ``fixed_offset_m``, flight
    2 RTK float stated to FLOAT_SIGMA_ENU_M per exposure, its error a common bias ``float_bias_m`` (default: one
    stated sigma on each axis, signs + - +) plus ``float_white_m`` of noise per exposure. ``rule``: the offsets'
    prior from the quality (flight_offset_groups), else the default prior for each flight. ANEES of the camera
    centres and of 12 check points (tie points) against the truth. ``vce_groups``: a GNSS variance factor per quality
    (fixed / float) instead of one for all."""
    bias = FLOAT_SIGMA_ENU_M * np.array([1.0, -1.0, 1.0]) if float_bias_m is None else np.asarray(float_bias_m, float)
    prob, truth, checks = two_flight_block(seed, np.array([fixed_offset_m, np.zeros(3)]), n_control,
                                           per_line=per_line, n_points=n_points)
    fl = prob.gnss_flight
    rng = np.random.default_rng(500 + seed)
    fl2 = fl == 1
    prob.antenna_enu_m[fl2] += bias + rng.normal(0, float_white_m, (int(fl2.sum()), 3))
    prob.antenna_cov_enu_m2[fl2] = np.diag(FLOAT_SIGMA_ENU_M ** 2)
    status = np.where(fl2, 2, 1)                  # PPK / RtkFlag codes as ImageGnss.status: 1 fixed, 2 float
    names = [f"DJI_{k:04d}.JPG" for k in range(len(fl))]
    if rule:
        sig = np.sqrt(np.einsum("kii->ki", prob.antenna_cov_enu_m2))
        group_of, rows = flight_offset_groups({n: (int(f), int(s), sg) for n, f, s, sg in zip(names, fl, status, sig)},
                                              DEFAULT_SIGMA_ENU_M)
        prob.gnss_flight = np.array([group_of[n] for n in names])
        prob.flight_offset_prior_cov_m2 = flight_offset_prior_cov(len(rows), 0.0, [r["sigma_enu_m"] for r in rows])
    else:
        prob.flight_offset_prior_cov_m2 = flight_offset_prior_cov(2, 0.0, DEFAULT_SIGMA_ENU_M)
    if vce_groups:
        prob.gnss_variance_group = (status != 1).astype(int)
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                     estimate_delay=False, cov_points=tuple(int(c) for c in checks)))
    p = res.problem
    e_c = p.centre_enu_m - truth["C"]
    e_p = p.points_enu_m[checks] - truth["P"][checks]
    return {"anees_cameras": anees(e_c, res.camera_cov[:, 3:, 3:]),
            "anees_checks": anees(e_p, np.array([res.point_cov_enu_m2[int(c)] for c in checks])),
            "offsets_m": res.flight_offset_enu_m, "offsets_sigma_m": np.sqrt(np.diag(res.flight_offset_cov_m2))}


def test_float_flight_gets_its_own_prior_and_honest_covariances():
    """Without the rule the float flight's 6-10 cm bias is held to 1-1.5 cm: ANEES of cameras and check points far
    above 1 (> 5, > 3). With it the flight's prior is its median stated sigma and both ANEES are in [0.3, 2]; the
    flights' difference is measured within 2 sigma."""
    old = float_flight_case(0, rule=False)
    new = float_flight_case(0, rule=True)
    print(f"float flight: ANEES cameras / check points, default prior {old['anees_cameras']:.2f} / "
          f"{old['anees_checks']:.2f}, prior from the quality {new['anees_cameras']:.2f} / {new['anees_checks']:.2f}")
    assert old["anees_cameras"] > 5 and old["anees_checks"] > 3, old
    assert 0.3 <= new["anees_cameras"] <= 2 and 0.3 <= new["anees_checks"] <= 2, new
    assert np.allclose(new["offsets_sigma_m"][3:] > 0.015, True)     # the float flight's offset is not held to 1 cm
    true_diff = np.array([0.01, -0.01, 0.015]) - FLOAT_SIGMA_ENU_M * [1, -1, 1]
    sd = new["offsets_sigma_m"].reshape(2, 3)
    diff = new["offsets_m"][0] - new["offsets_m"][1]
    assert np.all(np.abs(diff - true_diff) < 2 * np.hypot(sd[0], sd[1])), (diff, true_diff)


def test_groups_by_flight_and_fix_state_with_median_sigmas():
    ex = {"a": (0, 1, [0.004, 0.004, 0.008]), "b": (0, 1, [0.02, 0.02, 0.03]), "c": (0, 1, [0.02, 0.03, 0.04]),
          "d": (0, 2, [0.2, 0.3, 0.5]), "e": (0, 5, [1.5, 1.5, 3.0]), "f": (1, 1, [0.005, 0.005, 0.01])}
    group_of, rows = flight_offset_groups(ex, DEFAULT_SIGMA_ENU_M)
    assert [group_of[n] for n in "abcdef"] == [0, 0, 0, 1, 1, 2]
    assert [(r["flight"], r["quality"], r["images"]) for r in rows] == [(1, "fixed", 3), (1, "not fixed", 2),
                                                                        (2, "fixed", 1)]
    # fixed flight 1: its median stated sigma (2 cm, 2 cm, 3 cm) is above the default; flight 2: the default
    assert rows[0]["sigma_enu_m"] == [0.02, 0.02, 0.03] and rows[2]["sigma_enu_m"] == [0.01, 0.01, 0.015]
    assert rows[1]["sigma_enu_m"] == [0.85, 0.9, 1.75] and rows[1]["status"] == [2, 5]


def _gnss(n, status, from_photos=False, kind=""):
    return ImageGnss([f"IMG_{k:03d}.JPG" for k in range(n)], np.arange(n, dtype=float), np.zeros((n, 3)),
                     np.zeros((n, 3)), np.full((n, 3), 0.01), np.asarray(status, int), "test", from_photos=from_photos,
                     kind=kind)


@pytest.mark.parametrize("from_photos", [False, True])
def test_auto_models_one_flight_that_is_not_fixed(from_photos):
    """One flight over a surveyed base, all fixed: auto leaves the adjustment as it was; RTK-tagged photos, all fixed:
    auto models their session's error (docs/dji.md, "The RTK session's error"); the same flight with float exposures
    gets the offsets, the float ones their own with their median sigma."""
    opts = GeorefOptions()
    kind = "rtk" if from_photos else ""
    g = _gnss(4, [1, 1, 1, 1], from_photos, kind)
    fixed = {n: (0, 1, np.array([0.01, 0.01, 0.02])) for n in g.names}
    one_fixed = flight_offset_prior(opts, g, 1, None, fixed)
    assert (one_fixed is None) != from_photos
    if from_photos:
        assert one_fixed["groups"][0]["sigma_enu_m"] == [0.01, 0.01, 0.02] and "session" in one_fixed["common_source"]
    mixed = dict(fixed, **{n: (0, 2, np.array([0.08, 0.07, 0.15])) for n in g.names[2:]})
    prior = flight_offset_prior(opts, g, 1, None, mixed)
    assert prior is not None and [r["quality"] for r in prior["groups"]] == ["fixed", "not fixed"]
    assert prior["groups"][1]["sigma_enu_m"] == [0.08, 0.07, 0.15]
    assert prior["group_of_image"] == {"IMG_000.JPG": 0, "IMG_001.JPG": 0, "IMG_002.JPG": 1, "IMG_003.JPG": 1}
    assert ("RtkStd" in prior["flight_source"]) == from_photos
    # the modes gcp and similarity get the same prior (their fits model the offsets too)
    for mode in ("gcp", "similarity"):
        assert flight_offset_prior(GeorefOptions(mode=mode), g, 2, None, fixed) is not None


def test_summary_rows_and_accuracy_text_name_the_not_fixed_part():
    """The summary has one row per offset (flight, quality, prior from the rule); absolute_accuracy names the float
    part's prior in joint mode and leaves the offsets out in mode gcp (they move the lever arm and delay only)."""
    from types import SimpleNamespace

    from georef_core.steps.georef import _absolute_accuracy, _flight_offsets_summary, _offset_groups_of

    g = _gnss(6, [1, 1, 2, 2, 1, 1])
    flights = {n: 0 if k < 4 else 1 for k, n in enumerate(g.names)}
    ex = {n: (flights[n], int(g.status[k]), np.array([0.1, 0.1, 0.2]) if g.status[k] == 2 else np.full(3, 0.005))
          for k, n in enumerate(g.names)}
    prior = flight_offset_prior(GeorefOptions(), g, 2, None, ex)
    prior.update(flights=flights, flights_from="test")
    idx, cov, present = _offset_groups_of(prior, g.names)
    assert idx.tolist() == [0, 0, 1, 1, 2, 2] and np.allclose(np.sqrt(np.diag(cov))[3:6], [0.1, 0.1, 0.2])
    res = SimpleNamespace(flight_offset_enu_m=np.zeros((3, 3)), flight_offset_cov_m2=cov)
    fo = _flight_offsets_summary(prior, g.names, res, "nothing: no control point")
    assert [(r["flight"], r["quality"], r["prior_sigma_enu_m"]) for r in fo["flights"]] == [
        (1, "fixed", [0.01, 0.01, 0.015]), (1, "not fixed", [0.1, 0.1, 0.2]), (2, "fixed", [0.01, 0.01, 0.015])]
    enu = {n: (np.zeros(3), np.zeros(3), np.eye(3) * 1e-4, 1, 0.0) for n in g.names}
    adj = SimpleNamespace(stats={"mode": "joint", "flight_offsets": fo}, gnss_rows=[{"image": n} for n in g.names],
                          centre_cov_enu_m2=np.repeat(np.eye(3)[None] * 1e-4, 6, 0))
    text = _absolute_accuracy(g, adj, SimpleNamespace(points={}), enu)["text"]
    assert "Each of the 2 flight(s)" in text and "flight 1's 2 exposures not fixed" in text and "10.0 cm" in text
    adj.stats["mode"] = "gcp"
    assert "flight(s)" not in _absolute_accuracy(g, adj, SimpleNamespace(points={}), enu)["text"]


def test_float_stretches_split_by_fixed_exposures_and_time_gaps():
    """A flight's not-fixed exposures get one offset per stretch: contiguous in time, ended by a fixed exposure or
    by more than FLOAT_STRETCH_GAP_S (60 s) without an exposure; ordered by time, not by the order given."""
    from georef_core.steps.georef import FLOAT_STRETCH_GAP_S

    s = [0.05, 0.05, 0.08]
    ex = {"f": (0, 2, s, 8.0 + FLOAT_STRETCH_GAP_S + 1), "a": (0, 1, DEFAULT_SIGMA_ENU_M, 0.0), "b": (0, 2, s, 2.0),
          "c": (0, 2, s, 4.0), "d": (0, 1, DEFAULT_SIGMA_ENU_M, 6.0), "e": (0, 5, [1.0, 1.0, 2.0], 8.0),
          "g": (1, 2, s, 300.0), "h": (1, 2, s, 302.0)}
    group_of, rows = flight_offset_groups(ex, DEFAULT_SIGMA_ENU_M)
    assert [group_of[n] for n in "abcdefgh"] == [0, 1, 1, 0, 2, 3, 4, 4]
    assert [(r["flight"], r["quality"], r["images"], r.get("stretch")) for r in rows] == [
        (1, "fixed", 2, None), (1, "not fixed", 2, 1), (1, "not fixed", 1, 2), (1, "not fixed", 1, 3),
        (2, "not fixed", 2, None)]
    assert rows[2]["sigma_enu_m"] == [1.0, 1.0, 2.0] and rows[1]["sigma_enu_m"] == [0.05, 0.05, 0.08]
    # without times (3-tuples) the order given is the time order: b, c one stretch, e another after the fixed d
    g3, _ = flight_offset_groups({n: v[:3] for n, v in ex.items() if n != "f"}, DEFAULT_SIGMA_ENU_M)
    assert [g3[n] for n in "abcdegh"] == [0, 1, 1, 0, 2, 3, 3]
