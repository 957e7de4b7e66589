"""`georef georef` on the real COPR kite survey (shared data, 40 images at 1600 px, ODM gcp_list with
ten painted targets surveyed by hand-held GPS, heights not surveyed). The file carries a known labelling
blunder: gcp04's measurement in IMG_0031.jpg is the pixel of gcp00 (PROVENANCE.txt). It must be named,
the rest processed, and the check-point table written. The targets' coordinates are only good to a
couple of metres, so the bands here are metres: what is tested is the chain, not the survey."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from georef_core.cli.main import main

from ..shared_images import shared_image_set

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def copr_survey(tmp_path_factory) -> Path:
    src = shared_image_set("copr_subset40")
    if not (src / "gcp_list_1600px.txt").is_file():
        pytest.skip(f"shared data not available ({src})")
    survey = tmp_path_factory.mktemp("copr") / "survey"
    (survey / "images").mkdir(parents=True)
    for img in sorted(src.glob("IMG_*.jpg")):
        (survey / "images" / img.name).symlink_to(img)
    (survey / "gcp").mkdir()
    (survey / "gcp" / "gcp_list.txt").write_text((src / "gcp_list_1600px.txt").read_text())
    return survey


def test_copr_blunder_named_and_check_table(copr_survey, tmp_path):
    out = tmp_path / "out"
    rc = main(["georef", str(copr_survey), "--out", str(out), "--check", "gcp02,gcp05,gcp08", "--no-leave-one-out"])
    assert rc == 0
    s = json.loads((out / "georef_summary.json").read_text())
    assert [(b["point"], b["image"]) for b in s["blunders"]] == [("gcp04", "IMG_0031.jpg")]
    assert s["adjustment"]["converged"]
    assert s["images"]["registered"] >= 35
    assert s["adjustment"]["rms_reprojection_px"] < 1.0
    res = json.loads((out / "residuals.json").read_text())
    assert {r["name"] for r in res["points"]} == {"gcp02", "gcp05", "gcp08"}
    st = res["statistics"]
    assert st["horizontal"]["rmse_m"] < 5.0          # hand-held GPS targets: metres, not centimetres
    # the control points' variance factor says how good their coordinates really are (metres, not the
    # a-priori centimetre): an honest adjustment does not pretend
    assert s["adjustment"]["sigma0"]["control"] > 20
    # ... and the run says it in words (georef.control_accuracy_warning)
    assert any("control points fit the block" in w for w in s["warnings"]), s["warnings"]
    assert (out / "residuals.csv").read_text().splitlines()[0].startswith("point,role,dx_m")
