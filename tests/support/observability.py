"""The shipped dashboard's and alert rules' PromQL, and the metric names each of them reads.

Why only names with the ``bfields_`` prefix: every metric the service exports has it and no
label, function or keyword of PromQL does, so the identifiers that start with it are exactly the
metric names an expression reads (a histogram's ``_bucket`` / ``_sum`` / ``_count`` series
included). A test compares them with a real scrape (tests/services/api/test_metrics_exported.py).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
ALERTS = REPO / "deploy" / "prometheus" / "alerts.yaml"
PROMETHEUS_RULE = REPO / "deploy" / "prometheus" / "prometheus-rule.yaml"
DASHBOARD = REPO / "deploy" / "grafana" / "bfields-dashboard.json"

_METRIC = re.compile(r"\bbfields_[a-zA-Z0-9_:]*")


def alert_rules() -> list[dict]:
    """Every rule of alerts.yaml, across its groups."""
    return [rule for group in yaml.safe_load(ALERTS.read_text())["groups"] for rule in group["rules"]]


def dashboard_queries() -> list[tuple[str, str]]:
    """(panel title, PromQL) of every query of every panel of the dashboard (rows hold none)."""
    panels = json.loads(DASHBOARD.read_text())["panels"]
    nested = [child for panel in panels for child in panel.get("panels", [])]
    return [(p["title"], t["expr"]) for p in panels + nested for t in p.get("targets", [])]


def expressions() -> dict[str, str]:
    """{where: PromQL} of every alert rule and dashboard query."""
    found = {f"alert {rule['alert']}": str(rule["expr"]) for rule in alert_rules()}
    for n, (title, expr) in enumerate(dashboard_queries()):
        found[f"panel {title!r} #{n}"] = expr
    return found


def metric_names(expr: str) -> set[str]:
    return set(_METRIC.findall(expr))


def scraped_names(exposition: str) -> set[str]:
    """The sample names of a Prometheus text exposition (``name{labels} value`` or ``name value``)."""
    return {
        re.split(r"[{\s]", line, maxsplit=1)[0]
        for line in exposition.splitlines()
        if line and not line.startswith("#")
    }


def unexported(exprs: dict[str, str], exported: set[str]) -> dict[str, set[str]]:
    """{where: names it reads that `exported` lacks}, for each expression that reads one; an
    expression that reads no ``bfields_`` metric at all is reported too (as reading '<none>')."""
    missing: dict[str, set[str]] = {}
    for where, expr in exprs.items():
        names = metric_names(expr)
        if not names:
            missing[where] = {"<none>"}
        elif names - exported:
            missing[where] = names - exported
    return missing
