"""The MRK's RTK quality against the photos' XMP (georef_core/photo/rtk_cross_check.py, docs/dji.md "MRK against
XMP"): on the seeded simulated DJI flight (seed 23, 30 photos) the two records agree; with one photo's XMP edited
(RtkFlag 50 -> 34, RtkStdHgt 1.5 -> 9 cm) that photo, and only it, is counted, listed and named in a warning."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from georef_core.photo.rtk_cross_check import _sigma_mismatch, rtk_quality_class
from georef_core.steps.survey_inputs import survey_inputs

from ..adjustment.test_dji_survey import _simulate
from ..once_per_session import once_per_session

pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def dji_survey(tmp_path_factory) -> Path:
    # the same seeded survey (and shared folder) as tests/adjustment/test_dji_survey.py
    return once_per_session(tmp_path_factory, "dji_survey_seed23",
                            lambda folder: _simulate(folder / "site", 1, seed=23, images=30))


def _copy(survey: Path, dest: Path, edited: str | None = None) -> Path:
    """The survey without raw log and base (photos alone), photos linked; ``edited``: the photo copied and its XMP
    changed to RtkFlag 34 and RtkStdHgt 0.09 m (same lengths: the XMP segment keeps its size)."""
    for src in survey.rglob("*"):
        rel = src.relative_to(survey)
        if src.is_dir() or src.name.endswith("_PPKRAW.bin") or rel.parts[0] == "base":
            continue
        dst = dest / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if src.name == edited:
            data = src.read_bytes()
            new = data.replace(b'drone-dji:RtkFlag="50"', b'drone-dji:RtkFlag="34"').replace(
                b'drone-dji:RtkStdHgt="0.01500"', b'drone-dji:RtkStdHgt="0.09000"')
            assert new != data and len(new) == len(data)
            dst.write_bytes(new)
        elif src.suffix.upper() == ".JPG":
            dst.symlink_to(src)
        else:
            shutil.copy2(src, dst)
    return dest


def test_mrk_and_xmp_agree_then_one_edited_photo_is_named(dji_survey, tmp_path):
    photos = sorted(p.name for p in dji_survey.rglob("DJI_*_V.JPG"))
    assert len(photos) == 30
    clean = survey_inputs(_copy(dji_survey, tmp_path / "clean"), tmp_path / "out_clean")
    cc = clean.summary()["rtk_cross_check"]
    assert (cc["checked"], cc["disagree"], cc["not_checked"]) == (30, 0, 0), cc
    assert not any("disagree" in w for w in clean.warnings)

    victim = photos[11]
    found = survey_inputs(_copy(dji_survey, tmp_path / "edited", edited=victim), tmp_path / "out_edited")
    cc = found.summary()["rtk_cross_check"]
    assert (cc["checked"], cc["agree"], cc["disagree"]) == (30, 29, 1), cc
    assert cc["images"] == [victim]
    row = cc["disagreements"][0]
    assert (row["mrk_quality"], row["xmp_rtk_flag"]) == (50, 34)
    assert row["xmp_sigma_neu_m"][2] == 0.09 and row["mrk_sigma_neu_m"][2] == 0.015
    assert len(row["why"]) == 2 and row["why"][0].startswith("quality") and "sigma up" in row["why"][1]
    warn = [w for w in found.warnings if "disagree" in w]
    assert len(warn) == 1 and victim in warn[0] and "1 of 30" in warn[0] and "photos' XMP positions" in warn[0]


def test_rule_classes_and_sigma_tolerance():
    assert [rtk_quality_class(q) for q in (50, 34, 40, 16, 0, -1, 60)] == \
        ["fixed", "float", "float", "single", "none", None, "code 60"]
    assert _sigma_mismatch([0.010, 0.010, 0.015], [0.0101, 0.0099, 0.0151]) == []          # printing precision
    assert _sigma_mismatch([0.010, 0.010, 0.015], [0.012, 0.010, 0.015]) == []             # factor 1.2
    assert len(_sigma_mismatch([0.010, 0.010, 0.015], [0.013, 0.010, 0.015])) == 1          # factor 1.3
    assert _sigma_mismatch([0.002, 0.001, 0.015], [0.004, 0.003, 0.015]) == []             # below the 5 mm floor
    assert _sigma_mismatch([np.nan, 0.01, 0.015], [0.5, 0.01, 0.015]) == []                # MRK without sigmas
