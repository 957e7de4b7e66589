"""Ground/check point input (ODM gcp_list.txt, points CSV in any CRS), triangulation with blunder
detection, target refinement and the residual table, each against constructed truth."""

import json

import numpy as np
import pytest
from PIL import Image

from georef_core.adjustment.control_points import (ImageMeasurement, load_control, parse_crs, points_to_enu,
                                                    read_gcp_list, read_points_csv)
from georef_core.adjustment.residual_table import ResidualRow, ResidualTable
from georef_core.adjustment.target_refinement import refine_measurements
from georef_core.adjustment.triangulation import find_blunders, triangulate
from georef_core.errors import InputFileError
from georef_core.project_frame import ProjectFrame

INTR = np.array([1000.0, 640.0, 480.0, -0.05, 0.01, 0.0, 0.0, 0.0])


def test_gcp_list_with_odm_utm_header_and_unnamed_points(tmp_path):
    p = tmp_path / "gcp_list.txt"
    p.write_text("WGS84 UTM 11N\n"
                 "500010.0 3700020.0 101.5 100.5 200.25 IMG_1.jpg\n"
                 "500010.0 3700020.0 101.5 300.0 210.0 IMG_2.jpg\n"
                 "500050.0 3700060.0 99.0 50.0 60.0 IMG_1.jpg gcp_b\n")
    crs, points, meas = read_gcp_list(p)
    assert crs == "EPSG:32611"
    assert sorted(points) == ["gcp01", "gcp_b"]
    assert [m.point for m in meas] == ["gcp01", "gcp01", "gcp_b"]
    np.testing.assert_allclose(meas[0].uv_px, [100.5, 200.25])
    assert meas[2].source == "gcp_list.txt:4"


@pytest.mark.parametrize("text, message", [
    ("EPSG:999999\n1 2 3 4 5 a.jpg\n", "unknown coordinate reference system"),
    ("EPSG:32611\n1 2 3 4 a.jpg\n", "expected 'x y z px py image"),
    ("EPSG:32611\n1 2 x 4 5 a.jpg\n", "not a number"),
    ("EPSG:32611\n1 2 3 4 5 a.jpg p1\n1 2 4 4 5 b.jpg p1\n", "two different coordinates"),
    ("", "empty"),
])
def test_gcp_list_errors_name_the_file(tmp_path, text, message):
    p = tmp_path / "gcp_list.txt"
    p.write_text(text)
    with pytest.raises(InputFileError, match=message) as exc:
        read_gcp_list(p)
    assert "gcp_list.txt" in str(exc.value)


def test_points_csv_roles_and_errors(tmp_path):
    p = tmp_path / "points.csv"
    p.write_text("name,easting_m,northing_m,ellipsoidal_height_m,role\n"
                 "A,500000,3700000,100,control\nB,500100,3700000,101,check\nC,500100,3700100,102,\n")
    pts = read_points_csv(p, "EPSG:32611")
    assert {k: v.role for k, v in pts.items()} == {"A": "control", "B": "check", "C": "check"}
    p.write_text("name,easting_m,northing_m,ellipsoidal_height_m\nA,500000,3700000,abc\n")
    with pytest.raises(InputFileError, match="line 2"):
        read_points_csv(p, "EPSG:32611")
    p.write_text("name,foo,bar\nA,1,2\n")
    with pytest.raises(InputFileError, match="needs columns"):
        read_points_csv(p, "EPSG:32611")
    with pytest.raises(InputFileError, match="CRS of the point file is unknown"):
        load_control(points_csv=p)


def test_points_csv_and_gcp_list_merge_csv_wins(tmp_path):
    g = tmp_path / "gcp_list.txt"
    g.write_text("EPSG:32611\n500000 3700000 100 10 10 a.jpg P9\n500000 3700000 100 12 10 b.jpg P9\n")
    c = tmp_path / "points.csv"
    c.write_text("name,x,y,z,role\nP1,500000,3700010,100,control\nP9,500000.002,3700000,100.01,check\n")
    data = load_control(points_csv=c, gcp_list=g)   # the CRS of the CSV is the gcp list's
    assert set(data.points) == {"P1", "P9"}
    assert data.points["P9"].role == "check" and data.points["P9"].xyz_crs[2] == pytest.approx(100.01)
    assert len(data.measurements_of("P9")) == 2 and data.measurements_of("P1") == []


def test_same_point_in_utm_and_geographic_gives_the_same_enu():
    from pyproj import Transformer

    from georef_core.adjustment.control_points import GroundPoint

    frame = ProjectFrame(32611, 500000.0, 3762000.0, 300.0)
    e, n, h = 500123.4, 3762345.6, 312.3
    lon, lat = Transformer.from_crs("EPSG:32611", "EPSG:4326", always_xy=True).transform(e, n)
    a = points_to_enu([GroundPoint("u", np.array([e, n, h]), "EPSG:32611")], frame)[0]
    b = points_to_enu([GroundPoint("g", np.array([lon, lat, h]), "EPSG:4326")], frame)[0]
    assert np.linalg.norm(a - b) < 1e-3
    assert parse_crs("wgs84 utm 33s") == "EPSG:32733"


