"""Browser checks of the survey views' layout and of where the volume of a drawn outline comes from, in
headless Chromium on the built UI with the API answered by the test (no platform: a few seconds).

- Starting "Draw an outline" (and adding corners) must not move the map: it used to push it down under the
  cursor (a hint paragraph and a Cancel button appeared above it).
- The volume shown for an outline before it is saved is the server's (POST /runs/{id}/volumes: the volumes
  step's computation), not a second estimate computed in the browser (22.4 +- 0.20 where the server said
  24.44 +- 0.16)."""

from __future__ import annotations

import json
import re

import pytest

from .ui_helpers import fulfil_with_built_file

ORIGIN = "http://georef.test"
SITE, SURVEY, RUN = "site-1", "survey-1", "run-1"
T = "2024-06-24T08:10:05Z"
SERVER_VOLUME = {"run_id": RUN, "crs": "EPSG:32653", "name": "outline", "volume_m3": 24.4412, "net_m3": 24.4412,
                 "cut_m3": 24.5013, "fill_m3": 0.0601, "area_m2": 61.2,
                 "uncertainty": {"sigma_m3": 0.1612, "ci95_m3": 0.316},
                 "base": {"method": "plane", "z_ref_m": 100.12}, "warnings": []}

ME = {"user": {"id": "u1", "email": "demo@georef.local", "name": "Demo", "organisation_id": "o1", "is_org_admin": False},
      "organisation": {"id": "o1", "name": "Demo Ltd"}, "auth": "session", "scopes": ["read", "write"],
      "csrf_token": "t", "site_roles": [{"site_id": SITE, "site_name": "Quarry", "role": "editor"}]}
SITE_OBJ = {"id": SITE, "organisation_id": "o1", "name": "Quarry", "crs": "EPSG:32653", "vertical_datum": None,
            "geoid": None, "description": "", "tolerance_horizontal_m": 0.03, "tolerance_vertical_m": 0.05,
            "created_at": T, "updated_at": T, "version": 1}
SURVEY_OBJ = {"id": SURVEY, "site_id": SITE, "name": "Demo flight", "flown_at": T, "flown_at_source": "gnss",
              "notes": "", "settings": {}, "created_at": "2025-01-01T00:00:00Z", "updated_at": T, "version": 1}
RUN_OBJ = {"id": RUN, "survey_id": SURVEY, "site_id": SITE, "number": 1, "state": "succeeded", "trigger": "manual",
           "parent_run_id": None, "previous_run_id": None, "from_step": None,
           "steps": ["gnss", "georef", "dense", "volumes", "report"], "settings": {}, "settings_hash": "h",
           "inputs": {}, "cancel_requested": False, "error": None, "created_at": T, "started_at": T, "finished_at": T}


def _page(items):
    return {"items": items, "total": len(items), "limit": 50, "offset": 0}


def _api(path: str, method: str):
    """(status, body) of the fake API."""
    if path == "/auth/me":
        return 200, ME
    if path == f"/surveys/{SURVEY}":
        return 200, SURVEY_OBJ
    if path == f"/sites/{SITE}":
        return 200, SITE_OBJ
    if path == f"/surveys/{SURVEY}/runs":
        return 200, _page([RUN_OBJ])
    if path == f"/sites/{SITE}/surveys":
        return 200, _page([SURVEY_OBJ])
    if path == f"/sites/{SITE}/stockpiles":
        return 200, []
    if path == f"/runs/{RUN}/volumes" and method == "POST":
        return 200, SERVER_VOLUME
    return 404, {"type": "about:blank", "title": "Not Found", "status": 404, "detail": "not in this test"}


@pytest.fixture
def ui(browser, frontend_dist):
    """A page on the built UI whose API calls the test answers; `posted` collects the request bodies."""
    ctx = browser.new_context(viewport={"width": 1366, "height": 900}, base_url=ORIGIN)
    page = ctx.new_page()
    page.set_default_timeout(15000)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    posted: dict[str, list] = {}

    def handle(route):
        req = route.request
        url = req.url.split("#", 1)[0]
        path = re.sub(r"\?.*$", "", url[len(ORIGIN):]) or "/"
        if path.startswith("/api/v1/"):
            api_path = path[len("/api/v1"):]
            if req.method == "POST":
                posted.setdefault(api_path, []).append(json.loads(req.post_data or "null"))
            status, body = _api(api_path, req.method)
            route.fulfill(status=status, body=json.dumps(body),
                          content_type="application/json" if status < 400 else "application/problem+json")
            return
        fulfil_with_built_file(route, frontend_dist, path)

    page.route(f"{ORIGIN}/**", handle)
    page.errors = errors
    page.posted = posted
    yield page
    ctx.close()


def test_drawing_an_outline_does_not_move_the_map(ui):
    ui.goto(f"/#/surveys/{SURVEY}/volumes")
    button = ui.get_by_role("button", name="Draw an outline")
    button.wait_for()
    m = ui.get_by_test_id("map")
    before = m.bounding_box()
    width_before = button.bounding_box()["width"]
    button.click()
    finish = ui.get_by_role("button", name=re.compile(r"Finish outline \(0 corners\)"))
    finish.wait_for()
    ui.get_by_text("Click the corners of the pile's toe").wait_for()      # the hint is shown (over the map)
    after = m.bounding_box()
    assert after["y"] == before["y"] and after["height"] == before["height"], (before, after)
    assert finish.bounding_box()["width"] == width_before                  # the toggle keeps its width
    ui.get_by_role("button", name="Cancel").click()
    ui.get_by_role("button", name="Draw an outline").wait_for()
    assert m.bounding_box()["y"] == before["y"]
    assert ui.errors == []


def test_the_outline_volume_shown_is_the_servers(ui):
    ui.goto(f"/#/surveys/{SURVEY}/volumes")
    ui.get_by_text("Type the corner coordinates").click()
    corners = [(679500.0, 3889230.0), (679510.0, 3889230.0), (679510.0, 3889240.0), (679500.0, 3889240.0)]
    ui.get_by_label(re.compile("One corner per line")).fill("\n".join(f"{e} {n}" for e, n in corners))
    ui.get_by_role("button", name="Use these corners").click()
    quick = ui.get_by_test_id("quick-volume")
    quick.wait_for()
    text = quick.inner_text()
    # the server's figures, written by the one volume rule (decimals from the uncertainty)
    assert "24.44 ± 0.16 m³" in text and "24.50 m³" in text and "0.06 m³" in text, text
    assert "base at 100.12 m" in text, text
    bodies = ui.posted.get(f"/runs/{RUN}/volumes")
    assert bodies and bodies[-1]["base"] == "plane", ui.posted
    ring = bodies[-1]["outline"]["coordinates"][0]
    assert [tuple(c[:2]) for c in ring[:4]] == corners and ring[0] == ring[-1]
    assert ui.errors == []


def test_the_survey_says_where_its_flight_date_comes_from(ui):
    ui.goto(f"/#/surveys/{SURVEY}/volumes")
    date = ui.get_by_test_id("flight-date")
    date.wait_for()
    assert date.inner_text() == "flown 2024-06-24 (from the GNSS data)"
