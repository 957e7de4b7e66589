"""The per-flight offsets' prior from the positions' RTK quality (docs/dji.md, "The per-flight prior from the RTK
quality"), and the offsets in the modes similarity and gcp, on synthetic blocks with known truth.

Quality: the blocks of tests/adjustment/test_flight_offset_quality.py (4 lines of 8 photos, 500 ground points;
flight 1 = lines 1-2, RTK fixed: an offset drawn from N(0, 1 cm / 1 cm / 1.5 cm) plus 4 mm noise, stated 4 mm;
flight 2 = lines 3-4, RTK float stated to 6 / 6 / 10 cm per exposure, its error a bias common to the flight holding
90 % of that variance plus independent noise holding 10 %), adjusted with the default prior (1 cm / 1.5 cm for
every flight: before the rule) and with the prior from the quality (the rule), with no control point and with one;
and the same block flown as one all-float flight (before the rule: no offsets at all, as `auto` left one flight
over a surveyed base). Prints the ANEES of the camera centres and of 12 check points over the surveys, and the
ratio to the default's.

Float stretches (`--stretches N`): the same block flown as one flight, lines 1 and 3 RTK fixed (a common offset
drawn from N(0, 1 / 1 / 1.5 cm) plus 4 mm noise, stated 4 mm), lines 2 and 4 two separate RTK-float stretches stated
to 6 / 6 / 10 cm, each with its own bias (90 % of that variance) plus 10 % independent noise. Adjusted with one
offset for all float exposures of the flight (before) and one per stretch (flight_offset_groups), each with one GNSS
variance factor and with a factor per quality group (fixed / not fixed: gnss_variance_group). Seeds 0-3 were looked
at while writing it; the figures quoted are of seeds from `--first-seed` (100) on.

Modes: the two-flight blocks of tests/adjustment/test_flight_offset_modes.py, offsets drawn from their prior
(3.5 cm per flight and axis), 200 surveys each: camera-centre ANEES (similarity) and z-score RMS of lever arm and
delay (gcp), offsets modelled or not.

    python bench/flight_offsets_quality.py [--surveys 8] [--stretches 16 --first-seed 100 --only-stretches]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from georef_core.adjustment.bundle_adjustment import BundleOptions, adjust, flight_offset_prior_cov  # noqa: E402
from georef_core.adjustment.camera_model import free_mask  # noqa: E402
from georef_core.steps.georef import flight_offset_groups  # noqa: E402
from tests.adjustment import test_flight_offset_modes as modes  # noqa: E402
from tests.adjustment.test_flight_offset_quality import (DEFAULT_SIGMA_ENU_M, FLOAT_SIGMA_ENU_M,  # noqa: E402
                                                         float_flight_case)
from tests.adjustment.test_flight_offsets import anees, two_flight_block  # noqa: E402

COMMON_SHARE = 0.9      # share of a float solution's stated variance that is a bias common to the flight


def one_float_flight(seed: int, rule: bool, rng) -> tuple[float, float]:
    """The whole block one RTK-float flight (bias + noise as above); before the rule no offset was modelled."""
    prob, truth, checks = two_flight_block(seed, np.zeros((2, 3)), 0, per_line=8, n_points=500)
    n = len(prob.gnss_camera)
    prob.antenna_enu_m += rng.normal(0, np.sqrt(COMMON_SHARE) * FLOAT_SIGMA_ENU_M) + \
        rng.normal(0, np.sqrt(1 - COMMON_SHARE) * FLOAT_SIGMA_ENU_M, (n, 3))
    prob.antenna_cov_enu_m2[:] = np.diag(FLOAT_SIGMA_ENU_M ** 2)
    if rule:
        names = [str(k) for k in range(n)]
        g, rows = flight_offset_groups({k: (0, 2, FLOAT_SIGMA_ENU_M) for k in names}, DEFAULT_SIGMA_ENU_M)
        prob.gnss_flight = np.zeros(n, int)
        prob.flight_offset_prior_cov_m2 = flight_offset_prior_cov(1, 0.0, [r["sigma_enu_m"] for r in rows])
    else:
        prob.gnss_flight = None
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                     estimate_delay=False, cov_points=tuple(int(c) for c in checks)))
    p = res.problem
    return (anees(p.centre_enu_m - truth["C"], res.camera_cov[:, 3:, 3:]),
            anees(p.points_enu_m[checks] - truth["P"][checks], np.array([res.point_cov_enu_m2[int(c)] for c in checks])))


def two_stretch_case(seed: int, per_stretch: bool, vce_groups: bool, n_control: int = 0) -> tuple[float, float, float]:
    """One flight (docstring: float stretches); ANEES cameras, ANEES check points, ANEES of the float cameras."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 77]))
    prob, truth, checks = two_flight_block(seed, np.zeros((2, 3)), n_control, per_line=8, n_points=500)
    n = len(prob.gnss_camera)
    line = np.arange(n) // 8
    fl = (line == 1) | (line == 3)
    prob.antenna_enu_m[~fl] += rng.normal(0, DEFAULT_SIGMA_ENU_M)
    for ln in (1, 3):
        m = line == ln
        prob.antenna_enu_m[m] += rng.normal(0, np.sqrt(COMMON_SHARE) * FLOAT_SIGMA_ENU_M) + \
            rng.normal(0, np.sqrt(1 - COMMON_SHARE) * FLOAT_SIGMA_ENU_M, (int(m.sum()), 3))
    prob.antenna_cov_enu_m2[fl] = np.diag(FLOAT_SIGMA_ENU_M ** 2)
    sig = np.sqrt(np.einsum("kii->ki", prob.antenna_cov_enu_m2))
    names = [f"DJI_{k:04d}.JPG" for k in range(n)]
    ex = {nm: (0, 2 if f else 1, sg, 2.0 * k) for k, (nm, f, sg) in enumerate(zip(names, fl, sig))}
    if per_stretch:
        group_of, rows = flight_offset_groups(ex, DEFAULT_SIGMA_ENU_M)
        prob.gnss_flight = np.array([group_of[nm] for nm in names])
        own = [r["sigma_enu_m"] for r in rows]
    else:     # the rule until now: one offset for the flight's fixed exposures, one for all its others
        prob.gnss_flight = fl.astype(int)
        own = [np.maximum(DEFAULT_SIGMA_ENU_M, np.median(sig[g], axis=0)) for g in (~fl, fl)]
    prob.flight_offset_prior_cov_m2 = flight_offset_prior_cov(len(own), 0.0, own)
    prob.gnss_variance_group = fl.astype(int) if vce_groups else None
    res = adjust(prob, BundleOptions(free_intrinsics=free_mask("brown"), estimate_lever_arm=False,
                                     estimate_delay=False, cov_points=tuple(int(c) for c in checks)))
    p = res.problem
    cc = res.camera_cov[:, 3:, 3:]
    e = p.centre_enu_m - truth["C"]
    return (anees(e, cc), anees(p.points_enu_m[checks] - truth["P"][checks],
                                np.array([res.point_cov_enu_m2[int(c)] for c in checks])), anees(e[fl], cc[fl]))