def _cameras(n=6):
    """Nadir cameras 50 m above a point at the origin, in a ring (ENU, camera z down)."""
    R = np.array([np.diag([1.0, -1.0, -1.0])] * n)
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    C = np.column_stack([15 * np.cos(ang), 15 * np.sin(ang), np.full(n, 50.0)])
    return R, C


def _project(X, R, C):
    from georef_core.adjustment.camera_model import project_camera_points

    pc = np.einsum("nji,nj->ni", R, X[None] - C)
    return project_camera_points(pc, INTR)


def test_triangulation_recovers_the_point_and_names_a_blunder():
    rng = np.random.default_rng(0)
    R, C = _cameras()
    X = np.array([1.0, -2.0, 0.5])
    uv = _project(X, R, C) + rng.normal(0, 0.2, (len(C), 2))
    t = triangulate(uv, np.arange(len(C)), R, C, INTR)
    assert np.linalg.norm(t.xyz_enu_m - X) < 0.02
    assert np.all(np.linalg.norm(t.residual_px, axis=1) < 1.0)
    names = [f"IMG_{k}.jpg" for k in range(len(C))]
    uv_bad = uv.copy()
    uv_bad[3] += [25.0, -12.0]                           # a click on the wrong target
    keep, reports = find_blunders("gcp04", names, uv_bad, np.arange(len(C)), R, C, INTR)
    assert len(reports) == 1 and reports[0].image == "IMG_3.jpg"
    assert "gcp04" in reports[0].message and 3 not in keep
    assert reports[0].residual_px > 20
    keep, reports = find_blunders("gcp04", names, uv, np.arange(len(C)), R, C, INTR)
    assert reports == [] and keep == list(range(len(C)))


def _checker_image(path, centre_uv, size=(120, 100)):
    """A black/white checker target, antialiased by supersampling, centred at a sub-pixel position."""
    ss = 8
    w, h = size
    yy, xx = np.mgrid[0:h * ss, 0:w * ss]
    u = (xx + 0.5) / ss - 0.5 - centre_uv[0]
    v = (yy + 0.5) / ss - 0.5 - centre_uv[1]
    img = np.where((u > 0) ^ (v > 0), 230.0, 25.0)
    img = img.reshape(h, ss, w, ss).mean(axis=(1, 3))
    Image.fromarray(img.astype(np.uint8)).save(path)


def test_target_refinement_moves_a_click_onto_the_checker_centre(tmp_path):
    rng = np.random.default_rng(1)
    truths, meas = [], []
    for k in range(5):
        c = np.array([60.0, 50.0]) + rng.uniform(-3, 3, 2)
        _checker_image(tmp_path / f"t{k}.png", c)
        truths.append(c)
        meas.append(ImageMeasurement("p", f"t{k}.png", c + rng.normal(0, 0.4, 2)))
    before = np.array([np.linalg.norm(m.uv_px - t) for m, t in zip(meas, truths)])
    n_ref, n_keep = refine_measurements(tmp_path, meas)
    after = np.array([np.linalg.norm(m.uv_px - t) for m, t in zip(meas, truths)])
    assert n_ref == 5 and n_keep == 0
    assert np.sqrt(np.mean(after ** 2)) < 0.1 < np.sqrt(np.mean(before ** 2))
    # a uniform patch is not a target: the click is kept as it was
    Image.fromarray(np.full((100, 120), 128, np.uint8)).save(tmp_path / "flat.png")
    m = ImageMeasurement("q", "flat.png", np.array([60.3, 50.2]))
    assert refine_measurements(tmp_path, [m]) == (0, 1)
    np.testing.assert_allclose(m.uv_px, [60.3, 50.2])


def test_residual_table_statistics_and_files(tmp_path):
    rows = [ResidualRow("a", "check", 0.01, -0.02, 0.03, float(np.linalg.norm([0.01, -0.02, 0.03])), 4),
            ResidualRow("b", "check", -0.01, 0.00, 0.01, float(np.linalg.norm([-0.01, 0, 0.01])), 5)]
    t = ResidualTable("check points", "EPSG:32611", rows)
    st = t.stats()
    assert st["n"] == 2
    assert st["dx"]["mean_m"] == pytest.approx(0.0)
    assert st["dx"]["std_m"] == pytest.approx(np.std([0.01, -0.01], ddof=1))
    assert st["dz"]["rmse_m"] == pytest.approx(np.sqrt((0.03 ** 2 + 0.01 ** 2) / 2))
    assert st["3d"]["rmse_m"] == pytest.approx(np.sqrt((0.01 ** 2 + 0.02 ** 2 + 0.03 ** 2 + 0.01 ** 2 + 0.01 ** 2) / 2))
    t.write(tmp_path / "r.json", tmp_path / "r.csv")
    back = json.loads((tmp_path / "r.json").read_text())
    assert back["statistics"]["n"] == 2 and back["points"][0]["name"] == "a"
    lines = (tmp_path / "r.csv").read_text().splitlines()
    assert lines[0].startswith("point,role,dx_m") and lines[1].startswith("a,check,0.0100,-0.0200,0.0300")
    assert "RMSE" in t.format_text()


