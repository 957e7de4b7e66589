"""`georef dense` and the step's handling of bad input and cancellation."""

from __future__ import annotations

import json
import shutil

import cv2
import pytest
import rasterio

from georef_core.cli.main import main
from georef_core.errors import InputFileError, StepCancelled
from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
from georef_core.steps.dense import DenseOptions, run_dense


def test_cancel_then_cli_rerun_in_the_same_folder(dense_sim, tmp_path, capsys):
    elsewhere = tmp_path / "georef" / "my_oriented.json"
    oriented_images_from_simulator_truth(dense_sim.out_dir).write(elsewhere)
    run = tmp_path / "run"

    def cancel(stage, done, total):
        if stage == "depth maps" and done >= 3:
            raise StepCancelled("cancelled by the test")

    with pytest.raises(StepCancelled):
        run_dense(run, DenseOptions(oriented_path=str(elsewhere)), progress=cancel)
    rc = main(["dense", str(run), "--oriented", str(elsewhere), "--resolution", "0.2", "--no-ortho", "--quiet"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "DSM" in out and "points:" in out
    d = run / "dense"
    assert (d / "dsm.tif").is_file() and (d / "points.laz").is_file() and not (d / "ortho.tif").exists()
    assert not (d / "depthmaps").exists()
    with rasterio.open(d / "dsm.tif") as ds:
        assert ds.transform.a == pytest.approx(0.2)
    s = json.loads((d / "dense_summary.json").read_text())
    assert s["dsm_resolution_m"] == 0.2 and s["ortho"] is None and s["oriented_images"] == str(elsewhere)


def test_cli_errors(tmp_path, capsys):
    assert main(["dense", str(tmp_path / "nothing")]) == 2
    err = capsys.readouterr().err
    assert "georef: error:" in err and "oriented_images.json: oriented-images file not found" in err
    (tmp_path / "oriented_images.json").write_text("{not json")
    assert main(["dense", str(tmp_path), "--quiet"]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    assert main(["dense", str(tmp_path), "--resolution", "0", "--quiet"]) == 2
    assert "resolution_m must be a positive number" in capsys.readouterr().err


@pytest.fixture()
def copied_survey(dense_sim, tmp_path):
    images = tmp_path / "images"
    shutil.copytree(dense_sim.out_dir / "images", images)
    oi = oriented_images_from_simulator_truth(dense_sim.out_dir)
    oi.image_dir = images
    return oi, tmp_path


def test_bad_images_are_named(copied_survey):
    oi, tmp = copied_survey
    run = tmp / "run"
    oi.write(run / "oriented_images.json")
    (oi.image_dir / "IMG_0005.JPG").unlink()
    with pytest.raises(InputFileError, match="IMG_0005.JPG.*not found"):
        run_dense(run)
    small = cv2.resize(cv2.imread(str(oi.image_dir / "IMG_0004.JPG")), (320, 240))
    cv2.imwrite(str(oi.image_dir / "IMG_0005.JPG"), small)
    with pytest.raises(InputFileError, match=r"IMG_0005.JPG: image is 320 x 240 px but its camera says 640 x 480"):
        run_dense(run)
    (oi.image_dir / "IMG_0005.JPG").write_bytes(b"\xff\xd8 truncated")
    with pytest.raises(InputFileError, match="IMG_0005.JPG: cannot read the image"):
        run_dense(run)


def test_bad_oriented_files_are_named(copied_survey):
    oi, tmp = copied_survey
    path = tmp / "run" / "oriented_images.json"
    cam = oi.cameras[1]
    cam.model = "THIN_PRISM_FISHEYE"
    oi.write(path)
    with pytest.raises(InputFileError, match="oriented_images.json: camera model THIN_PRISM_FISHEYE"):
        run_dense(tmp / "run")
    cam.model = "FULL_OPENCV"
    oi.images = oi.images[:1]
    oi.write(path)
    with pytest.raises(InputFileError, match="at least 2 oriented images"):
        run_dense(tmp / "run")


def test_options_from_a_dict():
    from georef_core.errors import ProcessingError

    o = DenseOptions.from_dict({"workers": 1, "resolution_m": 0.1, "fusion": {"min_views": 4}})
    assert o.workers == 1 and o.resolution_m == 0.1 and o.fusion.min_views == 4 and o.pairs.n_sources == 3
    with pytest.raises(ProcessingError, match="unknown dense option 'colour'"):
        DenseOptions.from_dict({"colour": True})
    with pytest.raises(ProcessingError, match="fusion.views"):
        DenseOptions.from_dict({"fusion": {"views": 2}})
