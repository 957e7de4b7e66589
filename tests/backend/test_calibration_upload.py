"""A site calibration uploaded to a survey (backend/services/file_kinds.recognise, uploads._place): the JSON
`georef datum calibrate` writes and a CSV of control pairs are recognised by content as "site-calibration" (not
as survey.json or the ground points, which they would otherwise replace) and placed in calibration/, where the
datum step reads them (tests/datums/test_calibration_step.py); a damaged one is refused with the core's reason."""

from __future__ import annotations

import pytest

from backend.services.file_kinds import UnrecognisedFile, recognise
from backend.services.uploads import _place
from georef_core.datums.site_calibration import ControlPair, solve_calibration

PAIRS = ("name,easting_m,northing_m,height_m,local_e_m,local_n_m,local_h_m\n"
         "K1,448005,5412008,150.1,1005.2,2007.9,102.85\nK2,448096,5412004,151.9,1096.1,2004.6,104.62\n"
         "K3,448093,5412097,151.0,1092.6,2097.5,103.79\nK4,448003,5412092,149.2,1002.7,2091.9,101.96\n")


def test_calibration_files_recognised_and_placed(tmp_path):
    pairs = [ControlPair(f"K{i}", (448000.0 + x, 5412000.0 + y, 150.0), (1000.0 + x, 2000.0 + y, 102.7 + 0.001 * x), "hv")
             for i, (x, y) in enumerate([(5, 8), (96, 4), (93, 97), (3, 92)], start=1)]
    cal = solve_calibration(pairs, crs="EPSG:32631", height_datum="ellipsoidal", name="North grid")
    js = cal.write(tmp_path / "anything.json")
    r = recognise(js)
    assert r.kind == "site-calibration" and r.meta == {"format": "json", "points": 4, "height_datum": "ellipsoidal",
                                                        "crs": "EPSG:32631"}
    csv = tmp_path / "pairs.txt"
    csv.write_text(PAIRS)
    r = recognise(csv)
    assert r.kind == "site-calibration" and r.meta == {"format": "csv", "points": 4}
    assert _place("site-calibration", "my pairs.CSV", None, None) == ("calibration/pairs.csv", None)
    assert _place("site-calibration", "cal.json", None, None) == ("calibration/site_calibration.json", None)
    # a points table without the local columns stays ground points; a survey.json stays one
    pts = tmp_path / "points.csv"
    pts.write_text("name,easting_m,northing_m,height_m,role\nG1,448005,5412008,150.1,control\n")
    assert recognise(pts).kind == "points"
    sj = tmp_path / "survey.json"
    sj.write_text('{"project_crs": "EPSG:32631"}')
    assert recognise(sj).kind == "survey-metadata"


def test_damaged_calibrations_refused_with_the_reason(tmp_path):
    bad = tmp_path / "pairs.csv"
    bad.write_text(PAIRS.replace("K3,448093,5412097,151.0", "K3,448093,north,151.0"))
    with pytest.raises(UnrecognisedFile, match=r"site calibration: row .*K3.*not a number \(line 4\)"):
        recognise(bad)
    bad.write_text(PAIRS.replace(",local_h_m", ",h_local"))
    with pytest.raises(UnrecognisedFile, match=r"site calibration: needs the columns .*missing: local_h_m"):
        recognise(bad)
    js = tmp_path / "cal.json"
    js.write_text('{"format": "georef-site-calibration", "version": 2}')
    with pytest.raises(UnrecognisedFile, match=r"site calibration: calibration version 2"):
        recognise(js)
