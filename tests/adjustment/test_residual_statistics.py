"""One definition of the check-point statistics (issue 24): the georef step writes them into residuals.json
(residual_table.residual_statistics: sample std with n - 1), and the API, the PDF report, run comparison,
the site summary and the browser show those numbers; none computes its own (the PDF used the population std,
so the PDF and the UI disagreed for the same run)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from georef_core.adjustment.residual_table import ResidualRow, ResidualTable, residual_statistics

FIXTURE = Path(__file__).resolve().parents[2] / "frontend" / "tests" / "fixtures" / "residuals_core.json"


def _table() -> ResidualTable:
    rng = np.random.default_rng(11)
    t = ResidualTable("check points", "EPSG:32631 (E, N, ellipsoidal h)")
    for i, d in enumerate(rng.normal(0.0, [0.01, 0.012, 0.02], size=(7, 3))):
        t.rows.append(ResidualRow(f"CP{i + 1}", "check", float(d[0]), float(d[1]), float(d[2]),
                                  float(np.linalg.norm(d)), 5 + i, [0.004, 0.004, 0.009], ""))
    return t


def test_statistics_definition():
    d = np.array([[0.012, -0.004, 0.021], [-0.006, 0.008, -0.035], [0.003, 0.001, 0.007]])
    s = residual_statistics(d)
    assert s["n"] == 3
    assert abs(s["dx"]["std_m"] - 0.009) < 1e-12          # sample std (n - 1) of 0.012, -0.006, 0.003
    assert abs(s["dz"]["rmse_m"] - np.sqrt(np.mean(d[:, 2] ** 2))) < 1e-15
    assert abs(s["3d"]["std_m"] - np.linalg.norm(d, axis=1).std(ddof=1)) < 1e-15
    assert residual_statistics(d[:1])["dx"]["std_m"] is None and residual_statistics(np.zeros((0, 3))) == {"n": 0}


def test_the_browser_fixture_is_what_the_core_writes(tmp_path):
    """frontend/tests/fixtures/residuals_core.json (read by frontend/tests/residuals.test.ts) is this table as
    the core writes it; regenerate with `python tests/adjustment/test_residual_statistics.py`."""
    t = _table()
    t.write(tmp_path / "residuals.json", tmp_path / "residuals.csv")
    _assert_same(json.loads(FIXTURE.read_text()), json.loads((tmp_path / "residuals.json").read_text()))


def _assert_same(a, b, where="residuals.json"):
    """Equal structure and text, numbers equal to 1e-12 relative (the last digit of a float may differ
    between numpy releases: the fixture was written with one, the test may run with another)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (where, a, b)
        for k in a:
            _assert_same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), (where, a, b)
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{k}]")
    elif isinstance(a, float) or isinstance(b, float):
        assert isinstance(a, (int, float)) and isinstance(b, (int, float)), (where, a, b)
        assert abs(a - b) <= 1e-12 * max(1.0, abs(a)), (where, a, b)
    else:
        assert a == b, (where, a, b)


def test_api_pdf_comparison_and_site_summary_show_the_core_statistics(tmp_path):
    from backend.services import report_pdf, result_files, results

    t = _table()
    t.write(tmp_path / "residuals.json", tmp_path / "residuals.csv")
    core = t.stats()
    # the API's view of the table (residuals endpoint, site summary)
    api = result_files.normalise_residuals((tmp_path / "residuals.json").read_text(), None)
    assert api["stats"] == json.loads(json.dumps(core))
    assert results.check_rmse(api["stats"]) == {"horizontal": core["horizontal"]["rmse_m"],
                                                 "vertical": core["dz"]["rmse_m"], "3d": core["3d"]["rmse_m"], "n": 7}
    # a table that has only its CSV gets the same numbers from the same function (to the CSV's 0.1 mm)
    csv_only = result_files.normalise_residuals(None, (tmp_path / "residuals.csv").read_text())
    assert abs(csv_only["stats"]["dx"]["std_m"] - core["dx"]["std_m"]) < 1e-4
    assert result_files.rmse_3d_m(api) == core["3d"]["rmse_m"]
    # the PDF prints the core's sample std, not a population std
    report_pdf.build_report(tmp_path, tmp_path / "report" / "r.pdf", {"site": "S", "survey": "V", "crs": "EPSG:32631"})
    from tests.security.conftest import pdf_text

    text = pdf_text((tmp_path / "report" / "r.pdf").read_bytes())
    pop_std = float(np.array([r.dx_m for r in t.rows]).std(ddof=0))
    assert f"{core['dx']['std_m']:.3f}" in text
    assert f"{core['3d']['std_m']:.3f}" in text
    assert f"{core['dx']['std_m']:.3f}" != f"{pop_std:.3f}"      # the two definitions differ at the printed digits


if __name__ == "__main__":      # regenerates the browser's fixture
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        _table().write(Path(d) / "residuals.json", Path(d) / "residuals.csv")
        FIXTURE.write_text((Path(d) / "residuals.json").read_text())
    print(f"wrote {FIXTURE}")
