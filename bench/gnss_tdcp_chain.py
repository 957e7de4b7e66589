"""A judge of fixed positions that needs no ambiguity and no anchor reachable by unbroken signals: the rover's
displacement between consecutive epochs from its own time-differenced carrier phase (TDCP; rover only, so base
gaps do not matter), chained epoch by epoch from an anchor (an epoch both engines fix alike) to the judged epoch.
Each step needs only that enough signals be unbroken between the two epochs of the step (slip_cum: flagged
and TDCP-detected slips, outages, half-cycle changes), not the same signals along the whole chain, so it reaches
where the carrier-phase judge (phase_consistency.anchored_rms_m: signals unbroken from anchor to epoch) cannot.

Step model, per pair of epochs (e, e+1) and system: the rover phase minus the broadcast model at one position
p (the rough position of epoch e, for both epochs), differenced in time, is -los . dx + a clock change per
system; least squares for dx with the worst signal beyond 3 cm dropped and the fit repeated; a step with fewer
than (3 + systems + 2) signals, or a post-fit RMS over 2 cm, breaks the chain. Only signals above the
configuration's elevation mask (pos1-elmask) are used: the walk's horizon satellites (0-5 degrees, which the
filter never uses) have a steady 6-25 mm/s time-differenced residual, below the 3 cm outlier test, that made
the chain drift ~3 mm per step. A step that breaks is tried again with one clock change for all systems (the
inter-system bias barely changes in a second), which needs one signal less.

Checked first between anchors (the chain from one anchor predicting another: error against length), then
applied to the walk's disputed stretches: our fixes and demo5's, each compared with the position chained from the
nearest anchor before and after (docs/gnss.md, "TDCP chain").

    GEOREF_SHARED_DATA=/work/shared python bench/gnss_tdcp_chain.py [--doppler] [--all-elevations] [--two-clocks]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from georef_core.gnss.fix_continuity import refuse_jumping_fixes
from georef_core.gnss.input_files import load_navigation, load_observations
from georef_core.gnss.ppk import prepare
from georef_core.gnss.rtk_filter import STATUS_FIX, RtkFilter
from georef_core.gnss.rtk_kernels import rover_model_m
from georef_core.gnss.rtk_options import read_rtklib_conf
from georef_core.gnss.solution_io import read_pos
from tests.gnss.rtklib_cases import reference_cases
from tests.gnss.solution_compare import pos_ecef_m

OUTLIER_M = 0.03
MAX_STEP_RMS_M = 0.02
MIN_ELEVATION_DEG = 15.0


def tdcp_steps(arrays, rough_ecef_m, single_difference: bool = True, min_elevation_deg: float = MIN_ELEVATION_DEG,
               one_clock: bool = False):
    """Displacement (E-1, 3) from each epoch to the next (NaN where the step breaks), post-fit RMS (E-1,) and
    the number of signals used (E-1,). Band 0 only. single_difference: the base's phase residuals (interpolated
    and extrapolated across base gaps, base_alignment.py) are subtracted, which removes the ionosphere's and
    the broadcast orbits' change; else rover phase alone."""
    n_e, n_s = arrays.el.shape
    phase = arrays.rover_phase_m[:, :, 0]
    if single_difference:
        phase = phase - arrays.base_phase_res_m[:, :, 0]
    usable = np.isfinite(phase) & np.isfinite(arrays.rover_code_m[:, :, 0]) & (np.abs(arrays.sat_pos).sum(axis=2) > 0)
    usable &= arrays.el >= np.radians(min_elevation_deg)
    slip = arrays.slip_cum[:, :, 0]
    sys_code = np.zeros_like(arrays.sys_code) if one_clock else arrays.sys_code
    n_sys = int(sys_code.max()) + 1
    dx = np.full((n_e - 1, 3), np.nan)
    rms = np.full(n_e - 1, np.nan)
    n_used = np.zeros(n_e - 1, int)
    los0, los1 = np.empty((n_s, 3)), np.empty((n_s, 3))
    for e in range(n_e - 1):
        p = rough_ecef_m[e]
        if not np.isfinite(p).all():
            continue
        ok = usable[e] & usable[e + 1] & (slip[e + 2] == slip[e + 1])
        if ok.sum() < 3 + n_sys + 2:
            continue
        g0 = rover_model_m(arrays, e, p, los0)
        g1 = rover_model_m(arrays, e + 1, p, los1)
        y_all = (phase[e + 1] - g1) - (phase[e] - g0)
        idx = np.nonzero(ok)[0]
        while True:
            systems = np.unique(sys_code[idx])
            h = np.zeros((len(idx), 3 + len(systems)))
            h[:, :3] = -los1[idx]
            for k, s in enumerate(systems):
                h[sys_code[idx] == s, 3 + k] = 1.0
            if len(idx) < h.shape[1] + 2:
                break
            sol, *_ = np.linalg.lstsq(h, y_all[idx], rcond=None)
            res = y_all[idx] - h @ sol
            worst = int(np.argmax(np.abs(res)))
            if abs(res[worst]) > OUTLIER_M:
                idx = np.delete(idx, worst)
                continue
            r = float(np.sqrt(np.sum(res**2) / (len(idx) - h.shape[1])))
            if r <= MAX_STEP_RMS_M:
                dx[e], rms[e], n_used[e] = sol[:3], r, len(idx)
            break
    return dx, rms, n_used


