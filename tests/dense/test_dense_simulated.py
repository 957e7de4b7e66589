"""The dense step on the small simulated survey with its true orientations, against the simulator's truth:
DSM heights (truth/dsm.tif), target positions in the orthophoto (truth/targets.csv), the LAZ file and the
raster files' form. Measured on this scene (seed 1): DSM RMSE 1.1 cm over the measured cells of the work
area (median 0.0 cm, p95 2.3 cm), completeness 99.4 %, targets found in the orthophoto within 0.64 cm of
their truth (ortho cells of 7 cm)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio

from georef_core.dense.dsm_compare import compare_dsm
from georef_core.dense.dsm_raster import MASK_COARSE, MASK_FILLED, MASK_MEASURED, MASK_NODATA, NODATA


def test_dsm_against_truth(dense_run, dense_sim, work_area_bounds):
    out, summary, _ = dense_run
    c = compare_dsm(out / "dense" / "dsm.tif", dense_sim.out_dir / "truth" / "dsm.tif",
                    out / "dense" / "dsm_filled_mask.tif", bounds=work_area_bounds)
    m = c["measured"]
    assert m["n"] > 20000
    assert m["rmse_m"] < 0.03, c  # measured 0.011
    assert abs(m["median_m"]) < 0.01, c  # measured -0.0001
    assert m["p95_abs_m"] < 0.06, c  # measured 0.023
    assert c["all"]["rmse_m"] < 0.035, c  # filled cells included
    assert c["completeness"] > 0.95, c  # measured 0.994
    # the internal precision estimate written for the volume uncertainty is of the right size
    est = summary["dsm_vertical_rmse_m"]
    assert 0.5 * m["rmse_m"] < est < 3.0 * m["rmse_m"], (est, m["rmse_m"])  # measured 1.3-1.4 x
    # the reach of the matching window (+ one cell) that volume outlines sample beyond
    r = summary["dsm_smoothing_radius_m"]
    assert summary["dsm_resolution_m"] < r < 0.5 * 7 * summary["matching_gsd_m"] + 2 * summary["dsm_resolution_m"], r


def test_dsm_cells_are_robust_medians(dense_run, dense_sim):
    """Over the whole DSM (edges of the coverage included) gross errors are rare."""
    out, _, _ = dense_run
    c = compare_dsm(out / "dense" / "dsm.tif", dense_sim.out_dir / "truth" / "dsm.tif",
                    out / "dense" / "dsm_filled_mask.tif")
    d = c["measured"]
    assert d["n"] > 40000
    assert d["p95_abs_m"] < 0.08, c
    assert d["rmse_m"] < 0.05, c


def test_orthophoto_places_targets(dense_run, dense_sim):
    from georef_core.dense.ortho_check import read_targets, target_offsets

    out, summary, _ = dense_run
    with rasterio.open(out / "dense" / "ortho.tif") as ds:
        assert ds.count == 4 and ds.crs.to_epsg() == 32653
        res = ds.transform.a
    assert res == pytest.approx(summary["ortho"]["resolution_m"])
    targets = read_targets(dense_sim.out_dir / "truth" / "targets.csv")
    assert len(targets) >= 5
    for t in target_offsets(out / "dense" / "ortho.tif", targets):
        assert t.pattern_ok, t
        assert t.offset_m < 0.35 * res, (t, res)  # measured <= 0.64 cm, res 7 cm
    # a shifted orthophoto is caught
    shifted = [dict(t, easting_m=str(float(t["easting_m"]) + 2 * res)) for t in targets]
    found = target_offsets(out / "dense" / "ortho.tif", shifted)
    assert all(not t.pattern_ok or t.offset_m > res for t in found)


def test_point_cloud_file(dense_run, dense_sim):
    from georef_core.dense.point_cloud_io import read_point_cloud

    out, summary, _ = dense_run
    xyz, rgb, crs, las = read_point_cloud(out / "dense" / "points.laz")
    assert len(xyz) == summary["points"]["written"] > 100000
    assert crs is not None and crs.to_2d().to_epsg() == 32653
    assert len(crs.axis_info) == 3 and "ellipsoidal" in crs.axis_info[2].name.lower()
    assert las.header.version.minor == 4 and las.header.point_format.id == 7
    assert np.all(las.user_data >= 2)  # every point agreed in at least 2 views (2: the edge sweep)
    assert np.mean(las.user_data >= 3) > 0.8  # most in 3 or more
    assert rgb.std() > 10  # coloured, not constant
    # points lie on the true surface
    with rasterio.open(dense_sim.out_dir / "truth" / "dsm.tif") as ts:
        sel = xyz[:: max(1, len(xyz) // 20000)]
        T = ts.transform
        cols = np.floor((sel[:, 0] - T.c) / T.a).astype(int)
        rows = np.floor((sel[:, 1] - T.f) / T.e).astype(int)
        ok = (rows >= 0) & (rows < ts.height) & (cols >= 0) & (cols < ts.width)
        truth = ts.read(1)[rows[ok], cols[ok]]
    dz = sel[ok, 2] - truth
    assert ok.sum() > 5000
    assert abs(np.median(dz)) < 0.01 and np.percentile(np.abs(dz), 95) < 0.10


def test_raster_files_are_cogs(dense_run):
    out, summary, _ = dense_run
    d = out / "dense"
    with rasterio.open(d / "dsm.tif") as ds:
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ds.dtypes[0] == "float32" and ds.nodata == NODATA and ds.crs.to_epsg() == 32653
        assert ds.block_shapes[0] == (512, 512)
        assert bool(ds.overviews(1)) == (max(ds.width, ds.height) > 512)  # GDAL's COG: overviews above one tile
        assert "ellipsoidal" in ds.tags()["HEIGHTS"]
        assert ds.transform.a == pytest.approx(summary["dsm_resolution_m"])
        dsm = ds.read(1)
        dsm_transform = ds.transform
    with rasterio.open(d / "dsm_filled_mask.tif") as ms:
        assert ms.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ms.transform == dsm_transform
        mask = ms.read(1)
    assert set(np.unique(mask)) <= {MASK_MEASURED, MASK_FILLED, MASK_COARSE, MASK_NODATA}
    with rasterio.open(d / "dsm_support.tif") as ss:
        assert ss.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG" and ss.transform == dsm_transform
        support = ss.read(1)
    assert np.all((support == 255) == (mask == MASK_NODATA)) and np.all((support == 0) == (mask == MASK_FILLED))
    # band 2: why (dsm_support.CAUSE_*): measured, coarse, interpolated or empty - seen by 2+ images or not
    from georef_core.dense import dsm_support as S

    with rasterio.open(d / "dsm_support.tif") as ss:
        causes = ss.read(2)
    assert np.all((causes == S.CAUSE_MEASURED) == (mask == MASK_MEASURED))
    assert np.all(np.isin(causes[mask == MASK_FILLED], [S.CAUSE_FILLED_SEEN, S.CAUSE_FILLED_UNSEEN]))
    assert np.all(np.isin(causes[mask == MASK_NODATA], [S.CAUSE_EMPTY_SEEN, S.CAUSE_EMPTY_UNSEEN]))
    by = summary["dsm"]["cells_by_cause"]
    print("cells by cause:", by)
    assert by == S.cause_counts(causes) and sum(by.values()) == causes.size
    # the block's interior is seen by many images: its holes are "seen, no consistent depth"; the grid's corners
    # beyond every footprint are "unseen"
    assert by["interpolated_seen"] > by["interpolated_unseen"] and by["no_data_unseen"] > 0
    assert np.all(support[mask == MASK_MEASURED] >= 2)
    assert np.all((dsm == NODATA) == (mask == MASK_NODATA))
    filled = np.count_nonzero(mask == MASK_FILLED)
    measured = np.count_nonzero(mask == MASK_MEASURED)
    assert summary["dsm"]["filled_cells"] == filled and summary["dsm"]["measured_cells"] == measured
    assert 0 < filled / (filled + measured) < 0.1
    with rasterio.open(d / "ortho.tif") as os_:
        assert os_.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG" and os_.overviews(1)
        assert os_.colorinterp[3] == rasterio.enums.ColorInterp.alpha


def test_summary_and_progress(dense_run):
    out, summary, calls = dense_run
    s = json.loads((out / "dense" / "dense_summary.json").read_text())
    assert s["n_images"] == 12 and s["pairs"]["count"] >= 24 and not s["pairs"]["images_without_partner"]
    assert s["gsd_m"] == pytest.approx(0.0714, abs=0.003)  # 40 m / 560 px
    assert s["dsm_resolution_m"] == pytest.approx(2 * s["gsd_m"], rel=0.05)
    for k in ("sparse_prior", "depth_maps", "fusion", "dsm", "orthophoto", "las", "total"):
        assert s["timings_s"][k] >= 0
    stages = {c[0] for c in calls}
    assert {"depth maps", "fusion", "dsm", "orthophoto", "point cloud", "done"} <= stages
    depth = [c for c in calls if c[0] == "depth maps"]
    assert depth[-1] == ("depth maps", 12, 12) and [c[1] for c in depth] == sorted(c[1] for c in depth)
