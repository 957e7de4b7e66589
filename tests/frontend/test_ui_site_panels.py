"""Browser checks of the site page's stockpile inventory and design progress and of the Downloads tab's
"Open in QGIS / GIS" panel, in headless Chromium on the built UI with the API answered by the test (no
platform: a few seconds). The inventory served is the core's own output (the unit tests' fixture, kept equal
to georef_core.deliverables.inventory by test_inventory_fixture.py).

- the inventory table shows the server's figures with "± x (1σ)", the totals row, and CSV / XLSX links for
  the date picked; another date asks the server again;
- a design file the server refuses: its 422 message is on the page; the tolerance is sent in metres with
  If-Match = the design's ETag; the net ± 1σ chart and table show every compared survey;
- the GIS panel lists the run's layers, creates a tile token with the days asked and shows the WMTS and XYZ
  URLs with it."""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest

from .ui_helpers import fulfil_with_built_file, horizontal_overflow, unlabelled_controls
from .test_ui_layout import ME, ORIGIN, RUN, RUN_OBJ, SITE, SITE_OBJ, SURVEY, SURVEY_OBJ, _page

INVENTORY = json.loads((Path(__file__).resolve().parents[2] / "frontend" / "tests" / "fixtures" /
                        "inventory_site.json").read_text())
DESIGN_ETAG = '"dsite-1.v3"'
DESIGN = {"site_id": SITE, "filename": "fg.xml", "format": "landxml", "sha256": "ab" * 32, "size": 20480,
          "surface_name": None, "described": {"kind": "tin", "n_points": 441, "n_triangles": 800,
                                              "height_range_m": [99.5, 101.2], "extent": [679490, 3889220, 679560, 3889290]},
          "area": {"type": "Polygon", "coordinates": [[[679490, 3889220], [679560, 3889220], [679560, 3889290],
                                                        [679490, 3889290], [679490, 3889220]]]},
          "area_m2": 4900.0, "tolerance_m": 0.05, "key": "k1", "created_at": "2024-06-01T00:00:00Z",
          "updated_at": "2024-06-01T00:00:00Z", "version": 3}
PROGRESS = {"design": {"filename": "fg.xml", "format": "landxml", "sha256": "ab" * 32, "key": "k1", "surface_name": None,
                       "area_m2": 4900.0, "tolerance_m": 0.05},
            "conventions": "cut_m3: surveyed above design",
            "surveys": [{"survey_id": SURVEY, "survey_name": "Demo flight", "flown_at": "2024-06-24T08:10:05Z",
                         "run_id": RUN, "run_number": 1, "cut_m3": 25.31, "fill_m3": 10.23, "net_m3": 15.08,
                         "sigma_m3": {"cut_m3": 0.15, "fill_m3": 0.12, "net_m3": 0.21}, "on_grade_share": 0.634,
                         "on_grade_expected_share": 0.61, "tolerance_m": 0.05, "area_m2": 4900.0, "warnings": []}],
            "not_compared": [{"survey_id": "s0", "survey_name": "April flight", "flown_at": None,
                              "reason": "no successful run with the design step"}]}
REFUSED = "fg.xml: surface 'FG': face '1 2 999' references point id '999' which is not in <Pnts>"
LAYERS = {"run_id": RUN, "layers": [
    {"name": "dsm", "title": "DSM", "style": "heights", "step": "dense", "source": "dense/dsm.tif",
     "lonlat_bounds": [135.1, 35.1, 135.2, 35.2], "min_zoom": 0, "max_zoom": 22,
     "tiles": f"http://10.0.0.5:8000/api/v1/runs/{RUN}/tiles/dsm/{{z}}/{{x}}/{{y}}.png", "legend": "x"},
    {"name": "ortho", "title": "Orthophoto", "style": "rgb", "step": "dense", "source": "dense/ortho.tif",
     "lonlat_bounds": [135.1, 35.1, 135.2, 35.2], "min_zoom": 0, "max_zoom": 22,
     "tiles": f"http://10.0.0.5:8000/api/v1/runs/{RUN}/tiles/ortho/{{z}}/{{x}}/{{y}}.png", "legend": "x"}]}
