"""Design progress between two surveys surface against surface (georef_core.design.surface_change), on the valley
scene (tests/design/scenes.py) with analytic volumes: the May survey has the cone (1 m, 37.70 m3 above the design)
and the pit (0.8 m deep); by June the cone was dug out and 0.2 m below the design over 3 m (over-excavation) and the
pit filled to 0.3 m deep. June is flown on a grid shifted by half a cell. A comparison of the two surveys' cut/fill
totals would say "cut removed 37.70, fill placed 11.20"; the earth moved is 39.58 removed and 13.09 placed."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from georef_core.design.surface_change import SurveyAccuracy, surface_change
from georef_core.steps.design import run_design
from tests.design import scenes
from tests.volumes.synthetic import cone_height, cone_volume, write_dsm

OVERCUT = dict(cx=scenes.BUMP["cx"], cy=scenes.BUMP["cy"], radius=3.0, h=0.2)   # below the design where the cone was
LATER_PIT = {**scenes.PIT, "h": 0.3}
OPTS = {"tolerance_m": 0.05, "dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02, "correlation_length_m": 1.0}


def _june(E, N):
    return (scenes.design_height(E, N) - cone_height(**OVERCUT)(E, N)
            - cone_height(LATER_PIT["cx"], LATER_PIT["cy"], LATER_PIT["radius"], LATER_PIT["h"])(E, N))


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    d = tmp_path_factory.mktemp("surface-change")
    design = scenes.write_design_landxml(d / "fg.xml")
    may = scenes.write_scene(d / "may")
    (d / "june").mkdir()
    half = scenes.RES / 2
    june_dsm = write_dsm(d / "june" / "dsm.tif", _june, (scenes.SIZE_M - scenes.RES, scenes.SIZE_M - scenes.RES),
                         scenes.RES, origin=(scenes.E0 + half, scenes.N0 + half))
    crs = f"EPSG:{scenes.EPSG}"
    docs = {}
    for name, dsm in (("may", may["dsm"]), ("june", june_dsm)):
        docs[name] = run_design(dsm, design, may["polygon"], d / name / "design", OPTS, site_crs=crs)
    area = json.loads(may["polygon"].read_text())["features"][0]["geometry"]
    acc = {n: SurveyAccuracy.from_cut_fill(docs[n]) for n in docs}
    ch = surface_change(d / "may" / "design" / "difference.tif", d / "june" / "design" / "difference.tif", area,
                        acc["may"], acc["june"])
    same = surface_change(d / "may" / "design" / "difference.tif", d / "may" / "design" / "difference.tif", area,
                          acc["may"], acc["may"])
    return {"change": ch, "same": same, "docs": docs}


def test_earth_moved_cell_by_cell_against_analytic_volumes(compared):
    ch, docs = compared["change"], compared["docs"]
    removed = cone_volume(scenes.BUMP["radius"], scenes.BUMP["h"]) + cone_volume(OVERCUT["radius"], OVERCUT["h"])
    placed = cone_volume(scenes.PIT["radius"], scenes.PIT["h"] - LATER_PIT["h"])
    assert ch["method"] == "surfaces" and ch["grid"]["earlier_resampled"] is True
    assert abs(ch["cut_moved_m3"] - removed) < 0.005 * removed, (ch["cut_moved_m3"], removed)
    assert abs(ch["fill_placed_m3"] - placed) < 0.005 * placed, (ch["fill_placed_m3"], placed)
    assert abs(ch["net_change_m3"] - (placed - removed)) < 0.005 * removed
    over = cone_volume(OVERCUT["radius"], OVERCUT["h"])
    assert abs(ch["cut_below_design_m3"] - over) < 0.02 * over and abs(ch["fill_above_design_m3"]) < 0.01
    assert abs(ch["area_m2"] - scenes.area_m2()) < 0.01 * scenes.area_m2()
    # the two totals' difference misses the over-excavation (counted as fill to place, not as cut removed)
    totals_cut = docs["may"]["cut_m3"] - docs["june"]["cut_m3"]
    totals_fill = docs["may"]["fill_m3"] - docs["june"]["fill_m3"]
    assert abs(totals_cut - removed) > 1.5 and abs(totals_fill - placed) > 1.5


def test_sigma_from_both_surveys_accuracy(compared):
    ch, same = compared["change"], compared["same"]
    A = ch["area_m2"]
    net = ch["uncertainty"]["net_change_m3"]["components_m3"]
    # each survey's vertical bias over the area, independent: 2 cm x A each
    assert net["vertical_bias_later_m3"] == pytest.approx(0.02 * A, rel=1e-3)
    assert net["vertical_bias_earlier_m3"] == pytest.approx(0.02 * A, rel=1e-3)
    assert net["dsm_noise_later_m3"] > 0 and net["dsm_noise_earlier_m3"] == pytest.approx(net["dsm_noise_later_m3"], rel=0.02)
    assert ch["sigma_m3"]["net_change_m3"] == pytest.approx(math.sqrt(sum(v * v for v in net.values())), abs=1e-3)
    # cut moved, the secant of a 2 cm bias: b for each cell that went down (the cone, 113 m2), b/2 for each unchanged
    # cell (a bias turns it into removed material under one sign), 0 where the pit was raised by more than b
    cut = ch["uncertainty"]["cut_moved_m3"]["components_m3"]
    cone_a, pit_a = math.pi * 6 ** 2, math.pi * 5 ** 2
    assert cut["vertical_bias_later_m3"] == pytest.approx(0.02 * cone_a + 0.01 * (A - cone_a - pit_a), rel=0.03)
    # a survey against itself: nothing moved, only the noise's inflation of the gross quantities
    assert same["cut_moved_m3"] == 0 and same["fill_placed_m3"] == 0 and same["grid"]["earlier_resampled"] is False
    assert same["one_survey_only_m2"] == 0


def test_missing_accuracy_is_a_clear_error():
    from georef_core.errors import ProcessingError

    with pytest.raises(ProcessingError, match="vertical_rmse_m"):
        SurveyAccuracy.from_cut_fill({"significance": {"dsm_sigma_m": 0.02}}, "run 3 design/cut_fill.json")
    assert np.isfinite(SurveyAccuracy.from_cut_fill({"significance": OPTS | {"correlation_length_m": 1}}).dsm_sigma_m)
