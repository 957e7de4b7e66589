"""End-to-end tests of the browser application in headless Chromium against the real platform (API,
Celery worker, SQLite): what a site manager does, checked against the API and the science library.

Screenshots of the main views: GEOREF_UI_SCREENSHOTS=1 .venv/bin/python -m pytest tests/frontend -k flow
writes docs/images/ui-*.png."""

from __future__ import annotations

import json
import re
import urllib.request

import pytest

from . import e2e_platform
from .ui_helpers import (horizontal_overflow, login, residual_cells, shot, survey_files, unlabelled_controls,
                         world_to_screen)

RUN_TIMEOUT_MS = 240_000


def api_json(page, path: str):
    r = page.request.get(f"/api/v1{path}")
    assert r.ok, f"GET {path}: {r.status} {r.text()[:300]}"
    return r.json()


def test_sign_in_errors_and_keyboard(page):
    page.goto("/")
    # the first focusable fields are the e-mail, the password, then the button (Tab order)
    page.get_by_label("E-mail").focus()
    page.keyboard.press("Tab")
    assert page.evaluate("document.activeElement.id") == "password"
    page.keyboard.press("Tab")
    assert page.evaluate("document.activeElement.textContent") == "Sign in"
    page.get_by_label("E-mail").fill(e2e_platform.DEMO_EMAIL)
    page.get_by_label("Password").fill("not-the-password")
    page.keyboard.press("Enter")
    alert = page.get_by_role("alert")
    alert.wait_for()
    assert "password is wrong" in alert.inner_text()
    assert unlabelled_controls(page) == []
    login(page)
    page.get_by_role("heading", name="Sites").wait_for()
    card = page.locator(".site-card", has_text=e2e_platform.DEMO_SITE)
    card.wait_for()
    # the card's figures arrive after the card itself: wait for them (a slow machine shows "Loading figures...")
    card.filter(has_text=re.compile("No survey yet|Latest survey")).wait_for(timeout=60_000)
    # signing out returns to the sign-in form, and the session is gone on the server too
    page.get_by_role("button", name="Sign out").click()
    page.get_by_role("heading", name="Sign in to Georef").wait_for()
    assert page.request.get("/api/v1/auth/me").status == 401
    assert page.errors == []


def test_preflight_finds_problems_before_upload(page, small_site, tmp_path):
    """Navigation missing and no rover/base overlap are reported in the browser, before any upload."""
    login(page)
    page.get_by_role("link", name=e2e_platform.DEMO_SITE).click()
    page.get_by_role("button", name="New survey").click()
    page.get_by_label("Survey name").fill("Pre-flight check")
    page.get_by_role("button", name="Create and upload data").click()
    page.get_by_text("Drop the flight's folder here").wait_for()
    # a base file from another day: shift the TIME OF FIRST/LAST OBS header lines and epochs by one day
    base = (small_site / "base" / "base.obs").read_text()
    shifted = re.sub(r"(?m)^(>? ?\s*2024\s+0?6\s+)24", lambda m: m.group(1) + "23", base)
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "base_other_day.obs").write_text(shifted)
    files = [str(small_site / "rover" / "rover.obs"), str(tmp_path / "base" / "base_other_day.obs")]
    files += [str(p) for p in sorted((small_site / "images").iterdir())[:3]]
    page.locator("input[data-testid=file-input]").set_input_files(files)
    page.get_by_role("heading", name="What was found").wait_for()
    problems = page.locator(".problems")
    problems.wait_for()
    codes = problems.locator("li").evaluate_all("els => els.map(e => e.dataset.code)")
    text = problems.inner_text()
    assert "missing_nav" in codes and "Navigation data missing" in text
    assert "no_overlap" in codes and "2024-06-23" in text and "2024-06-24" in text
    # 12 camera events in the rover file for 3 photos: no "without events" warning, but points are missing
    assert "images_without_events" not in codes
    assert page.locator(".group-rover").inner_text().count("12 camera events") == 1
    assert unlabelled_controls(page) == []
    assert page.errors == []


