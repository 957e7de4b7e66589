"""The dense step in tiles (steps/dense_tiles.py, contract.Split): a 2-tile run of the small simulated
survey against the one-run DSM (conftest dense_run) - the same cells within a stated tolerance, no step
along the tile borders, the targets found at their place in the merged orthophoto, each image's depth map
computed once (the depth parts, then the tiles fusing them) - and the split run through the worker's own
functions (worker/pipeline.py plan_parts / run_part / merge_parts) in-process."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def tiled_run(dense_sim, dense_run, tmp_path_factory):
    """The dense step through the worker's plan / part / merge functions, 2 tiles, on the one run's cells."""
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from worker import pipeline

    out = tmp_path_factory.mktemp("dense_tiled")
    oriented_images_from_simulator_truth(dense_sim.out_dir).write(out / "oriented_images.json")
    one = dense_run[1]
    options = {"tiles": 2, "tile_margin": 0.0, "workers": 2, "resolution_m": one["dsm_resolution_m"],
               "ortho_resolution_m": one["ortho"]["resolution_m"]}
    run = {"site": {"crs": "EPSG:32631"}, "id": 0}
    calls = []
    parts = pipeline.plan_parts("dense", dense_sim.out_dir, out, options, run)
    parts = [dict(p, index=k) for k, p in enumerate(parts)]
    matched = []   # every stereo pair matched, by reference image, in whichever part
    from georef_core.dense import depth_pass

    real = depth_pass.pair_depth_map

    def counting(view, *a, **kw):
        matched.append((view.name, view.width))
        return real(view, *a, **kw)

    depth_pass.pair_depth_map = counting
    try:
        for p in parts:
            pipeline.run_part("dense", dense_sim.out_dir, out, options, p, lambda s, d, t: calls.append(s), run)
    finally:
        depth_pass.pair_depth_map = real
    summary = pipeline.merge_parts("dense", dense_sim.out_dir, out, options, parts, lambda *a: None, run)
    print("tiles:", [(t["images"], t["seconds"]) for t in summary["tiles"]["per_tile"]],
          "depth parts:", summary["tiles"]["per_depth_part"])
    return out, summary, parts, calls, matched


def _read(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(), ds.transform


def test_each_depth_map_is_computed_once(tiled_run, dense_run):
    """Phase 1 matches each image's pairs once for the block (the one run's pairs); the tiles only fuse."""
    out, summary, parts, calls, matched = tiled_run
    depth = [p for p in parts if p["phase"] == "depth"]
    fuse = [p for p in parts if p["phase"] == "fuse"]
    assert len(fuse) == 2 and len(depth) >= 1 and [p["phase"] for p in parts] == ["depth"] * len(depth) + ["fuse"] * 2
    assert all(set(p["after"]) <= {d["index"] for d in depth} and p["after"] for p in fuse)
    one = dense_run[1]
    n_matched = one["n_images"] - len(one["pairs"]["images_without_partner"])
    # counted as it ran: every pair matched once (as many as the one run's), at full and at coarse size
    full = max(w for _, w in matched)
    fine = [n for n, w in matched if w == full]
    coarse = [n for n, w in matched if w < full]
    assert len(fine) == one["pairs"]["count"] == summary["pairs"]["count"]
    assert len(coarse) == (len(fine) if one["coarse_pass"] else 0)
    assert len(set(fine)) == n_matched and summary["tiles"]["depth_maps_computed"] == n_matched
    assert summary["tiles"]["depth_maps_computed_twice"] == []
    # the images near the cut are fused in both tiles (their points cut at the core), not matched again
    assert summary["tiles"]["images_processed"] > n_matched
    assert any(c.startswith("tile 2/2: fusion") for c in calls) and not any(c.startswith("tile") and "depth maps" in c
                                                                            for c in calls)


def test_tiles_agree_with_one_run(tiled_run, dense_run):
    out, summary, parts, calls, _ = tiled_run
    assert summary["tiles"]["count"] == 2 and summary["tiles"]["shape"] == [2, 1] and summary["parts"] == len(parts)
    assert any(c.startswith("tile 2/2: fusion") for c in calls)       # progress per tile
    assert json.loads((out / "dense" / "dense_summary.json").read_text())["tiles"]["count"] == 2
    assert not (out / "dense" / "parts").exists()
    (d1,), t1 = _read(dense_run[0] / "dense" / "dsm.tif")
    (m1,), _ = _read(dense_run[0] / "dense" / "dsm_filled_mask.tif")
    (d4,), t4 = _read(out / "dense" / "dsm.tif")
    (m4,), _ = _read(out / "dense" / "dsm_filled_mask.tif")
    res = t1.a
    assert abs(t4.a - res) < 1e-12
    # the one run's grid inside the tiled run's (both on multiples of the cell)
    c0, r0 = int(round((t1.c - t4.c) / res)), int(round((t4.f - t1.f) / res))
    assert c0 >= 0 and r0 >= 0 and r0 + d1.shape[0] <= d4.shape[0] and c0 + d1.shape[1] <= d4.shape[1]
    d4w = d4[r0:r0 + d1.shape[0], c0:c0 + d1.shape[1]]
    m4w = m4[r0:r0 + d1.shape[0], c0:c0 + d1.shape[1]]
    both = (m1 == 0) & (m4w == 0)
    assert both.sum() > 0.8 * (m1 == 0).sum()          # the tiles measure (nearly) every cell the one run does
    dz = (d4w - d1)[both]
    print(f"tiled - one run, measured cells ({both.sum()}): median {1000 * np.median(dz):.2f} mm, "
          f"p99 |dz| {1000 * np.percentile(np.abs(dz), 99):.1f} mm")
    assert abs(np.median(dz)) < 0.002                  # no offset: the same surface, within 2 mm
    assert np.percentile(np.abs(dz), 99) < 0.05        # and cell by cell within 5 cm (99 %)
    # no step along the tile borders: the tiled DSM's jumps across a border cut like those elsewhere
    cut_e = next(p for p in parts if p["phase"] == "fuse")["core"][2]
    col = int(round((cut_e - t4.c) / res))
    ok = (m4[:, col - 1] == 0) & (m4[:, col] == 0)
    across = np.abs(d4[ok, col] - d4[ok, col - 1])
    ref_ok = (m4[:, col - 6] == 0) & (m4[:, col - 5] == 0)
    elsewhere = np.abs(d4[ref_ok, col - 5] - d4[ref_ok, col - 6])
    print(f"cell-to-cell |dz| across the E cut: median {1000 * np.median(across):.2f} mm, 5 cells west "
          f"{1000 * np.median(elsewhere):.2f} mm")
    assert ok.sum() > 20 and np.median(across) < 2.0 * np.median(elsewhere) + 0.005


def test_tiled_orthophoto_and_points(tiled_run, dense_sim, dense_run):
    import laspy

    from georef_core.dense.ortho_check import read_targets, target_offsets

    out, summary = tiled_run[:2]
    offs = target_offsets(out / "dense" / "ortho.tif", read_targets(dense_sim.out_dir / "truth" / "targets.csv"))
    found = [o for o in offs if o.pattern_ok]
    assert len(found) >= len(offs) - 1 and len(found) >= 3
    h = summary["ortho"]["tile_harmonisation"]       # the two tiles' gains put on one gauge
    print("orthophoto gains across the tiles:", h)
    assert h["shared_images"] > 0 and h["tiles_linked"] == 2
    assert h["residual_rms_percent"] <= h["residual_rms_percent_before"]
    res_o = summary["ortho"]["resolution_m"]
    assert max(o.offset_m for o in found) < 2.0 * res_o + 0.01   # at their place: within 2 ortho cells + 1 cm
    with laspy.open(out / "dense" / "points.laz") as f:
        n = f.header.point_count
    assert n == summary["points"]["written"]
    one = dense_run[1]["points"]["written"]
    assert 0.7 * one < n < 1.5 * one                    # the cores hold each point once (no duplicated margins)


def test_tile_gains_are_harmonised_on_shared_images():
    """Each tile's gains have their own gauge (mean 0 over its images): the merge's factors undo the tiles'
    offsets, recovered from the images they share (known offsets; one badly estimated image with few
    observations barely weighs), and leave a lone tile alone."""
    from georef_core.steps.dense_tiles import _scale_colours, harmonise_tile_gains

    rng = np.random.default_rng(3)
    true = {f"im{k}": rng.normal(0.0, 0.1, 3) for k in range(12)}
    offsets = np.array([[0.06, 0.02, -0.01], [-0.01, 0.03, 0.02], [-0.05, -0.05, -0.01]])
    members = [range(0, 6), range(4, 10), range(8, 12)]
    tiles = [{f"im{k}": [*(true[f"im{k}"] + offsets[t]), 5000] for k in m} for t, m in enumerate(members)]
    tiles[0]["edge"], tiles[1]["edge"] = [0.3, 0.3, 0.3, 50], [-0.3, -0.3, -0.3, 60]   # seen at the tiles' rims
    tiles.append({"other": [0.2, 0.2, 0.2]})       # shares nothing
    factors, info = harmonise_tile_gains(tiles)
    assert info["shared_images"] == 5 and info["tiles_linked"] == 3
    assert np.allclose(np.log(factors[:3]), offsets, atol=0.003)
    assert np.allclose(factors[3], 1.0) and info["residual_rms_percent"] < info["residual_rms_percent_before"]
    rgba = np.zeros((4, 2, 2), np.uint8)
    rgba[:3] = 100
    rgba[3, 0] = 255                               # the second row: no data, left as it is
    out = _scale_colours(rgba, factors[0])
    assert out[0, 0, 0] == round(100 * np.exp(0.06)) and out[0, 1, 0] == 100 and out[3].tolist() == rgba[3].tolist()
