"""Property-based fuzzing of every operation of the OpenAPI document with schemathesis (bounded number
of examples per operation), authenticated with an admin API token of a user who owns a site with a
survey: no request may produce a server error, and every error is RFC 9457 problem+json."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from .platform_helpers import POINTS_CSV, Api, add_user, upload_bytes

MAX_EXAMPLES = 6
STATUS: dict = {}
KNOWN: dict = {}   # real ids substituted in every other request, so handlers run past the lookup


@pytest.fixture(scope="module")
def fuzz_token(platform):
    add_user(platform, f"fuzz-{platform.shape}@example.org", org_admin=True)
    api = Api(platform, f"fuzz-{platform.shape}@example.org")
    site = api.post("/api/v1/sites", json={"name": "Fuzz", "crs": "EPSG:32653"}).json()
    survey = api.post(f"/api/v1/sites/{site['id']}/surveys", json={"name": "F"}).json()
    upload_bytes(api, survey["id"], "points.csv", POINTS_CSV, "points")
    run = api.post(f"/api/v1/surveys/{survey['id']}/runs", json={"steps": ["gnss"]}).json()
    KNOWN.update(site_id=site["id"], survey_id=survey["id"], run_id=run["id"])
    return api.post("/api/v1/tokens", json={"name": "fuzz", "scopes": ["admin"]}).json()["token"]


def _content_type(response) -> str:
    ctype = response.headers.get("content-type", "")
    return (ctype[0] if isinstance(ctype, list) else ctype) or ""


def test_no_server_error(platform, fuzz_token):
    """Every operation, MAX_EXAMPLES generated requests each (schemathesis strategies driven by
    Hypothesis directly: its pytest plugin does not support this pytest version)."""
    from hypothesis import given

    schema = schemathesis.openapi.from_asgi("/openapi.json", platform.app)
    headers = {"Authorization": f"Bearer {fuzz_token}"}
    failures: list[str] = []
    calls = 0
    STATUS.clear()
    for result in schema.get_all_operations():
        op = result.ok()

        @given(case=op.as_strategy())
        @settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck),
                  derandomize=True, database=None)
        def check(case):
            nonlocal calls
            if calls % 2 == 0 and case.method != "DELETE" and case.path_parameters:
                case.path_parameters = {k: KNOWN.get(k, v) for k, v in case.path_parameters.items()}
            if case.path.endswith("/events"):
                case.query = {**(case.query or {}), "max_s": 0.2}
            response = case.call(headers=headers)
            calls += 1
            STATUS[response.status_code] = STATUS.get(response.status_code, 0) + 1
            if response.status_code >= 500:
                failures.append(f"{op.label}: {response.status_code} {response.text[:200]}")
            elif response.status_code >= 400 and not _content_type(response).startswith("application/problem+json"):
                failures.append(f"{op.label}: {response.status_code} as {_content_type(response)}")
        check()
    assert calls > 100
    assert sum(n for code, n in STATUS.items() if code < 300) > 40     # real objects were reached
    assert not failures, "\n".join(failures[:20])
