"""SfM reuse is keyed on its inputs (issue 24): a stored model is reused only when made from the same
photos (names, sizes, content) with the same options; before, the key was the camera model alone, so a
re-run with added photos reused the stale model and reported the new photos 'not registered'."""

from __future__ import annotations

import shutil

from PIL import Image

from georef_core.photo.sfm import SfmOptions, sfm_inputs_key


def _photo(path, colour):
    Image.new("RGB", (320, 240), colour).save(path, "JPEG")


def test_the_key_follows_the_photos_and_the_options(tmp_path):
    d = tmp_path / "images"
    d.mkdir()
    for i in range(3):
        _photo(d / f"IMG_{i}.JPG", (10 * i, 80, 120))
    (d / "notes.txt").write_text("not a photo")
    opts = SfmOptions(camera_model="OPENCV")
    k0 = sfm_inputs_key(d, opts)
    assert sfm_inputs_key(d, SfmOptions(camera_model="OPENCV")) == k0          # the same inputs: reused
    (d / "notes.txt").write_text("still not a photo")
    assert sfm_inputs_key(d, opts) == k0                                       # other files do not count
    _photo(d / "IMG_3.JPG", (200, 10, 10))
    k_added = sfm_inputs_key(d, opts)
    assert k_added != k0                                                       # a photo added
    _photo(d / "IMG_3.JPG", (10, 200, 10))
    assert sfm_inputs_key(d, opts) != k_added                                  # a photo replaced
    (d / "IMG_3.JPG").unlink()
    assert sfm_inputs_key(d, opts) == k0                                       # back to the first set
    assert sfm_inputs_key(d, SfmOptions(camera_model="RADIAL")) != k0           # another camera model
    # GNSS positions steer spatial matching only: keyed (to the centimetre) when the matcher is spatial
    pos = {"IMG_0.JPG": (1.0, 2.0, 3.0)}
    exhaustive = SfmOptions(camera_model="OPENCV", positions=pos)              # 3 photos: exhaustive
    assert sfm_inputs_key(d, exhaustive) == k0
    for spatial in ({"matcher": "spatial"}, {"exhaustive_max_images": 2}):
        with_pos = SfmOptions(camera_model="OPENCV", positions=pos, **spatial)
        k_pos = sfm_inputs_key(d, with_pos)
        other = SfmOptions(camera_model="OPENCV", positions={"IMG_0.JPG": (1.5, 2.0, 3.0)}, **spatial)
        assert sfm_inputs_key(d, other) != k_pos                               # another position: matched anew
        moved = SfmOptions(camera_model="OPENCV", positions={"IMG_0.JPG": (1.004, 2.0, 3.0)}, **spatial)
        assert sfm_inputs_key(d, moved) == k_pos                               # to the centimetre
    shutil.copy(d / "IMG_0.JPG", d / "IMG_9.jpeg")
    assert sfm_inputs_key(d, opts) != k0
