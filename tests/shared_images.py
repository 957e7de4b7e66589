"""Where the shared real image sets live: $GEOREF_SHARED_DATA (the 'shared' folder or its 'data') or
<repo>/../shared, then data/images/<name>. Tests that need a set skip when it is absent."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def shared_image_set(name: str) -> Path:
    env = os.environ.get("GEOREF_SHARED_DATA")
    root = Path(env) if env else REPO.parent / "shared"
    for cand in (root / "data" / "images" / name, root / "images" / name):
        if cand.is_dir():
            return cand
    return root / "data" / "images" / name
