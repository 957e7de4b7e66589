"""Where the shared real data live: $GEOREF_SHARED_DATA (the 'shared' folder or its 'data') or
<repo>/../shared, then data/<parts...>. Tests that need a file skip when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def shared_path(*parts: str) -> Path:
    """The shared file or folder data/<parts...> (it may not exist: check before use)."""
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else REPO.parent / "shared"
    for cand in (root / "data" / Path(*parts), root / Path(*parts)):
        if cand.exists():
            return cand
    return root / "data" / Path(*parts)


def dji_auckland_dir() -> Path:
    """The real Phantom 4 RTK flight of 2018-10-24 (raw RTCM 3 log, Timestamp.MRK, event log)."""
    return shared_path("dji", "p4rtk_auckland_2018")