def test_site_manager_flow(page, small_site, ui_platform, tmp_path):
    """Sign in, upload the small simulated survey, watch it process, read the check-point residuals
    (equal to the API's), outline a stockpile and read its volume, download the results."""
    login(page)
    page.get_by_role("heading", name="Sites").wait_for()
    page.get_by_role("link", name=e2e_platform.DEMO_SITE).click()
    page.get_by_role("heading", name=e2e_platform.DEMO_SITE).wait_for()

    # --- a new survey and its data
    page.get_by_role("button", name="New survey").click()
    page.get_by_label("Survey name").fill("Flight 24 June")
    page.get_by_label("Flight date").fill("2024-06-24")
    page.get_by_role("button", name="Create and upload data").click()
    page.get_by_text("Drop the flight's folder here").wait_for()
    page.locator("input[data-testid=file-input]").set_input_files(survey_files(small_site))
    page.get_by_role("heading", name="What was found").wait_for()
    assert "rover.obs" in page.locator(".group-rover").inner_text()
    assert "base.obs" in page.locator(".group-base").inner_text()
    assert "12 photos" in page.locator(".group-images").inner_text()
    assert "3 control, 2 check" in page.locator(".group-points").inner_text()
    page.get_by_text("Everything needed for processing is there.").wait_for()
    assert unlabelled_controls(page) == []
    shot(page, "upload")
    page.get_by_role("button", name=re.compile(r"^Upload \d+ files")).click()
    page.get_by_text("all files uploaded").wait_for(timeout=60000)
    page.get_by_text("Ready to process.").wait_for()
    survey_id = re.search(r"#/surveys/([^/]+)/", page.url).group(1)
    files = api_json(page, f"/surveys/{survey_id}/files")
    paths = {f["path"] for f in files}
    assert {"rover/rover.obs", "base/base.obs", "nav/base.nav", "gcp/points.csv", "events.csv"} <= paths
    assert sum(p.startswith("images/") for p in paths) == 12
    # what the browser computed is what the server stored (SHA-256 of the local files)
    import hashlib

    local = hashlib.sha256((small_site / "rover" / "rover.obs").read_bytes()).hexdigest()
    assert next(f for f in files if f["path"] == "rover/rover.obs")["sha256"] == local

    # --- processing, live
    page.get_by_role("button", name="Start processing").click()
    page.get_by_role("heading", name=re.compile(r"^Run 1")).wait_for()
    page.locator(".live").wait_for()
    page.locator("li.step-succeeded[data-step=gnss]").wait_for(timeout=RUN_TIMEOUT_MS)
    page.wait_for_timeout(1500)   # the next step's progress and the log lines arrive
    shot(page, "processing")
    run_id = re.search(r"run=([0-9a-f-]+)", page.url).group(1)
    page.locator(".run-panel .page-head .pill-succeeded, .run-panel .page-head .pill-failed, "
                 ".run-panel .page-head .pill-cancelled").wait_for(timeout=RUN_TIMEOUT_MS)
    run = api_json(page, f"/runs/{run_id}")
    steps = {s["name"]: s for s in run["step_details"]}
    shown = {li.get_attribute("data-step"): li.get_attribute("class") for li in page.locator("li.step").all()}
    for name, s in steps.items():
        assert f"step-{s['state']}" in shown[name], (name, s["state"], shown[name])
    assert page.locator(".log-box").inner_text().count("run 1 created") == 1
    failed = {n: s["error"] for n, s in steps.items() if s["state"] == "failed"}
    assert not failed, f"processing failed: {failed}"
    assert steps["gnss"]["state"] == "succeeded"
    for piece in ("georef", "dense"):
        if steps[piece]["state"] != "succeeded":
            pytest.skip(f"the run's {piece} step is {steps[piece]['state']} ({steps[piece]['error']}): the accuracy "
                        "and volume parts of this test wait for it")
    assert run["state"] == "succeeded"

    # --- accuracy: the table shows the API's values
    page.get_by_role("link", name="Accuracy").click()
    page.locator("[data-testid=residual-table]").first.wait_for()
    api_res = api_json(page, f"/runs/{run_id}/results/residuals")
    shown = residual_cells(page)
    checks = [p for p in api_res["points"] if str(p.get("role", "check")).startswith("check")]
    assert checks, "the simulated survey has 2 check points"
    assert set(shown) == {p["name"] for p in checks}
    for p in checks:
        want = [p["dx_m"], p["dy_m"], p["dz_m"], p.get("d_m") or p.get("d3_m")]
        got = [float(v.replace("+", "")) for v in shown[p["name"]]]
        for w, g in zip(want, got):
            assert g == pytest.approx(w * 100, abs=0.051), (p["name"], want, got)   # cm, 1 decimal
    rmse_dz = float(page.locator("[data-testid=residual-table]").first.locator("tfoot tr[data-stat=rmse] td.num").nth(2).inner_text())
    expect = (sum(p["dz_m"] ** 2 for p in checks) / len(checks)) ** 0.5 * 100
    assert rmse_dz == pytest.approx(expect, abs=0.051)
    # sorting by |dh| puts the larger vertical residual first
    table = page.locator("[data-testid=residual-table]").first
    table.get_by_role("button", name=re.compile(r"^dh")).click()   # numbers sort largest |value| first
    assert table.locator("th[aria-sort=descending]").inner_text().startswith("dh")
    first = table.locator("tbody tr").first.get_attribute("data-point")
    assert first == max(checks, key=lambda p: abs(p["dz_m"]))["name"]
    page.locator(".chart svg").first.wait_for()
    assert unlabelled_controls(page) == []
    shot(page, "accuracy")

    # --- the map
    page.get_by_role("link", name="Map").click()
    page.get_by_label("Surface model (DSM)").check()
    page.wait_for_function("() => (document.querySelector('[data-testid=map]')?.dataset.rasters || '').includes('dsm-overview')",
                           timeout=30000)
    shot(page, "map")

    # --- volumes: outline a true stockpile of the simulator by clicking on the map
    truth = json.loads((small_site / "truth" / "stockpiles.geojson").read_text())
    pile = truth["features"][0]
    ring = pile["geometry"]["coordinates"][0][:-1]
    page.get_by_role("link", name="Volumes").click()
    page.wait_for_function("() => (document.querySelector('[data-testid=map]')?.dataset.rasters || '').includes('overview')",
                           timeout=30000)
    volume_posts = []
    page.on("request", lambda r: volume_posts.append(r) if r.method == "POST" and r.url.endswith("/volumes") else None)
    page.get_by_role("button", name="Draw an outline").click()
    # 12 corners around the pile, 0.6 m outside its toe; the base: a plane through the outline (sloping ground)
    cx = sum(c[0] for c in ring) / len(ring)
    cy = sum(c[1] for c in ring) / len(ring)
    corners = []
    for k in range(0, len(ring), max(1, len(ring) // 12)):
        x, y = ring[k][0], ring[k][1]
        d = ((x - cx) ** 2 + (y - cy) ** 2) ** 0.5
        corners.append((cx + (x - cx) * (d + 0.6) / d, cy + (y - cy) * (d + 0.6) / d))
    for x, y in corners:
        sx, sy = world_to_screen(page, x, y)
        page.mouse.click(sx, sy)
    page.keyboard.press("Enter")
    page.get_by_label("Base (what the volume is measured above)").select_option("plane")
    quick = page.locator("[data-testid=quick-volume]")
    quick.wait_for(timeout=30000)
    net = float(quick.locator("dd").nth(2).get_attribute("data-value"))
    true_volume = pile["properties"].get("volume_m3") or pile["properties"].get("analytic_volume_m3")
    assert net > 0
    if true_volume:
        assert net == pytest.approx(true_volume, rel=0.15), (net, true_volume)
    # the same outline and base through the science library on the run's DSM (exact cell coverage)
    from georef_core.steps.volumes import run_volumes

    dsm = tmp_path / "dsm.tif"
    dsm.write_bytes(page.request.get(f"/api/v1/runs/{run_id}/results/dsm").body())
    poly = tmp_path / "pile.geojson"
    poly.write_text(json.dumps({"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"name": "A"},
                    "geometry": {"type": "Polygon", "coordinates": [[*map(list, corners), list(corners[0])]]}}]}))
    core = run_volumes(dsm, poly, base="plane", polygon_crs=e2e_platform.DEMO_CRS)["results"][0]
    assert net == pytest.approx(core["net_m3"], rel=0.05, abs=0.3), (net, core["net_m3"])
    # the figure shown is the server's (POST /runs/{id}/volumes: the volumes step's computation, what the
    # saved stockpile gets), not a second estimate made in the browser
    asked = [r for r in volume_posts if r.url.endswith(f"/runs/{run_id}/volumes")]
    assert asked, "the outline's volume was not asked of the server"
    body = json.loads(asked[-1].post_data)
    assert body["base"] == "plane"
    csrf = next(c["value"] for c in page.context.cookies() if c["name"] == "georef_csrf")
    server = page.request.post(f"/api/v1/runs/{run_id}/volumes", data=json.dumps(body),
                               headers={"X-CSRF-Token": csrf, "Content-Type": "application/json"})
    assert server.ok, server.text()
    assert net == pytest.approx(server.json()["volume_m3"], abs=1e-9), (net, server.json()["volume_m3"])
    page.get_by_label("Name").fill("Pile A")
    shot(page, "volumes")
    page.get_by_role("button", name="Save stockpile").click()
    page.get_by_text("Not measured in this run: Pile A").wait_for()
    assert api_json(page, f"/sites/{ui_platform.site_id}/stockpiles")[0]["name"] == "Pile A"

    # --- downloads
    page.get_by_role("link", name="Downloads").click()
    page.get_by_role("heading", name="Check-point residuals").wait_for()
    csv_link = page.locator(".product", has_text="Check-point residuals").get_by_role("link", name="CSV")
    r = page.request.get(csv_link.get_attribute("href"))
    assert r.ok and "dx" in r.text().splitlines()[0]
    shot(page, "downloads")
    # "Open in QGIS / GIS": the URLs shown with a new tile token work without the session (as in a GIS client)
    page.get_by_role("button", name="Create a tile token").click()
    wmts_url = page.get_by_role("textbox", name="WMTS capabilities URL").input_value()
    ortho_url = page.get_by_role("textbox", name=re.compile("XYZ tiles: ortho")).input_value()
    with urllib.request.urlopen(wmts_url, timeout=30) as resp:
        assert b"<Capabilities" in resp.read(2000)
    with urllib.request.urlopen(ortho_url.format(z=0, x=0, y=0), timeout=60) as resp:
        assert resp.headers["Content-Type"] == "image/png" and resp.read(8) == b"\x89PNG\r\n\x1a\n"

    # --- the overview: the site's card shows the latest survey, its state and the check RMSE of the API
    page.goto("/")
    card = page.locator(".site-card", has_text=e2e_platform.DEMO_SITE)
    card.get_by_text("Check RMSE (3D)").wait_for()
    page.locator(".site-card .pill-succeeded").wait_for()
    rmse3d = (sum(p["dx_m"] ** 2 + p["dy_m"] ** 2 + p["dz_m"] ** 2 for p in checks) / len(checks)) ** 0.5 * 100
    assert f"{rmse3d:.1f} cm" in card.inner_text()
    assert "Flight 24 June" in card.inner_text()
    shot(page, "sites")

    # --- a tablet: no sideways scrolling on the main views
    page.set_viewport_size({"width": 820, "height": 1180})
    for url in [f"/#/sites/{ui_platform.site_id}"] + [f"/#/surveys/{survey_id}/{t}" for t in ("accuracy", "volumes", "processing", "upload")]:
        page.goto(url)
        page.locator("main h1").wait_for()
        page.wait_for_timeout(300)
        assert horizontal_overflow(page) <= 0, url
    page.goto(f"/#/surveys/{survey_id}/accuracy")
    page.locator("[data-testid=residual-table]").first.wait_for()
    shot(page, "tablet-accuracy")
    assert page.errors == []
