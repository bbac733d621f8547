"""The sample Grafana dashboard names only series (and labels) /metrics exports."""

from __future__ import annotations

import json
import re

import pytest
from prometheus_client.parser import text_string_to_metric_families

from tests.conftest import ROOT

DASHBOARD = ROOT / "docs" / "grafana" / "printhost-farm.json"
#: Labels Prometheus adds to every scraped series.
TARGET_LABELS = {"job", "instance"}
SELECTOR = re.compile(r"\b([a-zA-Z_:][a-zA-Z0-9_:]*)\s*\{([^}]*)\}")
NAME = re.compile(r"\bprinthost_[a-z0-9_]+\b")
MATCHER = re.compile(r"([a-zA-Z_][a-zA-Z0-9_]*)\s*(?:=~|!~|!=|=)")


def expressions(node: object) -> list[str]:
    """Every PromQL text in the dashboard: panel targets and variable queries."""
    found: list[str] = []
    if isinstance(node, dict):
        for key, value in node.items():
            if key in ("expr", "definition") and isinstance(value, str):
                found.append(value)
            else:
                found.extend(expressions(value))
    elif isinstance(node, list):
        for item in node:
            found.extend(expressions(item))
    return found


@pytest.fixture
def exported(db, farm, client, scrape) -> dict[str, set[str]]:
    """{sample name: its label names} of a scrape where every family has samples."""
    client.get("/api/version")  # a request for the latency histogram
    response = client.get("/metrics")
    series: dict[str, set[str]] = {}
    for family in text_string_to_metric_families(response.content.decode()):
        for sample in family.samples:
            series.setdefault(sample.name, set()).update(sample.labels)
    return series


def test_the_dashboard_is_valid_json_with_panels_and_a_printer_variable():
    board = json.loads(DASHBOARD.read_text())
    variables = {v["name"] for v in board["templating"]["list"]}
    assert {"printer", "host"} <= variables
    titles = [p["title"] for p in board["panels"]]
    for wanted in (
        "Heartbeat age",
        "Web latency p95",
        "Celery queue lengths",
        "Job progress",
    ):
        assert wanted in titles


def test_every_expression_names_exported_series_and_their_labels(exported):
    board = json.loads(DASHBOARD.read_text())
    texts = expressions(board)
    assert len(texts) > 20
    unknown, wrong_labels = set(), []
    for text in texts:
        unknown |= {name for name in NAME.findall(text) if name not in exported}
        for name, matchers in SELECTOR.findall(text):
            if name not in exported:
                unknown.add(name)
                continue
            for label in MATCHER.findall(matchers):
                if label not in exported[name] | TARGET_LABELS:
                    wrong_labels.append(f"{name}{{{label}}}")
    assert not unknown, f"not exported by /metrics: {sorted(unknown)}"
    assert not wrong_labels, f"labels these series do not have: {wrong_labels}"


def test_the_check_would_catch_a_series_that_does_not_exist(exported):
    assert "printhost_printer_link_use_ratio" in exported
    assert "printhost_printer_link_usage" not in exported
