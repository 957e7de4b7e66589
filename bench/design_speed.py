"""Cut/fill to design at a realistic size, against a naive reference in the same script.

Scene: a 200 m x 200 m site at 5 cm cells (4000 x 4000 DSM), the valley design of tests/design/scenes.py
scaled up as a LandXML TIN of N x N vertices (default 101 x 101: 20000 triangles), the surveyed surface =
design + 12 cones and 12 pits of known volume, a 36-vertex polygon. Prints the quantities against the
analytic volumes, our time, the naive reference's time (rasterised polygon mask at cell centres, scipy's
LinearNDInterpolator on the TIN's points, numpy sums) and their ratio.

    python bench/design_speed.py [--n 101] [--size 200] [--res 0.05]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.volumes.synthetic import E0, N0, cone_height, write_dsm, write_geojson  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=101, help="TIN vertices per side")
    ap.add_argument("--size", type=float, default=200.0)
    ap.add_argument("--res", type=float, default=0.05)
    a = ap.parse_args()
    L = a.size
    xc, yc = E0 + L / 2, N0 + L / 2

    def design(E, N):
        return 100.0 + 0.02 * (N - yc) + 0.05 * np.abs(E - xc) + 0.3 * np.sin((E - E0) / 37.0)

    rng = np.random.default_rng(3)
    shapes = []
    while len(shapes) < 24:  # cones and pits that do not overlap (their volumes then add up exactly)
        k = len(shapes)
        r, h = rng.uniform(0.015, 0.04) * L, rng.uniform(0.3, 2.0) * (1 if k % 2 == 0 else -1)
        ang, rad = rng.uniform(0, 2 * math.pi), rng.uniform(0, 0.33 * L)
        cx, cy = xc + rad * math.cos(ang), yc + rad * math.sin(ang)
        if all(math.hypot(cx - o[0], cy - o[1]) > r + o[2] + 0.5 for o in shapes):
            shapes.append((cx, cy, r, h))

    # the TIN is piecewise linear: the surveyed surface is that TIN's surface plus the cones (exact truth)
    from scipy.interpolate import LinearNDInterpolator

    xs = np.linspace(E0 - 1, E0 + L + 1, a.n)
    ys = np.linspace(N0 - 1, N0 + L + 1, a.n)
    X, Y = np.meshgrid(xs, ys)
    pts = np.column_stack([X.ravel(), Y.ravel(), design(X.ravel(), Y.ravel())])
    from scipy.spatial import Delaunay

    tri = Delaunay(pts[:, :2] - pts[:, :2].mean(axis=0)).simplices
    lin = LinearNDInterpolator(pts[:, :2], pts[:, 2])

    def surveyed(E, N):
        z = lin(E, N)
        for cx, cy, r, h in shapes:
            z = z + np.sign(h) * cone_height(cx, cy, r, abs(h))(E, N)
        return z

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        dsm = write_dsm(tmp / "dsm.tif", surveyed, (L, L), a.res, block_rows=256)
        ang = np.linspace(0, 2 * math.pi, 36, endpoint=False)
        ring = np.column_stack([xc + 0.46 * L * np.cos(ang) * (1 + 0.05 * np.sin(5 * ang)),
                                yc + 0.46 * L * np.sin(ang) * (1 + 0.05 * np.sin(5 * ang))])
        poly = write_geojson(tmp / "area.geojson", {"area": ring})
        body = "".join(f'<P id="{k}">{y:.4f} {x:.4f} {z:.5f}</P>' for k, (x, y, z) in enumerate(pts))
        faces = "".join(f"<F>{i} {j} {k}</F>" for i, j, k in tri)
        xml = tmp / "design.xml"
        xml.write_text('<LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2"><Units><Metric linearUnit="meter"/>'
                       f'</Units><Surfaces><Surface name="FG"><Definition><Pnts>{body}</Pnts><Faces>{faces}</Faces>'
                       "</Definition></Surface></Surfaces></LandXML>")
        print(f"scene written in {time.perf_counter() - t:.1f} s: {int(L / a.res)}^2 cells, {len(tri)} triangles")
        import shapely

        area_poly = shapely.Polygon(ring)
        want_cut = sum(math.pi * r * r * h / 3 for cx, cy, r, h in shapes if h > 0
                       and area_poly.contains(shapely.Point(cx, cy).buffer(r)))
        want_fill = sum(-math.pi * r * r * h / 3 for cx, cy, r, h in shapes if h < 0
                        and area_poly.contains(shapely.Point(cx, cy).buffer(r)))

        from georef_core.steps.design import run_design

        opts = {"tolerance_m": 0.05, "dsm_sigma_m": 0.02, "vertical_rmse_m": 0.015}
        run_design(dsm, xml, poly, None, opts)  # warm (numba caches, imports)
        times = []
        for _ in range(3):
            t = time.perf_counter()
            doc = run_design(dsm, xml, poly, tmp / "out", opts)
            times.append(time.perf_counter() - t)
        ours = min(times)
        print(f"cut  {doc['cut_m3']:.3f} m3 vs analytic {want_cut:.3f} ({100 * (doc['cut_m3'] / want_cut - 1):+.4f} %)")
        print(f"fill {doc['fill_m3']:.3f} m3 vs analytic {want_fill:.3f} ({100 * (doc['fill_m3'] / want_fill - 1):+.4f} %)")
        print(f"on grade {100 * doc['on_grade']['share']:.2f} %, net sigma {doc['uncertainty']['net_m3']['sigma_m3']:.2f} m3")

        # naive reference: whole arrays, mask of cell centres inside, LinearNDInterpolator on the TIN
        import rasterio
        from rasterio.features import rasterize

        t = time.perf_counter()
        with rasterio.open(dsm) as ds:
            z = ds.read(1).astype(np.float64)
            mask = rasterize([area_poly], out_shape=z.shape, transform=ds.transform).astype(bool)
            rows, cols = np.nonzero(mask)
            x, y = rasterio.transform.xy(ds.transform, rows, cols)
        g = LinearNDInterpolator(pts[:, :2], pts[:, 2])(np.asarray(x), np.asarray(y))
        d = z[rows, cols] - g
        cell = a.res * a.res
        naive_cut, naive_fill = float(np.sum(np.maximum(d, 0)) * cell), float(np.sum(np.maximum(-d, 0)) * cell)
        naive = time.perf_counter() - t
        print(f"naive: cut {naive_cut:.3f} fill {naive_fill:.3f} (cell-centre mask: edge cells all or nothing)")
        print(f"time: ours {ours:.2f} s (best of 3, writing difference/classes/contours), naive {naive:.2f} s "
              f"(quantities only), ratio naive/ours {naive / ours:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
