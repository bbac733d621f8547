"""schemathesis against the API's own OpenAPI schema: no request gets a 5xx.

Every operation is called with generated parameters and bodies, as a superuser's API
key, through Django's WSGI handler (in process, in the test's database). A printer
with the slug the generator favours exists, so handlers run past the lookup too.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import schemathesis
from django.core.wsgi import get_wsgi_application
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error

from printhost.api import api

schema = schemathesis.openapi.from_dict(api.get_openapi_schema())
schema.app = get_wsgi_application()


@pytest.fixture
def api_key(db: None, storage: Path) -> str:
    from django.contrib.auth import get_user_model

    from printers.models import Printer
    from printhost.access import issue_key

    Printer.objects.create(name="Fuzz", slug="fuzz", port="/dev/null")
    user = get_user_model().objects.create_superuser("fuzz", password="fuzz")
    return issue_key(user, "fuzz")[1]


@schema.parametrize()
@settings(
    max_examples=15,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
def test_no_request_gets_a_server_error(case: schemathesis.Case, api_key: str):
    response = case.call(headers={"X-Api-Key": api_key})
    case.validate_response(response, checks=[not_a_server_error])
