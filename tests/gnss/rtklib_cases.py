"""The real datasets of shared/data/gnss and their RTKLIB reference cases (conf + .pos)."""

from __future__ import annotations

import math
import os
import re
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def shared_gnss_dir() -> Path | None:
    """The shared GNSS data folder: $GEOREF_SHARED_DATA (the 'shared' folder, its 'data' or 'data/gnss')
    or <repo>/../shared; None when absent (tests that need it skip)."""
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else REPO.parent / "shared"
    for cand in (root / "data" / "gnss", root / "gnss", root):
        if (cand / "matrtklib_static_1m").is_dir():
            return cand
    return None


DATASETS = {
    "rtklib_gsi_0759_3040_static": ("07590920.05o", "30400920.05o", ["07590920.05n", "30400920.05n"]),
    "cssrlib_2021_265_car_kinematic": ("SEPT265G.21O", "3034265G.21O", ["SEPT2650.21P"]),
    "matrtklib_static_1m": ("rover.obs", "base.obs", ["base.nav"]),
    "ublox_m8p_20181004_walk": ("rover-20181004-1532.obs", "base-20181004-1452.obs", ["base-20181004-1452.nav"]),
}


def reference_cases(build: str = "demo5_ex251"):
    """(dataset, case, rover, base, navs, conf, ref_pos) for every reference solution present."""
    root = shared_gnss_dir()
    if root is None:
        return []
    out = []
    for ds, (rover, base, navs) in DATASETS.items():
        ref_dir = root / "reference" / build / ds
        if not ref_dir.is_dir():
            continue
        for conf in sorted(ref_dir.glob("*.conf")):
            out.append((ds, conf.stem, root / ds / rover, root / ds / base, [root / ds / n for n in navs], conf,
                        conf.with_suffix(".pos")))
    return out


_SOLTYPE_LINE = re.compile(r"^(pos1-soltype\s*=\s*)(\w+)", re.MULTILINE)
_REVERSE = {"forward": "backward", "backward": "forward"}


def reversed_conf(conf: Path, out_dir: Path) -> Path | None:
    """A copy of an rnx2rtkp configuration in out_dir with its filter direction reversed (forward <->
    backward), everything else as it is; None for a combined (or unstated) solution type."""
    text = Path(conf).read_text()
    m = _SOLTYPE_LINE.search(text)
    if m is None or m.group(2).lower() not in _REVERSE:
        return None
    out = Path(out_dir) / f"{Path(conf).stem}_reversed.conf"
    out.write_text(text[:m.start(2)] + _REVERSE[m.group(2).lower()] + text[m.end(2):])
    return out


_NITER_LINE = re.compile(r"^(pos2-niter\s*=\s*)(\d+)", re.MULTILINE)


def iterated_conf(conf: Path, out_dir: Path, niter: int = 3) -> Path:
    """A copy of an rnx2rtkp configuration in out_dir with `niter` measurement-update iterations per epoch
    (pos2-niter), everything else as it is. With one (the reference cases' setting) demo5 evaluates the rover
    troposphere at the single-point position the epoch starts from and has no troposphere partial in its design
    matrix, so its fixed heights carry ~0.9 mm per metre of single-point height error; iterating re-evaluates it
    at the updated position (docs/gnss.md, "Troposphere height partial")."""
    text = Path(conf).read_text()
    line = f"pos2-niter         ={niter}"
    text = _NITER_LINE.sub(line, text) if _NITER_LINE.search(text) else text.rstrip("\n") + "\n" + line + "\n"
    out = Path(out_dir) / f"{Path(conf).stem}_niter{niter}.conf"
    out.write_text(text)
    return out


