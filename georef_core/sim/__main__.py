"""``python -m georef_core.sim OUT_DIR [--seed N] [--small] ...``: simulate a survey into OUT_DIR.

The same command as ``georef simulate`` (:mod:`georef_core.cli.simulate_command`)."""

from __future__ import annotations

from ..cli.simulate_command import main

if __name__ == "__main__":
    raise SystemExit(main())
