"""The survey report of a processed run folder rendered to PNG pages (the screenshots of docs/deliverables.md):

    python scripts/report_pages.py SITE_DIR OUT_DIR PAGES_DIR [--pages 1,3,4] [--dpi 75]

SITE_DIR: a simulated site (`georef simulate`: its gcp/, survey.json and truth/stockpiles.geojson give the
points and the stockpile outlines); OUT_DIR: the run folder its steps wrote (`georef step gnss|georef|dense
SITE_DIR --out OUT_DIR`). The volumes shown are the README demo's figures; the company and tolerance are
examples. Needs pdftoppm (Debian poppler-utils)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from backend.services.report import build_report  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("site_dir", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("pages_dir", type=Path)
    ap.add_argument("--pages", default="1,3,4")
    ap.add_argument("--dpi", type=int, default=75)
    a = ap.parse_args()
    piles = json.loads((a.site_dir / "truth" / "stockpiles.geojson").read_text())["features"]
    info = json.loads((a.site_dir / "survey.json").read_text())
    meta = {"site": "Quarry North", "company": "Example Earthworks Ltd", "crs": info["project_crs"],
            "vertical_datum": None, "survey": "Weekly stockpile flight", "flown_at": None, "run_number": 1,
            "steps": [{"name": n, "state": "succeeded", "error": None} for n in ("gnss", "georef", "dense", "volumes")],
            "settings": {}, "tolerance_horizontal_m": 0.03, "tolerance_vertical_m": 0.05,
            "volumes": [{"name": f["properties"]["name"], "base": "plane", "volume_m3": v, "sigma_m3": s,
                         "material": f["properties"].get("material", ""), "density_t_m3": d}
                        for f, (v, s, d) in zip(piles, ((15.25, 0.13, 1.6), (24.44, 0.16, None)))],
            "stockpile_outlines": [{"name": f["properties"]["name"], "outline": f["geometry"]} for f in piles]}
    a.pages_dir.mkdir(parents=True, exist_ok=True)
    pdf = a.pages_dir / "survey_report.pdf"
    print(build_report(a.out_dir, pdf, meta, survey_dir=a.site_dir)["sections"])
    from PIL import Image

    for p in (int(x) for x in a.pages.split(",")):
        stem = a.pages_dir / f"survey_report_page{p}"
        subprocess.run(["pdftoppm", "-r", str(a.dpi), "-f", str(p), "-l", str(p), "-singlefile", "-png", str(pdf),
                        str(stem)], check=True)
        png = stem.with_suffix(".png")       # 256 colours: the map pages stay under 300 KB
        Image.open(png).convert("RGB").quantize(256, dither=Image.Dither.NONE).save(png, optimize=True)
        print(png, png.stat().st_size // 1024, "KB")


if __name__ == "__main__":
    main()