def _line(name, old, new):
    o, n = np.array(old), np.array(new)
    print(f"  {name}: ANEES cameras / check points: before the rule {o[:, 0].mean():.2f} (median "
          f"{np.median(o[:, 0]):.2f}) / {o[:, 1].mean():.2f}; with it {n[:, 0].mean():.2f} (median "
          f"{np.median(n[:, 0]):.2f}) / {n[:, 1].mean():.2f}; ratio {o[:, 0].mean() / n[:, 0].mean():.1f} / "
          f"{o[:, 1].mean() / n[:, 1].mean():.1f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surveys", type=int, default=8)
    ap.add_argument("--stretches", type=int, default=0, help="surveys of the two-float-stretch case")
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--only-stretches", action="store_true")
    a = ap.parse_args()
    t0 = time.perf_counter()
    if a.stretches:
        cases = {"one offset for all float, one variance factor (before)": (False, False),
                 "one offset per stretch, one variance factor": (True, False),
                 "one offset for all float, a factor per quality": (False, True),
                 "one offset per stretch, a factor per quality": (True, True)}
        out = {k: [] for k in cases}
        for s in range(a.first_seed, a.first_seed + a.stretches):
            for k, (ps, vg) in cases.items():
                out[k].append(two_stretch_case(s, ps, vg))
            print(f"stretch survey {s} ({time.perf_counter() - t0:.0f} s)", flush=True)
        print(f"two float stretches in one flight, seeds {a.first_seed}-{a.first_seed + a.stretches - 1}, 0 GCP: "
              "ANEES cameras (median) / check points / float cameras")
        ref = np.array(out[next(iter(cases))])
        for k, v in out.items():
            v = np.array(v)
            print(f"  {k}: {v[:, 0].mean():.2f} ({np.median(v[:, 0]):.2f}) / {v[:, 1].mean():.2f} / "
                  f"{v[:, 2].mean():.2f}; ratio to before {v[:, 0].mean() / ref[:, 0].mean():.2f} / "
                  f"{v[:, 1].mean() / ref[:, 1].mean():.2f}")
        if a.only_stretches:
            return 0
    rng = np.random.default_rng(7)
    res = {k: [] for k in ("0_old", "0_new", "1_old", "1_new", "one_old", "one_new", "0_vce", "1_vce")}
    for s in range(a.surveys):
        fixed = rng.normal(0, DEFAULT_SIGMA_ENU_M)
        bias = rng.normal(0, np.sqrt(COMMON_SHARE) * FLOAT_SIGMA_ENU_M)
        white = float(np.sqrt(1 - COMMON_SHARE) * FLOAT_SIGMA_ENU_M[0])
        for n_control in (0, 1):
            for rule in (False, True):
                r = float_flight_case(s, rule, n_control, float_bias_m=bias, float_white_m=white, fixed_offset_m=fixed)
                res[f"{n_control}_{'new' if rule else 'old'}"].append((r["anees_cameras"], r["anees_checks"]))
            r = float_flight_case(s, True, n_control, float_bias_m=bias, float_white_m=white, fixed_offset_m=fixed,
                                  vce_groups=True)
            res[f"{n_control}_vce"].append((r["anees_cameras"], r["anees_checks"]))
        seed_rng = np.random.default_rng(900 + s)
        for rule in (False, True):
            res[f"one_{'new' if rule else 'old'}"].append(one_float_flight(s, rule, np.random.default_rng(seed_rng.integers(1 << 30))))
        print(f"survey {s + 1}/{a.surveys} ({time.perf_counter() - t0:.0f} s)", flush=True)
    print(f"prior from the RTK quality, {a.surveys} surveys (fixed flight + float flight):")
    _line("0 GCP", res["0_old"], res["0_new"])
    _line("1 GCP", res["1_old"], res["1_new"])
    _line("0 GCP, the rule + a GNSS variance factor per quality (vs the rule alone)", res["0_new"], res["0_vce"])
    _line("1 GCP, the rule + a GNSS variance factor per quality (vs the rule alone)", res["1_new"], res["1_vce"])
    _line("one all-float flight, 0 GCP", res["one_old"], res["one_new"])

    # modes similarity and gcp (no bundle adjustment: cheap)
    from scipy.spatial.transform import Rotation

    from georef_core.adjustment.lever_arm_delay import (estimate_lever_arm_delay, fit_similarity_delay,
                                                        similarity_centre_cov)
    s_true, R_true, t_true = 0.37, Rotation.from_rotvec([0.1, -0.2, 0.7]).as_matrix(), np.array([5.0, -3.0, 2.0])
    nees, z = {True: [], False: []}, {True: [], False: []}
    for C, R, V, A, cov, fl, off, rng2 in modes._draws(200, seed=11):
        c = (C - t_true) @ R_true / s_true + rng2.normal(0, 0.002 / s_true, C.shape)
        Rm = np.einsum("ji,kjl->kil", R_true, R)
        Cg = C + rng2.normal(0, modes.CAMERA_SIGMA_M, C.shape)
        for m in (False, True):
            kw = {"flight": fl, "offset_prior_cov_m2": modes.PRIOR} if m else {}
            fit = fit_similarity_delay(c, Rm, A, V, cov + np.eye(3) * 1e-5, modes.TRUE_LEVER, **kw)
            sc, Rs, t = fit.similarity
            ccov = similarity_centre_cov(fit, c)[0] + np.mean(np.trace(cov, axis1=1, axis2=2)) / 3 * fit.sigma0 ** 2 * np.eye(3)
            nees[m].append(np.mean(modes._nees(sc * c @ Rs.T + t - C, ccov)))
            g = estimate_lever_arm_delay(R, Cg, A, V, cov + np.eye(3) * modes.CAMERA_SIGMA_M ** 2, **kw)
            z[m].append((np.r_[g.lever_arm_cam_m, g.delay_s] - np.r_[modes.TRUE_LEVER, modes.TRUE_DELAY]) /
                        np.array([g.sigma(k) for k in modes.LEVER_NAMES + ("delay",)]))
    print("modes, 200 surveys, offsets drawn from a 3.5 cm prior per flight and axis:")
    print(f"  similarity: camera centres ANEES not modelled {np.mean(nees[False]):.2f} (median "
          f"{np.median(nees[False]):.2f}), modelled {np.mean(nees[True]):.2f} (median {np.median(nees[True]):.2f})")
    for m in (False, True):
        print(f"  gcp: z-score RMS lever x, y, z, delay {'modelled' if m else 'not modelled'}: "
              f"{np.sqrt(np.mean(np.square(z[m]), axis=0)).round(2).tolist()}")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
