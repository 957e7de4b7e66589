"""oriented_images.json found its images by the absolute path of the georef run's folder only: a later run
that reused the georef result, or a part of the tiled dense step in its own folder (parts/dense-<k>/survey,
.../out), failed with "image of oriented_images.json not found" once that folder was cleaned (found by
bench/dense_over_workers.py through a real worker). The file now also names the folder relative to itself."""

from __future__ import annotations

import json
import shutil

import numpy as np

from georef_core.photo.oriented_images import OrientedCamera, OrientedImage, OrientedImages, read_oriented_images
from georef_core.project_frame import ProjectFrame


def _write_run(root):
    (root / "survey" / "images").mkdir(parents=True)
    (root / "survey" / "images" / "IMG_0001.JPG").write_bytes(b"jpeg")
    oi = OrientedImages(ProjectFrame(32631, 500000.0, 4000000.0, 50.0), (root / "survey" / "images").resolve(),
                        {1: OrientedCamera("PINHOLE", 640, 480, [500.0, 500.0, 320.0, 240.0])},
                        [OrientedImage("IMG_0001.JPG", 1, np.eye(3), np.zeros(3))])
    return oi.write(root / "out" / "oriented_images.json")


def test_images_found_beside_a_moved_run_folder(tmp_path):
    path = _write_run(tmp_path / "runs" / "r1")
    doc = json.loads(path.read_text())
    assert doc["image_dir_relative"] == "../survey/images"
    # as a worker materialises a later run (or a part) and cleans the first run's folder
    shutil.copytree(tmp_path / "runs" / "r1", tmp_path / "runs" / "r2" / "parts" / "dense-0001")
    shutil.rmtree(tmp_path / "runs" / "r1")
    moved = tmp_path / "runs" / "r2" / "parts" / "dense-0001" / "out" / "oriented_images.json"
    oi = read_oriented_images(moved)
    assert oi.image_path(oi.images[0]).is_file()
    assert oi.image_dir == (tmp_path / "runs" / "r2" / "parts" / "dense-0001" / "survey" / "images").resolve()
    assert "image_dir_relative" not in oi.extra


def test_absolute_folder_kept_when_the_file_alone_moves(tmp_path):
    path = _write_run(tmp_path / "a")
    (tmp_path / "elsewhere").mkdir()
    alone = tmp_path / "elsewhere" / "oriented_images.json"
    shutil.copy(path, alone)
    oi = read_oriented_images(alone)
    assert oi.image_dir == (tmp_path / "a" / "survey" / "images").resolve()
    assert oi.image_path(oi.images[0]).is_file()
