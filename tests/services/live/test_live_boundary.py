"""One package knows Redis's keys and the broker (issue 43 item 2): `services/live/`.

A key written in one module and read in another is an interface; spelled outside `live/` it is
one nobody sees (the job's live key was once defined twice and written a third time inside a Lua
script). So no module of the service outside `live/` holds a string that starts with the
service's key prefix ``bf:`` (an f-string included), and none imports kombu, the broker's client
library (the API's outage answer reads `live.broker.BROKER_ERRORS` instead). The scan reads the
source with `ast`, so a comment or a docstring that *mentions* a key does not count, and a key in
a late import or a nested function does.
"""

from __future__ import annotations

import ast
from pathlib import Path

from tests.support.source_scan import docstring_nodes

ROOT = Path(__file__).resolve().parents[3]
SERVICE = ROOT / "services"
LIVE = SERVICE / "live"
KEY_PREFIX = "bf:"


def key_literals(source: str) -> list[str]:
    """Strings in `source` (plain or the leading text of an f-string) that start with ``bf:``."""
    tree = ast.parse(source)
    docs = docstring_nodes(tree)
    found: list[str] = []
    in_fstring: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            in_fstring.update(id(v) for v in node.values)
            first = node.values[0] if node.values else None
            if isinstance(first, ast.Constant) and str(first.value).startswith(KEY_PREFIX):
                found.append(ast.unparse(node))
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and id(node) not in docs
            and id(node) not in in_fstring
            and node.value.startswith(KEY_PREFIX)
        ):
            found.append(node.value)
    return found


def kombu_imports(source: str) -> list[str]:
    """Every `import kombu...` / `from kombu... import` in `source`, at any depth."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.split(".")[0] == "kombu"]
        elif (
            isinstance(node, ast.ImportFrom)
            and not node.level
            and (node.module or "").split(".")[0] == "kombu"
        ):
            found.append(node.module or "")
    return found


def outside_live() -> list[Path]:
    files = [p for p in sorted(SERVICE.rglob("*.py")) if LIVE not in p.parents]
    assert len(files) > 50, "the scan found too few service modules to mean anything"
    return files


def test_no_redis_key_is_spelled_outside_live() -> None:
    offenders = {
        str(p.relative_to(ROOT)): keys for p in outside_live() if (keys := key_literals(p.read_text()))
    }
    assert offenders == {}, "Redis keys belong in services/live/redis_keys.py"


def test_no_module_outside_live_imports_kombu() -> None:
    offenders = {
        str(p.relative_to(ROOT)): names for p in outside_live() if (names := kombu_imports(p.read_text()))
    }
    assert offenders == {}, "the broker's details belong in services/live/ (broker.BROKER_ERRORS)"


def test_the_keys_and_the_broker_are_in_live() -> None:
    """The scans see what they look for where it is allowed: the keys and kombu are in `live/`."""
    assert key_literals((LIVE / "redis_keys.py").read_text())
    assert kombu_imports((LIVE / "broker.py").read_text()) == ["kombu.exceptions"]


def test_the_scans_can_fail() -> None:
    source = '''
"""bf: a docstring that mentions a key is prose"""
def f(tenant):
    """bf:job: also prose"""
    import kombu.exceptions
    from kombu import Connection
    return f"bf:job:{tenant}", "bf:flight", "bfx:not-ours", f"{tenant}:bf:"
'''
    assert sorted(key_literals(source)) == ["bf:flight", "f'bf:job:{tenant}'"]
    assert kombu_imports(source) == ["kombu.exceptions", "kombu"]
