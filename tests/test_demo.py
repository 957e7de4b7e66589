"""The README's run command (`georef demo`), on the small demo site."""

from __future__ import annotations

import re

from georef_core.cli.main import main


def test_demo_small_site_end_to_end(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--small"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"120 epochs, 9\d\.\d % fixed|120 epochs, 100\.0 % fixed", out), out
    m = re.search(r"camera triggers vs truth: 3D RMS ([\d.]+) mm, max ([\d.]+) mm", out)
    assert m, out
    assert float(m.group(1)) < 20.0 and float(m.group(2)) < 50.0
    assert (tmp_path / "site" / "ppk" / "trajectory.pos").exists()
    assert len(list((tmp_path / "site" / "images").glob("*.JPG"))) == 12
