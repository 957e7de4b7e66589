"""design-progress's change between surveys (services/designs.add_changes) on two simulated surveys of the valley
scene (tests/design/scenes.py) compared with the LandXML design by the design step's own code: cut removed and
fill placed since the first survey against the analytic cone volumes, what remains, the share done, and the
design's own error cancelling in the change's sigma. No platform needed (the service's arithmetic on the
entries design_progress builds from the steps' summaries; the platform path: tests/backend/test_site_design.py).
"""

from __future__ import annotations

import math
from datetime import datetime, timezone

import pytest

from backend.services.designs import PROGRESS_KEYS, add_changes
from georef_core.steps.design import run_design, summary_of
from tests.design import scenes
from tests.volumes.synthetic import cone_volume

LATER_BUMP = {**scenes.BUMP, "h": 0.4}     # the cone cut down from 1 m to 0.4 m
LATER_PIT = {**scenes.PIT, "h": 0.3}       # the pit filled from 0.8 m deep to 0.3 m


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("progress-change")
    return {"design": scenes.write_design_landxml(d / "fg.xml"), "may": scenes.write_scene(d / "may"),
            "june": scenes.write_scene(d / "june", bump=LATER_BUMP, pit=LATER_PIT)}


_DONE: dict = {}


def _entries(scene, tmp, design_sigma_m: float) -> list[dict]:
    if design_sigma_m in _DONE:   # each design computed once per module
        return [dict(e) for e in _DONE[design_sigma_m]]
    out = []
    for name, flown in (("may", datetime(2026, 5, 4, 9, tzinfo=timezone.utc)),
                        ("june", datetime(2026, 6, 8, 9, tzinfo=timezone.utc))):
        doc = run_design(scene[name]["dsm"], scene["design"], scene[name]["polygon"], None,
                         {"tolerance_m": 0.05, "dsm_sigma_m": 0.02, "vertical_rmse_m": 0.02,
                          "design_sigma_m": design_sigma_m}, site_crs=f"EPSG:{scenes.EPSG}")
        s = summary_of(doc)
        s["surface"] = "dsm"
        # what design_progress keeps of each summary
        e = {"survey_id": f"sv-{name}", "survey_name": name, "flown_at": flown}
        e.update({k: s.get(k) for k in PROGRESS_KEYS})
        e.update(sigma_m3=s["sigma_m3"], design_sigma_m3=s["design_sigma_m3"], warnings=[])
        out.append(e)
    add_changes(out)
    _DONE[design_sigma_m] = out
    return [dict(e) for e in out]


def test_change_since_the_previous_survey_against_analytic_volumes(scene, tmp_path):
    may, june = _entries(scene, tmp_path, design_sigma_m=0.0)
    assert may["since_previous"] is None
    c = june["since_previous"]
    assert c["previous_survey_name"] == "may" and c["days"] == 35.0 and c["notes"] == []
    cut_moved = scenes.cut_volume() - cone_volume(LATER_BUMP["radius"], LATER_BUMP["h"])       # 37.70 - 15.08
    fill_placed = scenes.fill_volume() - cone_volume(LATER_PIT["radius"], LATER_PIT["h"])     # 20.94 - 7.85
    assert abs(c["cut_moved_m3"] - cut_moved) < 0.001 * cut_moved, (c["cut_moved_m3"], cut_moved)
    assert abs(c["fill_placed_m3"] - fill_placed) < 0.001 * fill_placed, (c["fill_placed_m3"], fill_placed)
    assert abs(c["net_change_m3"] - (fill_placed - cut_moved)) < 0.01
    assert abs(c["remaining_cut_m3"] - cone_volume(6.0, 0.4)) < 0.001 * cone_volume(6.0, 0.4)
    assert abs(c["remaining_fill_m3"] - cone_volume(5.0, 0.3)) < 0.001 * cone_volume(5.0, 0.3)
    assert abs(c["done_share"]["cut_m3"] - cut_moved / scenes.cut_volume()) < 0.002
    assert abs(c["done_share"]["fill_m3"] - fill_placed / scenes.fill_volume()) < 0.002
    # without a design error the two surveys' errors are independent: sigmas in quadrature
    for k, src in (("cut_moved_m3", "cut_m3"), ("fill_placed_m3", "fill_m3"), ("net_change_m3", "net_m3")):
        want = math.hypot(may["sigma_m3"][src], june["sigma_m3"][src])
        assert 0 < c["sigma_m3"][k] and abs(c["sigma_m3"][k] - want) < 1e-9


def test_the_designs_own_error_cancels_in_the_change(scene, tmp_path):
    exact = _entries(scene, tmp_path, design_sigma_m=0.0)[1]["since_previous"]
    may, june = _entries(scene, tmp_path, design_sigma_m=0.03)
    c = june["since_previous"]
    # each survey's net is much less certain with a 3 cm design error (3 cm x 889 m2 = 26.7 m3) ...
    assert may["sigma_m3"]["net_m3"] > 20 and may["design_sigma_m3"]["net_m3"] > 20
    # ... but the change between them is not: the same design under both surveys
    assert abs(c["sigma_m3"]["net_change_m3"] - exact["sigma_m3"]["net_change_m3"]) < 2e-3
    naive2 = may["sigma_m3"]["net_m3"] ** 2 + june["sigma_m3"]["net_m3"] ** 2   # as if independent
    d = may["design_sigma_m3"]["net_m3"]
    assert june["design_sigma_m3"]["net_m3"] == d and abs(naive2 - c["sigma_m3"]["net_change_m3"] ** 2 - 2 * d * d) < 0.05
    assert c["cut_moved_m3"] == pytest.approx(exact["cut_moved_m3"], abs=1e-9)
