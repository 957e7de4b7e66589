"""Stale base data in the simulated cases of bench/gnss_sim_vs_demo5.py (issue 22): how the double-difference
error grows with the age of the base data, whether our fixed epochs' formal sigma covers it, and what an
ephemeris record change inside a base gap does. TUNE seeds only unless --split JUDGE is given; docs/gnss.md,
"Stale base data (2026-11-27)".

Three parts (each can be run alone with --part):

* ``dd``: the base's zero-difference phase residuals as the engine computes them (base_alignment.
  base_zero_difference: observation - range - satellite clock - troposphere at the known base position) on the
  base's own epochs. For every pair of epochs ``a`` seconds apart (both present, no loss of lock between
  them, satellites above 15 degrees, one system) the double difference (against the system's highest
  satellite) of ``res(t + a) - res(t)`` is the error of holding the base data ``a`` seconds (the nearest-epoch
  pairing of demo5 and of an RTKLIB configuration, misc-timeinterp off), and ``res(t + a) - (res(t) + res(t +
  2a)) / 2`` the error of interpolating across a 2a-second gap at its middle (our default). Pairs across an
  ephemeris record change (the record the engine selects for a satellite differs between the two epochs)
  are counted apart: they are not an age effect. Printed: RMS and 99th percentile (mm) per lag, and the model's
  double-difference age term sqrt(2) c clock_stability a for comparison.
* ``calib``: our engine (RTKLIB configuration of the bench: kinematic L1, continuous and fix-and-hold,
  forward and backward) on each case; per fixed epoch the 3-D error against the truth, the formal 3-D sigma
  sqrt(trace(covariance)) and the engine's base age; a table per age bin: RMS error, median and largest
  sigma, RMS and 99th percentile of error / sigma, fixed epochs beyond 5 cm.
* ``record``: the same solutions without and with base residuals dropped (set to no data) where the
  ephemeris record the engine selects at the base epoch(s) paired with a rover epoch differs from the one it
  selects at the rover epoch (base_alignment.align_base_to_rover's ``records``, which ppk.prepare does not
  pass yet: wired here by a patch of ppk for this measurement). On the split's (or the given) cases as they are, and for TUNE also on a constructed case:
  TUNE seed 14 with its base epochs 08:30:14-08:30:40 GPST removed (a gap across the GLONASS record change at
  08:30:18 GPST).

    python bench/gnss_stale_base.py                       # all three parts on TUNE (a few minutes on 2 cores)
    python bench/gnss_stale_base.py --part record --split JUDGE
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import gnss_sim_vs_demo5 as sim  # noqa: E402
from gnss_corpus import _match, make_conf  # noqa: E402

from georef_core.gnss import ppk  # noqa: E402
from georef_core.gnss.base_alignment import base_zero_difference, ephemeris_records  # noqa: E402
from georef_core.gnss.constants import CLIGHT_M_S, wavelength_table_m  # noqa: E402
from georef_core.gnss.cycle_slips import lli_slips  # noqa: E402
from georef_core.gnss.gnss_time import calendar_to_gps_time_s, gps_time_s_to_datetime  # noqa: E402
from georef_core.gnss.input_files import load_navigation  # noqa: E402
from georef_core.gnss.observations import select_bands  # noqa: E402
from georef_core.gnss.rtk_options import RtkOptions, read_rtklib_conf  # noqa: E402
from georef_core.gnss.satellite_geometry import compute_observed_satellites  # noqa: E402

LAGS_S = tuple(range(1, 31))
MIN_ELEVATION_DEG = 15.0
AGE_BINS_S = ((0.0, 0.5), (0.5, 3.0), (3.0, 6.0), (6.0, 10.0), (10.0, 15.0), (15.0, 20.0), (20.0, 31.0))
PASS_SET = (("continuous", "forward"), ("continuous", "backward"), ("fix-and-hold", "forward"),
            ("fix-and-hold", "backward"))


# ------------------------------------------------------------------------------------------- part dd

def base_residuals(case: sim.SimCase):
    """(times, phase residuals (E, S) m, elevation (E, S) rad, sat_ids, cumulative loss-of-lock count (E, S),
    record index (E, S)) of the case's base, band 1, GPS and GLONASS."""
    loaded, _ = ppk.load_receiver(case.corpus_case.base, "base")
    nav = load_navigation(list(case.corpus_case.navs))
    base = select_bands(loaded.observations)
    sat_ids = [s for s in base.sat_ids if s[0] in "GR"]
    base = ppk.reindex_satellites(base, sat_ids)
    lam = wavelength_table_m(sat_ids, {**base.header.glonass_fcn, **nav.glonass_fcn()})
    bsat = compute_observed_satellites(base, nav)
    opts = RtkOptions()
    phase, _, el = base_zero_difference(base, bsat, nav, base.header.approx_position_ecef_m, lam, opts.troposphere,
                                        "off", opts.dd_troposphere_humidity)
    slips = lli_slips(base.lli, base.phase_cyc)[..., 0]
    return (base.gps_time_s, phase[..., 0], el, sat_ids, np.cumsum(slips, axis=0),
            ephemeris_records(nav, sat_ids, base.gps_time_s))


