"""Bring a database to the latest schema: `python -m backend.db.migrate [DATABASE_URL]`."""

from __future__ import annotations

import sys
from pathlib import Path

from alembic import command
from alembic.config import Config

INI = Path(__file__).resolve().parents[1] / "alembic.ini"


def alembic_config(database_url: str) -> Config:
    cfg = Config(str(INI))
    cfg.attributes["database_url"] = database_url
    cfg.attributes["configure_logging"] = False
    return cfg


def upgrade(database_url: str, revision: str = "head") -> None:
    if database_url.startswith("sqlite:///"):
        Path(database_url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
    command.upgrade(alembic_config(database_url), revision)


def downgrade(database_url: str, revision: str = "base") -> None:
    command.downgrade(alembic_config(database_url), revision)


def main(argv: list[str] | None = None) -> int:
    from ..core.settings import get_settings

    argv = sys.argv[1:] if argv is None else argv
    url = argv[0] if argv else get_settings().resolved_database_url()
    upgrade(url)
    print(f"database at the latest schema: {url.split('@')[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
