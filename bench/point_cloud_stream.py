"""Benchmark: a dense cloud (LAZ, point format 7) rewritten as LAS, streamed a million points at a time
(georef_core.dense.point_cloud_io.copy_point_cloud: what the API's LAZ-to-LAS download, the datum
conversion and the DTM step's classified cloud do) against the whole-file way (laspy.read + write, what they
did before). Prints each one's seconds and peak traced memory (numpy and laspy allocations, tracemalloc)
and the ratios whole / streamed (> 1: streaming uses less), and checks that both files hold the same points.

    python bench/point_cloud_stream.py                 # 5 million points (synthetic, 200 x 200 m)
    python bench/point_cloud_stream.py --points 20000000
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from georef_core.dense.point_cloud_io import (copy_point_cloud, dense_cloud_header, dense_points,  # noqa: E402
                                              point_cloud_writer)


def _measure(fn):
    tracemalloc.start()
    t0 = time.perf_counter()
    fn()
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, peak


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=5_000_000)
    args = ap.parse_args(argv)
    import laspy

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        src = d / "points.laz"
        rng = np.random.default_rng(1)
        header = dense_cloud_header(32631, [448000.0, 5412000.0, 0.0])
        with point_cloud_writer(src, header) as w:      # written in chunks too, so the input costs no memory
            for a in range(0, args.points, 1_000_000):
                n = min(1_000_000, args.points - a)
                xyz = np.column_stack([448000 + rng.uniform(0, 200, n), 5412000 + rng.uniform(0, 200, n),
                                       100 + rng.normal(0, 2, n)])
                w.write_points(dense_points(header, xyz, rng.integers(0, 256, (n, 3)), rng.integers(2, 12, n)))
        print(f"input: {args.points:,} points, {src.stat().st_size / 1e6:.1f} MB LAZ")
        t_s, m_s = _measure(lambda: copy_point_cloud(src, d / "streamed.las"))
        t_w, m_w = _measure(lambda: laspy.read(str(src)).write(str(d / "whole.las")))
        same = (d / "streamed.las").stat().st_size == (d / "whole.las").stat().st_size
        with laspy.open(str(d / "streamed.las")) as a, laspy.open(str(d / "whole.las")) as b:
            for pa, pb in zip(a.chunk_iterator(1_000_000), b.chunk_iterator(1_000_000)):
                same = same and np.array_equal(pa.array, pb.array)
        print(f"streamed (copy_point_cloud): {t_s:6.2f} s, peak {m_s / 1e6:7.1f} MB")
        print(f"whole (laspy.read + write):  {t_w:6.2f} s, peak {m_w / 1e6:7.1f} MB")
        print(f"ratio whole / streamed: time {t_w / t_s:.2f}, memory {m_w / max(m_s, 1):.1f}; same points: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
