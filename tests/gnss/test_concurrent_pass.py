"""The second filter pass run in a forked child (georef_core/gnss/concurrent_pass.py) gives the .pos of the
serial solve, byte for byte; a child that fails or is cancelled leaves the pass to this process; the
arbiter's blocked anchor search (phase_consistency.anchored_rms_m) picks the anchors the one-by-one loop
picked. GEONET sample (tests/data/gnss/gsi_0759_3040, 120 epochs, GPS L1): the static forward run has fixes
its witness contradicts, so the arbiter runs."""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np
import pytest

from georef_core.gnss import concurrent_pass, phase_consistency, ppk
from georef_core.gnss.fix_continuity import refuse_jumping_fixes
from georef_core.gnss.rtk_filter import STATUS_FIX, RtkFilter
from georef_core.gnss.rtk_kernels import phase_residuals
from georef_core.gnss.rtk_options import RtkOptions
from georef_core.gnss.solution_io import write_pos

DATA = Path(__file__).resolve().parents[1] / "data" / "gnss" / "gsi_0759_3040"
ROVER, BASE = DATA / "07590920.05o", DATA / "30400920.05o"
NAVS = [DATA / "07590920.05n", DATA / "30400920.05n"]
# the demo5 reference configuration static_l1_fwd_cont of shared/data/gnss as RtkOptions
GEONET = RtkOptions(mode="static", n_bands=1, systems=("G",), filter_direction="forward", ar_mode="continuous",
                    glonass_ar=False, base_interpolation=False, phase_error_a_m=0.003, phase_error_b_m=0.003,
                    base_position_ecef_m=(-3978241.958, 3382840.234, 3649900.853))


class _Spy:
    """Counts the second passes a child delivered (not computed again here)."""

    def __init__(self, monkeypatch):
        self.forked = self.from_child = 0
        real = concurrent_pass.ForkedPass
        spy = self

        class Counting(real):
            def __init__(self, fn):
                spy.forked += 1
                self._calls_here = 0

                def here():
                    self._calls_here += 1
                    return fn()
                super().__init__(fn)
                self.fn = here   # the fallback, should the child fail

            def result(self):
                value = super().result()
                spy.from_child += self._calls_here == 0
                return value

        monkeypatch.setattr(concurrent_pass, "ForkedPass", Counting)


def _pos_bytes(tmp_path: Path, opts: RtkOptions, name: str) -> bytes:
    sol = ppk.solve_files(ROVER, BASE, NAVS, opts)
    write_pos(tmp_path / name, sol)
    return (tmp_path / name).read_bytes()


@pytest.mark.parametrize("direction,mode", [("forward", "static"), ("backward", "kinematic"),
                                            ("combined", "kinematic")])
def test_forked_second_pass_gives_the_serial_pos(tmp_path, monkeypatch, direction, mode):
    opts = dataclasses.replace(GEONET, filter_direction=direction, mode=mode)
    monkeypatch.setenv(concurrent_pass.ENV, "0")
    serial = _pos_bytes(tmp_path, opts, "serial.pos")
    spy = _Spy(monkeypatch)
    monkeypatch.setenv(concurrent_pass.ENV, "1")
    forked = _pos_bytes(tmp_path, opts, "forked.pos")
    assert (spy.forked, spy.from_child) == (1, 1)   # the second pass did come from the child
    assert forked == serial
    assert sum(line[0] != "%" for line in serial.decode().splitlines()) == 120


def test_static_forward_witness_conflicts_are_decided_the_same(monkeypatch):
    """The case where the arbiter runs: the forked witness refuses the same fixes."""
    monkeypatch.setenv(concurrent_pass.ENV, "0")
    serial = ppk.solve_files(ROVER, BASE, NAVS, GEONET)
    monkeypatch.setenv(concurrent_pass.ENV, "1")
    forked = ppk.solve_files(ROVER, BASE, NAVS, GEONET)
    assert serial.fix_conflicts is not None and serial.fix_conflicts.any()
    np.testing.assert_array_equal(forked.fix_conflicts, serial.fix_conflicts)
    np.testing.assert_array_equal(forked.status, serial.status)
    np.testing.assert_array_equal(forked.covariance_ecef_m2, serial.covariance_ecef_m2)


def test_a_failing_child_leaves_the_pass_to_this_process():
    parent = os.getpid()

    def work():
        if os.getpid() != parent:
            raise RuntimeError("the child fails")
        return np.arange(5.0)

    np.testing.assert_array_equal(concurrent_pass.ForkedPass(work).result(), np.arange(5.0))


