"""Bad design files are named with their problem; the `georef design` command (--json) and the design step."""

from __future__ import annotations

import json
import math

import pytest

from georef_core.cli.main import main
from georef_core.design import read_design
from georef_core.errors import InputFileError
from georef_core.steps.design import run_design
from tests.design import scenes as S


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("design_inputs")
    sc = S.write_scene(d)
    sc["xml"] = S.write_design_landxml(d / "design.xml")
    sc["dir"] = d
    return sc


def _xml(body: str) -> str:
    return ('<?xml version="1.0"?><LandXML xmlns="http://www.landxml.org/schema/LandXML-1.2" version="1.2">'
            f"{body}</LandXML>")


def test_bad_landxml_files_are_named(tmp_path):
    cases = {
        "nosurf.xml": (_xml("<Units><Metric linearUnit='meter'/></Units>"), "no <Surface> in the file"),
        "missing.xml": (_xml("<Surfaces><Surface name='FG'><Definition><Pnts><P id='1'>0 0 1</P><P id='2'>0 1 1</P>"
                             "<P id='3'>1 0 1</P></Pnts><Faces><F>1 2 7</F></Faces></Definition></Surface></Surfaces>"),
                        "face '1 2 7' references point id '7' which is not in <Pnts>"),
        "twocoords.xml": (_xml("<Surfaces><Surface name='FG'><Definition><Pnts><P id='1'>0 0</P><P id='2'>0 1 1</P>"
                               "<P id='3'>1 0 1</P></Pnts></Definition></Surface></Surfaces>"),
                          "point '1': expected 'northing easting elevation'"),
        "broken.xml": ("<LandXML><Surfaces>", "not well-formed XML"),
        "other.xml": ("<?xml version='1.0'?><kml/>", "not a LandXML file"),
        "unit.xml": (_xml("<Units><Imperial linearUnit='furlong'/></Units><Surfaces/>"), "unknown length unit"),
    }
    for name, (text, problem) in cases.items():
        p = tmp_path / name
        p.write_text(text)
        with pytest.raises(InputFileError) as e:
            read_design(p)
        assert str(p) in str(e.value) and problem in str(e.value), (name, str(e.value))


def test_bad_dxf_and_other_files_are_named(tmp_path):
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.modelspace().add_line((0, 0, 0), (10, 0, 1))
    doc.modelspace().add_lwpolyline([(0, 0), (5, 5), (0, 5)])
    p = tmp_path / "lines.dxf"
    doc.saveas(p)
    with pytest.raises(InputFileError, match=r"lines\.dxf: no 3DFACE, polyface mesh or MESH entity .* found: "
                                             r"LINE, LWPOLYLINE"):
        read_design(p)
    junk = tmp_path / "junk.dxf"
    junk.write_text("0\nSECTION\n2\nENTITIES\n0\nBOGUS\n")
    with pytest.raises(InputFileError, match="junk.dxf"):
        read_design(junk)
    with pytest.raises(InputFileError, match="unknown design surface format"):
        (tmp_path / "a.csv").write_text("1,2,3\n")
        read_design(tmp_path / "a.csv")
    with pytest.raises(InputFileError, match="file not found"):
        read_design(tmp_path / "nope.xml")
    tif = tmp_path / "bad.tif"
    tif.write_bytes(b"II*\x00" + b"\x00" * 64)
    with pytest.raises(InputFileError, match="bad.tif"):
        read_design(tif)


