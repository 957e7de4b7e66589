"""SfM step on real (Caliterra subset) and simulated images."""

from __future__ import annotations

import json

import numpy as np
import pytest

from georef_core.errors import InputFileError
from georef_core.photo import colmap_api
from georef_core.photo.align import fit_similarity
from georef_core.photo.sfm import SfmOptions, choose_matcher, run_sfm


def test_caliterra_all_registered_subpixel(caliterra_sfm):
    result, stages = caliterra_sfm
    assert result.matcher == "exhaustive"
    assert result.n_images == 30
    assert result.n_registered == 30
    assert result.mean_reprojection_error_px < 1.0
    rec = result.reconstruction
    assert len(rec.points_xyz) > 5000
    assert np.all(rec.points_track_length >= 2)
    (cam,) = rec.cameras.values()  # shared intrinsics
    assert cam.model == "SIMPLE_RADIAL"
    assert 1100 < cam.params[0] < 1300  # 4.5 mm on a 6.2 mm wide sensor, 1600 px
    assert {s for s, _, _ in stages} >= {"extraction", "matching", "mapping", "done"}
    assert all(result.timings_s[k] > 0 for k in ("extraction", "matching", "mapping"))
    summary = json.loads(result.summary_path.read_text())
    assert summary["n_registered"] == 30 and summary["matcher"] == "exhaustive"
    back = colmap_api.read_model(result.model_dir)
    assert back.num_registered == 30
    assert abs(back.mean_reprojection_error_px - result.mean_reprojection_error_px) < 1e-6


def test_sim_registered_and_centres_match_truth(sim_sfm, photo_sim):
    result = sim_sfm
    assert result.n_registered == 12
    assert result.mean_reprojection_error_px < 1.0
    truth = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    centres = result.centres_by_name()
    names = [t["name"] for t in truth]
    src = np.array([centres[n] for n in names])
    dst = np.array([t["camera_centre_enu_m"] for t in truth])
    sim, res = fit_similarity(src, dst)
    assert np.max(np.linalg.norm(res, axis=1)) < 0.05
    # rotations: R_cam_to_enu ~= R_sim @ R_cam_to_model
    rec = result.reconstruction.image_by_name()
    for t in truth:
        r_est = sim.R @ rec[t["name"]].R_cam_from_world.T
        cos = (np.trace(r_est.T @ np.array(t["R_cam_to_enu"])) - 1) / 2
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 0.2


def test_rerun_overwrites(sim_sfm, photo_sim):
    again = run_sfm(photo_sim.out_dir / "images", sim_sfm.work_dir, SfmOptions(camera_model="OPENCV", refine_principal_point=True))
    assert again.n_registered == 12
    assert len(list((sim_sfm.work_dir / "sparse").iterdir())) == 1


def test_matcher_choice():
    o = SfmOptions()
    assert choose_matcher(30, True, o) == "exhaustive"
    assert choose_matcher(31, True, o) == "spatial"
    assert choose_matcher(31, False, o) == "sequential"
    assert choose_matcher(10, True, SfmOptions(matcher="sequential")) == "sequential"


def test_spatial_and_sequential_matchers_run(photo_sim, tmp_path):
    images = photo_sim.out_dir / "images"
    for matcher in ("spatial", "sequential"):
        r = run_sfm(images, tmp_path / matcher, SfmOptions(matcher=matcher, max_image_size=640, num_threads=2))
        assert r.matcher == matcher
        assert r.summary["database"]["verified_pairs"] > 11
        if matcher == "spatial":
            assert r.summary["database"]["pose_priors"] == 12


def test_empty_folder_error(tmp_path):
    with pytest.raises(InputFileError) as e:
        run_sfm(tmp_path, tmp_path / "work")
    assert str(tmp_path) in str(e.value)


def test_missing_folder_error(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        run_sfm(tmp_path / "nope", tmp_path / "work")


def test_non_image_file_error(tmp_path):
    bad = tmp_path / "IMG_0001.jpg"
    bad.write_text("this is not a JPEG")
    with pytest.raises(InputFileError) as e:
        run_sfm(tmp_path, tmp_path / "work")
    assert e.value.path == str(bad)
