"""Volume of a visible stockpile on the real Caliterra images (a soil heap at the south-west of the site),
from the DSM of bench/dense_caliterra.py, with every outline base, the stated uncertainty and a picture.

    .venv/bin/python bench/dense_caliterra.py --work work_out/caliterra_dense      # the DSM (about 3 min)
    .venv/bin/python bench/caliterra_stockpile_volume.py [--work work_out/caliterra_dense] [--png]

The outline (bench/data/caliterra_pile.geojson, project CRS of the DSM) was drawn once on the DSM's
hillshade along the heap's toe. Caliterra has no surveyed control: its scale and orientation come from
the cameras' EXIF GPS (PROVENANCE.txt), so the absolute volume carries a scale uncertainty the DSM-based
uncertainty does not contain; it is estimated here from the GPS fit and printed separately.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=REPO / "work_out" / "caliterra_dense")
    ap.add_argument("--polygon", type=Path, default=REPO / "bench" / "data" / "caliterra_pile.geojson")
    ap.add_argument("--png", action="store_true", help="write docs/images/caliterra_pile.png")
    args = ap.parse_args()

    from georef_core.steps.volumes import run_volumes

    dsm = args.work / "dense" / "dsm.tif"
    if not dsm.is_file():
        raise SystemExit(f"{dsm}: run bench/dense_caliterra.py --work {args.work} first")
    by_base = {base: run_volumes(dsm, args.polygon, base=base)["results"] for base in ("plane", "tin", "lowest", "mean")}
    names = [f["properties"]["name"] for f in json.loads(args.polygon.read_text())["features"]]
    print(f"DSM {dsm}  polygons {args.polygon.name}")
    print(f"{'pile':8s} {'base':8s} {'cut m3':>9s} {'fill m3':>9s} {'net m3':>9s} {'sigma m3':>9s} {'area m2':>8s}")
    for k, name in enumerate(names):
        for base, results in by_base.items():
            r = results[k]
            print(f"{name:8s} {base:8s} {r['cut_m3']:9.2f} {r['fill_m3']:9.2f} {r['net_m3']:9.2f} "
                  f"{r['uncertainty']['sigma_m3']:9.2f} {r['area_m2']:8.1f}")
    plane = by_base["plane"][0]
    print(f"\n{names[0]}, plane base, full result:")
    print(json.dumps({k: plane[k] for k in ("cut_m3", "fill_m3", "net_m3", "area_m2", "base", "uncertainty")}, indent=1))

    info_path = args.work / "caliterra_alignment.json"
    if info_path.is_file():
        info = json.loads(info_path.read_text())
        oi = json.loads((args.work / "oriented_images.json").read_text())
        c = np.array([im["centre_enu_m"] for im in oi["images"]])[:, :2]
        spread = np.sqrt(np.sum((c - c.mean(axis=0)) ** 2))        # sqrt of the sum of squared distances
        # a 2-D similarity fit: sigma(scale)/scale ~ sigma_xy / sqrt(sum |x - mean|^2) per axis pair
        rel = info["gps_horizontal_residual_rms_m"] / np.sqrt(2) / spread
        print(f"\nalignment to EXIF GPS: {info}")
        print(f"scale from EXIF GPS: sigma {100 * rel:.2f} % -> volume (scale^3) sigma {100 * 3 * rel:.1f} %")
        for k, name in enumerate(names):
            r = by_base["plane"][k]
            v, s_dsm = r["net_m3"], r["uncertainty"]["sigma_m3"]
            print(f"  {name}: {v:.2f} m3, DSM sigma {s_dsm:.2f} m3, scale sigma {3 * rel * v:.2f} m3, "
                  f"total 1 sigma {np.hypot(3 * rel * v, s_dsm):.2f} m3")

    if args.png:
        write_png(dsm, args.polygon, REPO / "docs" / "images" / "caliterra_pile.png", by_base["plane"], names)
    return 0


def write_png(dsm: Path, polygon: Path, out: Path, results: list[dict], names: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import rasterio
    from rasterio.windows import from_bounds

    rings = [np.array(f["geometry"]["coordinates"][0]) for f in json.loads(polygon.read_text())["features"]]
    allp = np.vstack(rings)
    pad = 4.0
    x0, y0 = allp.min(axis=0) - pad
    x1, y1 = allp.max(axis=0) + pad
    with rasterio.open(dsm) as src:
        win = from_bounds(x0, y0, x1, y1, src.transform).round_offsets().round_lengths()
        z = src.read(1, window=win, masked=True).astype(float).filled(np.nan)
        tr = src.window_transform(win)
    res = tr.a
    gy, gx = np.gradient(z, res)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, alt = np.radians(315.0), np.radians(45.0)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    extent = (tr.c, tr.c + res * z.shape[1], tr.f + tr.e * z.shape[0], tr.f)
    fig, ax = plt.subplots(figsize=(6, 5), dpi=120)
    ax.imshow(z, extent=extent, cmap="terrain")
    ax.imshow(shade, extent=extent, cmap="gray", alpha=0.45)
    for ring, r, name in zip(rings, results, names):
        ax.plot(ring[:, 0], ring[:, 1], "r-", lw=1.5)
        ax.annotate(f"{name}\n{r['net_m3']:.1f} ± {r['uncertainty']['sigma_m3']:.1f} m³", ring.mean(axis=0),
                    color="k", fontsize=8, ha="center", va="center")
    ax.set_title("Caliterra: stockpile volumes on the dense DSM (plane base, 1σ from the DSM)", fontsize=9)
    ax.set_xlabel("easting (m)")
    ax.set_ylabel("northing (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    fig.tight_layout()
    fig.savefig(out)
    print(f"written {out}")


if __name__ == "__main__":
    raise SystemExit(main())
