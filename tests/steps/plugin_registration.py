"""Loading a plug-in step (GEOREF_STEP_PLUGINS) into the test process for one test, and unloading it after:
the step contract, the platform's step catalogue and the module cache as they were."""

from __future__ import annotations

import contextlib
import sys


@contextlib.contextmanager
def plugin_registered(monkeypatch, module: str, step: str):
    from backend.services import steps_catalog
    from georef_core.steps import contract

    monkeypatch.setenv("GEOREF_STEP_PLUGINS", module)
    contract.load_plugins()
    steps_catalog.refresh()
    try:
        yield
    finally:
        contract.unregister(step)
        contract._PLUGINS_LOADED.discard(module)
        sys.modules.pop(module, None)
        monkeypatch.delenv("GEOREF_STEP_PLUGINS")
        steps_catalog.refresh()
