"""The survey report (backend/services/report) built from a processed small simulated survey
(tests/data/report_run: the gnss, georef and dense steps' outputs as the run folder holds them) with small
rasters drawn here in the same place, rendered to PNG pages with pdftoppm and read back with pdftotext
(Debian poppler-utils): pages that are not blank, the ASPRS Edition 2 statement with the figures computed
here from the residual table, the verdict against the site tolerance, the units, the lever arm and delay in
words, no server path, user text shown as typed."""

from __future__ import annotations

import gzip
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from backend.services.report_pdf import build_report

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data" / "report_run"
CRS = "EPSG:32653"
E0, N0 = 679460.0, 3889270.0          # north-west corner of the drawn rasters (the simulated site's area)
PILES = [("SP01_cone", 679479.3, 3889232.0, 3.0), ("SP02_ridge", 679504.3, 3889229.5, 2.2)]

pytestmark = pytest.mark.skipif(shutil.which("pdftoppm") is None or shutil.which("pdftotext") is None,
                                reason="poppler-utils (pdftoppm, pdftotext) not installed: make install")


def _write_tif(path: Path, data: np.ndarray, cell: float, nodata=None) -> None:
    import rasterio
    from rasterio.transform import from_origin

    path.parent.mkdir(parents=True, exist_ok=True)
    bands = data if data.ndim == 3 else data[None]
    with rasterio.open(path, "w", driver="GTiff", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0],
                       dtype=bands.dtype, crs=CRS, transform=from_origin(E0, N0, cell, cell), nodata=nodata) as dst:
        dst.write(bands)


