"""The DTM step's ground classification under vegetation and machines, on seeded synthetic clouds with a known
bare earth (georef_core/sim/bare_earth_scene.py: undulating sloped terrain, a ridge stockpile, a cut batter,
trees and bushes with foliage gaps, machines, grass; the DSM gridded from the cloud as the dense step does).
Bands in metres and rates; the seeds here were not used to choose the rules (tuning seeds 1-4). Realistic
sizes and more seeds: bench/dtm_vegetation.py."""

from __future__ import annotations

import dataclasses

import pytest

from georef_core.sim.bare_earth_scene import BareEarthSceneOptions, build_bare_earth_scene, evaluate_ground_filter

SMALL = dataclasses.replace(BareEarthSceneOptions(), size_m=(44.0, 34.0), n_trees=3, n_bushes=6, points_per_m2=160.0)


@pytest.mark.parametrize("seed", [21, 22])
def test_vegetation_machines_removed_and_earthworks_kept(seed):
    r = evaluate_ground_filter(build_bare_earth_scene(seed, SMALL))
    assert r["objects"]["trees"] >= 2 and r["objects"]["bushes"] >= 4 and r["objects"]["machines"] >= 2
    e, t1, t2 = r["dtm_error"], r["type_i"], r["type_ii"]
    # open ground: the DTM is the DSM (3 cm noise, some grass)
    assert e["open"]["rmse_m"] <= 1.05 * r["dsm_error_open"]["rmse_m"] and e["open"]["rmse_m"] < 0.05
    # under objects: interpolated from the ground around (and seen through foliage gaps)
    assert e["under_trees"]["rmse_m"] < 0.12 and e["under_trees"]["max_abs_m"] < 0.6
    assert e["under_bushes"]["rmse_m"] < 0.20 and e["under_bushes"]["max_abs_m"] < 0.8
    assert e["under_machines"]["rmse_m"] < 0.12 and e["under_machines"]["max_abs_m"] < 0.6
    # type II: objects kept as ground
    assert t2["trees"]["rate"] < 0.01 and t2["machines"]["rate"] < 0.01
    assert t2["bushes_0.9m_up"]["cells"] == 0 or t2["bushes_0.9m_up"]["rate"] < 0.05
    assert r["points"]["objects_as_2"]["rate"] < 0.03
    # type I: the pile, its crest, the batter and its edges are ground
    for k in ("open", "pile", "batter", "pile_crest", "batter_edges"):
        assert t1[k]["cells"] > 50 and t1[k]["rate"] < 0.002, k
    assert r["points"]["ground_not_2"]["rate"] < 0.01
    # the pile and the batter: the DTM is the DSM there
    assert e["pile"]["rmse_m"] < 0.06 and e["batter"]["rmse_m"] < 0.06


def test_smooth_earthworks_without_objects_are_untouched():
    """A nearly noise-free DSM (5 mm) of bare earthworks: the sharp crest and batter edges are neither stepped
    nor rough: nothing is removed."""
    o = dataclasses.replace(SMALL, n_trees=0, n_bushes=0, machines=(), grass_patches=0, noise_m=0.005)
    r = evaluate_ground_filter(build_bare_earth_scene(23, o))
    assert r["type_i"]["all"]["cells"] > 50_000 and r["type_i"]["all"]["rate"] == 0.0
    assert r["dtm_error"]["pile"]["max_abs_m"] < 0.1 and r["dtm_error"]["batter"]["max_abs_m"] < 0.1
