"""Worker tests share the platform fixtures of tests/backend, and one factory for a platform closed after
the test (its database, storage, broker and any worker it started)."""

import pytest

from ..backend.conftest import small_survey  # noqa: F401  (fixture re-export)
from ..backend.platform_helpers import close_platform, have_postgres, have_redis, make_platform


@pytest.fixture
def platform(tmp_path):
    """platform(shape, queue, **settings) -> a Platform (platform_helpers.make_platform) in the test's folder;
    a "postgres" shape skips the test when PostgreSQL or Redis is not running."""
    made = []

    def make(shape: str, queue: str, **overrides):
        if shape == "postgres" and not (have_postgres() and have_redis()):
            pytest.skip("PostgreSQL (127.0.0.1:5432) and Redis (127.0.0.1:6379) are needed")
        p = make_platform(tmp_path, shape, queue=queue, **overrides)
        made.append(p)
        return p

    yield make
    for p in made:
        close_platform(p)