def _surface(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Ground sloping 1 cm/m to the east, two cones (the piles)."""
    z = 80.0 + 0.01 * (e - E0)
    for _, pe, pn, r in PILES:
        z = z + np.clip(1.2 * (1 - np.hypot(e - pe, n - pn) / r), 0, None)
    return z


def _run_folder(tmp: Path, with_rasters: bool = True) -> tuple[Path, Path]:
    """A worker-like run folder (out/ beside survey/) with the stored outputs of the simulated run."""
    run = tmp / "work" / "runs" / "7c0ffee-run"
    out, survey = run / "out", run / "survey"
    shutil.copytree(DATA / "out", out)
    shutil.copytree(DATA / "survey", survey)
    gz = out / "ppk" / "trajectory.pos.gz"
    (out / "ppk" / "trajectory.pos").write_bytes(gzip.decompress(gz.read_bytes()))
    gz.unlink()
    if with_rasters:
        rng = np.random.default_rng(3)
        cell = 0.25
        c = np.arange(260) * cell + cell / 2
        e, n = np.meshgrid(E0 + c, N0 - c)
        z = (_surface(e, n) + rng.normal(0, 0.005, e.shape)).astype(np.float32)
        z[:30, :30] = np.nan                                         # a corner without data
        _write_tif(out / "dense" / "dsm.tif", z, cell, nodata=float("nan"))
        cell_o = 0.1
        c = np.arange(650) * cell_o + cell_o / 2
        e, n = np.meshgrid(E0 + c, N0 - c)
        grey = 110 + 40 * np.sin(e / 3.0) * np.cos(n / 5.0) + rng.normal(0, 12, e.shape)
        road = np.abs((e - E0) - 0.4 * (N0 - n) - 20) < 2.5
        rgb = np.stack([grey * 0.9, grey * 1.0, grey * 0.7]).clip(0, 255)
        rgb[:, road] = 200
        for _, pe, pn, r in PILES:
            rgb[:, np.hypot(e - pe, n - pn) < r] = np.array([150, 120, 90])[:, None]
        _write_tif(out / "dense" / "ortho.tif", rgb.astype(np.uint8), cell_o)
        d = (z - 80.35).astype(np.float32)                           # surveyed minus a design plane
        _write_tif(out / "design" / "difference.tif", d, cell, nodata=float("nan"))
        (out / "design" / "cut_fill.json").write_text(json.dumps({
            "tolerance_m": 0.05, "cut_m3": 412.3, "fill_m3": 388.9, "net_m3": 23.4, "area_m2": 4225.0,
            "uncertainty": {k: {"sigma_m3": s} for k, s in (("cut_m3", 3.1), ("fill_m3", 2.9), ("net_m3", 4.4))},
            "on_grade": {"share": 0.121}, "polygon": {"name": "Pad A"}}))
    return out, survey


def _meta(**kw) -> dict:
    outline = lambda pe, pn, r: {"type": "Polygon", "coordinates": [[  # noqa: E731
        [pe + r * math.cos(a), pn + r * math.sin(a)] for a in np.linspace(0, 2 * math.pi, 25)]]}
    meta = {"site": "<b>Quarry & Co</b>", "company": "Acme <Earthworks>", "crs": CRS, "vertical_datum": None,
            "survey": "Weekly flight <i>24</i>", "flown_at": "2024-06-24T08:10:36Z", "flown_at_source": "gnss",
            "run_number": 4,
            "steps": [{"name": s, "state": "succeeded", "error": None} for s in ("gnss", "georef", "dense", "volumes")],
            "settings": {"gnss": {"elmask": 15.0}, "georef": {"gcp_sigma_m": [0.005, 0.01]}},
            "tolerance_horizontal_m": 0.03, "tolerance_vertical_m": 0.05,
            "volumes": [{"name": "SP01_cone", "base": "plane", "volume_m3": 15.25, "sigma_m3": 0.13,
                         "material": "crushed_stone", "density_t_m3": 1.6},
                        {"name": "SP02_ridge", "base": "lowest", "volume_m3": 24.44, "sigma_m3": 0.16,
                         "material": "sand", "density_t_m3": None}],
            "stockpile_outlines": [{"name": name, "outline": outline(pe, pn, r)} for name, pe, pn, r in PILES],
            "previous": {"run_number": 3, "volumes": {"SP01_cone": 14.90}, "rmse_d_m": 0.008}}
    meta.update(kw)
    return meta


def _pages(pdf: Path, tmp: Path) -> list[np.ndarray]:
    from PIL import Image

    subprocess.run(["pdftoppm", "-r", "40", "-png", str(pdf), str(tmp / "page")], check=True, timeout=120)
    files = sorted(tmp.glob("page-*.png"), key=lambda p: int(p.stem.split("-")[-1]))
    return [np.asarray(Image.open(f).convert("RGB"), dtype=float) for f in files]


def _text(pdf: Path) -> str:
    raw = subprocess.run(["pdftotext", str(pdf), "-"], check=True, capture_output=True, timeout=60).stdout.decode()
    return " ".join(raw.split())


def test_report_of_a_processed_survey(tmp_path):
    out, survey = _run_folder(tmp_path)
    pdf = tmp_path / "report.pdf"
    summary = build_report(out, pdf, _meta(), survey_dir=survey)
    assert {"cover", "equipment", "settings", "gnss_plot", "lever_arm", "residuals", "tolerance",
            "accuracy_statement", "maps", "volumes", "design"} <= set(summary["sections"]), summary["sections"]

    pages = _pages(pdf, tmp_path)
    assert 4 <= len(pages) <= 10, len(pages)
    inked = [float(np.mean(p.min(axis=2) < 200)) for p in pages]       # share of pixels with ink
    assert all(f > 0.01 for f in inked), inked                          # no blank page
    colour = [float(np.mean(p.max(axis=2) - p.min(axis=2) > 40)) for p in pages]
    assert max(colour) > 0.15, colour                                   # a page of maps (orthophoto, hillshade)

    text = _text(pdf)
    # the ASPRS Edition 2 statement, with the figures computed here: RMSE per axis from the residuals, the
    # check points' survey (0.5 cm per horizontal axis, 1.0 cm vertical) added in quadrature
    res = json.loads((DATA / "out" / "residuals.json").read_text())["points"]
    d = np.array([[p["dx_m"], p["dy_m"], p["dz_m"]] for p in res if p["role"] == "check"]) * 100
    rmse_h = math.hypot(math.sqrt(np.mean(d[:, 0] ** 2) + np.mean(d[:, 1] ** 2)), math.sqrt(2) * 0.5)
    rmse_v = math.hypot(math.sqrt(np.mean(d[:, 2] ** 2)), 1.0)
    assert (f"This data set was tested against the ASPRS Positional Accuracy Standards for Digital Geospatial Data, "
            f"Edition 2 (2023) using {len(d)} check points, fewer than the minimum of thirty (30) the standard calls "
            f"for. The tested horizontal positional accuracy was found to be RMSE_H = {rmse_h:.1f} (cm).") \
        in text, text
    assert f"was found to be RMSE_V = {rmse_v:.1f} (cm)" in text
    # the verdict against the site tolerance
    assert (f"WITHIN TOLERANCE: all {len(d)} check points within the site tolerance of 3.0 cm horizontally and "
            "5.0 cm vertically.") in text
    # lever arm and delay in words, with their sigmas (from the run's lever_arm_delay.json), not field names
    la = json.loads((DATA / "out" / "lever_arm_delay.json").read_text())
    (x, y, z), (sx, sy, sz) = la["lever_arm_cam_m"], la["lever_arm_sigma_m"]
    assert (f"sits {100 * abs(x):.1f} cm ± {100 * sx:.1f} cm to the {'right' if x >= 0 else 'left'}, "
            f"{100 * abs(y):.1f} cm ± {100 * sy:.1f} cm towards the {'bottom' if y >= 0 else 'top'} of the image and "
            f"{100 * abs(z):.1f} cm ± {100 * sz:.1f} cm along the viewing direction") in text, text
    assert f"exposes {1000 * la['delay_s']:.1f} ms ± {1000 * la['delay_sigma_s']:.1f} ms after the trigger" in text
    for field in ("lever_arm_cam_m", "delay_sigma_s", "gcp_sigma_m", "fix_rate"):
        assert field not in text, field
    # units: volumes in m3 with their uncertainty, tonnage in t (15.25 m3 x 1.6 t/m3), centimetres
    assert "volume (m3)" in text and "tonnage (t)" in text and "24.40 ± 0.21" in text and "15.25 ± 0.13" in text
    # sand without a density of its own: the inventory's default 1.60 +- 0.10 t/m3 -> 39.10 t, sigma
    # hypot(1.6 x 0.16, 24.44 x 0.10) = 2.46 t
    assert "1.60 ± 0.10 (default)" in text and "39.1 ± 2.5" in text
    assert "cut (m3)" in text and "412.3 ± 3.1" in text
    assert "100.0 %" in text                                               # the fix rate
    # no server paths, user text as typed
    for leak in ("/tmp", "/work", "/var", "7c0ffee-run", str(tmp_path)):
        assert leak not in text, leak
    assert "Site <b>Quarry & Co</b>, project CRS" in text and "Acme <Earthworks>" in text
    assert "Accuracy report: Weekly flight <i>24</i>" in text


def test_thirty_check_points_make_a_compliance_statement_and_a_point_outside_is_named(tmp_path):
    """33 check points: 32 of +-0.9, +-1.2, +-2.0 cm and T33 with dz 9 cm (beyond the 5 cm tolerance). By hand:
    RMSE_H(measured) = sqrt(32 x 2.25 / 33) = 1.477 cm, with the survey's sqrt(2) x 0.3 cm: 1.537 cm -> the
    2 cm class; RMSE_V = sqrt((32 x 4 + 81) / 33) = 2.517 cm, with 0.5 cm: 2.566 cm -> the 3 cm class."""
    out, _ = _run_folder(tmp_path, with_rasters=False)
    s = np.where(np.arange(32) % 2 == 0, 1.0, -1.0)
    rows = [{"name": f"T{i + 1:02d}", "role": "check", "dx_m": 0.009 * s[i], "dy_m": 0.012 * s[i],
             "dz_m": 0.02 * s[i]} for i in range(32)]
    rows.append({"name": "T33", "role": "check", "dx_m": 0.0, "dy_m": 0.0, "dz_m": 0.09})
    (out / "residuals.json").write_text(json.dumps({"points": rows}))
    (out / "residuals.csv").unlink()
    pdf = tmp_path / "r.pdf"
    meta = _meta(settings={"georef": {"gcp_sigma_m": [0.003, 0.005]}}, volumes=[], stockpile_outlines=[])
    summary = build_report(out, pdf, meta)
    assert "maps" not in summary["sections"]
    acc = summary["accuracy"]
    assert acc["compliant"] and acc["horizontal"]["class_cm"] == 2.0 and acc["vertical"]["class_cm"] == 3.0
    text = _text(pdf)
    assert ("This data set was tested to meet ASPRS Positional Accuracy Standards for Digital Geospatial Data, "
            "Edition 2 (2023) for a 2 (cm) RMSE_H Horizontal Positional Accuracy Class. The tested horizontal "
            "positional accuracy was found to be RMSE_H = 1.5 (cm).") in text, text
    assert ("for a 3 (cm) RMSE_V Vertical Accuracy Class. NVA accuracy was found to be RMSE_V = 2.6 (cm).") in text
    assert "OUTSIDE TOLERANCE: 1 of 33 check points beyond the site tolerance of 3.0 cm horizontally and 5.0 cm " \
           "vertically: T33." in text
    assert summary["tolerance"]["outside"] == ["T33"] and not summary["tolerance"]["pass"]


def test_a_site_without_tolerance_is_not_judged(tmp_path):
    out, _ = _run_folder(tmp_path, with_rasters=False)
    pdf = tmp_path / "r.pdf"
    build_report(out, pdf, _meta(tolerance_horizontal_m=None, tolerance_vertical_m=None, volumes=[]))
    text = _text(pdf)
    assert "No tolerance set for this site: the residuals are not judged." in text
    assert "WITHIN TOLERANCE" not in text and "OUTSIDE TOLERANCE" not in text
