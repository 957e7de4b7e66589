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
from tests.design import change_mc, scenes
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
    return {"change": ch, "same": same, "docs": docs,
            "paths": {"may": d / "may" / "design" / "difference.tif", "june": d / "june" / "design" / "difference.tif",
                      "area": area, "acc": acc}}


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
    # the surveys' biases independent (common_bias_m = 0): their difference has sigma 2 cm x sqrt(2), over the area
    beta = 0.02 * math.sqrt(2)
    assert ch["accuracy"]["relative_bias_m"] == pytest.approx(beta, abs=1e-6) and ch["accuracy"]["common_bias_m"] == 0
    assert net["vertical_bias_m3"] == pytest.approx(beta * A, rel=1e-3)
    assert net["dsm_noise_later_m3"] > 0 and net["dsm_noise_earlier_m3"] == pytest.approx(net["dsm_noise_later_m3"], rel=0.02)
    assert ch["sigma_m3"]["net_change_m3"] == pytest.approx(math.sqrt(sum(v * v for v in net.values())), abs=1e-3)
    # cut moved, the secant of the relative bias: beta for each cell that went down (the cone, 113 m2), beta/2 for each
    # unchanged cell (a bias turns it into removed material under one sign), 0 where the pit was raised by more
    cut = ch["uncertainty"]["cut_moved_m3"]["components_m3"]
    cone_a, pit_a = math.pi * 6 ** 2, math.pi * 5 ** 2
    assert cut["vertical_bias_m3"] == pytest.approx(beta * cone_a + beta / 2 * (A - cone_a - pit_a), rel=0.03)
    # a survey against itself: nothing moved, only the noise's inflation of the gross quantities; no resampling
    assert same["cut_moved_m3"] == 0 and same["fill_placed_m3"] == 0 and same["grid"]["earlier_resampled"] is False
    assert same["one_survey_only_m2"] == 0
    assert same["uncertainty"]["net_change_m3"]["components_m3"]["resampling_m3"] == 0


def test_resampling_error_from_the_roughness_and_the_offset(compared):
    """June's grid is shifted by half a cell: bilinear interpolation errs where the earlier surface bends (the
    valley line, the cones' rims and apexes: 1/2 t(1-t) x its second difference, at most a few mm), so the term is
    small but present; on a plane it is zero (tests below)."""
    ch = compared["change"]
    net = ch["uncertainty"]["net_change_m3"]["components_m3"]
    assert 0 < net["resampling_m3"] < 0.05 * net["vertical_bias_m3"]
    assert 0 < ch["accuracy"]["resampling_mean_m"] < 0.002


def test_no_resampling_error_on_a_plane_and_more_on_a_rough_surface(tmp_path):
    acc = SurveyAccuracy(0.0, 0.02, 1.0)
    area = change_mc.area_geometry()

    def plane(E, N):
        return 0.03 * (E - scenes.E0) - 0.02 * (N - scenes.N0)

    def rough(E, N):   # 1 cm waves 0.4 m long: bilinear on 10 cm cells errs by ~1/8 x 0.1^2 x (2 pi / 0.4)^2 x 1 cm
        return plane(E, N) + 0.01 * np.sin(2 * np.pi * E / 0.4) * np.cos(2 * np.pi * N / 0.4)

    out = {}
    for name, fn in (("plane", plane), ("rough", rough)):
        a = change_mc.write_difference(tmp_path / f"{name}-a.tif", fn, (0.0, 0.0), None)
        b = change_mc.write_difference(tmp_path / f"{name}-b.tif", fn, (0.05, 0.05), None)
        out[name] = surface_change(a, b, area, acc, acc)
    assert out["plane"]["accuracy"]["resampling_mean_m"] < 1e-5
    assert abs(out["plane"]["net_change_m3"]) < 0.01
    # the stated error and the one made (the rough surface is the same under both: the net is the resampling error)
    r = out["rough"]
    assert 0.002 < r["accuracy"]["resampling_mean_m"] < 0.006
    assert abs(r["net_change_m3"]) < 3 * r["uncertainty"]["net_change_m3"]["components_m3"]["resampling_m3"]
    # random in sign, the resampling error inflates cut and fill like noise: the stated inflation counts it
    for k in ("cut_moved_m3", "fill_placed_m3"):
        assert abs(r[k] - r["noise_inflation_m3"]) < 3 * r["uncertainty"][k]["components_m3"]["resampling_m3"], r


