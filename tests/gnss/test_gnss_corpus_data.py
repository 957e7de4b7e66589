"""The real-data corpus of bench/data/gnss_corpus (docs/gnss.md "Real corpus"): every file is the one its
PROVENANCE.md records (sha256), and a transcription check finds no single-epoch outlier in it."""

from __future__ import annotations

import hashlib
import re
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CORPUS = REPO / "bench" / "data" / "gnss_corpus"
CASE_DIRS = sorted(p for p in CORPUS.iterdir() if (p / "PROVENANCE.md").exists()) if CORPUS.is_dir() else []


def _recorded_hashes(case_dir: Path) -> dict[str, str]:
    text = (case_dir / "PROVENANCE.md").read_text()
    return {m.group(1): m.group(2) for m in re.finditer(r"^- (\S+) ([0-9a-f]{64})$", text, re.MULTILINE)}


@pytest.mark.parametrize("case_dir", CASE_DIRS, ids=[p.name for p in CASE_DIRS])
def test_files_are_the_recorded_ones(case_dir):
    hashes = _recorded_hashes(case_dir)
    data_files = sorted(p.name for p in case_dir.iterdir() if p.name != "PROVENANCE.md")
    assert sorted(hashes) == data_files
    for name, digest in hashes.items():
        assert hashlib.sha256((case_dir / name).read_bytes()).hexdigest() == digest, name


def test_yamatogawa_transcription_check_is_clean(capsys):
    sys.path.insert(0, str(REPO / "bench"))
    from gnss_corpus_check import check

    d = CORPUS / "gogps_yamatogawa_walk"
    nav = [str(d / "yamatogawa_rover.nav")]
    assert check(str(d / "yamatogawa_rover.obs"), nav, 0.05, 15.0, 15.0) == 0
    assert check(str(d / "yamatogawa_master.obs"), nav, 0.05, 15.0, 15.0) == 0
    out = capsys.readouterr().out
    assert "203 epochs" in out and "193 epochs" in out