def bridge_with_doppler(dx, time_s, velocity_ecef_m_s):
    """Broken steps replaced by the Doppler velocity (single point, rover) integrated over the step (mean of
    the two epochs' velocities times the interval); returns the new steps and which were bridged."""
    v = velocity_ecef_m_s
    bridged = ~np.isfinite(dx[:, 0]) & np.isfinite(v[:-1]).all(axis=1) & np.isfinite(v[1:]).all(axis=1)
    out = dx.copy()
    dt = np.diff(time_s)
    out[bridged] = 0.5 * (v[:-1] + v[1:])[bridged] * dt[bridged, None]
    return out, bridged


def chained(dx, anchors_idx, anchors_pos, e):
    """Positions of epoch e chained from the nearest anchor before and after it ((3,) or None each), and the
    number of steps of each chain."""
    out = []
    before = anchors_idx[anchors_idx <= e]
    if len(before):
        a = before[-1]
        steps = dx[a:e]
        out.append((anchors_pos[a] + steps.sum(axis=0), e - a) if np.isfinite(steps).all() else (None, e - a))
    else:
        out.append((None, 0))
    after = anchors_idx[anchors_idx >= e]
    if len(after):
        a = after[0]
        steps = dx[e:a]
        out.append((anchors_pos[a] - steps.sum(axis=0), a - e) if np.isfinite(steps).all() else (None, a - e))
    else:
        out.append((None, 0))
    return out


def on_epochs(pos, time_s):
    """A .pos solution on the filter's epochs: (E, 3) positions (NaN where none) and status."""
    x = np.full((len(time_s), 3), np.nan)
    st = np.zeros(len(time_s), int)
    p = pos_ecef_m(pos)
    for e, t in enumerate(time_s):
        j = int(np.argmin(np.abs(pos.time_s - t)))
        if abs(pos.time_s[j] - t) < 0.2:
            x[e], st[e] = p[j], pos.status[j]
    return x, st


