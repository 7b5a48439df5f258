"""The architecture page's layer picture is the one `tests/test_layers.py` enforces.

The page (docs/development/architecture.md) draws the library as a chain of one node per floor
and lists the packages in a table, top down; both are checked here against `LAYERS`, so a floor
moved in the test (or on the page) without the other fails with the order to write.
"""

from __future__ import annotations

import re
from pathlib import Path

from tests.test_layers import LAYERS, SERVICE_LAYERS

PAGE = Path(__file__).resolve().parents[1] / "docs" / "development" / "architecture.md"
BASE = {"params", "errors", "__init__"}


def _floor_names() -> list[str]:
    """One name per floor, top down: the package, or 'base' for params/errors."""
    names = []
    for members in LAYERS:
        if members == BASE:
            names.append("base")
        else:
            assert len(members) == 1, f"draw floor {sorted(members)} as one node per package"
            names.append(next(iter(members)))
    return names


def _library_chain(page: str) -> list[str]:
    """The node ids of the mermaid chain starting at `cli -->` (continued on following lines)."""
    chain: list[str] = []
    for line in page.splitlines():
        parts = [p.strip() for p in line.strip().split("-->")]
        if len(parts) < 2 or not all(re.fullmatch(r"\w+", p) for p in parts):
            continue
        if parts[0] == "cli" or (chain and parts[0] == chain[-1]):
            chain += parts if not chain else parts[1:]
    return chain


def test_the_diagram_draws_the_floors_in_order() -> None:
    expected = _floor_names()
    drawn = _library_chain(PAGE.read_text())
    assert drawn == expected, (
        "docs/development/architecture.md's library chain must be tests/test_layers.py's LAYERS, "
        "one node per floor, top down:\n    " + " --> ".join(expected)
    )


def test_the_table_lists_the_packages_top_down() -> None:
    floor_of = {name: i for i, members in enumerate(LAYERS) for name in members}
    table = PAGE.read_text().split("| package | what it holds |", 1)[1]
    rows = []
    for line in table.splitlines()[2:]:  # the table's rows: up to its first non-row line
        if not line.startswith("| `"):
            break
        rows.append(line)
    floors = []
    for row in rows:
        names = [n.rstrip("/").removesuffix(".py") for n in re.findall(r"`([^`]+)`", row.split("|")[1])]
        floors.append(min(floor_of[n] for n in names))
    assert rows and floors == sorted(floors), "order the table's rows by their packages' floors in LAYERS"
    assert {n for members in LAYERS for n in members} - {"__init__"} <= {
        n.rstrip("/").removesuffix(".py") for row in rows for n in re.findall(r"`([^`]+)`", row.split("|")[1])
    }


def test_the_service_diagram_draws_the_service_floors_in_order() -> None:
    """The service's chain (`jobs --> ... --> config`) is `SERVICE_LAYERS` from the jobs domain down,
    the one floor of several adapters drawn as one node, `adapters`."""
    expected = []
    for members in SERVICE_LAYERS[SERVICE_LAYERS.index({"jobs"}) :]:
        if members == {"__init__"}:
            continue
        expected.append(next(iter(members)) if len(members) == 1 else "adapters")
    drawn: list[str] = []
    for line in PAGE.read_text().splitlines():
        parts = [p.strip() for p in line.strip().split("-->")]
        if len(parts) > 2 and parts[0] == "jobs" and all(re.fullmatch(r"\w+", p) for p in parts):
            drawn = parts
    assert drawn == expected, (
        "docs/development/architecture.md's service chain must be tests/test_layers.py's SERVICE_LAYERS "
        "from jobs down, one node per floor (several adapters: `adapters`):\n    " + " --> ".join(expected)
    )
