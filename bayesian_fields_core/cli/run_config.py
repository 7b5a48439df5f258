"""A run's full configuration, written beside its result and accepted back by ``bfields run --config``.

``<out>/config.yaml`` holds what decides the result: the scene folder, the tasks, every pipeline
parameter (all of them, defaults included, so a later change of a default cannot change a re-run),
the model profile, the splat transform, and the versions that ran it (for the record; they are
not checked on the way back in). Paths are written absolute; a relative path in a hand-written
file is read relative to the file's folder. Flags given beside ``--config`` win over the file.
"""

from __future__ import annotations

import platform
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from bayesian_fields_core.errors import InputError

CONFIG_FILE = "config.yaml"
"""The configuration's name in a run's output folder."""

CONFIG_KIND = "bfields-run-config"
CONFIG_VERSION = 1
"""Bumped when a field changes meaning; a reader refuses versions it does not know."""

_HEADER = "# bfields run configuration: re-run with `bfields run --config {path}` (flags override it)\n"


@dataclass(frozen=True)
class RunConfig:
    """What `bfields run` was asked to do, in the form `config.yaml` stores."""

    scene: Path
    tasks: list[str]
    parameters: dict[str, Any]
    profile: Path | None = None
    splat_transform: Path | None = None
    versions: dict[str, str] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": CONFIG_KIND,
            "version": CONFIG_VERSION,
            "scene": str(self.scene.resolve()),
            "tasks": list(self.tasks),
            "profile": None if self.profile is None else str(self.profile.resolve()),
            "splat_transform": None if self.splat_transform is None else str(self.splat_transform.resolve()),
            "parameters": self.parameters,
            "versions": self.versions,
        }


def running_versions() -> dict[str, str]:
    """The versions of what computes a result: this package, Python, numpy and torch."""
    import numpy
    import torch

    try:
        package = version("bayesian-fields")
    except PackageNotFoundError:  # run from a source tree that was never installed
        from bayesian_fields_core import __version__ as package
    return {
        "bayesian_fields": package,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "torch": str(torch.__version__),
    }


def write_run_config(out: Path, config: RunConfig) -> Path:
    """Write `config` as `out/config.yaml`; returns its path."""
    import yaml

    path = out / CONFIG_FILE
    out.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(config.to_dict(), sort_keys=False, allow_unicode=True)
    path.write_text(_HEADER.format(path=path) + text, encoding="utf-8")
    return path


def read_run_config(path: Path) -> RunConfig:
    """The configuration in `path`, or a one-line error naming the file and the field."""
    import yaml

    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", source=str(path)) from None
    except yaml.YAMLError as exc:
        raise InputError(f"cannot parse YAML: {exc}", source=str(path)) from None
    if not isinstance(data, dict) or data.get("kind") != CONFIG_KIND:
        raise InputError(f"not a run configuration (expected kind: {CONFIG_KIND})", source=str(path))
    if data.get("version") != CONFIG_VERSION:
        raise InputError(
            f"configuration version {data.get('version')!r}; this bfields reads version {CONFIG_VERSION}",
            source=str(path),
        )
    scene = data.get("scene")
    tasks = data.get("tasks")
    parameters = data.get("parameters") or {}
    if not isinstance(scene, str) or not scene:
        raise InputError("scene: expected the scene folder's path", source=str(path))
    if not isinstance(tasks, list) or not all(isinstance(t, str) for t in tasks):
        raise InputError("tasks: expected a list of tasks", source=str(path))
    if not isinstance(parameters, dict):
        raise InputError("parameters: expected a mapping of parameter names to values", source=str(path))

    def where(value: Any, name: str) -> Path | None:
        if value is None:
            return None
        if not isinstance(value, str):
            raise InputError(f"{name}: expected a path or null", source=str(path))
        return path.parent / value  # an absolute value stays absolute

    return RunConfig(
        scene=path.parent / scene,
        tasks=tasks,
        parameters=parameters,
        profile=where(data.get("profile"), "profile"),
        splat_transform=where(data.get("splat_transform"), "splat_transform"),
        versions={str(k): str(v) for k, v in (data.get("versions") or {}).items()},
    )


__all__ = ["CONFIG_FILE", "RunConfig", "read_run_config", "running_versions", "write_run_config"]