def main():
    cases = [c for c in reference_cases() if "ublox" in c[0] and "_comb_" in c[1]]
    for ds, name, rover, base, navs, conf, ref in cases:
        opts = read_rtklib_conf(conf).options
        data, spp = prepare(load_observations(rover).observations, load_observations(base).observations,
                            load_navigation(navs), opts)[:2]
        flt = RtkFilter(data, opts)
        arrays = flt.arrays()

        def passes():
            return [refuse_jumping_fixes(flt.arrays(), flt.config(), flt.run(backward=b))[0] for b in (False, True)]

        f0, b0 = passes()
        demo5, demo5_status = on_epochs(read_pos(ref), data.time_s)
        rough = np.where(np.isfinite(f0.float_position_ecef_m), f0.float_position_ecef_m, data.spp_position_ecef_m)
        mask_deg = -90.0 if "--all-elevations" in sys.argv else opts.elevation_mask_deg
        dx, rms, n_used = tdcp_steps(arrays, rough, min_elevation_deg=mask_deg)
        # where a step breaks (too few signals for a clock change per system): one clock change for all
        # systems (the receiver's inter-system bias barely changes in a second)
        dx1, rms1, n1 = tdcp_steps(arrays, rough, min_elevation_deg=mask_deg, one_clock=True)
        one = ~np.isfinite(dx[:, 0]) & np.isfinite(dx1[:, 0])
        if "--two-clocks" not in sys.argv:
            dx[one], rms[one], n_used[one] = dx1[one], rms1[one], n1[one]
        else:
            one[:] = False
        ok_steps = np.isfinite(dx[:, 0])
        tdcp_only = dx.copy()
        if "--doppler" in sys.argv:
            dx, bridged = bridge_with_doppler(dx, data.time_s, spp.velocity_ecef_m_s)
        else:
            bridged = np.zeros(len(dx), bool)
        print(f"\n== {ds} {name}: elevation mask {mask_deg:.0f} deg; TDCP steps {ok_steps.sum()} of {len(dx)} "
              f"(one clock: {one.sum()} at GPST {[int(t) % 10000 for t in data.time_s[:-1][one]]}; median RMS "
              f"{np.nanmedian(rms)*1e3:.1f} mm, median signals {np.median(n_used[ok_steps]):.0f}); Doppler-bridged "
              f"steps {bridged.sum()} at GPST {[int(t) % 10000 for t in data.time_s[:-1][bridged]]}")
        if "--doppler" in sys.argv:
            # the Doppler bridge's own error: the integrated velocity against the TDCP steps, summed over k
            # consecutive steps (where all k have a TDCP step)
            vdx, _ = bridge_with_doppler(np.full_like(tdcp_only, np.nan), data.time_s, spp.velocity_ecef_m_s)
            diff = vdx - tdcp_only
            for k in (1, 2, 3, 5, 10, 20):
                win = np.array([diff[i:i + k].sum(axis=0) for i in range(len(diff) - k + 1)])
                win = np.linalg.norm(win[np.isfinite(win).all(axis=1)], axis=1)
                print(f"  Doppler bridge against TDCP over {k} consecutive steps: n {len(win)}, error median "
                      f"{np.median(win)*1e3:.0f} mm, 95 % {np.percentile(win, 95)*1e3:.0f} mm, "
                      f"max {win.max()*1e3:.0f} mm")
        # anchors: epochs where demo5's combined fix and one of our passes (as configured) fix within 2 cm
        anchor = np.zeros(len(data.time_s), bool)
        for out in (f0, b0):
            anchor |= (demo5_status == 1) & (out.status == STATUS_FIX) & (
                np.linalg.norm(out.position_ecef_m - demo5, axis=1) < 0.02)
        a_idx = np.nonzero(anchor)[0]
        a_pos = np.full_like(demo5, np.nan)
        a_pos[a_idx] = demo5[a_idx]
        print(f"  anchors {len(a_idx)}")
        # check: every anchor predicted from every other anchor the chain reaches (error against chain length)
        errs = []
        cum = np.vstack([np.zeros(3), np.cumsum(np.nan_to_num(dx), axis=0)])
        broken = np.concatenate([[0], np.cumsum(~np.isfinite(dx[:, 0]))])
        n_bridged = np.concatenate([[0], np.cumsum(bridged)])
        for i in a_idx:
            for j in a_idx[a_idx > i]:
                if broken[j] - broken[i]:
                    break
                errs.append((j - i, np.linalg.norm(a_pos[i] + (cum[j] - cum[i]) - a_pos[j]),
                             n_bridged[j] - n_bridged[i]))
        errs = np.array(errs)
        for lab, sel in (("TDCP only", 0), ("with Doppler-bridged steps", 1)):
            for lo, hi in ((1, 2), (2, 10), (10, 50), (50, 100), (100, 200), (200, 400), (400, 800)):
                m = ((errs[:, 0] >= lo) & (errs[:, 0] < hi) & ((errs[:, 2] > 0) == sel)
                     if len(errs) else np.zeros(0, bool))
                if m.any():
                    print(f"  anchor from anchor over {lo}-{hi - 1} steps, {lab}: n {m.sum()}, error median "
                          f"{np.median(errs[m, 1])*1e3:.0f} mm, 95 % {np.percentile(errs[m, 1], 95)*1e3:.0f} mm, "
                          f"max {errs[m, 1].max()*1e3:.0f} mm" + (f", bridged steps {int(errs[m, 2].min())}-"
                                                                 f"{int(errs[m, 2].max())}" if sel else ""))
        # every fixed epoch of each candidate that is not an anchor: distance to the chained positions
        for lab, pos, st in (("ours F", f0.position_ecef_m, f0.status), ("ours B", b0.position_ecef_m, b0.status),
                             ("demo5 C", demo5, demo5_status)):
            fixed = np.nonzero((st == 1) & ~anchor)[0]
            n_reach, bad = 0, []
            for e in fixed:
                best = None
                for p, n in chained(dx, a_idx, a_pos, e):
                    if p is not None and (best is None or n < best[1]):
                        best = (np.linalg.norm(pos[e] - p), n)
                if best is None:
                    continue
                n_reach += 1
                if best[0] > 0.10:
                    bad.append((int(data.time_s[e]) % 10000, best[0], best[1]))
            runs = []
            for t, d, n in bad:
                if runs and t - runs[-1][1] <= 2:
                    runs[-1][1] = t
                    runs[-1][2] = max(runs[-1][2], d)
                else:
                    runs.append([t, t, d, n])
            print(f"  {lab:18s}: fixed (not anchors) {len(fixed)}, reached {n_reach}, > 10 cm from the chain "
                  f"{len(bad)}: " + ", ".join(f"{a}-{b} ({d:.2f} m, {n} steps)" for a, b, d, n in runs))
        # the stretch docs/gnss.md calls undecidable (GPST 1222702676-684): every candidate's fix against both chains
        for e in np.nonzero((data.time_s >= 1222702675) & (data.time_s <= 1222702690))[0]:
            row = f"  {data.time_s[e]:.0f}"
            for lab, pos, st in (("F", f0.position_ecef_m, f0.status), ("B", b0.position_ecef_m, b0.status),
                                 ("demo5", demo5, demo5_status)):
                if st[e] != 1:
                    continue
                (pb, nb), (pa, na) = chained(dx, a_idx, a_pos, e)
                parts = [f"{np.linalg.norm(pos[e] - p):.2f} m/{n} ({int(nbr)} bridged)" if p is not None else f"-/{n}"
                         for p, n, nbr in ((pb, nb, bridged[e - nb:e].sum()), (pa, na, bridged[e:e + na].sum()))]
                row += f" | {lab} fixed: chain before {parts[0]}, after {parts[1]}"
            print(row)


if __name__ == "__main__":
    main()