def reverse_passes(conf, rover, base, navs, out_dir, tag: str = "") -> dict:
    """For a forward (or backward) configuration, both engines' solutions of the same files the other way,
    as judge_fixes takes them ({"ours_reverse", "ref_reverse"}: the witnesses where the carrier phase is not
    decisive); {} for a combined one. Written as out_dir/{tag}ours_reversed.pos, {tag}demo5_reversed.pos."""
    from georef_core.gnss.ppk import solve_files
    from georef_core.gnss.rtk_options import read_rtklib_conf
    from georef_core.gnss.solution_io import read_pos, write_pos

    rev = reversed_conf(conf, out_dir)
    if rev is None:
        return {}
    ours, theirs = Path(out_dir) / f"{tag}ours_reversed.pos", Path(out_dir) / f"{tag}demo5_reversed.pos"
    run_demo5(rev, [rover, base, *navs], theirs)
    write_pos(ours, solve_files(rover, base, navs, read_rtklib_conf(rev).options))
    return {"ours_reverse": read_pos(ours), "ref_reverse": read_pos(theirs)}


def run_demo5(conf, files, out) -> float:
    """RTKLIB demo5 (pyrtklib5, in this process) on `files` with the configuration `conf`, writing the .pos
    `out`; returns the seconds postpos took."""
    import pyrtklib5 as rtk

    rtk.resetsysopts()
    rtk.loadopts(str(conf), rtk.sysopts[0])
    popt, sopt, fopt = rtk.prcopt_t(), rtk.solopt_t(), rtk.filopt_t()
    rtk.getsysopts(popt, sopt, fopt)
    t0 = time.perf_counter()
    rc = rtk.postpos(rtk.gtime_t(), rtk.gtime_t(), 0.0, 0.0, popt, sopt, fopt, [str(f) for f in files], len(files),
                     str(out), "", "")
    elapsed = time.perf_counter() - t0
    if rc != 0:
        raise RuntimeError(f"demo5 postpos failed ({rc}) on {conf}")
    return elapsed


# ------------------------------------------------------------------------------------------ RTCM 3 decoding
UNIX_MINUS_GPS_S = 315964800      # RTKLIB's gtime_t counts Unix seconds


def rtklib_sat_id(rtk, sat: int) -> str:
    """'G05', 'R12', 'J02', ... of an RTKLIB satellite number."""
    letters = {rtk.SYS_GPS: "G", rtk.SYS_GLO: "R", rtk.SYS_GAL: "E", rtk.SYS_QZS: "J", rtk.SYS_CMP: "C"}
    prn = rtk.Arr1Dint(1)
    system = rtk.satsys(sat, prn)
    return f"{letters[system]}{prn[0] - (192 if system == rtk.SYS_QZS else 0):02d}"


def rtklib_gtime(rtk, t_gps_s: float):
    """RTKLIB's gtime_t of a gps_time_s."""
    g = rtk.gtime_t()
    g.time = int(math.floor(t_gps_s)) + UNIX_MINUS_GPS_S
    g.sec = float(t_gps_s - math.floor(t_gps_s))
    return g


def rtklib_decode_rtcm3(rtk, data: bytes, t_start_gps_s: float):
    """RTKLIB demo5's decoding of an RTCM 3 stream, byte by byte (input_rtcm3), dated from a time near its
    start: (rows (gps_time_s, sat, code, P, L, D, SNR, LLI) of every signal, number of epochs, the rtcm_t
    with its final navigation data)."""
    r = rtk.rtcm_t()
    rtk.init_rtcm(r)
    r.time = rtklib_gtime(rtk, float(int(t_start_gps_s)))
    rows, epochs = [], 0
    for b in data:
        if rtk.input_rtcm3(r, b) != 1:
            continue
        epochs += 1
        for i in range(r.obs.n):
            d = r.obs.data[i]
            sat = rtklib_sat_id(rtk, d.sat)
            t = d.time.time - UNIX_MINUS_GPS_S + d.time.sec
            for k in range(3):
                if d.code[k]:
                    rows.append((t, sat, rtk.code2obs(d.code[k]), d.P[k], d.L[k], d.D[k], d.SNR[k], d.LLI[k]))
    return rows, epochs, r
