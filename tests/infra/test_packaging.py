"""What the distribution installs: the library and the service under distinct import names.

pyproject lists the packages by hand (the service's folders, `services/`, are mapped to the
import name `bayesian_fields_service`), so a new sub-package that is not listed would be left out
of the wheel. This test compares the list with the folders.
"""

from __future__ import annotations

import tomllib
from importlib.metadata import entry_points
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FOLDERS = {
    "bayesian_fields_core": ROOT / "bayesian_fields_core",
    "bayesian_fields_service": ROOT / "services",
}


def packages_on_disk() -> set[str]:
    found = set()
    for name, folder in FOLDERS.items():
        for init in folder.rglob("__init__.py"):
            parts = init.parent.relative_to(folder).parts
            found.add(".".join([name, *parts]))
    return found


def test_the_package_list_matches_the_folders() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert set(config["packages"]) == packages_on_disk()
    assert config["package-dir"] == {"bayesian_fields_service": "services"}
    assert not any(p == "services" or p.startswith("services.") for p in config["packages"])


def test_the_service_plugs_its_verbs_into_the_cli() -> None:
    from bayesian_fields_core.cli.main import build_parser

    (plugin,) = entry_points(group="bayesian_fields.cli")
    assert plugin.value.startswith("bayesian_fields_service.")
    verbs = build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    assert {"run", "submit", "status", "fetch", "batch", "serve", "view"} <= set(verbs)
    (download,) = entry_points(group="bayesian_fields.job_download")
    assert callable(download.load())
