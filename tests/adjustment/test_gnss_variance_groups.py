"""A GNSS variance factor per group of positions (BundleProblem.gnss_variance_group: e.g. RTK fixed / float), each
from its own residuals and redundancy numbers, instead of one for all (docs/dji.md, "Variance factors per
quality": opt-in, not used by the georef step). Synthetic block of make_block with known truth: half the positions
noisier than stated by a factor 3, the other half as stated. The adjustment's two rounds of variance-component
estimation are far from converged for these low-redundancy positions (the image block carries the cameras to about a
millimetre): the factors come out 0.25 and 1.54 for the truth 1 and 3, which the test records rather than hides."""

import numpy as np

from georef_core.adjustment.bundle_adjustment import BundleOptions, adjust
from georef_core.adjustment.camera_model import free_mask
from tests.adjustment.test_bundle_adjustment import TRUE_DELAY, TRUE_LEVER, make_block

STATED_M = 0.004       # make_block's GNSS noise and stated sigma


def _case(groups: bool):
    prob, truth = make_block(5, per_line=8, n_points=500)
    n = len(prob.gnss_camera)
    noisy = np.arange(n) >= n // 2                       # lines 3-4
    rng = np.random.default_rng(55)
    prob.antenna_enu_m[noisy] += rng.normal(0, np.sqrt(3.0 ** 2 - 1.0) * STATED_M, (int(noisy.sum()), 3))
    prob.lever_arm_cam_m, prob.delay_s = TRUE_LEVER.copy(), TRUE_DELAY
    if groups:
        prob.gnss_variance_group = noisy.astype(int)
    return adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                      estimate_delay=False, min_gnss_sigma_m=0.0))


def test_each_group_gets_its_own_variance_factor():
    """The noisier group gets the larger factor, the one shared factor lies between the two, and the group factors
    are carried from one adjustment to the next (initial_variances, as the georef step's leave-one-out re-runs)."""
    one, two = _case(False), _case(True)
    s = one.sigma0
    g0, g1 = two.sigma0["gnss_group_0"], two.sigma0["gnss_group_1"]
    print(f"GNSS sigma0: one factor {s['gnss']:.2f}; per group {g0:.2f} (stated right) / {g1:.2f} (3x)")
    assert "gnss_group_0" not in s and two.sigma0["gnss"] == 1.0
    assert g1 > 3 * g0 and g0 < s["gnss"] < g1, (s, two.sigma0)
    prob = two.problem
    var = {k: v ** 2 for k, v in two.sigma0.items()}
    again = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                       estimate_delay=False, min_gnss_sigma_m=0.0, variance_components=False,
                                       initial_variances=var))
    assert np.isclose(again.sigma0["gnss_group_0"], g0) and np.isclose(again.sigma0["gnss_group_1"], g1)
