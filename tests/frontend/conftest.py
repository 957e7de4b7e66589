"""Fixtures of the browser tests: the built UI, the real platform (API + worker + SQLite), Chromium."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from . import e2e_platform

CHROMIUM = os.environ.get("GEOREF_CHROMIUM", "/usr/bin/chromium")
FRONTEND = e2e_platform.REPO / "frontend"


def _dist_is_stale() -> bool:
    index = FRONTEND / "dist" / "index.html"
    if not index.is_file():
        return True
    built = index.stat().st_mtime
    sources = [p for p in (FRONTEND / "src").rglob("*") if p.is_file()] + [FRONTEND / "index.html"]
    return any(p.stat().st_mtime > built for p in sources)


@pytest.fixture(scope="session")
def frontend_dist() -> Path:
    """frontend/dist, built now when missing or older than the sources (needs node/npm)."""
    if _dist_is_stale():
        npm = shutil.which("npm")
        if npm is None:
            pytest.skip("frontend/dist is missing or stale and npm is not installed (make install builds it)")
        if not (FRONTEND / "node_modules").is_dir():
            subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=FRONTEND, check=True, capture_output=True)
        r = subprocess.run([npm, "run", "build"], cwd=FRONTEND, capture_output=True, text=True)
        assert r.returncode == 0, f"frontend build failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return FRONTEND / "dist"


@pytest.fixture(scope="module")
def ui_platform(frontend_dist, tmp_path_factory):
    p = e2e_platform.start(tmp_path_factory.mktemp("ui-platform"))
    yield p
    e2e_platform.stop(p)


@pytest.fixture(scope="session")
def small_site(tmp_path_factory) -> Path:
    return e2e_platform.simulate_small(tmp_path_factory.mktemp("ui-sim") / "site", seed_value=7)


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"Chromium not found at {CHROMIUM} (apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def page(browser, ui_platform):
    ctx = browser.new_context(viewport={"width": 1366, "height": 900}, base_url=ui_platform.url)
    pg = ctx.new_page()
    pg.set_default_timeout(20000)
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.errors = errors
    yield pg
    ctx.close()
