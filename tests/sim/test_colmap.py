"""The rendered images register in COLMAP (pycolmap, CPU) with sub-pixel reprojection error, and the
reconstructed camera centres match the truth up to a similarity."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from .helpers import similarity_fit

pytestmark = pytest.mark.skipif(importlib.util.find_spec("pycolmap") is None, reason="pycolmap missing")


def test_images_register_in_colmap(small_sim, tmp_path):
    import pycolmap

    intr = json.loads((small_sim.truth_dir / "intrinsics.json").read_text())
    db = tmp_path / "db.db"
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = intr["colmap_model"]
    reader.camera_params = ",".join(repr(float(v)) for v in intr["colmap_params"])
    ext = pycolmap.FeatureExtractionOptions()
    ext.sift.max_num_features = 2500
    ext.num_threads = 2
    pycolmap.extract_features(db, small_sim.out_dir / "images", camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, extraction_options=ext, device=pycolmap.Device.cpu)
    match = pycolmap.FeatureMatchingOptions()
    match.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=match, device=pycolmap.Device.cpu)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.ba_refine_focal_length = False
    opts.ba_refine_principal_point = False
    opts.ba_refine_extra_params = False
    opts.multiple_models = False
    opts.random_seed = 0
    opts.num_threads = 2
    (tmp_path / "sparse").mkdir()
    recs = pycolmap.incremental_mapping(db, small_sim.out_dir / "images", tmp_path / "sparse", options=opts)
    assert recs, "no reconstruction"
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    assert rec.num_reg_images() == small_sim.n_images
    assert rec.compute_mean_reprojection_error() < 0.5
    poses = {p["name"]: p for p in json.loads((small_sim.truth_dir / "camera_poses.json").read_text())["images"]}
    src = np.array([im.projection_center() for im in rec.images.values()])
    dst = np.array([poses[im.name]["camera_centre_enu_m"] for im in rec.images.values()])
    s, R, t = similarity_fit(src, dst)
    res = dst - (s * src @ R.T + t)
    assert np.sqrt(np.mean(np.sum(res**2, axis=1))) < 0.03  # metres, with a ~7 cm GSD
