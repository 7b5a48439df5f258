"""Fuzz-suite plumbing: the case budget and the case count (each module sets `pytestmark` fuzz).

`BFIELDS_FUZZ_SCALE` scales every test's CI budget (`budget(n)` examples): unset, a normal
`pytest -q` run takes a 1 % sample (at least 5 cases a test) so the suite stays quick; `.ci/fuzz.sh`
sets it to 1 for the full >= 10,000-case run. Every executed case is counted and the totals are
printed at the end of the session, per test and overall. The API fuzz tests' real-stack fixtures
(`api`, `scene_dir`, `stored_scene`) come from `tests/services/support/stack_fixtures.py` through the root conftest.
"""

from __future__ import annotations

import os
from collections import Counter

from hypothesis import HealthCheck, settings

CASES: Counter[str] = Counter()


def budget(ci_examples: int) -> settings:
    """Hypothesis settings for a test that runs `ci_examples` cases in the full CI run."""
    scale = float(os.environ.get("BFIELDS_FUZZ_SCALE", "0.01"))
    return settings(
        max_examples=max(5, int(ci_examples * scale)),
        deadline=None,
        database=None,
        derandomize=os.environ.get("BFIELDS_FUZZ_SEED") is None and scale < 1,
        suppress_health_check=list(HealthCheck),
        print_blob=True,
    )


def count(name: str) -> None:
    CASES[name] += 1


def pytest_terminal_summary(terminalreporter) -> None:  # noqa: ANN001
    if not CASES:
        return
    terminalreporter.section("fuzz cases")
    for name, n in sorted(CASES.items()):
        terminalreporter.write_line(f"{n:7d}  {name}")
    terminalreporter.write_line(f"{sum(CASES.values()):7d}  total")
