"""Worker tests share the platform fixtures of tests/backend."""

from ..backend.conftest import small_survey  # noqa: F401  (fixture re-export)