def test_design_not_covering_the_polygon_says_the_share(scene, tmp_path):
    # a TIN over the western 60 % of the site only: part of the area has no design
    import numpy as np

    pts, _ = S.tin_vertices()
    x_cut = S.E0 + 24.0
    west = np.array([[S.E0 - 1, S.N0 - 1], [S.XC, S.N0 - 1], [x_cut, S.N0 - 1],
                     [S.E0 - 1, S.N0 + 41], [S.XC, S.N0 + 41], [x_cut, S.N0 + 41]])
    z = S.design_height(west[:, 0], west[:, 1])
    body = "".join(f'<P id="{k}">{n} {e} {h}</P>' for k, (e, n, h) in enumerate(zip(west[:, 0], west[:, 1], z)))
    faces = "<F>0 1 4</F><F>0 4 3</F><F>1 2 5</F><F>1 5 4</F>"
    p = tmp_path / "west.xml"
    p.write_text(_xml(f"<Surfaces><Surface name='W'><Definition><Pnts>{body}</Pnts><Faces>{faces}</Faces>"
                      "</Definition></Surface></Surfaces>"))
    import shapely

    uncovered = shapely.Polygon(S.AREA).difference(shapely.box(S.E0 - 1, S.N0 - 1, x_cut, S.N0 + 41)).area
    share = 100 * uncovered / S.area_m2()
    with pytest.raises(InputFileError) as e:
        run_design(scene["dsm"], p, scene["polygon"], tmp_path / "out", {"tolerance_m": 0.05})
    msg = str(e.value)
    assert "west.xml" in msg and f"({share:.1f} %)" in msg and "does not cover" in msg, msg
    assert not list((tmp_path / "out").glob("*")), "no partial outputs left behind"


def test_cli_json_and_exit_code(scene, tmp_path, capsys):
    rc = main(["design", "--dsm", str(scene["dsm"]), "--design", str(scene["xml"]), "--polygon", str(scene["polygon"]),
               "--tolerance", "0.05", "--dsm-sigma", "0.01", "--vertical-rmse", "0.015", "--json",
               "--out", str(tmp_path / "out")])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["cut_m3"] == pytest.approx(S.cut_volume(), rel=0.01)
    assert doc["fill_m3"] == pytest.approx(S.fill_volume(), rel=0.01)
    assert doc["on_grade"]["share"] == pytest.approx(1 - S.off_grade_area(0.05) / S.area_m2(), abs=0.002)
    assert doc["uncertainty"]["net_m3"]["components_m3"]["vertical_bias_m3"] == pytest.approx(0.015 * S.area_m2(), rel=1e-3)
    assert doc["significance"]["sources"]["vertical_rmse_m"] == "given"
    assert (tmp_path / "out" / "classes.tif").exists() and (tmp_path / "out" / "cut_fill.json").exists()
    rc = main(["design", "--dsm", str(scene["dsm"]), "--design", str(tmp_path / "none.xml"),
               "--polygon", str(scene["polygon"])])
    assert rc == 2 and "none.xml: file not found" in capsys.readouterr().err
    rc = main(["design", "--dsm", str(scene["dsm"]), "--design", str(scene["xml"]), "--polygon", str(scene["polygon"])])
    out = capsys.readouterr().out
    assert rc == 0 and "on grade (+-0.05 m)" in out and "cut  (above design, to remove)" in out


def test_design_step_through_its_contract(scene, tmp_path):
    import shutil

    from georef_core.steps.contract import Workspace, get_spec

    spec = get_spec("design")
    assert spec.depends_on == ("dense",) and spec.output("classes").path == "design/classes.tif"
    run = tmp_path / "run"
    (run / "dense").mkdir(parents=True)
    shutil.copy(scene["dsm"], run / "dense" / "dsm.tif")
    (run / "residuals.json").write_text(json.dumps({"statistics": {"n": 4, "dz": {"rmse_m": 0.018}}}))
    ws = Workspace(tmp_path / "survey", run)
    fn = spec.resolve()
    skipped = fn(ws, {}, None, {"crs": f"EPSG:{S.EPSG}"})
    assert skipped["skipped"] is True
    area = {"type": "Polygon", "coordinates": [S.AREA.tolist() + [S.AREA[0].tolist()]]}
    ctx = {"crs": f"EPSG:{S.EPSG}", "design": {"path": str(scene["xml"]), "polygon": area, "name": "phase 1"}}
    summary = fn(ws, spec.validate({"tolerance_m": 0.05}), None, ctx)
    assert summary["cut_m3"] == pytest.approx(S.cut_volume(), rel=0.01)
    assert summary["sigma_m3"]["net_m3"] > 0.018 * S.area_m2() * 0.99  # the check-point RMSE as the bias
    assert summary["surface"] == "dsm" and summary["design"] == "FG design"
    for key in ("quantities", "difference", "classes", "contours"):
        assert ws.path("design", key).exists(), key
    with pytest.raises(InputFileError, match="no DTM"):
        fn(ws, spec.validate({"surface": "dtm"}), None, ctx)
    assert math.isfinite(summary["on_grade_share"])