def test_common_bias_cancels_in_the_change(compared, tmp_path):
    """b_i = c + u_i with var(c) = common^2: the change sees b_l - b_e, sigma sqrt(2 rmse^2 - 2 common^2); a common
    part larger than either survey's RMSE is clipped (the whole bias common: nothing of it left)."""
    d = compared["paths"]
    A = compared["change"]["area_m2"]
    half = surface_change(d["may"], d["june"], d["area"], d["acc"]["may"], d["acc"]["june"], common_bias_m=0.01)
    assert half["accuracy"]["relative_bias_m"] == pytest.approx(math.sqrt(2 * 0.02 ** 2 - 2 * 0.01 ** 2), abs=1e-6)
    assert half["uncertainty"]["net_change_m3"]["components_m3"]["vertical_bias_m3"] == pytest.approx(
        half["accuracy"]["relative_bias_m"] * A, rel=1e-3)
    whole = surface_change(d["may"], d["june"], d["area"], d["acc"]["may"], d["acc"]["june"], common_bias_m=0.5)
    assert whole["accuracy"]["common_bias_m"] == 0.02 and whole["accuracy"]["relative_bias_m"] == 0
    for k in ("cut_moved_m3", "fill_placed_m3", "net_change_m3"):
        assert whole["uncertainty"][k]["components_m3"]["vertical_bias_m3"] == 0
        assert whole[k] == compared["change"][k]   # the figures themselves do not depend on the model


def test_monte_carlo_coverage_with_noise_common_bias_and_grid_shift(tmp_path):
    """Seeded Monte Carlo (tests/design/change_mc.py: 2 cm noise over 1 m, a 1.5 cm common bias and a 1 cm own bias
    per survey, June on a random sub-cell shift). With the common part stated, (net - truth) / sigma has RMS about 1
    (chi-square bounds for 12 seeds: 0.55 - 1.45); treating the biases as independent overstates sigma by
    sqrt(2 x 1.8^2 / (2 x 1.0^2)) = 1.8 (RMS z about 0.55). bench/design_change_sigma_mc.py runs 200 seeds."""
    truth = change_mc.truth()["net_change_m3"]
    z_after, z_before = [], []
    for seed in range(12):
        r = change_mc.one_seed(seed, tmp_path / "s")
        out = surface_change(r["may"], r["june"], change_mc.area_geometry(), r["accuracy"], r["accuracy"],
                             common_bias_m=0.015)
        u = out["uncertainty"]["net_change_m3"]
        before = math.sqrt(u["sigma_m3"] ** 2 - u["components_m3"]["vertical_bias_m3"] ** 2
                           + (math.sqrt(2) * r["accuracy"].vertical_rmse_m * out["area_m2"]) ** 2)
        z_after.append((out["net_change_m3"] - truth) / u["sigma_m3"])
        z_before.append((out["net_change_m3"] - truth) / before)
    rms_after = math.sqrt(np.mean(np.square(z_after)))
    rms_before = math.sqrt(np.mean(np.square(z_before)))
    assert 0.55 < rms_after < 1.45, z_after
    assert rms_before < 0.75 * rms_after


def test_missing_accuracy_is_a_clear_error():
    from georef_core.errors import ProcessingError

    with pytest.raises(ProcessingError, match="vertical_rmse_m"):
        SurveyAccuracy.from_cut_fill({"significance": {"dsm_sigma_m": 0.02}}, "run 3 design/cut_fill.json")
    assert np.isfinite(SurveyAccuracy.from_cut_fill({"significance": OPTS | {"correlation_length_m": 1}}).dsm_sigma_m)