TOKEN = {"id": "tok-7", "name": "QGIS", "prefix": "grf_Zx9q", "scopes": ["tiles"], "created_at": "2024-06-30T12:00:00Z",
         "expires_at": "2099-07-30T12:00:00Z", "last_used_at": None, "revoked_at": None, "token": "grf_Zx9qSECRET"}


def _api(path: str, method: str, query: dict):
    """(status, body, headers) of the fake API."""
    if path == "/auth/me":
        return 200, ME, {}
    if path == f"/sites/{SITE}":
        return 200, SITE_OBJ, {}
    if path == f"/sites/{SITE}/surveys":
        return 200, _page([SURVEY_OBJ]), {}
    if path == f"/sites/{SITE}/stockpiles":
        return 200, [], {}
    if path == f"/sites/{SITE}/inventory":
        return 200, {**INVENTORY, "date": query.get("date", ["today"])[0]}, {}
    if path == f"/sites/{SITE}/design" and method == "GET":
        return 200, DESIGN, {"ETag": DESIGN_ETAG}
    if path == f"/sites/{SITE}/design" and method == "PATCH":
        return 200, DESIGN, {"ETag": DESIGN_ETAG}
    if path == f"/sites/{SITE}/design/file" and method == "PUT":
        return 422, {"type": "https://georef.dev/problems/bad-design", "title": "Unprocessable", "status": 422,
                     "detail": REFUSED}, {}
    if path == f"/sites/{SITE}/design-progress":
        return 200, PROGRESS, {}
    if path == f"/surveys/{SURVEY}":
        return 200, SURVEY_OBJ, {}
    if path == f"/surveys/{SURVEY}/runs":
        return 200, _page([RUN_OBJ]), {}
    if path == f"/runs/{RUN}/results":
        return 200, [], {}
    if path == "/steps":
        return 200, {"items": []}, {}
    if path == f"/runs/{RUN}/tiles":
        return 200, LAYERS, {}
    if path == "/tokens/tile" and method == "POST":
        return 201, TOKEN, {}
    return 404, {"type": "about:blank", "title": "Not Found", "status": 404, "detail": "not in this test"}, {}


