"""HTTP client of the batch service and the `bfields submit|status|fetch|batch` commands.

The names below are loaded on first use (PEP 562), so importing a light submodule (`verbs`, which
`bfields` loads for every command) does not pull in httpx and rich through this package.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_WHERE = {
    "BFieldsClient": "api",
    "ClientError": "api",
    "batch": "commands",
    "fetch": "commands",
    "status": "commands",
    "submit": "commands",
    "register_client_commands": "verbs",
}


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)


__all__ = ["BFieldsClient", "ClientError", "batch", "fetch", "register_client_commands", "status", "submit"]