def test_upload_check_and_georef_step_read_points_csv_alike(tmp_path):
    """One reading of points.csv (issue 24): the upload check (backend file_kinds) uses the core's
    parse_points_table, so a table the georef step reads is accepted at upload (usual column names such as
    x/y/z and a 'type' column with 'gcp'), with the same rows, and a bad one is refused with the same words."""
    import pytest as _pytest

    from backend.services.file_kinds import parse_points_csv
    from georef_core.adjustment.control_points import read_points_csv
    from georef_core.errors import InputFileError

    text = "id,x,y,z,type\nA,500000.0,5700000.0,101.5,gcp\nB,500010.0,5700020.0,99.25,check\n"
    p = tmp_path / "points.csv"
    p.write_text(text)
    core = read_points_csv(p, "EPSG:32631")
    upload = parse_points_csv(text)
    assert [(r["name"], r["role"], r["easting_m"], r["ellipsoidal_height_m"]) for r in upload] == \
        [(n, g.role, float(g.xyz_crs[0]), float(g.xyz_crs[2])) for n, g in core.items()]
    assert upload[0]["role"] == "control"
    bad = text.replace("99.25", "ninety")
    p.write_text(bad)
    with _pytest.raises(InputFileError, match="z 'ninety' is not a number") as err:
        read_points_csv(p, "EPSG:32631")
    assert err.value.line == 3
    with _pytest.raises(ValueError, match="line 3: z 'ninety' is not a number"):
        parse_points_csv(bad)


def test_upload_check_and_steps_read_gcp_list_and_events_alike(tmp_path):
    """One reading of gcp_list.txt and events.csv (issue 24): the upload check uses the core's parsers, so
    what it accepts the steps read, with the same rows, and what a step refuses is refused at upload with
    the same words (the upload check used to accept NaN trigger times and any CRS-looking first line)."""
    import pytest as _pytest

    from backend.services.file_kinds import parse_events_csv, parse_gcp_list
    from georef_core.gnss.camera_events import read_event_csv

    gcp = "WGS84 UTM 11N\n# a comment\n500010.0 3700020.0 101.5 100.5 200.25 IMG_1.jpg\n" \
          "500050.0 3700060.0 99.0 50.0 60.0 IMG_2.jpg gcp_b\n"
    (tmp_path / "gcp_list.txt").write_text(gcp)
    crs, points, meas = read_gcp_list(tmp_path / "gcp_list.txt")
    summary = parse_gcp_list(gcp)
    assert summary == {"crs": crs, "measurements": len(meas), "images": ["IMG_1.jpg", "IMG_2.jpg"],
                       "points": sorted(points)}
    assert meas[1].source == "gcp_list.txt:4"            # the file's own line number, comments counted
    with _pytest.raises(ValueError, match="line 3: a coordinate is not a finite number"):
        parse_gcp_list(gcp.replace("101.5", "nan"))
    with _pytest.raises(ValueError, match="unknown coordinate reference system"):
        parse_gcp_list(gcp.replace("WGS84 UTM 11N", "EPSG:999999"))

    # a trigger_gps_time_s column that is not the first: both read it, with the image names
    ev = "image,trigger_gps_time_s\nDJI_0001.JPG,1400000000.25\nDJI_0002.JPG,1400000002.5\n"
    (tmp_path / "events.csv").write_text(ev)
    np.testing.assert_array_equal(read_event_csv(tmp_path / "events.csv"), [1400000000.25, 1400000002.5])
    assert parse_events_csv(ev) == [{"gps_time_s": 1400000000.25, "image": "DJI_0001.JPG"},
                                    {"gps_time_s": 1400000002.5, "image": "DJI_0002.JPG"}]
    bad = ev.replace("1400000002.5", "inf")
    (tmp_path / "events.csv").write_text(bad)
    with _pytest.raises(InputFileError, match="'inf' is not a finite number") as err:
        read_event_csv(tmp_path / "events.csv")
    assert err.value.line == 3
    with _pytest.raises(ValueError, match="line 3: event time 'inf' is not a finite number"):
        parse_events_csv(bad)


def test_control_accuracy_warning_follows_the_chi_square_bound():
    """The control points' variance factor is flagged beyond its 99.9 % chi-square bound for n points (1.72
    for 10 points, 3.29 for one), and not below it nor without control."""
    from georef_core.steps.georef import control_accuracy_warning

    assert control_accuracy_warning({"control": 1.6}, 10) is None
    w = control_accuracy_warning({"control": 1.8}, 10)
    assert w is not None and "1.72" in w and "10 point(s)" in w
    assert control_accuracy_warning({"control": 3.2}, 1) is None
    assert control_accuracy_warning({"control": 3.4}, 1) is not None
    assert control_accuracy_warning({"control": 50.0}, 0) is None
    assert control_accuracy_warning({"image": 1.0}, 5) is None
