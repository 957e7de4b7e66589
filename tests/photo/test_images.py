"""EXIF reading of the image inputs."""

from __future__ import annotations

import datetime as dt
import json
import warnings

import numpy as np
import pytest
from PIL import Image

from georef_core.errors import InputFileError
from georef_core.photo.images import (
    ExifWarning,
    list_images,
    local_positions_m,
    read_image_info,
    read_images,
)


def test_caliterra_exif(caliterra_images):
    info = read_image_info(caliterra_images / "IMG_9385.jpg")
    assert (info.width, info.height) == (1600, 1200)
    assert info.make == "Canon" and "SX260" in info.model
    assert info.focal_length_mm == pytest.approx(4.5)
    assert info.sensor_width_mm == pytest.approx(6.2, abs=0.05)
    assert info.focal_length_px == pytest.approx(1160, abs=15)
    assert info.time_original == dt.datetime(2014, 10, 19, 13, 21, 56)
    assert info.gps_lat_deg == pytest.approx(30.17, abs=0.01)
    assert info.gps_lon_deg == pytest.approx(-98.09, abs=0.01)
    assert info.gps_alt_m == pytest.approx(380.5)


def test_caliterra_local_positions(caliterra_images):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExifWarning)
        infos = read_images(caliterra_images)
    pos, frame = local_positions_m(infos)
    assert frame["type"] == "ENU" and len(pos) == 30
    xyz = np.array(list(pos.values()))
    assert np.all(np.abs(xyz.mean(axis=0)) < 1.0)
    assert 20 < np.ptp(xyz[:, 0]) + np.ptp(xyz[:, 1]) < 1000  # a site-sized flight, in metres


def test_sim_exif_matches_truth(photo_sim):
    truth_k = json.loads((photo_sim.truth_dir / "intrinsics.json").read_text())
    poses = json.loads((photo_sim.truth_dir / "camera_poses.json").read_text())["images"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExifWarning)
        infos = read_images(photo_sim.out_dir / "images")
    assert len(infos) == len(poses) == 12
    for info, t in zip(infos, poses):
        assert info.name == t["name"]
        assert info.focal_length_mm == pytest.approx(truth_k["focal_mm"], abs=0.01)
        assert info.sensor_width_mm == pytest.approx(truth_k["sensor_width_mm"], rel=1e-3)
        assert info.sensor_height_mm == pytest.approx(truth_k["sensor_height_mm"], rel=1e-3)
        assert info.focal_length_px == pytest.approx(truth_k["fx"], rel=2e-3)
        assert info.make == truth_k["make"] and info.model == truth_k["model"]
        exp = dt.datetime.fromisoformat(t["exposure_utc"])
        assert info.time_original.utcoffset() == dt.timedelta(0)
        assert 0 <= (exp - info.time_original).total_seconds() < 1e-3  # truncated to ms
        assert info.has_gps


def test_missing_exif_warns(tmp_path):
    p = tmp_path / "plain.jpg"
    Image.new("RGB", (64, 48), (120, 120, 120)).save(p)
    with pytest.warns(ExifWarning, match="plain.jpg"):
        info = read_image_info(p)
    assert info.time_original is None and info.focal_length_px is None and not info.has_gps
    assert "DateTimeOriginal" in info.missing


def test_unreadable_image_names_file(tmp_path):
    p = tmp_path / "broken.JPG"
    p.write_bytes(b"\xff\xd8\xff garbage")
    with pytest.raises(InputFileError) as e:
        read_image_info(p)
    assert e.value.path == str(p) and "not a readable image" in str(e.value)
    with pytest.raises(InputFileError, match="does not exist"):
        read_image_info(tmp_path / "missing.jpg")


def test_empty_folder_names_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("no images here")
    with pytest.raises(InputFileError) as e:
        list_images(tmp_path)
    assert e.value.path == str(tmp_path) and "no image files" in str(e.value)


def test_photos_are_grouped_by_camera_and_a_stray_photo_is_named():
    """One camera per (make/model, size, focal length); a group of fewer than 3 photos is left out, each
    of its photos named with what differs; when no group has 3 photos nothing is left out."""
    from pathlib import Path

    from georef_core.photo.images import ImageInfo, group_cameras

    def info(name, w, h, model="FC6310", focal=8.8):
        return ImageInfo(path=Path(name), name=name, width=w, height=h, make="DJI", model=model,
                         focal_length_mm=focal)

    infos = ([info(f"A{i}.JPG", 5472, 3648) for i in range(5)] + [info(f"B{i}.JPG", 4000, 3000, "FC330", 3.61)
                                                                  for i in range(3)]
             + [info("small.JPG", 1368, 912)])
    groups, left_out = group_cameras(infos)
    assert [(g.model, g.width, len(g.names)) for g in groups] == [("FC6310", 5472, 5), ("FC330", 4000, 3)]
    assert [lo["image"] for lo in left_out] == ["small.JPG"]
    reason = left_out[0]["reason"]
    assert reason.startswith("small.JPG: left out") and "1368 x 912 px" in reason and "5472 x 3648" in reason
    assert "at least 3" in reason
    # a zoomed photo (same camera and size, another focal length) is another camera too
    groups, left_out = group_cameras(infos[:5] + [info("zoom.JPG", 5472, 3648, focal=12.0)])
    assert len(groups) == 1 and left_out[0]["image"] == "zoom.JPG" and "focal length 12.0 mm" in left_out[0]["reason"]
    # nothing to calibrate better with: everything kept
    groups, left_out = group_cameras([info("a.JPG", 640, 480), info("b.JPG", 800, 600)])
    assert len(groups) == 2 and not left_out
