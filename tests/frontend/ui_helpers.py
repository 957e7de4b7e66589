"""Small helpers of the browser tests: log in, read tables, accessibility checks, screenshots."""

from __future__ import annotations

import os
from pathlib import Path

from . import e2e_platform

IMAGES = e2e_platform.REPO / "docs" / "images"


def login(page, email=e2e_platform.DEMO_EMAIL, password=e2e_platform.DEMO_PASSWORD) -> None:
    page.goto("/")
    page.get_by_label("E-mail").fill(email)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()


def shot(page, name: str, full_page: bool = True) -> None:
    """docs/images/ui-NAME.png (only when GEOREF_UI_SCREENSHOTS=1: the committed pictures are not rewritten by every test run)."""
    if os.environ.get("GEOREF_UI_SCREENSHOTS") == "1":
        IMAGES.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(IMAGES / f"ui-{name}.png"), full_page=full_page)


UNLABELLED_JS = """
() => {
  const bad = [];
  for (const el of document.querySelectorAll('input, select, textarea, button, a[href], [role=application]')) {
    if (el.type === 'hidden' || el.closest('[aria-hidden=true]')) continue;
    const st = getComputedStyle(el);
    if (st.display === 'none' || st.visibility === 'hidden') continue;
    const name = (el.getAttribute('aria-label') || '').trim()
      || (el.id && document.querySelector(`label[for="${CSS.escape(el.id)}"]`)?.textContent.trim())
      || el.closest('label')?.textContent.trim()
      || (el.getAttribute('aria-labelledby') && document.getElementById(el.getAttribute('aria-labelledby'))?.textContent.trim())
      || (['BUTTON', 'A'].includes(el.tagName) ? el.textContent.trim() : '')
      || el.getAttribute('title');
    if (!name) bad.push(el.outerHTML.slice(0, 160));
  }
  return bad;
}
"""


def unlabelled_controls(page) -> list[str]:
    """Form controls, buttons and links with no accessible name (label, aria-label or text)."""
    return page.evaluate(UNLABELLED_JS)


def horizontal_overflow(page) -> int:
    """How many CSS pixels the page is wider than the viewport (0 = no sideways scrolling)."""
    return page.evaluate("() => document.documentElement.scrollWidth - window.innerWidth")


def survey_files(site: Path) -> list[str]:
    """The files a site manager would drop: the survey folder without the simulator's truth."""
    out = []
    for p in sorted(site.rglob("*")):
        rel = p.relative_to(site).as_posix()
        if p.is_file() and not rel.startswith("truth/"):
            out.append(str(p))
    return out


def residual_cells(page) -> dict[str, list[str]]:
    """The residual table as {point: [dE, dN, dh, |d|]} (the texts shown)."""
    rows = page.locator("[data-testid=residual-table]").first.locator("tbody tr")
    out = {}
    for i in range(rows.count()):
        r = rows.nth(i)
        name = r.get_attribute("data-point")
        cells = r.locator("td.num")
        out[name] = [cells.nth(k).inner_text().strip() for k in range(4)]
    return out


def world_to_screen(page, x: float, y: float) -> tuple[float, float]:
    """Page coordinates of a site-CRS point on the map (from the map's published view)."""
    m = page.locator("[data-testid=map]").first
    box = m.bounding_box()
    cx, cy, res = (float(v) for v in m.get_attribute("data-view").split(","))
    return box["x"] + box["width"] / 2 + (x - cx) / res, box["y"] + box["height"] / 2 - (y - cy) / res

def fulfil_with_built_file(route, frontend_dist: Path, path: str) -> None:
    """Answer a browser request for ``path`` with the built UI's file (index.html for the app's own routes),
    for the tests that stand in for the API with their own answers."""
    import mimetypes

    f = frontend_dist / path.lstrip("/")
    if path == "/" or not f.is_file():
        f = frontend_dist / "index.html"
    route.fulfill(status=200, body=f.read_bytes(),
                  content_type=mimetypes.guess_type(f.name)[0] or "application/octet-stream")
