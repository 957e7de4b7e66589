"""Engine and session factory for SQLite (embedded) and PostgreSQL (production): one code path."""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Iterator

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker

_lock = threading.Lock()
_databases: dict[str, "Database"] = {}


def _sqlite_pragmas(dbapi_conn, _record) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.close()


def make_engine(url: str) -> Engine:
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30}, pool_size=20,
                               max_overflow=40)
        event.listen(engine, "connect", _sqlite_pragmas)

        # SQLite: take the write lock at BEGIN, so that read-then-write transactions never dead-lock
        # ("database is locked" on upgrade); PostgreSQL has row locks and needs nothing of the sort.
        @event.listens_for(engine, "connect")
        def _no_pysqlite_begin(dbapi_conn, _record):
            dbapi_conn.isolation_level = None

        @event.listens_for(engine, "begin")
        def _begin_immediate(conn):
            read_only = conn.get_execution_options().get("georef_read_only", False)
            conn.exec_driver_sql("BEGIN" if read_only else "BEGIN IMMEDIATE")
        return engine
    # no pre-ping (a round trip per checkout): a connection broken by a database restart fails one
    # request with 503 (see core/problems.py) and is replaced; connections are recycled every 30 min
    return create_engine(url, pool_pre_ping=False, pool_size=20, max_overflow=40, pool_recycle=1800)


class Database:
    def __init__(self, url: str):
        self.url = url
        self.engine = make_engine(url)
        self.sessionmaker = sessionmaker(self.engine, expire_on_commit=False)
        # read-only requests (GET) on SQLite begin a deferred transaction so that readers run in parallel
        read_engine = self.engine.execution_options(georef_read_only=True)
        if not url.startswith("sqlite"):
            # PostgreSQL: reads in autocommit, no BEGIN/ROLLBACK round trips around each request
            read_engine = self.engine.execution_options(georef_read_only=True, isolation_level="AUTOCOMMIT")
        self.read_sessionmaker = sessionmaker(read_engine, expire_on_commit=False)

    @property
    def is_sqlite(self) -> bool:
        return self.url.startswith("sqlite")

    @contextmanager
    def session(self, read_only: bool = False) -> Iterator[Session]:
        s = (self.read_sessionmaker if read_only else self.sessionmaker)()
        try:
            yield s
            s.commit()
        except BaseException:
            s.rollback()
            raise
        finally:
            s.close()


def get_database(url: str) -> Database:
    with _lock:
        db = _databases.get(url)
        if db is None:
            db = _databases[url] = Database(url)
        return db


def dispose_all() -> None:
    with _lock:
        for db in _databases.values():
            db.engine.dispose()
        _databases.clear()
