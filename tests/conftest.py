"""Test-session wiring shared by every test folder.

``make test`` runs ``pytest -n 2 --dist loadgroup``: tests are spread one by one over the two workers, except
those of a module that share a module-scoped fixture (a simulated survey and its georeferencing, a platform
with its servers and worker): a module's such tests are one group, run by one worker, so the fixture is built
once instead of once per worker. xdist sends the groups with the most tests first, the single tests after
them, which also keeps the end of the run balanced. Session-scoped fixtures are shared between the workers
by tests/once_per_session.py.
"""

from __future__ import annotations

import pytest


def _uses_module_fixture(item: pytest.Item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return False
    for defs in info.name2fixturedefs.values():
        if defs and defs[-1].scope == "module":
            return True
    return False


@pytest.hookimpl(tryfirst=True)   # before xdist's worker reads the marks (--dist loadgroup)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if _uses_module_fixture(item) and not any(item.iter_markers("xdist_group")):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::", 1)[0]))
