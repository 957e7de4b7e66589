"""The dense step in tiles (steps/dense_tiles.py, contract.Split): a 2-tile run of the small simulated
survey against the one-run DSM (conftest dense_run) - the same cells within a stated tolerance, no step
along the tile borders, the targets found at their place in the merged orthophoto, each image's depth map
computed once (the depth parts, then the tiles fusing them) - and the split run through the worker's own
functions (worker/pipeline.py plan_parts / run_part / merge_parts) in-process."""

from __future__ import annotations

import json
import shutil

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
    given = {}   # per reader (a part's index, "merge"): the parts' files the platform gives it, and all of them
    try:
        for p in parts:
            if p.get("after"):   # as on the platform: a folder of its own with only the earlier files it reads
                folder = _platform_folder(out, tmp_path_factory.mktemp(f"part{p['index']}"), p, given)
                pipeline.run_part("dense", dense_sim.out_dir, folder, options, p, lambda s, d, t: calls.append(s),
                                  run)
                shutil.copytree(folder / "dense" / "parts" / f"{p['index']:04d}",
                                out / "dense" / "parts" / f"{p['index']:04d}", dirs_exist_ok=True)
            else:
                pipeline.run_part("dense", dense_sim.out_dir, out, options, p, lambda s, d, t: calls.append(s), run)
    finally:
        depth_pass.pair_depth_map = real
    # the block's orthophoto radiometry (the radiometry part's file; the merge removes the parts' folders)
    rad = [p for p in parts if p["phase"] == "radiometry"]
    block_rad = (json.loads((out / "dense" / "parts" / f"{rad[0]['index']:04d}" / "radiometry.json").read_text())
                 if rad else None)
    # the merge, too, in a folder with only the parts' files it declared it reads (specs: Split.merge_reads)
    out = _platform_folder(out, tmp_path_factory.mktemp("merge"), None, given)
    summary = pipeline.merge_parts("dense", dense_sim.out_dir, out, options, parts, lambda *a: None, run)
    summary["_block_radiometry"] = block_rad
    summary["_given"] = given
    print("tiles:", [(t["images"], t["seconds"]) for t in summary["tiles"]["per_tile"]],
          "depth parts:", summary["tiles"]["per_depth_part"])
    return out, summary, parts, calls, matched


