"""Orthophoto seams: radiometric compensation and seamlines + multi-band blending against feathering.

Simulates one survey twice from the same seed: with per-image exposure gains (1 +- 15 %) and a cos^4-like
vignetting 30 % darker at the corners (``--exposure-spread 0.15 --vignetting 0.3``), and radiometrically
perfect (no vignetting, no gain jitter). The dense step runs once on the first one's true orientations
(DSM only); the orthophoto is then built from the same DSM and views three ways: feathering only (the
old behaviour), compensation only, compensation + seamlines + multi-band blending; and once from the
perfect images (feathering) as the reference. Prints the seam-contrast figure (``ortho_check.seam_contrast``:
the step of log luminance across the boundaries between views, against the reference, so that the
texture cancels; and without reference, seam / interior ratio), the recovered gains and vignetting
against the truth, and each way's time as a ratio to feathering, measured in this same run. Writes
before/after crops to ``--pictures`` (PNG).

    .venv/bin/python bench/ortho_seams.py [--images 20] [--seed 3] [--small] [--work DIR] [--pictures DIR]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def simulate(out: Path, args, perfect: bool) -> Path:
    from georef_core.cli.simulate_command import fit_site_content, scale_for_image_count
    from georef_core.sim import SimulationOptions, simulate_site

    if (out / "truth" / "radiometry.json").is_file():
        return out
    o = SimulationOptions.small() if args.small else SimulationOptions()
    o.gnss = None
    if not args.small:
        o, _ = scale_for_image_count(o, args.images)
        o, _ = fit_site_content(o, args.seed)
    o.render = (replace(o.render, vignetting=0.0, gain_jitter=0.0) if perfect else
                replace(o.render, exposure_spread=0.15, vignetting_cos4=0.30))
    t0 = time.perf_counter()
    simulate_site(out, seed=args.seed, options=o, verbose=False)
    print(f"simulated {out.name} in {time.perf_counter() - t0:.1f} s")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=20)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--small", action="store_true", help="the small 12-image scene (640 x 480) instead")
    ap.add_argument("--work", type=Path, default=Path("/tmp/georef_ortho_seams"))
    ap.add_argument("--pictures", type=Path, help="write before/after crops (PNG) here")
    args = ap.parse_args(argv)

    import cv2

    from georef_core.dense.ortho_check import ortho_inputs, read_targets, seam_contrast, target_offsets
    from georef_core.dense.orthophoto import OrthoOptions, build_orthophoto
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps.dense import DenseOptions, run_dense

    tag = "small" if args.small else f"{args.images}_seed{args.seed}"
    survey = simulate(args.work / f"radiometric_{tag}", args, perfect=False)
    perfect = simulate(args.work / f"perfect_{tag}", args, perfect=True)
    run = args.work / f"run_{tag}"
    if not (run / "dense" / "dsm.tif").is_file():
        oriented_images_from_simulator_truth(survey).write(run / "oriented_images.json")
        t0 = time.perf_counter()
        run_dense(run, DenseOptions(workers=2, ortho=False))
        print(f"dense step (DSM) in {time.perf_counter() - t0:.1f} s")
    inp = ortho_inputs(run)
    g = inp["ortho_grid"]
    print(f"{len(inp['views'])} images of {inp['views'][0].width} x {inp['views'][0].height} px; orthophoto "
          f"{g.width} x {g.height} cells of {100 * g.resolution_m:.1f} cm")
    truth = json.loads((survey / "truth" / "radiometry.json").read_text())

    ways = {"reference (perfect images, feathering)": (dict(inp, views=[replace(v, path=perfect / "images" / v.path.name)
                                                                        for v in inp["views"]]),
                                                       OrthoOptions(compensate=False, blend=False)),
            "feathering only (before)": (inp, OrthoOptions(compensate=False, blend=False)),
            "compensation only": (inp, OrthoOptions(blend=False)),
            "compensation + seams + multi-band (after)": (inp, OrthoOptions())}
    res = {}
    for name, (kw, opts) in ways.items():
        labels = np.full((g.height, g.width), -1, np.int32)
        info = {}
        t0 = time.perf_counter()
        cpu0 = time.process_time()
        rgba = build_orthophoto(**kw, options=opts, labels_out=labels, info=info)
        res[name] = (rgba, labels, info, time.perf_counter() - t0, time.process_time() - cpu0)
    names = list(ways)
    ref, voronoi = res[names[0]][0], res[names[1]][1]
    base_t, base_cpu = res[names[1]][3], res[names[1]][4]
    print(f"\n{'orthophoto':<44}{'wall s':>8}{'x feather':>10}{'CPU x':>7}  seam step % (Voronoi / own seams), "
          f"p90, ratio without reference")
    for name in names[1:]:
        rgba, labels, info, t, cpu = res[name]
        a = seam_contrast(rgba, voronoi, reference=ref)
        b = seam_contrast(rgba, labels, reference=ref)
        c = seam_contrast(rgba, voronoi)
        print(f"{name:<44}{t:8.2f}{t / base_t:10.2f}{cpu / base_cpu:7.2f}  {a['seam_step_percent']:.2f} / "
              f"{b['seam_step_percent']:.2f}, p90 {a['seam_p90_percent']:.2f}, ratio {c['ratio']:.2f}"
              + (f"  (radiometry {info['radiometry_s']:.1f} s, mosaic {info['mosaic_s']:.1f} s)"
                 if "radiometry" in info else ""))
    a = seam_contrast(ref, voronoi)
    print(f"reference itself: seam / interior ratio without reference {a['ratio']:.2f}")
    model = res[names[3]][2]["radiometry_model"]
    tg = np.array([truth["gains"][v.name] for v in inp["views"]])
    tg /= np.exp(np.mean(np.log(tg)))
    err = model.gains.mean(axis=1) / tg - 1
    rho = np.linspace(0.2, 1.0, 5)
    v = truth["vignetting"]
    W, H = inp["views"][0].full_width, inp["views"][0].full_height
    tv = (1 - v["a"] * rho ** 2 * (1 + (H / W) ** 2) / 1.5625) / (1 + v["k"] * rho ** 2) ** 2
    ev = model.vignetting(0, rho).mean(axis=1)
    print(f"gains: true {tg.min():.3f}-{tg.max():.3f}, recovered within {100 * np.abs(err).max():.2f} % (RMS "
          f"{100 * np.sqrt(np.mean(err ** 2)):.2f} %); vignetting at rho {rho.round(1).tolist()}: true "
          f"{tv.round(3).tolist()}, recovered {ev.round(3).tolist()}")
    # the blended orthophoto keeps features in place
    import tempfile

    from georef_core.dense import cog_writer

    with tempfile.TemporaryDirectory() as tmp:
        p = cog_writer.write_cog(Path(tmp) / "o.tif", res[names[3]][0], g.transform, inp["frame"].epsg,
                                 colorinterp=cog_writer.RGBA)
        offs = target_offsets(p, read_targets(survey / "truth" / "targets.csv"))
    ok = [o.offset_m for o in offs if o.pattern_ok]
    print(f"targets in the blended orthophoto: {len(ok)}/{len(offs)}, max offset "
          f"{100 * max(ok) if ok else float('nan'):.2f} cm")
    if args.pictures:
        args.pictures.mkdir(parents=True, exist_ok=True)
        for key, name in (("before", names[1]), ("after", names[3])):
            img = np.transpose(res[name][0][[2, 1, 0]], (1, 2, 0))
            h, w = img.shape[:2]
            crop = img[h // 4: h // 4 + min(h // 2, 900), w // 4: w // 4 + min(w // 2, 1200)]
            s = 600 / max(crop.shape[:2])
            crop = cv2.resize(crop, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(args.pictures / f"ortho_seams_{key}_{tag}.png"), crop,
                        [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return 0


if __name__ == "__main__":
    sys.exit(main())
