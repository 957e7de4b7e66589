"""The fisheye camera model through the whole chain: the projection against OpenCV's cv2.fisheye and the
simulator's lens, then a simulated fisheye survey (8 images of 960 x 720, about 90 degrees across)
through `georef georef --camera-model fisheye` and `georef dense`, with errors in physical units."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from georef_core.adjustment import camera_model as cm
from georef_core.cli.main import main
from georef_core.sim.camera import CameraModel, CameraOptions

from ..once_per_session import once_per_session

pytest.importorskip("pycolmap")


def _random_camera_points(seed: int, n: int = 300) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-45, 45, n), rng.uniform(25, 70, n)])


def test_fisheye_projection_matches_opencv_and_the_simulator():
    cam = CameraModel.from_options(CameraOptions.fisheye())
    model, params_colmap = cam.colmap_params()
    assert model == "OPENCV_FISHEYE"
    intr = cm.from_colmap(model, params_colmap)
    assert intr[0] == pytest.approx(cam.fx) and intr[1] == pytest.approx(cam.cx) and intr[6] == pytest.approx(cam.k4)
    pc = _random_camera_points(1)
    uv = cm.project_camera_points(pc, intr, fisheye=True)
    K = np.array([[intr[0], 0, intr[1]], [0, intr[0], intr[2]], [0, 0, 1.0]])
    uv_cv, _ = cv2.fisheye.projectPoints(pc.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, intr[3:7])
    assert np.abs(uv - uv_cv.reshape(-1, 2)).max() < 1e-6
    inside = np.isfinite(cam.project(pc)[:, 0])
    assert inside.sum() > 100
    assert np.abs(uv[inside] - cam.project(pc)[inside]).max() < 1e-6
    # back to normalised coordinates, and the model differs from the perspective one with the same numbers
    xy = cm.undistort_pixels(uv, intr, fisheye=True)
    assert np.abs(xy - pc[:, :2] / pc[:, 2:]).max() < 1e-9
    assert np.abs(cm.project_camera_points(pc, intr) - uv).max() > 50.0
    assert cm.to_colmap(intr, fisheye=True) == ("OPENCV_FISHEYE", pytest.approx(params_colmap))
    assert list(cm.free_mask("fisheye")) == [True] * 7 + [False]
    assert cm.param_names(True)[6] == "k4"


@pytest.fixture(scope="module")
def fisheye_survey(tmp_path_factory) -> Path:
    def make(folder):
        out = folder / "site"
        assert main(["simulate", str(out), "--seed", "12", "--small", "--lens", "fisheye", "--image-size", "960",
                     "720", "--quiet"]) == 0
        return out

    return once_per_session(tmp_path_factory, "fisheye_survey_seed12", make)


@pytest.fixture(scope="module")
def fisheye_run(fisheye_survey, tmp_path_factory) -> Path:
    def make(out):
        assert main(["georef", str(fisheye_survey), "--out", str(out), "--camera-model", "fisheye",
                     "--control", "T01,T03,T05", "--no-leave-one-out"]) == 0
        return out

    return once_per_session(tmp_path_factory, "fisheye_run", make)


def test_a_fisheye_survey_is_georeferenced(fisheye_survey, fisheye_run):
    truth = json.loads((fisheye_survey / "truth" / "intrinsics.json").read_text())
    assert truth["colmap_model"] == "OPENCV_FISHEYE"
    s = json.loads((fisheye_run / "georef_summary.json").read_text())
    assert s["images"]["registered"] == s["images"]["total"] >= 6
    assert s["adjustment"]["converged"] and s["adjustment"]["rms_reprojection_px"] < 0.6
    intr = s["intrinsics"]
    assert intr["projection"] == "fisheye" and intr["names"][3:7] == ["k1", "k2", "k3", "k4"]
    f, cx, cy = intr["values"][:3]
    assert abs(f - truth["fx"]) < 0.005 * truth["fx"], (f, truth["fx"])       # focal within 0.5 %
    assert abs(cx - truth["cx"]) < 3.0 and abs(cy - truth["cy"]) < 3.0       # principal point within 3 px
    res = json.loads((fisheye_run / "residuals.json").read_text())
    d = np.array([[r["dx_m"], r["dy_m"], r["dz_m"]] for r in res["points"]])
    assert len(d) >= 1
    assert np.all(np.abs(d[:, :2]) < 0.03) and np.all(np.abs(d[:, 2]) < 0.05), d
    oriented = json.loads((fisheye_run / "oriented_images.json").read_text())
    assert {c["model"] for c in oriented["cameras"].values()} == {"OPENCV_FISHEYE"}


def test_dense_views_project_through_the_fisheye(fisheye_survey):
    from georef_core.dense.camera_views import views_from_oriented
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth

    oriented = oriented_images_from_simulator_truth(fisheye_survey)
    truth = json.loads((fisheye_survey / "truth" / "intrinsics.json").read_text())
    cam = CameraModel(**{k: truth[k] for k in ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2",
                                                 "k4", "projection")})
    view = views_from_oriented(oriented, None)[0]
    im = oriented.images[0]
    assert view.fisheye
    rng = np.random.default_rng(3)
    ground = np.column_stack([rng.uniform(-30, 30, 400), rng.uniform(-30, 30, 400), rng.uniform(-2, 2, 400)])
    expected = cam.project_world(ground, im.centre_enu_m, im.R_cam_to_enu)
    uv, z = view.project_distorted(ground)
    ok = np.isfinite(expected[:, 0]) & view.inside(expected)
    assert ok.sum() > 50 and np.all(z[ok] > 0)
    assert np.abs(uv[ok] - expected[ok]).max() < 1e-6
    # undistorted points and the remap tables agree with the pinhole projection
    pin, _ = view.project_pinhole(ground[ok])
    xy = view.undistort_points(uv[ok])
    assert np.abs(xy * view.K[0, 0] + view.K[:2, 2] - pin).max() < 1e-3
    mx, my = view.rectify_maps(np.eye(3), view.K, (view.width, view.height))
    inside = (pin[:, 0] > 1) & (pin[:, 0] < view.width - 2) & (pin[:, 1] > 1) & (pin[:, 1] < view.height - 2)
    ij = np.round(pin[inside]).astype(int)
    back = np.column_stack([mx[ij[:, 1], ij[:, 0]], my[ij[:, 1], ij[:, 0]]])
    fwd = view.project_distorted(view.centre_enu_m + view.rays_enu(ij[:, 0].astype(float), ij[:, 1].astype(float)))[0]
    assert np.abs(back - fwd).max() < 0.05


def test_dense_surface_from_a_fisheye_survey(fisheye_survey, fisheye_run):
    from georef_core.dense.dsm_compare import compare_dsm

    assert main(["dense", str(fisheye_run)]) == 0
    c = compare_dsm(fisheye_run / "dense" / "dsm.tif", fisheye_survey / "truth" / "dsm.tif",
                    fisheye_run / "dense" / "dsm_filled_mask.tif")
    assert c["completeness"] > 0.9
    assert c["measured"]["rmse_m"] < 0.04, c["measured"]                      # DSM within 4 cm RMS of the truth


def test_a_calibration_fixes_the_camera_model(fisheye_run, fisheye_survey, tmp_path, capsys):
    rc = main(["georef", str(fisheye_survey), "--out", str(tmp_path / "x"), "--calibration", str(fisheye_run),
               "--camera-model", "brown"])
    assert rc == 2
    assert "does not match the calibration's camera model fisheye" in capsys.readouterr().err