def test_cancel_ends_the_child():
    job = concurrent_pass.ForkedPass(lambda: time.sleep(60))
    pid = job.pid
    assert pid is not None
    t0 = time.monotonic()
    job.cancel()
    assert time.monotonic() - t0 < 5
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)   # reaped, not a zombie


def test_worth_forking_rules(monkeypatch):
    monkeypatch.setenv(concurrent_pass.ENV, "0")
    assert not concurrent_pass.worth_forking(10 ** 9)
    monkeypatch.setenv(concurrent_pass.ENV, "1")
    assert concurrent_pass.worth_forking(1)
    monkeypatch.delenv(concurrent_pass.ENV)
    monkeypatch.setattr(concurrent_pass.threading, "active_count", lambda: 1)   # (pytest-xdist's workers run threads)
    monkeypatch.setattr(concurrent_pass, "_load_1min", lambda: 0.5)
    assert not concurrent_pass.worth_forking(concurrent_pass.MIN_SIGNAL_EPOCHS - 1)
    monkeypatch.setattr(concurrent_pass, "usable_cpus", lambda: 1)
    assert not concurrent_pass.worth_forking(10 ** 9)
    monkeypatch.setattr(concurrent_pass, "usable_cpus", lambda: 2)
    assert concurrent_pass.worth_forking(10 ** 9)
    monkeypatch.setattr(concurrent_pass, "_load_1min", lambda: 1.5)   # no idle CPU of the two
    assert not concurrent_pass.worth_forking(10 ** 9)
    monkeypatch.setattr(concurrent_pass, "usable_cpus", lambda: 16)
    assert concurrent_pass.worth_forking(10 ** 9)
    monkeypatch.setattr(concurrent_pass, "_load_1min", lambda: 0.5)
    monkeypatch.setattr(concurrent_pass.threading, "active_count", lambda: 2)
    assert not concurrent_pass.worth_forking(10 ** 9)


def _anchored_rms_one_by_one(spans, position_ecef_m, fixed, anchor_ecef_m, anchors, max_anchors, min_signals):
    """The anchor search as a plain loop: every anchor, nearest first, tested on its own."""
    d, cfg = spans.d, spans.cfg
    out = np.full(len(d.time_s), np.nan)
    for e in np.nonzero(fixed)[0]:
        rms = []
        for a in anchors[np.argsort(np.abs(anchors - e), kind="stable")]:
            lo, hi = min(a, e), max(a, e)
            ok = phase_consistency._span_signals(d, lo, hi, spans.unbroken)
            if a == e or ok.sum() < min_signals:
                continue
            r_a = phase_residuals(d, cfg, a, np.asarray(anchor_ecef_m[a], float), spans.zero_amb, ok)[0]
            r_e = phase_residuals(d, cfg, e, np.asarray(position_ecef_m[e], float), spans.zero_amb, ok)[0]
            change = phase_consistency.reference_free_change_rms(r_a, r_e, ok, d.sys_code)
            if np.isfinite(change):
                rms.append(float(change))
            if len(rms) == max_anchors:
                break
        if rms:
            out[e] = float(np.median(rms))
    return out


def test_blocked_anchor_search_matches_the_plain_loop():
    from georef_core.gnss.input_files import load_navigation, load_observations

    opts = dataclasses.replace(GEONET, mode="kinematic")
    data = ppk.prepare(load_observations(ROVER).observations, load_observations(BASE).observations,
                       load_navigation(NAVS), opts)[0]
    flt = RtkFilter(data, opts)
    arrays, config = flt.arrays(), flt.config()
    fwd = refuse_jumping_fixes(arrays, config, flt.run(backward=False))[0]
    bwd = refuse_jumping_fixes(arrays, config, flt.run(backward=True))[0]
    fixed = fwd.status == STATUS_FIX
    anchors = np.nonzero(fixed & (bwd.status == STATUS_FIX))[0][::3]   # sparse: some epochs look far
    spans = phase_consistency.PhaseSpans(data, opts)
    for min_signals in (4, 6):
        got, used = phase_consistency.anchored_rms_m(data, opts, fwd.position_ecef_m, fixed, bwd.position_ecef_m,
                                                     anchors, min_signals=min_signals, spans=spans)
        want = _anchored_rms_one_by_one(spans, fwd.position_ecef_m, fixed, bwd.position_ecef_m, anchors,
                                        phase_consistency.MAX_ANCHORS, min_signals)
        assert np.isfinite(got).sum() > 50
        np.testing.assert_array_equal(got, want)
        # and again through the anchor residuals cached by the first call
        again, _ = phase_consistency.anchored_rms_m(data, opts, fwd.position_ecef_m, fixed, bwd.position_ecef_m,
                                                    anchors, min_signals=min_signals, spans=spans)
        np.testing.assert_array_equal(again, want)
