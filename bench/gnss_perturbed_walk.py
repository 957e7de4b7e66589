"""Benchmark: integrity of each engine's own forward and backward passes on perturbed copies of the shared
u-blox walk (issue 22). The walk taught the engine; these copies are not new data, but they put it in
situations it was not tuned on: base epochs dropped at random (40 %, three seeds, on top of the base's own
losses), the rover log cut to start later (150, 400, 700 epochs: the filters start elsewhere), and
satellites excluded (the rest must carry the fix). For each copy both engines (ours through
`solve_files`, RTKLIB demo5 through pyrtklib5) solve forward and backward separately with demo5's walk
configuration (fix-and-hold and continuous); printed per copy: fix rates, and the epochs both passes of one
engine fix more than 5 cm and more than 1 m apart (at most one of the two can be right there).

    python bench/gnss_perturbed_walk.py          # about 2 minutes on two cores
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.gnss.judged_comparison import positions_on_epochs  # noqa: E402
from georef_core.gnss.ppk import solve_files  # noqa: E402
from georef_core.gnss.rtk_options import read_rtklib_conf  # noqa: E402
from georef_core.gnss.solution_io import read_pos, write_pos  # noqa: E402
from tests.gnss.rtklib_cases import reversed_conf, run_demo5, shared_gnss_dir  # noqa: E402


def rinex3_epochs(path: Path) -> tuple[str, list[str]]:
    """(header, epoch blocks) of a RINEX 3 observation file."""
    text = path.read_text()
    i = text.index("END OF HEADER")
    j = text.index("\n", i) + 1
    blocks = re.split(r"(?m)^(?=> )", text[j:])
    return text[:j], [b for b in blocks if b.startswith(">")]


def write_subset(src: Path, dst: Path, keep) -> Path:
    head, blocks = rinex3_epochs(src)
    mask = keep(len(blocks))
    dst.write_text(head + "".join(b for b, k in zip(blocks, mask) if k))
    return dst


def conf_with(conf: Path, dst: Path, **settings) -> Path:
    text = conf.read_text()
    for key, value in settings.items():
        text = re.sub(rf"(?m)^({re.escape(key)}\s*=).*$", rf"\g<1>{value}", text)
    dst.write_text(text)
    return dst


def passes(tmp: Path, tag: str, rover: Path, base: Path, navs: list[Path], conf_fwd: Path) -> str:
    conf_bwd = reversed_conf(conf_fwd, tmp)
    line = f"{tag:24s}"
    for engine in ("ours", "demo5"):
        sol = {}
        for direction, conf in (("fwd", conf_fwd), ("bwd", conf_bwd)):
            out = tmp / f"{engine}_{direction}.pos"
            if engine == "ours":
                write_pos(out, solve_files(rover, base, navs, read_rtklib_conf(conf).options))
            else:
                run_demo5(conf, [rover, base, *navs], out)
            sol[direction] = read_pos(out)
        t = np.unique(np.concatenate([p.time_s for p in sol.values()]))
        pf, ff, _ = positions_on_epochs(sol["fwd"], t)
        pb, fb, _ = positions_on_epochs(sol["bwd"], t)
        d = np.linalg.norm(pf - pb, axis=1)
        both = ff & fb
        rate = 100.0 / max(len(sol["fwd"].time_s), 1)
        line += (f" | {engine}: fix fwd {rate * ff.sum():5.1f} % bwd {rate * fb.sum():5.1f} %,"
                 f" both fixed apart > 5 cm {int(np.sum(both & (d > 0.05))):3d}, > 1 m {int(np.sum(both & (d > 1.0))):3d}")
    return line


def main() -> int:
    root = shared_gnss_dir()
    if root is None:
        print("shared/data/gnss not found (set GEOREF_SHARED_DATA)")
        return 1
    walk = root / "ublox_m8p_20181004_walk"
    ref = root / "reference" / "demo5_ex251" / "ublox_m8p_20181004_walk"
    rover, base, nav = walk / "rover-20181004-1532.obs", walk / "base-20181004-1452.obs", walk / "base-20181004-1452.nav"
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for mode in ("fah", "cont"):
            conf = ref / f"kinematic_l1_fwd_{mode}.conf"
            print(passes(tmp, f"{mode} original", rover, base, [nav], conf), flush=True)
            for seed in (1, 2, 3):
                rng = np.random.default_rng(seed)
                lossy = write_subset(base, tmp / f"base_drop{seed}.obs", lambda n, r=rng: r.random(n) > 0.4)
                print(passes(tmp, f"{mode} base -40 % seed {seed}", rover, lossy, [nav], conf), flush=True)
            for cut in (150, 400, 700):
                late = write_subset(rover, tmp / f"rover_from{cut}.obs", lambda n, c=cut: np.arange(n) >= c)
                print(passes(tmp, f"{mode} start +{cut}", late, base, [nav], conf), flush=True)
            for excl in ("G23", "R24", "G09 R17"):
                c2 = conf_with(conf, tmp / f"excl_{excl.replace(' ', '_')}.conf", **{"pos1-exclsats": excl})
                print(passes(tmp, f"{mode} without {excl}", rover, base, [nav], c2), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
