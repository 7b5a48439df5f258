"""Named extension points of the service processes, and the plugins an operator installs on them.

Why: some work needs to act at a precise place inside a request or a stage without the code there
knowing who acts: holding a scene completion between two storage calls to force one interleaving
of a race, counting the encoder's image batches across worker processes, a tracing span around a
step, a fault injected at one spot. Production code names those places here (`POINTS`, `WRAPS`)
and calls `point(name, **context)` or `wrap(name, obj)`; a plugin registers functions for them.
With nothing registered, the state of every deployment that names no plugin, `point` is one dict
lookup and `wrap` hands its object back unchanged.

Installation: `BFIELDS_HOOKS_PLUGINS` (`ServiceSettings.hooks_plugins`, a JSON list of module
names). Each process calls `install(settings)` where it starts (the API's `create_app`, the
worker's Celery app, the control process's `main`); every named module is imported once and its
``install(registry, settings)`` called, which registers with `registry.on` / `registry.wrap_with`.
Why a setting rather than the alternatives:
- an environment variable read here at import would be a second kind of configuration beside
  `ServiceSettings`, the one place every ``BFIELDS_*`` variable is declared, validated and listed
  in `.env.example`;
- Python entry points install a plugin into every process of every environment the package is
  installed in: an operator could not turn one off without uninstalling it, and the tests' plugin
  would have to be packaged with the service.
A plugin is named by module, never by file: it must be importable code the operator installed, and
the setting's validator refuses anything but dotted Python names. Like every setting it comes from
the process's environment, which no request can reach. A plugin's exception is the caller's
exception (a hook that fails is not silently skipped), so a plugin does only what it must.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from bayesian_fields_service.config.settings import ServiceSettings

T = TypeVar("T")

#: The points production code calls, each with the context it passes (keyword arguments).
POINTS: dict[str, str] = {
    "scene.complete.claimed": "scene_id: the upload's completion is claimed, nothing fetched yet",
    "scene.complete.fetched": "scene_id: the uploaded files are read, nothing published yet",
    "scene.complete.before_publish": "scene_id: the checked scene is about to be published",
    "scene.complete.publishing": "scene_id: inside the publishing transaction, the row locked",
    "scene.delete.marked": "scene_id: the row says deleting, nothing removed yet",
    "stage.before_lock": "tenant, job_id, stage, scene_id: a stage's message taken, its lock not",
    "stage.progress": "tenant, job_id, step, fraction: a step of a running stage reports progress",
}

#: The objects production code lets a plugin wrap: ``wrap(name, obj)`` returns a replacement.
WRAPS: dict[str, str] = {
    "encoder": "a worker's image/text encoder, when its model profile builds it",
}

#: The function a plugin module defines: called once per process with the registry and settings.
Installer = Callable[["HookRegistry", "ServiceSettings"], None]


class HookRegistry:
    """The functions registered on each point and wrap, in registration order."""

    def __init__(self) -> None:
        self._points: dict[str, list[Callable[..., None]]] = {}
        self._wraps: dict[str, list[Callable[[Any], Any]]] = {}
        self._installed: set[str] = set()

    def on(self, name: str, fn: Callable[..., None]) -> None:
        """Call `fn(**context)` at point `name` (a name of `POINTS`; a typo fails here, at start)."""
        if name not in POINTS:
            raise ValueError(f"no hook point {name!r}; the points are {sorted(POINTS)}")
        self._points.setdefault(name, []).append(fn)

    def wrap_with(self, name: str, fn: Callable[[Any], Any]) -> None:
        """Pass the object of wrap `name` (a name of `WRAPS`) through `fn`, which returns its stand-in."""
        if name not in WRAPS:
            raise ValueError(f"no hook wrap {name!r}; the wraps are {sorted(WRAPS)}")
        self._wraps.setdefault(name, []).append(fn)

    def point(self, name: str, **context: Any) -> None:
        """Run what is registered on point `name` (nothing by default)."""
        for fn in self._points.get(name, ()):
            fn(**context)

    def wrap(self, name: str, obj: T) -> T:
        """`obj` through every wrapper registered on `name` (itself, unchanged, by default)."""
        for fn in self._wraps.get(name, ()):
            obj = fn(obj)
        return obj

    def empty(self) -> bool:
        """Whether nothing is registered on any point or wrap."""
        return not any(self._points.values()) and not any(self._wraps.values())

    def install(self, settings: ServiceSettings) -> None:
        """Import each module of `settings.hooks_plugins` not installed yet and run its ``install``.
        An unknown module, or one without ``install``, stops the process's start with the reason."""
        for module_name in settings.hooks_plugins:
            if module_name in self._installed:
                continue
            module = importlib.import_module(module_name)
            installer: Installer | None = getattr(module, "install", None)
            if not callable(installer):
                raise RuntimeError(
                    f"BFIELDS_HOOKS_PLUGINS names {module_name}, which defines no install(registry, settings)"
                )
            installer(self, settings)
            self._installed.add(module_name)


#: The process's registry: what production code calls.
REGISTRY = HookRegistry()
point = REGISTRY.point
wrap = REGISTRY.wrap
install = REGISTRY.install
