"""List endpoints page with limit/offset: the items of the page in order, the total of all matching rows
(X-Total-Count and the body), Link headers to the next and previous pages, and a page past the end that
still reports the total; on both shapes (PostgreSQL and SQLite)."""

from __future__ import annotations

import re

from .platform_helpers import Api, add_user


def test_pages_totals_and_links(platform):
    add_user(platform, "pager@example.org")
    api = Api(platform, "pager@example.org")
    names = [f"Pit {k:02d}" for k in range(7)]
    for n in names:
        r = api.post("/api/v1/sites", json={"name": n, "crs": "EPSG:32631"})
        assert r.status_code == 201, r.text
    seen = []
    url = "/api/v1/sites?limit=3&q=pit"
    pages = 0
    while url:
        r = api.get(url)
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["total"] == 7 and r.headers["x-total-count"] == "7"
        seen += [s["name"] for s in body["items"]]
        pages += 1
        m = re.search(r'<([^>]+)>; rel="next"', r.headers.get("link", ""))
        url = m.group(1).split("://", 1)[-1].split("/", 1)[-1] if m else None
        url = "/" + url if url else None
    assert pages == 3 and seen == sorted(names)            # ordered by name, each exactly once
    last = api.get("/api/v1/sites?limit=3&offset=6&q=pit")
    assert [s["name"] for s in last.json()["items"]] == ["Pit 06"]
    assert 'rel="prev"' in last.headers["link"] and 'rel="next"' not in last.headers["link"]
    past = api.get("/api/v1/sites?limit=3&offset=50&q=pit")
    assert past.status_code == 200 and past.json()["items"] == [] and past.json()["total"] == 7
    none = api.get("/api/v1/sites?q=no-such-pit")
    assert none.json() == {"items": [], "total": 0, "limit": 50, "offset": 0}
