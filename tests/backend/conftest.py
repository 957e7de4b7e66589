"""Fixtures of the platform tests: a PostgreSQL + Redis platform and an embedded (SQLite) platform,
each with its own database created and dropped here; a simulated small survey shared by the session."""

from __future__ import annotations

import pytest

from .platform_helpers import close_platform, have_postgres, have_redis, make_platform, simulate_small


@pytest.fixture(scope="session")
def small_survey(tmp_path_factory):
    return simulate_small(tmp_path_factory.mktemp("sim") / "site", seed=7)


@pytest.fixture(scope="module", params=["postgres", "embedded"])
def platform(request, tmp_path_factory):
    if request.param == "postgres" and not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed for the production shape")
    p = make_platform(tmp_path_factory.mktemp(request.param), request.param)
    yield p
    close_platform(p)


@pytest.fixture(scope="module")
def pg_platform(tmp_path_factory):
    if not (have_postgres() and have_redis()):
        pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed")
    p = make_platform(tmp_path_factory.mktemp("pg"), "postgres")
    yield p
    close_platform(p)
