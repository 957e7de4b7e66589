"""The stockpile inventory fixture of the browser's unit tests (frontend/tests/fixtures/inventory_site.json,
read by frontend/tests/inventory.test.ts) is the JSON the API serves for these piles (services/inventory:
{site_id, site, **build_inventory(...).as_dict()}): this test fails when the core's output changes, so the
browser's table is always tested on what the server really sends.

Rewrite it with:  .venv/bin/python -m tests.frontend.test_inventory_fixture
"""

from __future__ import annotations

import json
from datetime import date
from pathlib import Path

FIXTURE = Path(__file__).resolve().parents[2] / "frontend" / "tests" / "fixtures" / "inventory_site.json"
ON_DATE = "2024-06-30"


def _doc() -> dict:
    from georef_core.deliverables.inventory import Measurement, Pile, build_inventory

    piles = [
        # sand: the material's default density 1.60 +- 0.10 t/m3; two surveys before the date
        Pile("North pile", "sand", measurements=[Measurement(date(2024, 5, 1), "May flight", 80.0, 1.5),
                                                 Measurement(date(2024, 6, 1), "June flight", 100.0, 2.0)]),
        # its own density, one survey: no change yet
        Pile("Gravel bay", "crushed_stone", 1.9, 0.05, [Measurement(date(2024, 6, 1), "June flight", 1523.4, 12.3)]),
        # no density known: volume only
        Pile("Wood chips", "wood chips", measurements=[Measurement(date(2024, 6, 1), "June flight", 10.0, 0.4)]),
        # first surveyed after the date
        Pile("Topsoil heap", "topsoil", measurements=[Measurement(date(2024, 7, 10), "July flight", 55.0, 0.9)]),
    ]
    inv = build_inventory(piles, ON_DATE)
    return json.loads(json.dumps({"site_id": "site-1", "site": "Quarry", **inv.as_dict()}))


def test_the_browser_fixture_is_the_servers_inventory():
    assert FIXTURE.is_file(), f"{FIXTURE} missing: python -m tests.frontend.test_inventory_fixture writes it"
    assert json.loads(FIXTURE.read_text()) == _doc(), \
        "the core's inventory changed: rewrite the fixture (python -m tests.frontend.test_inventory_fixture) and run the vitest"


if __name__ == "__main__":
    FIXTURE.write_text(json.dumps(_doc(), indent=1) + "\n")
    print(f"wrote {FIXTURE}")
