"""Mixed image sets: a survey whose photos come from two cameras (another drone, size and focal length:
`georef simulate --second-camera 512x384:4.8`, every other photo) is processed with one camera per
(make/model, size, focal length): every photo registers, each camera is calibrated on its own, the
check points land in the same band as the single-camera survey's (tests/adjustment/test_georef_step.py),
and the dense step builds the DSM from both cameras' views. Measured (seed 11, 12 photos, 6 per camera,
control T01, T03, T05, check points T02 and T04): 3D RMSE 34 mm (largest component 2.6 cm) with this
second camera of 1.6 x coarser pixels on the ground (f = 349 px against 560 px: its target clicks are
coarser), 6.7 mm with an 800 x 600 px, 5.5 mm second camera (f = 625 px; slower to extract, so not the
test's), 5.7 mm for the same survey with one camera; DSM against the truth 15.9 mm RMSE (median 5.6 mm)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from georef_core.cli.main import main

from ..once_per_session import once_per_session

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def mixed(tmp_path_factory) -> Path:
    def make(folder):
        out = folder / "site"
        assert main(["simulate", str(out), "--seed", "11", "--small", "--quiet", "--second-camera", "512x384:4.8"]) == 0
        return out

    return once_per_session(tmp_path_factory, "mixed_cameras_seed11", make)


@pytest.fixture(scope="module")
def mixed_run(mixed, tmp_path_factory) -> Path:
    def make(out):
        assert main(["georef", str(mixed), "--out", str(out), "--control", "T01,T03,T05", "--no-leave-one-out"]) == 0
        return out

    return once_per_session(tmp_path_factory, "mixed_cameras_run", make)


def test_two_cameras_register_and_georeference(mixed, mixed_run):
    s = json.loads((mixed_run / "georef_summary.json").read_text())
    assert s["images"]["registered"] == s["images"]["total"] == 12 and not s["images"]["left_out"]
    cams = {c["id"]: c for c in s["cameras"]}
    assert len(cams) == 2
    assert (cams[1]["width"], cams[1]["height"]) == (640, 480) and (cams[2]["width"], cams[2]["height"]) == (512, 384)
    assert "SimCam-GS-B" in cams[2]["label"] and "4.8 mm" in cams[2]["label"]
    # each camera calibrated on its own, against the simulator's truth
    for cid, truth_file in ((1, "intrinsics.json"), (2, "intrinsics_camera2.json")):
        t = json.loads((mixed / "truth" / truth_file).read_text())
        f, cx, cy, k1 = cams[cid]["values"][:4]
        assert abs(f / t["fx"] - 1) < 0.01 and abs(cx - t["cx"]) < 2 and abs(cy - t["cy"]) < 2, (cid, cams[cid], t)
        assert abs(k1 - t["k1"]) < 0.01, (cid, k1, t["k1"])
    # the hand-over to the dense step: each image with its own camera
    oi = json.loads((mixed_run / "oriented_images.json").read_text())
    truth_cam = json.loads((mixed / "truth" / "cameras.json").read_text())["images"]
    assert {int(k) for k in oi["cameras"]} == {1, 2}
    assert {im["name"]: im["camera_id"] for im in oi["images"]} == truth_cam
    # the same error band as the single-camera survey (test_georef_step: |dx|, |dy| < 3 cm, |dz| < 5 cm)
    res = json.loads((mixed_run / "residuals.json").read_text())
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in res["points"]])
    print(f"two cameras: check points {res['statistics']['3d']['rmse_m'] * 1000:.1f} mm 3D RMSE ({len(d)} points)")
    assert len(d) == 2 and np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d
    assert s["doming"]["camera_positions"] is not None


def test_dense_step_uses_both_cameras(mixed, mixed_run):
    from georef_core.dense.dsm_compare import compare_dsm
    from georef_core.steps.dense import run_dense

    summary = run_dense(mixed_run)
    site = json.loads((mixed / "truth" / "site.json").read_text())
    f, wa = site["frame"], site["work_area_site_xy_m"]
    bounds = (f["origin_E_m"] + wa[0][0], f["origin_N_m"] + wa[0][1], f["origin_E_m"] + wa[1][0], f["origin_N_m"] + wa[1][1])
    c = compare_dsm(mixed_run / "dense" / "dsm.tif", mixed / "truth" / "dsm.tif",
                    mixed_run / "dense" / "dsm_filled_mask.tif", bounds=bounds)
    m = c["measured"]
    print(f"two cameras: DSM - truth RMSE {1000 * m['rmse_m']:.1f} mm, median {1000 * m['median_m']:.1f} mm, "
          f"completeness {c['completeness']:.3f}")
    assert m["rmse_m"] < 0.03 and abs(m["median_m"]) < 0.015 and c["completeness"] > 0.9, c
    assert summary is not None