def _platform_folder(src, dest, part, given):
    """A copy of the run folder ``src`` as the worker materialises it for ``part`` (None: the merge): the other
    files, and of the parts' files those worker.tasks._own_file_wanted gives it (the descriptor's "after" and
    "reads", the Split's merge_reads); what it was given is counted in ``given``."""
    from georef_core.steps.contract import part_after
    from worker import tasks

    run = {"own_files": True, "part_reads": part_after(part) if part else [],
           "part_read_patterns": part.get("reads") if part else None}
    n_all = n_given = 0
    names = []
    for f in sorted(src.rglob("*")):
        rel = f.relative_to(src).as_posix()
        if not f.is_file():
            continue
        if rel.startswith("dense/parts/"):
            n_all += f.stat().st_size
            if not tasks._own_file_wanted(rel, "dense", None if part is None else part["index"], run):
                continue
            n_given += f.stat().st_size
            names.append(rel)
        (dest / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(f, dest / rel)
    given["merge" if part is None else part["index"]] = (n_given, n_all, names)
    return dest


def _read(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(), ds.transform


def test_each_depth_map_is_computed_once(tiled_run, dense_run):
    """Phase 1 matches each image's pairs once for the block (the one run's pairs); the tiles only fuse."""
    out, summary, parts, calls, matched = tiled_run
    depth = [p for p in parts if p["phase"] == "depth"]
    fuse = [p for p in parts if p["phase"] == "fuse"]
    rad = [p for p in parts if p["phase"] == "radiometry"]
    assert len(fuse) == 2 and len(depth) >= 1 and [p["phase"] for p in parts] == (["depth"] * len(depth) +
                                                                                  ["radiometry"] + ["fuse"] * 2)
    assert rad[0]["after"] == [d["index"] for d in depth]
    assert all(set(p["after"]) <= {d["index"] for d in depth} | {rad[0]["index"]} and rad[0]["index"] in p["after"]
               for p in fuse)
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
    print("orthophoto radiometry:", summary["ortho"]["radiometry"], summary["ortho"].get("block_radiometry"))
    res_o = summary["ortho"]["resolution_m"]
    assert max(o.offset_m for o in found) < 2.0 * res_o + 0.01   # at their place: within 2 ortho cells + 1 cm
    by = summary["dsm"]["cells_by_cause"]        # the support raster's band 2, merged from the tiles' cores
    assert by["measured"] == summary["dsm"]["measured_cells"] and by["interpolated_seen"] > 0
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


def test_block_radiometry_is_solved_once_for_every_tile(tiled_run, dense_sim):
    """The orthophoto's gains and vignetting are solved once for the block (the radiometry part, from the depth
    parts' observations) and every tile mosaics with them: the simulator's own per-image gains (3 % jitter) and
    vignetting (12 % at the corners) recovered against truth/radiometry.json, and nothing left for the merge to
    harmonise (no tile estimated gains of its own)."""
    from georef_core.dense.block_radiometry import model_for_views

    out, summary, parts = tiled_run[:3]
    block = summary["_block_radiometry"]
    assert block is not None and block["solved"], block
    truth = json.loads((dense_sim.out_dir / "truth" / "radiometry.json").read_text())
    names = sorted(block["images"])
    assert set(names) == set(truth["gains"])
    est = np.array([np.mean(block["images"][n][:3]) for n in names])
    true = np.log([truth["gains"][n] for n in names])
    true -= true.mean()                              # the block's gauge: mean log gain 0
    err = 100 * (est - true)
    print(f"block gains - truth: RMS {np.sqrt(np.mean(err ** 2)):.2f} %, max {np.abs(err).max():.2f} % "
          f"(truth spread {100 * true.std():.2f} %); {block['observations']} observations, {block['seconds']} s")
    assert np.abs(err).max() < 1.0 and np.sqrt(np.mean(err ** 2)) < 0.5

    class _V:   # the model for views by name (the tiles' path)
        def __init__(self, name):
            self.name = name

    model = model_for_views(block, [_V(n) for n in names])
    rho = np.array([0.5, 0.8, 1.0])
    a = truth["vignetting"]["a"]
    true_v = 1 - a * rho ** 2                         # the simulator's (4:3 images, no cos^4 term here)
    got = model.vignetting(int(model.camera_of_view[0]), rho).mean(axis=1)
    print("vignetting at rho 0.5, 0.8, 1:", np.round(got, 4), "truth", np.round(true_v, 4))
    assert np.all(np.abs(got - true_v) < 0.02)
    o = summary["ortho"]
    assert o["radiometry"].startswith("the block's") and o["block_radiometry"]["observations"] > 1000
    assert o["tile_harmonisation"]["shared_images"] == 0      # the tiles published no gains of their own


def test_readers_get_only_the_part_files_they_read(tiled_run):
    """On the platform a reader of parts' files is given only those it declared (the merge: the Split's
    merge_reads; a second-phase part: its descriptor's "reads"): the fixture ran every such reader in a folder
    holding only those, so its success shows they suffice; here, that the depth maps stayed out of the merge, that
    the radiometry part got the fine maps only, and that a tile got only its own images' maps."""
    from georef_core.steps.contract import get_spec

    out, summary, parts = tiled_run[:3]
    given = summary["_given"]
    assert "depth_summary.json" in get_spec("dense").split.merge_reads
    print({k: f"{g / 1e6:.2f} of {a / 1e6:.2f} MB" for k, (g, a, _) in given.items()})
    maps = [n for n in given["merge"][2] if "/depth/" in n]
    assert not maps and any(n.endswith("core_rasters.npz") for n in given["merge"][2])   # no depth map sent
    rad = next(p for p in parts if p["phase"] == "radiometry")
    # the radiometry part: the fine maps only (its occlusion test), never the coarse ones
    rad_maps = {n.rsplit("/", 1)[-1] for n in given[rad["index"]][2] if "/depth/" in n}
    assert rad_maps == {f"{stem}.npy" for _, stem in rad["depth"].values()}
    assert sum(n.endswith("radiometry_obs.npz") for n in given[rad["index"]][2]) == len(rad["after"])
    for p in parts:
        if p["phase"] == "fuse":   # a tile: its images' and their neighbours' maps, the block's radiometry
            got = {n.rsplit("/", 1)[-1] for n in given[p["index"]][2] if "/depth/" in n}
            assert got == {f"{stem}{s}" for _, stem in p["depth"].values() for s in (".npy", ".coarse.npy")} & got
            assert any(n.endswith("radiometry.json") for n in given[p["index"]][2])
            assert not [n for n in given[p["index"]][2] if "core_" in n or "radiometry_obs" in n]
