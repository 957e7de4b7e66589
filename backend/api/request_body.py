"""A raw request body received into a temporary file of the work folder, never more than a limit: the
chunk uploads and the site's design file (no database transaction is open while the bytes arrive)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import Request

from ..core.limits import SPOOLED_BODY_KEY
from ..core.problems import PayloadTooLarge


@contextlib.asynccontextmanager
async def body_in_temp_file(request: Request, work_dir: Path, prefix: str, limit: int, too_long: str,
                            suffix: str = "") -> AsyncIterator[tuple[Path, int]]:
    """(the file, the bytes received); 413 with ``too_long`` once the body passes ``limit`` bytes. The file
    is removed when the block ends (whoever keeps the bytes copies or moves them inside it).

    A body that core/limits.py RequestBodyGuard already spooled to a file of the work folder is that file,
    renamed (its bytes are not read back and written again: a 64 MiB chunk is written once, where it was
    received, and moved into a local store from there)."""
    tmp_dir = work_dir / "tmp"
    tmp_dir.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=tmp_dir)
    try:
        spooled = request.scope.get(SPOOLED_BODY_KEY)
        taken = spooled.take() if spooled is not None and spooled.size <= limit else None
        if taken is not None:
            os.close(fd)
            try:
                os.replace(taken, tmp)
            except OSError:
                taken.unlink(missing_ok=True)
                raise
            received = spooled.size
        else:
            received = 0
            with os.fdopen(fd, "wb") as f:
                async for block in request.stream():
                    received += len(block)
                    if received > limit:
                        raise PayloadTooLarge(too_long)
                    f.write(block)
        yield Path(tmp), received
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