def _dd(x: np.ndarray, ok: np.ndarray, el: np.ndarray, systems: np.ndarray) -> list[np.ndarray]:
    """Double differences of x (P, S) per row and system against the row's highest usable satellite."""
    out = []
    for sys_ in np.unique(systems):
        m = ok & (systems == sys_)[None, :]
        rows = np.nonzero(m.sum(axis=1) >= 2)[0]
        if len(rows) == 0:
            continue
        e = np.where(m[rows], el[rows], -np.inf)
        ref = np.argmax(e, axis=1)
        d = x[rows] - x[rows, ref][:, None]
        keep = m[rows].copy()
        keep[np.arange(len(rows)), ref] = False
        out.append(d[keep])
    return out


def dd_error_vs_age(seeds, tmp: Path) -> dict:
    """{lag: {"hold": array, "interp": array, "record_hold": array}} of DD errors (m) over the seeds."""
    acc = {a: {"hold": [], "interp": [], "record_hold": []} for a in LAGS_S}
    for seed in seeds:
        case = sim.build_case(seed, tmp)
        t, ph, el, sat_ids, cum, rec = base_residuals(case)
        systems = np.array([s[0] for s in sat_ids])
        sec = np.round(t - t[0]).astype(np.int64)
        pos = np.full(sec[-1] + 1, -1, dtype=np.int64)
        pos[sec] = np.arange(len(t))
        high = el > math.radians(MIN_ELEVATION_DEG)
        for a in LAGS_S:
            i = np.arange(len(t))
            tj = sec + a
            j = np.where(tj <= sec[-1], pos[np.minimum(tj, sec[-1])], -1)
            sel = j >= 0
            i, j = i[sel], j[sel]
            ok = (np.isfinite(ph[i]) & np.isfinite(ph[j]) & high[i] & (cum[i] == cum[j]) & (rec[i] >= 0))
            same_rec = rec[i] == rec[j]
            hold = ph[j] - ph[i]
            acc[a]["hold"] += _dd(hold, ok & same_rec, el[i], systems)
            # record change between the epochs, otherwise as above: the DD error of the pairs where any satellite
            # of the pair's system changed record
            acc[a]["record_hold"] += _dd(hold, ok & ~same_rec, el[i], systems) if np.any(ok & ~same_rec) else []
            tk = sec[i] + 2 * a
            k = np.where(tk <= sec[-1], pos[np.minimum(tk, sec[-1])], -1)
            s2 = k >= 0
            i2, j2, k2 = i[s2], j[s2], k[s2]
            ok2 = ((ok & same_rec)[s2] & np.isfinite(ph[k2]) & (cum[k2] == cum[i2]) & (rec[k2] == rec[i2]))
            acc[a]["interp"] += _dd(ph[j2] - 0.5 * (ph[i2] + ph[k2]), ok2, el[i2], systems)
    return {a: {k: (np.concatenate(v) if v else np.zeros(0)) for k, v in d.items()} for a, d in acc.items()}


def print_dd(acc: dict, clock_stability: float) -> None:
    print("base residual double differences vs the age of the base data (GPS+GLONASS, > 15 deg, no loss of lock, "
          "same ephemeris record); mm")
    print(" age s | hold RMS  p99      n | interp. RMS  p99      n | model sqrt(2) c clkstab age | across a record "
          "change: hold RMS  n")
    for a in LAGS_S:
        h, ip, rc = acc[a]["hold"], acc[a]["interp"], acc[a]["record_hold"]

        def f(x):
            return (f"{np.sqrt(np.mean(x ** 2)) * 1e3:7.1f} {np.percentile(np.abs(x), 99) * 1e3:6.1f} {len(x):6d}"
                    if len(x) else f"{'-':>7s} {'-':>6s} {0:6d}")
        rcs = f"{np.sqrt(np.mean(rc ** 2)) * 1e3:7.1f} {len(rc):5d}" if len(rc) else f"{'-':>7s} {0:5d}"
        print(f"  {a:4d} | {f(h)} | {f(ip)} | {math.sqrt(2) * CLIGHT_M_S * clock_stability * a * 1e3:8.1f} | {rcs}")


# ---------------------------------------------------------------------------------------- part calib

