"""Speed of ``read_rinex_obs`` on the real observation files and on a synthetic 10 Hz, 20-minute multi-GNSS file.

Usage:  python bench/rinex_parse_speed.py [--repeat N] [--no-georinex] [--georinex-epochs N]

For every file it prints the size (MB), the best time of N runs (s), s/MB, and the peer reader georinex's time on
the same file with the ratio georinex/ours. georinex needs ~25 s/MB on RINEX 3 (about 0.3 s/MB on RINEX 2),
so it is run in full on the RINEX 2 files only; for RINEX 3 files both readers are timed on the file's first
``--georinex-epochs`` epochs (lines marked 'head'). The synthetic file (written with ``write_rinex3_obs`` into a
temporary folder, 12000 epochs x ~40 satellites x 8 signals, one camera event every 2 s) also reports the peak
memory that reading it takes (tracemalloc, numpy arrays included).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from georef_core.gnss.observations import RawObservations, ReceiverHeader  # noqa: E402
from georef_core.gnss.rinex_obs import read_rinex_obs, write_rinex3_obs  # noqa: E402

SIGNALS = {
    "G": ("C1C", "L1C", "D1C", "S1C", "C2W", "L2W", "D2W", "S2W"),
    "R": ("C1C", "L1C", "D1C", "S1C", "C2C", "L2C", "D2C", "S2C"),
    "E": ("C1C", "L1C", "D1C", "S1C", "C5Q", "L5Q", "D5Q", "S5Q"),
    "C": ("C2I", "L2I", "D2I", "S2I", "C7I", "L7I", "D7I", "S7I"),
}
N_SATS = {"G": 12, "R": 9, "E": 10, "C": 12}


def shared_gnss_dir() -> Path | None:
    """The shared real-data folder (env GEOREF_SHARED_DATA, else ../shared beside the repository)."""
    candidates = []
    env = os.environ.get("GEOREF_SHARED_DATA")
    if env:
        candidates += [Path(env) / "data" / "gnss", Path(env) / "gnss", Path(env)]
    candidates.append(Path(__file__).resolve().parents[1].parent / "shared" / "data" / "gnss")
    for c in candidates:
        if (c / "rinex_summary.jsonl").is_file():
            return c
    return None


def synthetic_flight(n_epochs: int = 12000, rate_hz: float = 10.0, seed: int = 1) -> RawObservations:
    """A multi-GNSS 10 Hz rover: smooth pseudoranges (m), phases (cycles), Dopplers (Hz), SNR (dB-Hz), events."""
    rng = np.random.default_rng(seed)
    t = 1_400_000_000.0 + np.arange(n_epochs) / rate_hz
    sats = [f"{s}{p:02d}" for s in N_SATS for p in range(1, N_SATS[s] + 1)]
    codes: list[str] = []
    for sig in SIGNALS.values():
        codes += [c for c in sig if c not in codes]
    col = {c: k for k, c in enumerate(codes)}
    values = np.full((n_epochs, len(sats), len(codes)), np.nan)
    lli = np.zeros(values.shape, np.uint8)
    ssi = np.zeros(values.shape, np.uint8)
    dt = t - t[0]
    for s, sat in enumerate(sats):
        rho = rng.uniform(2.0e7, 2.6e7) + rng.uniform(-800, 800) * dt + 0.02 * dt ** 2
        rise, set_ = sorted(rng.uniform(-0.3, 1.3, 2) * n_epochs)
        visible = (np.arange(n_epochs) >= rise) & (np.arange(n_epochs) <= set_) if rng.random() < 0.15 else \
            np.ones(n_epochs, bool)
        for k_band, (c_code, l_code, d_code, s_code) in enumerate(zip(*[iter(SIGNALS[sat[0]])] * 4)):
            lam = 0.19 if k_band == 0 else 0.245
            snr = 45 - 6 * k_band + rng.normal(0, 1.5, n_epochs)
            values[visible, s, col[c_code]] = (rho + rng.normal(0, 0.3, n_epochs))[visible]
            values[visible, s, col[l_code]] = (rho / lam + rng.uniform(-1e6, 1e6))[visible]
            values[visible, s, col[d_code]] = (-np.gradient(rho, dt) / lam)[visible]
            values[visible, s, col[s_code]] = snr[visible]
            ssi[visible, s, col[l_code]] = np.clip(snr / 6, 1, 9).astype(np.uint8)[visible]
            slips = rng.random(n_epochs) < 1e-3
            lli[visible & slips, s, col[l_code]] = 1
    values = np.round(values, 3)
    events = t[0] + np.arange(1.0, dt[-1], 2.0) + rng.uniform(0, 0.05, len(np.arange(1.0, dt[-1], 2.0)))
    header = ReceiverHeader(marker_name="DRONE", receiver_type="SIM", antenna_type="SIM_ANT",
                            approx_position_ecef_m=np.array([4027893.6, 307045.7, 4919475.0]), interval_s=0.1,
                            glonass_fcn={f"R{p:02d}": (p % 14) - 7 for p in range(1, N_SATS["R"] + 1)})
    return RawObservations("synthetic", t, sats, codes, values, lli, ssi, header, events,
                           np.zeros(n_epochs, np.uint8))


def head_epochs(src: Path, dst: Path, n_epochs: int) -> None:
    """Copy the header and the first ``n_epochs`` epoch records of a RINEX 3 file."""
    out, seen = [], 0
    with open(src, "rb") as f:
        in_header = True
        for line in f:
            if in_header:
                out.append(line)
                in_header = b"END OF HEADER" not in line
                continue
            if line.startswith(b">"):
                seen += 1
                if seen > n_epochs:
                    break
            out.append(line)
    dst.write_bytes(b"".join(out))


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def time_georinex(path: Path) -> float | None:
    try:
        import georinex
    except ImportError:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        georinex.load(path, useindicators=True)
        return time.perf_counter() - t0


def report(name: str, path: Path, repeat: int, georinex_run: bool) -> None:
    mb = path.stat().st_size / 1e6
    ours = best_time(lambda: read_rinex_obs(path), repeat)
    line = f"{name:<58} {mb:8.2f} {ours:8.3f} {ours / mb:8.4f}"
    if georinex_run:
        g = time_georinex(path)
        if g is not None:
            line += f" {g:9.2f} {g / ours:8.0f}x"
    print(line, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-georinex", action="store_true")
    ap.add_argument("--georinex-epochs", type=int, default=30)
    args = ap.parse_args()
    use_g = not args.no_georinex
    print(f"{'file':<58} {'MB':>8} {'s':>8} {'s/MB':>8} {'georinex':>9} {'ratio':>9}")
    gnss = shared_gnss_dir()
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        if gnss is None:
            print("(shared data not found: real files skipped)")
        else:
            for entry in map(json.loads, (gnss / "rinex_summary.jsonl").read_text().splitlines()):
                path = gnss / entry["path"]
                if entry["version"] < 3:
                    report(entry["path"], path, args.repeat, use_g)
                else:
                    report(entry["path"], path, args.repeat, False)
                    if use_g:
                        head = tmpdir / f"head_{path.name}"
                        head_epochs(path, head, args.georinex_epochs)
                        report(f"  head {args.georinex_epochs} epochs", head, args.repeat, True)

        raw = synthetic_flight()
        synth = tmpdir / "synthetic_10hz_20min.rnx"
        t0 = time.perf_counter()
        write_rinex3_obs(synth, raw)
        t_write = time.perf_counter() - t0
        report("synthetic 10 Hz 20 min G+R+E+C (write_rinex3_obs)", synth, args.repeat, False)
        if use_g:
            head = tmpdir / "head_synthetic.rnx"
            head_epochs(synth, head, args.georinex_epochs * 3)
            report(f"  head {args.georinex_epochs * 3} epochs", head, args.repeat, True)
        tracemalloc.start()
        back = read_rinex_obs(synth)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        mb = synth.stat().st_size / 1e6
        out_mb = (back.values.nbytes + back.lli.nbytes + back.ssi.nbytes) / 1e6
        print(f"\nsynthetic file: {back.n_epochs} epochs x {len(back.sat_ids)} satellites x {len(back.obs_codes)} "
              f"codes, {len(back.event_gps_time_s)} events, {mb:.1f} MB; written in {t_write:.2f} s")
        print(f"reading it: peak traced memory {peak / 1e6:.0f} MB (result arrays {out_mb:.0f} MB)")
        same = np.array_equal(np.isnan(back.values), np.isnan(raw.values)) and \
            np.nanmax(np.abs(back.values - raw.values)) < 1e-6
        print(f"round trip identical: {same}")


if __name__ == "__main__":
    main()