@pytest.fixture
def ui(browser, frontend_dist):
    """A page on the built UI whose API calls the test answers; `calls` records (method, path, query, headers,
    body) of every API request."""
    ctx = browser.new_context(viewport={"width": 1366, "height": 900}, base_url=ORIGIN)
    page = ctx.new_page()
    page.set_default_timeout(15000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    calls: list[tuple] = []

    def handle(route):
        req = route.request
        parts = urlsplit(req.url)
        path = parts.path or "/"
        if path.startswith("/api/v1/"):
            api_path = path[len("/api/v1"):]
            query = parse_qs(parts.query)
            calls.append((req.method, api_path, query, req.headers, req.post_data_buffer))
            status, body, headers = _api(api_path, req.method, query)
            route.fulfill(status=status, body=json.dumps(body), headers=headers,
                          content_type="application/json" if status < 400 else "application/problem+json")
            return
        fulfil_with_built_file(route, frontend_dist, path)

    page.route(f"{ORIGIN}/**", handle)
    page.errors = errors
    page.calls = calls
    yield page
    ctx.close()


def test_the_site_inventory_shows_the_servers_figures_for_the_date(ui):
    ui.goto(f"/#/sites/{SITE}")
    table = ui.locator("[data-testid=inventory] table")
    table.wait_for()
    heads = [t.strip() for t in table.locator("thead th").all_inner_texts()]
    assert heads == ["Stockpile", "Material", "Surveyed", "Volume (m³)", "Density (t/m³)", "Tonnage (t)",
                     "Change since last survey (m³)"], heads
    north = table.locator("tbody tr", has_text="North pile").inner_text()
    # 100 +- 2 m3 of sand at the default 1.60 +- 0.10 t/m3: 160 t +- 10.5; +20 +- 2.5 m3 since 2024-05-01
    for text in ("100.0", "± 2.0 (1σ)", "1.60", "± 0.10 (1σ)", "default for sand", "160", "± 11 (1σ)",
                 "+20.0", "± 2.5 (1σ)", "since 2024-05-01"):
        assert text in north, (text, north)
    assert "no survey on or before 2024-06-30" in table.locator("tbody tr", has_text="Topsoil heap").inner_text()
    total = table.locator("tfoot tr").inner_text()
    assert "1,633" in total and "± 12 (1σ)" in total and "3,054" in total, total
    first = [c for c in ui.calls if c[1] == f"/sites/{SITE}/inventory"]
    assert first and first[0][2]["format"] == ["json"] and re.fullmatch(r"\d{4}-\d{2}-\d{2}", first[0][2]["date"][0])

    ui.get_by_label("Inventory on").fill("2024-06-30")
    ui.wait_for_function("() => document.querySelector('a[download=\"inventory_2024-06-30.csv\"]') !== null")
    csv = ui.get_by_role("link", name="Download CSV").get_attribute("href")
    xlsx = ui.get_by_role("link", name="Download XLSX").get_attribute("href")
    assert csv == f"/api/v1/sites/{SITE}/inventory?date=2024-06-30&format=csv", csv
    assert xlsx == f"/api/v1/sites/{SITE}/inventory?date=2024-06-30&format=xlsx", xlsx
    assert any(c[2].get("date") == ["2024-06-30"] and c[2]["format"] == ["json"]
               for c in ui.calls if c[1] == f"/sites/{SITE}/inventory")
    ui.get_by_test_id("design-panel").get_by_text("fg.xml").first.wait_for()
    assert unlabelled_controls(ui) == []
    ui.set_viewport_size({"width": 820, "height": 1180})      # a tablet: the tables scroll, not the page
    ui.wait_for_timeout(200)
    assert horizontal_overflow(ui) <= 0
    assert ui.errors == []


def test_design_progress_and_a_refused_design_file(ui, tmp_path):
    ui.goto(f"/#/sites/{SITE}")
    panel = ui.get_by_test_id("design-panel")
    panel.get_by_text("fg.xml").first.wait_for()
    row = panel.locator("tbody tr", has_text="Demo flight").inner_text()
    for text in ("2024-06-24", "25.31", "10.23", "+15.08", "± 0.21 (1σ)", "63 %"):
        assert text in row, (text, row)
    chart = panel.get_by_role("img", name=re.compile("Net to design"))
    assert "15.08" in chart.get_attribute("aria-label")
    assert "April flight: no successful run with the design step" in panel.text_content()   # in a closed <details>

    bad = tmp_path / "fg.xml"
    bad.write_text("<LandXML><Surfaces/></LandXML>")
    ui.get_by_label("Design file (LandXML, DXF or GeoTIFF)").set_input_files(str(bad))
    alert = panel.get_by_role("alert")
    alert.wait_for()
    assert REFUSED in alert.inner_text(), alert.inner_text()
    put = [c for c in ui.calls if c[0] == "PUT"][-1]
    assert put[1] == f"/sites/{SITE}/design/file" and put[2]["filename"] == ["fg.xml"]
    assert put[4] == bad.read_bytes() and put[3]["content-type"] == "application/octet-stream"

    ui.get_by_label("On-grade tolerance (± cm)").fill("2.5")
    ui.get_by_role("button", name="Set tolerance").click()
    panel.get_by_text("Tolerance set to ± 2.5 cm").wait_for()
    patch = [c for c in ui.calls if c[0] == "PATCH"][-1]
    assert json.loads(patch[4]) == {"tolerance_m": 0.025}
    assert patch[3]["if-match"] == DESIGN_ETAG and patch[3].get("x-csrf-token")
    assert ui.errors == []


def test_the_gis_panel_gives_wmts_and_xyz_urls_with_a_tile_token(ui):
    ui.goto(f"/#/surveys/{SURVEY}/downloads")
    panel = ui.get_by_test_id("gis-panel")
    panel.get_by_text("Map layers of run 1").wait_for()
    assert "dsm" in panel.inner_text() and "ortho" in panel.inner_text()
    ui.get_by_label(re.compile("Token valid for")).fill("7")
    ui.get_by_role("button", name="Create a tile token").click()
    wmts = ui.get_by_role("textbox", name="WMTS capabilities URL")
    wmts.wait_for()
    post = [c for c in ui.calls if c[1] == "/tokens/tile"][-1]
    assert json.loads(post[4])["expires_in_days"] == 7
    assert wmts.input_value() == f"{ORIGIN}/api/v1/runs/{RUN}/wmts/1.0.0/WMTSCapabilities.xml?token=grf_Zx9qSECRET"
    xyz = ui.get_by_role("textbox", name=re.compile("XYZ tiles: ortho")).input_value()
    assert xyz == f"{ORIGIN}/api/v1/runs/{RUN}/tiles/ortho/{{z}}/{{x}}/{{y}}.png?token=grf_Zx9qSECRET", xyz
    # http://georef.test is not a secure context (no navigator.clipboard): Copy selects the whole URL for Ctrl+C
    ui.get_by_role("button", name="Copy WMTS capabilities URL").click()
    panel.get_by_text(re.compile("^(Copied|Selected: press Ctrl\\+C to copy)$")).wait_for()
    assert wmts.evaluate("e => [e.selectionStart, e.selectionEnd]") == [0, len(wmts.input_value())]
    text = panel.inner_text()
    assert "expires 2099-07-30 12:00 UTC" in text and "shown only now" in text
    assert "Add WMS/WMTS Layer" in text and "XYZ Tiles" in text
    assert unlabelled_controls(ui) == []
    assert ui.errors == []


def _with_change(state: str, cut_moved: float, pending: bool) -> dict:
    """PROGRESS with a second, earlier survey and the change since it: queued (the totals' figures) or done."""
    may = {**PROGRESS["surveys"][0], "survey_id": "s-may", "survey_name": "May flight", "flown_at": "2024-05-20T09:00:00Z",
           "run_id": "r-may", "cut_m3": 37.7, "net_m3": 27.47}
    change = {"previous_survey_id": "s-may", "previous_survey_name": "May flight", "days": 35.0,
              "cut_moved_m3": cut_moved, "fill_placed_m3": 0.0, "net_change_m3": -cut_moved,
              "sigma_m3": {"cut_moved_m3": 1.5, "fill_placed_m3": 0.9, "net_change_m3": 2.0},
              "remaining_cut_m3": 25.31, "remaining_fill_m3": 10.23, "done_share": {"cut_m3": 0.33, "fill_m3": 0.0},
              "method": "surfaces" if state == "succeeded" else "totals", "surfaces_state": state,
              "notes": ["surface against surface: being computed by a worker"] if pending else []}
    june = {**PROGRESS["surveys"][0], "since_previous": change}
    return {**PROGRESS, "surveys": [{**may, "since_previous": None}, june], "changes_pending": pending}


def test_the_change_between_surveys_shows_pending_then_done_by_itself(ui, monkeypatch):
    """design-progress answers 202 while a worker computes the change (figures from the totals), then 200 with the
    stored result: the page shows pending, asks again on its own (no request waits on the computation) and shows
    the result."""
    answers = [(202, _with_change("queued", 12.39, True), {"Retry-After": "5"}),
               (200, _with_change("succeeded", 14.58, False), {})]
    inner = _api

    def fake(path, method, query):
        if path == f"/sites/{SITE}/design-progress":
            return answers.pop(0) if len(answers) > 1 else answers[0]
        return inner(path, method, query)

    monkeypatch.setitem(globals(), "_api", fake)
    ui.goto(f"/#/sites/{SITE}")
    table = ui.get_by_test_id("design-change")
    table.locator("[data-testid=change-state][data-state=queued]").wait_for()
    row = table.locator("tbody tr", has_text="Demo flight").inner_text()
    assert "pending" in row and "+12.4 ± 1.5" in row, row
    assert "updates by itself" in table.inner_text()
    table.locator("[data-testid=change-state][data-state=succeeded]").wait_for(timeout=15000)
    row = table.locator("tbody tr", has_text="Demo flight").inner_text()
    assert "done: surface against surface" in row and "+14.6 ± 1.5" in row, row
    assert "updates by itself" not in table.inner_text()
    asked = [c for c in ui.calls if c[1] == f"/sites/{SITE}/design-progress"]
    assert len(asked) == 2, asked   # asked again once (no more once done: vitest designProgress progressPollDelayMs)
    assert ui.errors == []
