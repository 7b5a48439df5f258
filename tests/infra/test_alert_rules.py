"""The shipped alert rules and dashboard (deploy/prometheus, deploy/grafana): `promtool check rules`
passes (Debian's `prometheus` package; skipped, saying so, where promtool is not installed), the
PrometheusRule manifest carries exactly alerts.yaml's groups, every alert has what the docs'
runbook links need, and the name check that tests/services/api/test_metrics_exported.py runs on a
real scrape rejects a misspelled metric (so its passing means something)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from tests.support.observability import (
    ALERTS,
    PROMETHEUS_RULE,
    REPO,
    alert_rules,
    dashboard_queries,
    expressions,
    unexported,
)

OPERATING = REPO / "docs" / "operations" / "operating.md"


def _promtool(*args: str) -> subprocess.CompletedProcess[str]:
    exe = shutil.which("promtool")
    if exe is None:
        pytest.skip("promtool is not on PATH (Debian: apt-get install prometheus; .ci/run installs it)")
    return subprocess.run([exe, *args], capture_output=True, text=True, timeout=60, check=False)


def test_promtool_checks_the_rules() -> None:
    result = _promtool("check", "rules", str(ALERTS))
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"SUCCESS: {len(alert_rules())} rules found" in result.stdout, result.stdout


def test_promtool_rejects_a_broken_rule(tmp_path: Path) -> None:
    broken = tmp_path / "alerts.yaml"
    broken.write_text(
        ALERTS.read_text().replace("min(bfields_database_up) == 0", "min(bfields_database_up ==", 1)
    )
    result = _promtool("check", "rules", str(broken))
    assert result.returncode != 0, result.stdout


def test_the_prometheus_rule_manifest_carries_the_same_rules() -> None:
    manifest = yaml.safe_load(PROMETHEUS_RULE.read_text())
    assert manifest["apiVersion"] == "monitoring.coreos.com/v1" and manifest["kind"] == "PrometheusRule"
    assert (
        manifest["metadata"]["namespace"]
        == yaml.safe_load((REPO / "deploy" / "kustomization.yaml").read_text())["namespace"]
    )
    assert manifest["spec"] == yaml.safe_load(ALERTS.read_text()), (
        "deploy/prometheus/prometheus-rule.yaml's spec must be alerts.yaml verbatim: copy the groups over"
    )


def test_the_alerts_the_issue_asks_for_are_there_each_with_a_runbook_section() -> None:
    rules = {rule["alert"]: rule for rule in alert_rules()}
    assert {"BfieldsDatabaseDown", "BfieldsRedisDown", "BfieldsNoLeader", "BfieldsJobsStalled",
            "BfieldsCallbackOutboxOld", "BfieldsStageQueueWaitHigh"} <= set(rules)  # fmt: skip
    docs = OPERATING.read_text()
    for name, rule in rules.items():
        assert rule["labels"]["severity"] in ("critical", "warning"), name
        assert rule["annotations"]["runbook"] == f"docs/operations/operating.md#{name.lower()}", name
        assert f"### {name}" in docs, f"{name} has no section in {OPERATING.relative_to(REPO)}"


def test_every_dashboard_panel_has_a_query_and_the_name_check_catches_a_misspelling() -> None:
    assert len(dashboard_queries()) >= 15
    exported = {"bfields_stage_seconds_bucket", "bfields_database_up"}
    assert (
        unexported({"ok": "histogram_quantile(0.9, rate(bfields_stage_seconds_bucket[5m]))"}, exported) == {}
    )
    assert unexported({"typo": "rate(bfields_stage_secs_bucket[5m])"}, exported) == {
        "typo": {"bfields_stage_secs_bucket"}
    }
    assert unexported({"none": "up == 0"}, exported) == {"none": {"<none>"}}
    assert len(expressions()) == len(alert_rules()) + len(dashboard_queries())
