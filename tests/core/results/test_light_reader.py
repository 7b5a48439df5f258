"""The result reader is light (issue 31, item 2): importing it in a fresh process loads only the
standard library, numpy and the project's own numpy-only modules, and takes < 0.3 s (median of
five fresh processes), so a robot-side process can read the id map and tables without torch.

The time is numpy's import plus ours. On a machine whose cores other work keeps busy, numpy alone
can take 0.3 s, so the budget is 0.3 s or numpy's own time plus `OWN_BUDGET_S`, whichever is
larger, and our share alone must stay under `OWN_BUDGET_S` (it was ~4 s with torch and scipy)."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys

import pytest

ALLOWED_THIRD_PARTY = {"numpy"}
"""Top-level packages besides the standard library the import may load."""

ALLOWED_PROJECT = {
    "bayesian_fields_core",
    "bayesian_fields_core.errors",
    "bayesian_fields_core.geometry",
    "bayesian_fields_core.geometry.box",
    "bayesian_fields_core.job",
    "bayesian_fields_core.job.atomic",  # temp files for atomic writes: os and secrets only
    "bayesian_fields_core.job.artifacts",
    "bayesian_fields_core.job.store",
    "bayesian_fields_core.objects",
    "bayesian_fields_core.objects.not_found",
    "bayesian_fields_core.objects.scores",
    "bayesian_fields_core.results",
    "bayesian_fields_core.results.format",
    "bayesian_fields_core.results.keys",
    "bayesian_fields_core.results.reader",
}
"""The project's modules on the reader's import chain (each imports only the above)."""

PROBE = """
import json, sys, time
t0 = time.perf_counter()
import numpy
t1 = time.perf_counter()
import bayesian_fields_core.results
t2 = time.perf_counter()
print(json.dumps({"numpy": t1 - t0, "own": t2 - t1, "seconds": t2 - t0, "modules": sorted(sys.modules),
                  "stdlib": sorted(sys.stdlib_module_names)}))
"""

BUDGET_S = 0.3
OWN_BUDGET_S = 0.1


def _probe() -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def _foreign(report: dict) -> set[str]:
    """Loaded modules outside the standard library, numpy and the allowed project modules."""
    stdlib = set(report["stdlib"])
    out = set()
    for name in report["modules"]:
        top = name.split(".")[0]
        if top in stdlib or top in ALLOWED_THIRD_PARTY or top.startswith("_") or top == "__main__":
            continue  # `_`-prefixed tops are CPython's own (_io, _ctypes) or the editable-install hook
        if top == "bayesian_fields_core" and name in ALLOWED_PROJECT:
            continue
        out.add(name)
    return out


def test_reader_import_loads_only_stdlib_numpy_and_light_project_modules() -> None:
    report = _probe()
    assert not _foreign(report), sorted(_foreign(report))
    for heavy in ("torch", "scipy", "PIL", "numba", "sklearn", "pydantic", "rich", "skimage"):
        assert heavy not in report["modules"]


@pytest.mark.slow
def test_reader_import_is_fast() -> None:
    probes = [_probe() for _ in range(5)]
    total, numpy_s, own = (statistics.median(p[k] for p in probes) for k in ("seconds", "numpy", "own"))
    assert own < OWN_BUDGET_S, probes
    assert total < max(BUDGET_S, numpy_s + OWN_BUDGET_S), (total, numpy_s)


def test_the_writer_is_still_reachable_from_the_package() -> None:
    from bayesian_fields_core.results import write_result
    from bayesian_fields_core.results.writer import write_result as direct

    assert write_result is direct
