"""Coverage of the stated 1-sigma of the change between two surveys (georef_core.design.surface_change), seeded Monte
Carlo on the valley scene with analytic volumes (tests/design/change_mc.py): per seed DSM noise on both surveys, a
vertical bias with a part common to both, June on a grid shifted by a random fraction of a cell.

"before": the model as it was (the two surveys' biases independent, no resampling term): common_bias_m = 0 and the
resampling component taken out; "after": the common bias given (Cov(b_l, b_e) = common^2) and the resampling term.
Printed per quantity: the share of seeds whose truth lies within 1 and 2 sigma (nominal 0.683 / 0.954) and the RMS
of (estimate - truth) / sigma (nominal 1). Cut removed and fill placed are gross quantities that the noise inflates
(noise_inflation_m3, stated beside them): they are judged raw and with the stated inflation taken off.

    python bench/design_change_sigma_mc.py --seeds 200 [--common 0.015 --own 0.01 --noise 0.02 --length 1.0]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from georef_core.design.surface_change import surface_change  # noqa: E402
from tests.design import change_mc  # noqa: E402

KEYS = ("net_change_m3", "cut_moved_m3", "fill_placed_m3")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=200)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--length", type=float, default=1.0)
    ap.add_argument("--common", type=float, default=0.015)
    ap.add_argument("--own", type=float, default=0.01)
    a = ap.parse_args()
    truth = change_mc.truth()
    z = {m: {k: [] for k in KEYS + ("cut_moved_m3-infl", "fill_placed_m3-infl")} for m in ("before", "after")}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(a.seeds):
            r = change_mc.one_seed(seed, Path(tmp) / "s", a.noise, a.length, a.common, a.own)
            for model, common in (("before", 0.0), ("after", a.common)):
                out = surface_change(r["may"], r["june"], change_mc.area_geometry(), r["accuracy"], r["accuracy"],
                                     common_bias_m=common)
                for k in KEYS:
                    u = out["uncertainty"][k]
                    s = u["sigma_m3"]
                    if model == "before":
                        s = math.sqrt(max(s * s - u["components_m3"]["resampling_m3"] ** 2, 0.0))
                    z[model][k].append((out[k] - truth[k]) / s)
                    if k != "net_change_m3":
                        z[model][k + "-infl"].append((out[k] - out["noise_inflation_m3"] - truth[k]) / s)
    dt = time.perf_counter() - t0
    print(f"seeds {a.seeds}, noise {a.noise} m (L {a.length} m), common bias {a.common} m, own bias {a.own} m "
          f"(stated vertical RMSE {math.hypot(a.common, a.own):.4f} m), {dt:.1f} s")
    print(f"{'quantity':<22} {'model':<7} {'within 1s':>9} {'within 2s':>9} {'rms z':>7} {'mean z':>7}")
    for k in z["before"]:
        for m in ("before", "after"):
            v = np.abs(np.array(z[m][k]))
            zz = np.array(z[m][k])
            print(f"{k:<22} {m:<7} {np.mean(v <= 1):9.3f} {np.mean(v <= 2):9.3f} {math.sqrt(np.mean(zz ** 2)):7.3f} "
                  f"{np.mean(zz):7.3f}")


if __name__ == "__main__":
    main()