def _solve(case: sim.SimCase, tmp: Path, mode: str, soltype: str, base_path=None):
    c = case.corpus_case
    conf = make_conf(c, tmp, f"{mode}_{soltype}", **{"pos1-posmode": "kinematic", "pos1-frequency": "l1",
                                                      "pos1-soltype": soltype, "pos2-armode": mode})
    return ppk.solve_files(c.rover, base_path or c.base, c.navs, read_rtklib_conf(conf).options)


def _fixed_rows(sol, case: sim.SimCase) -> np.ndarray:
    """(N, 3) base age s, 3-D error m, 3-D sigma m of the fixed epochs of a solution."""
    ia, ib = _match(sol.time_s, case.truth.time_s)
    fx = sol.status[ia] == 1
    err = np.linalg.norm(sol.position_ecef_m[ia] - case.truth.ecef[ib], axis=1)
    sig = np.sqrt(np.abs(np.trace(sol.covariance_ecef_m2[ia], axis1=1, axis2=2)))
    return np.column_stack([sol.age_s[ia], err, sig])[fx]


def calibration(seeds, tmp: Path) -> np.ndarray:
    rows = []
    for seed in seeds:
        case = sim.build_case(seed, tmp)
        for mode, soltype in PASS_SET:
            rows.append(_fixed_rows(_solve(case, tmp, mode, soltype), case))
    return np.concatenate(rows)


def print_calibration(rows: np.ndarray) -> None:
    age, err, sig = rows[:, 0], rows[:, 1], rows[:, 2]
    print(f"our fixed epochs (continuous and fix-and-hold, forward and backward; {len(rows)}) by the engine's base age")
    print(" age s        |      n | err RMS cm | sigma3d med / max cm | err/sigma RMS  p99 | > 5 cm")
    for lo, hi in AGE_BINS_S:
        m = (age >= lo) & (age < hi)
        if not m.any():
            continue
        z = err[m] / sig[m]
        print(f" [{lo:4.1f}, {hi:4.1f}) | {m.sum():6d} | {np.sqrt(np.mean(err[m] ** 2)) * 100:10.2f} | "
              f"{np.median(sig[m]) * 100:8.2f} / {sig[m].max() * 100:5.2f} | {np.sqrt(np.mean(z ** 2)):13.2f} "
              f"{np.percentile(z, 99):5.2f} | {np.sum(err[m] > sim.WRONG_FIX_M):6d}")


# --------------------------------------------------------------------------------------- part record

class RecordConsistentBase:
    """Context: ppk's base alignment given the ephemeris records of the base and rover epochs
    (base_alignment.align_base_to_rover's ``records``: a satellite whose paired base epoch(s) have another
    record than the rover epoch gets no base data there). ppk.prepare does not pass them (yet): this patch
    wires them for the measurement."""

    def __init__(self):
        self.dropped = 0

    def __enter__(self):
        self._bzd, self._align = ppk.base_zero_difference, ppk.align_base_to_rover
        state = {}

        def bzd(base, bsat, nav, *a, **k):
            state["nav"] = nav
            return self._bzd(base, bsat, nav, *a, **k)

        def align(rover_t, base, *a, **k):
            records = (ephemeris_records(state["nav"], base.sat_ids, base.gps_time_s),
                       ephemeris_records(state["nav"], base.sat_ids, rover_t))
            plain = self._align(rover_t, base, *a, **k)
            res = self._align(rover_t, base, *a, **k, records=records)
            self.dropped += int(np.sum(np.isfinite(plain.phase_res_m[..., 0]) & np.isnan(res.phase_res_m[..., 0])))
            return res

        ppk.base_zero_difference, ppk.align_base_to_rover = bzd, align
        return self

    def __exit__(self, *exc):
        ppk.base_zero_difference, ppk.align_base_to_rover = self._bzd, self._align
        return False


def cut_base(path: Path, t0_s: float, t1_s: float) -> Path:
    """A copy of a RINEX 3 observation file without its epochs in [t0_s, t1_s] (GPS s)."""
    out, skip = [], False
    for ln in Path(path).read_text().splitlines(keepends=True):
        if ln.startswith(">"):
            p = ln[1:].split()
            t = calendar_to_gps_time_s(int(p[0]), int(p[1]), int(p[2]), int(p[3]), int(p[4]), 0) + float(p[5])
            skip = t0_s <= t <= t1_s
        if not skip:
            out.append(ln)
    dst = Path(path).with_name(Path(path).stem + "_cut.obs")
    dst.write_text("".join(out))
    return dst


