"""The browser's pre-check and the server use one set of file-kind names (issue 24): GET /file-kinds serves the
server's (backend/services/file_kinds.served_kinds); frontend/tests/fixtures/file_kinds.json, which the vitest
tests/fileKinds.test.ts compares with the names in frontend/src/lib/sniff.ts, must be what it serves. Regenerate:
.venv/bin/python -c "import json; from backend.services.file_kinds import served_kinds;
print(json.dumps(served_kinds(), indent=1))" > frontend/tests/fixtures/file_kinds.json"""

from __future__ import annotations

import json
from pathlib import Path

from backend.services.file_kinds import HINT_ALIASES, HINTS, served_kinds

FIXTURE = Path(__file__).resolve().parents[2] / "frontend" / "tests" / "fixtures" / "file_kinds.json"


def test_the_ui_fixture_is_what_the_server_serves():
    assert json.loads(FIXTURE.read_text()) == served_kinds()


def test_old_hint_spellings_still_accepted():
    assert all(new in HINTS for new in HINT_ALIASES.values())
    assert not set(HINT_ALIASES) & set(HINTS)
