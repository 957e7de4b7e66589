"""The reverse pass as a witness (fix_witness.py): fixes the other filter direction contradicts are not
output as fixed, in forward, backward and combined solutions alike."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from georef_core.gnss.fix_witness import contradicted_fixes, fixed_runs, refuse_contradicted_fixes
from georef_core.gnss.rtk_filter import STATUS_FIX, STATUS_FLOAT, STATUS_SINGLE, FilterOutput

from .rtklib_cases import reference_cases

F, X, S = STATUS_FLOAT, STATUS_FIX, STATUS_SINGLE


def _pass(status, pos, float_pos=None):
    status = np.array(status)
    n = len(status)
    pos = np.array(pos, float)
    flt = np.full((n, 3), -7.0) if float_pos is None else np.array(float_pos, float)
    pos[status != X] = flt[status != X]
    return FilterOutput(status, pos, np.tile(np.eye(3) * 1e-4, (n, 1, 1)), np.full(n, 8), np.full(n, 3.5),
                        np.zeros((n, 2, 1)), np.zeros(n, np.int64), flt, np.tile(np.eye(3), (n, 1, 1)))


def _at(x):
    """(N, 3) positions with all three coordinates x[i]."""
    return np.repeat(np.array(x, float)[:, None], 3, axis=1)


def test_fixed_runs_numbers_runs_of_consecutive_fixes():
    assert list(fixed_runs(np.array([F, X, X, F, X, S, X, X]))) == [-1, 0, 0, -1, 1, -1, 2, 2]


def test_two_fixes_apart_are_both_refused_and_a_short_run_goes_whole():
    """Forward fixed throughout (12 epochs), backward fixed at epochs 4-7 only, 30 cm away. Nothing decides
    which is wrong: both refused at the overlap (the backward run, 4 epochs, is all overlap); the forward
    run (12 epochs, longer than MAX_REFUSED_RUN) keeps its other epochs and gets its own float at the
    overlap. A short run against a long one: the short run goes whole, the long one at the overlap only."""
    fwd = _pass([X] * 12, _at([0.0] * 12))
    bwd = _pass([F] * 4 + [X] * 4 + [F] * 4, _at([0.0] * 4 + [0.3] * 4 + [0.0] * 4))
    ra, rb, conflict = contradicted_fixes(fwd, bwd)
    assert list(np.nonzero(conflict)[0]) == [4, 5, 6, 7]
    assert list(np.nonzero(ra)[0]) == [4, 5, 6, 7]
    assert list(np.nonzero(rb)[0]) == [4, 5, 6, 7]
    fwd_out, refused = refuse_contradicted_fixes(fwd, bwd)
    assert list(fwd_out.status[3:9]) == [X, F, F, F, F, X]
    np.testing.assert_array_equal(fwd_out.position_ecef_m[4], [-7.0] * 3)      # its own float, not the fix
    # a short forward run against a longer backward one: the forward run goes whole
    short = _pass([F] * 2 + [X] * 4 + [F] * 6, _at([0.0] * 3 + [0.3] * 3 + [0.0] * 6))
    long_ = _pass([X] * 12, _at([0.0] * 12))
    bwd_long = dataclasses.replace(long_)
    bwd_long.status = np.array([F] + [X] * 11)
    ra, rb, conflict = contradicted_fixes(short, bwd_long)
    assert list(np.nonzero(conflict)[0]) == [3, 4, 5]
    assert list(np.nonzero(ra)[0]) == [2, 3, 4, 5]       # the whole 4-epoch run, epoch 2 alike included
    assert list(np.nonzero(rb)[0]) == [3, 4, 5]          # the 11-epoch run at the overlap only


def test_a_run_confirmed_elsewhere_wins_over_one_confirmed_nowhere():
    """Forward fixed throughout, backward agreeing over epochs 0-5 and then, after a float gap, a run of 3
    fixes 10 cm away: the forward run holds anchors (epochs both fix alike), the backward's second run none."""
    n = 12
    fwd = _pass([X] * n, np.zeros((n, 3)))
    status = [X] * 6 + [F, F] + [X] * 3 + [F]
    pos = np.zeros((n, 3))
    pos[8:11] = 0.1
    bwd = _pass(status, pos)
    ra, rb, conflict = contradicted_fixes(fwd, bwd)
    assert list(np.nonzero(conflict)[0]) == [8, 9, 10]
    assert not ra.any()
    assert list(np.nonzero(rb)[0]) == [8, 9, 10]


def test_arbiter_decides_and_both_kept_when_both_fit():
    n = 6
    fwd = _pass([X] * n, np.zeros((n, 3)))
    bwd = _pass([X] * n, _at([0, 0, 0.2, 0.2, 0, 0]))
    for verdict, keep_a, keep_b in ((1, True, False), (2, False, True), (3, True, True), (0, False, False)):
        def arbiter(epochs, pa, pb, anchors, apos, v=verdict):
            assert list(epochs) == [2, 3] and list(anchors) == [0, 1, 4, 5]
            return np.full(len(epochs), v, dtype=np.int8)
        ra, rb, _ = contradicted_fixes(fwd, bwd, arbiter)
        assert ra[2:4].any() != keep_a and rb[2:4].any() != keep_b, verdict


def test_a_lone_fix_without_the_other_pass_fixed_is_refused():
    fwd = _pass([F, X, F, F, X, X, F, X], np.zeros((8, 3)))
    bwd = _pass([F, F, F, S, F, F, F, X], np.zeros((8, 3)))
    ra, rb, _ = contradicted_fixes(fwd, bwd)
    assert list(np.nonzero(ra)[0]) == [1]        # 7 is alone too, but the other pass confirms it
    assert not rb.any()                          # backward's lone fix at 7: forward fixed alike there


WALK = [c for c in reference_cases() if c[0] == "ublox_m8p_20181004_walk" and c[1] == "kinematic_l1_fwd_fah"]


@pytest.mark.skipif(not WALK, reason="shared/data/gnss not found (set GEOREF_SHARED_DATA)")
def test_walk_forward_and_backward_solutions_never_contradict_each_other():
    """The shared u-blox walk (L1, lossy base), fix-and-hold: without the witness our forward and backward
    solutions are both fixed, metres apart, at two epochs (the backward pass's run of 2.6 m off fixes);
    with it (the default) no epoch is fixed in both more than 5 cm apart, and the fix rates stay above
    demo5's (34.9 % forward on the same configuration)."""
    from georef_core.gnss.input_files import load_navigation, load_observations
    from georef_core.gnss.ppk import solve
    from georef_core.gnss.rtk_options import read_rtklib_conf

    _, _, rover, base, navs, conf, _ = WALK[0]
    r, b = load_observations(rover).observations, load_observations(base).observations
    nav = load_navigation(navs)
    opts = read_rtklib_conf(conf).options

    def apart(witness):
        f = solve(r, b, nav, dataclasses.replace(opts, filter_direction="forward", reverse_witness=witness))
        k = solve(r, b, nav, dataclasses.replace(opts, filter_direction="backward", reverse_witness=witness))
        both = (f.status == X) & (k.status == X)
        d = np.linalg.norm(f.position_ecef_m - k.position_ecef_m, axis=1)
        return f, k, int(np.sum(both & (d > 1.0))), int(np.sum(both & (d > 0.05)))

    _, _, far, off = apart(False)
    assert far >= 1 and off >= far
    f, k, far, off = apart(True)
    assert far == 0 and off == 0
    assert f.fix_rate >= 0.349 and k.fix_rate > 0.1
    assert f.fix_conflicts is not None and f.fix_conflicts.sum() >= 1