def _pass_line(sol, case, window) -> tuple[str, int, int, int]:
    ia, ib = _match(sol.time_s, case.truth.time_s)
    fx = sol.status[ia] == 1
    err = np.linalg.norm(sol.position_ecef_m[ia] - case.truth.ecef[ib], axis=1)
    wrong = fx & (err > sim.WRONG_FIX_M)
    txt = f"fix {100 * fx.mean():5.1f} %, > 5 cm {wrong.sum():3d}, worst {100 * err[fx].max() if fx.any() else 0:5.1f} cm"
    if window is not None:
        w = (sol.time_s[ia] >= window[0]) & (sol.time_s[ia] <= window[1])
        txt += f"; in the gap and 30 s after: fixed {np.sum(fx & w)}/{w.sum()}, worst {100 * err[fx & w].max() if np.any(fx & w) else 0:5.1f} cm"
    return txt, int(fx.sum()), int(wrong.sum()), len(ia)


def record_comparison(seeds, tmp: Path, cut: tuple[float, float] | None, verbose: bool) -> None:
    modes = [(m, s) for m in sim.MODES for s in sim.PASSES]
    tot = {False: np.zeros((len(modes), 3), int), True: np.zeros((len(modes), 3), int)}
    changed = []
    for seed in seeds:
        case = sim.build_case(seed, tmp)
        base_path = cut_base(case.corpus_case.base, *cut) if cut else None
        window = (cut[0], cut[1] + 30.0) if cut else None
        lines = {}
        for drop in (False, True):
            for k, (mode, soltype) in enumerate(modes):
                if drop:
                    with RecordConsistentBase() as rc:
                        sol = _solve(case, tmp, mode, soltype, base_path)
                else:
                    rc = None
                    sol = _solve(case, tmp, mode, soltype, base_path)
                txt, n_fix, n_wrong, n = _pass_line(sol, case, window)
                tot[drop][k] += (n_fix, n_wrong, n)
                lines[(drop, k)] = txt + (f" (base residuals dropped: {rc.dropped})" if rc else "")
        diff = any(lines[(False, k)] != lines[(True, k)].split(" (base residuals")[0] for k in range(len(modes)))
        if diff:
            changed.append(seed)
        if verbose or diff:
            print(f"seed {seed} [{case.split}] {case.description}" + (" (base cut " + " - ".join(
                f"{gps_time_s_to_datetime(x):%H:%M:%S}" for x in cut) + " GPST)" if cut else ""))
            for k, (mode, soltype) in enumerate(modes):
                print(f"  {mode:12s} {soltype:8s} as is:          {lines[(False, k)]}")
                print(f"  {'':12s} {'':8s} record-consistent: {lines[(True, k)]}")
    print(f"seeds whose figures change: {changed or 'none'}")
    print("totals over the seeds (fixed epochs / epochs, fixed > 5 cm):")
    for k, (mode, soltype) in enumerate(modes):
        a, b = tot[False][k], tot[True][k]
        print(f"  {mode:12s} {soltype:8s} as is {100 * a[0] / max(a[2], 1):5.2f} % fixed, {a[1]:3d} > 5 cm | "
              f"record-consistent {100 * b[0] / max(b[2], 1):5.2f} % fixed, {b[1]:3d} > 5 cm")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=("dd", "calib", "record", "all"), default="all")
    ap.add_argument("--split", choices=("TUNE", "JUDGE"), default="TUNE")
    ap.add_argument("--seeds", type=int, nargs="*", help="these seeds instead of the split's")
    ap.add_argument("--verbose", action="store_true", help="record part: every seed, not only those that change")
    ap.add_argument("--cut-only", action="store_true", help="record part: only the constructed case (TUNE seed 14 cut)")
    args = ap.parse_args()
    seeds = args.seeds or (sim.TUNE_SEEDS if args.split == "TUNE" else sim.JUDGE_SEEDS)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="stale_base_") as tmp_s:
        tmp = Path(tmp_s)
        if args.part in ("dd", "all"):
            print_dd(dd_error_vs_age(seeds, tmp), RtkOptions().clock_stability)
        if args.part in ("calib", "all"):
            print_calibration(calibration(seeds, tmp))
        if args.part in ("record", "all"):
            if args.split == "TUNE" and (args.seeds is None or args.cut_only):
                day0 = calendar_to_gps_time_s(2024, 6, 24, 0, 0, 0)
                cut = (day0 + 8 * 3600 + 30 * 60 + 14, day0 + 8 * 3600 + 30 * 60 + 40)
                print("constructed case: TUNE seed 14, base epochs removed across the GLONASS record change")
                record_comparison([14], tmp, cut, True)
            if not args.cut_only:
                print(f"the cases as they are ({args.split if args.seeds is None else 'given'} seeds)")
                record_comparison(seeds, tmp, None, args.verbose)
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
