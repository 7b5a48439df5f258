"""The hook registry (`bayesian_fields_service.hooks`) and the rule it serves: no test hook in a
production module (issue 43 item 6).

Pause points and the encoder call log used to be settings (`test_pause_points`,
`test_encoder_call_log`) and calls in the scene routes and the worker. Now production code calls
named hook points that do nothing unless a plugin registers on them, and the tests' plugin
(`tests/services/support/service_hooks.py`) is what pauses and counts. The scan below reads the
source of `services/` and `bayesian_fields_core/` with `ast`, so prose in a docstring or a comment
does not count, and a late import or a nested name does.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.hooks import POINTS, WRAPS, HookRegistry
from tests.services.support import service_hooks
from tests.support.source_scan import docstring_nodes

ROOT = Path(__file__).resolve().parents[2]
PRODUCTION = [ROOT / "services", ROOT / "bayesian_fields_core"]

#: Names of the old test hooks: none may come back in production code.
FORBIDDEN_NAMES = {
    "test_pause_points",
    "test_encoder_call_log",
    "pause_points",
    "counting_encoder",
    "encoder_call_log",
}
#: Test-only text: the tests' Redis keys and environment variables.
FORBIDDEN_TEXT = ("bf:test:", "BFIELDS_TEST_", "TEST_HOOKS_")


def _identifiers(node: ast.AST) -> list[str]:
    """The names a node introduces or uses (each part of a dotted import counts)."""
    if isinstance(node, ast.Name):
        return [node.id]
    if isinstance(node, ast.Attribute):
        return [node.attr]
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
        return [node.name]
    if isinstance(node, ast.arg):
        return [node.arg]
    if isinstance(node, ast.keyword) and node.arg:
        return [node.arg]
    if isinstance(node, ast.alias):
        return [*node.name.split("."), *([node.asname] if node.asname else [])]
    if isinstance(node, ast.ImportFrom) and node.module:
        return node.module.split(".")
    return []


def hooks_in(source: str) -> list[str]:
    """What in `source` is a test hook: a forbidden or ``test_*`` name, or test-only text."""
    tree = ast.parse(source)
    docs = docstring_nodes(tree)
    found: list[str] = []
    for node in ast.walk(tree):
        found += [n for n in _identifiers(node) if n in FORBIDDEN_NAMES or n.startswith("test_")]
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            found += [t for t in FORBIDDEN_TEXT if t in node.value]
    return found


def production_modules() -> list[Path]:
    files = [p for root in PRODUCTION for p in sorted(root.rglob("*.py"))]
    assert len(files) > 200, "the scan found too few production modules to mean anything"
    return files


def test_no_production_module_holds_a_test_hook() -> None:
    offenders = {
        str(p.relative_to(ROOT)): found for p in production_modules() if (found := hooks_in(p.read_text()))
    }
    assert offenders == {}, "test hooks belong in a plugin under tests/ (bayesian_fields_service.hooks)"


def test_no_setting_is_a_test_switch() -> None:
    assert [name for name in ServiceSettings.model_fields if name.startswith("test")] == []


def test_the_scan_can_fail() -> None:
    source = '''
"""bf:test: in a docstring, test_pause_points in prose"""
from bayesian_fields_service.common.pause_points import pause
def f(settings, test_flag=False):
    if settings.test_encoder_call_log:
        return counting_encoder(settings)
    return "BFIELDS_TEST_PAUSE_POINTS", f"bf:test:pause:{settings}"
'''
    assert sorted(hooks_in(source)) == sorted(
        [
            "pause_points",
            "test_flag",
            "test_encoder_call_log",
            "counting_encoder",
            "BFIELDS_TEST_",
            "bf:test:",
        ]
    )
    assert hooks_in((ROOT / "tests/services/support/service_hooks.py").read_text())  # the plugin's keys


def _calls(attr: str) -> set[str]:
    """The first argument of every ``hooks.<attr>("...")`` call in the service."""
    names: set[str] = set()
    for path in (ROOT / "services").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == attr
                and isinstance(node.func.value, ast.Name)
                and node.func.value.id == "hooks"
            ):
                first = node.args[0]
                assert isinstance(first, ast.Constant), f"{path}: hooks.{attr} takes a literal name"
                names.add(first.value)
    return names


def test_every_point_called_is_declared_and_every_declared_point_is_called() -> None:
    assert _calls("point") == set(POINTS)
    assert _calls("wrap") == set(WRAPS)


# ---- the registry ---------------------------------------------------------------------------


def test_by_default_every_point_does_nothing_and_every_wrap_returns_its_object() -> None:
    registry = HookRegistry()
    assert registry.empty()
    for name in POINTS:
        assert registry.point(name, scene_id="s_x", job_id="j_x") is None
    encoder = object()  # the registry only passes objects along
    assert registry.wrap("encoder", encoder) is encoder
    registry.install(ServiceSettings())  # no plugin named: still nothing
    assert registry.empty()


@pytest.mark.parametrize(
    ("plugins", "empty"), [(None, True), (f'["{service_hooks.__name__}"]', False)], ids=["none", "tests"]
)
def test_a_worker_process_installs_what_the_setting_names(plugins: str | None, empty: bool) -> None:
    """Importing the routes and the worker's tasks (which builds the worker's app, its process's
    start) registers nothing when BFIELDS_HOOKS_PLUGINS is unset, and the named plugin when set."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("BFIELDS_", "TEST_HOOKS_"))}
    env["PYTHONPATH"] = str(ROOT)
    if plugins is not None:
        env["BFIELDS_HOOKS_PLUGINS"] = plugins
    code = (
        "import bayesian_fields_service.api.routes.scenes, bayesian_fields_service.worker.tasks\n"
        "from bayesian_fields_service import hooks\n"
        "print(hooks.REGISTRY.empty())"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(empty)


def test_registered_functions_run_in_order_with_the_context() -> None:
    registry = HookRegistry()
    seen: list[tuple[str, dict]] = []
    registry.on("scene.delete.marked", lambda **c: seen.append(("first", c)))
    registry.on("scene.delete.marked", lambda **c: seen.append(("second", c)))
    registry.point("scene.delete.marked", scene_id="s_1")
    registry.point("scene.complete.claimed", scene_id="s_2")  # nothing registered there
    assert seen == [("first", {"scene_id": "s_1"}), ("second", {"scene_id": "s_1"})]
    registry.wrap_with("encoder", lambda e: ("outer", e))
    assert registry.wrap("encoder", "enc") == ("outer", "enc")
    assert not registry.empty()


def test_an_unknown_name_is_refused_when_registered() -> None:
    registry = HookRegistry()
    with pytest.raises(ValueError, match="no hook point 'scene.complete.claim'"):
        registry.on("scene.complete.claim", lambda **_: None)
    with pytest.raises(ValueError, match="no hook wrap 'segmenter'"):
        registry.wrap_with("segmenter", lambda s: s)


def test_install_imports_each_plugin_once(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(service_hooks.ENCODER_CALL_LOG_ENV, raising=False)
    settings = ServiceSettings(hooks_plugins=[service_hooks.__name__])
    registry = HookRegistry()
    registry.install(settings)
    registry.install(settings)  # a second process start in one process: no second registration
    assert {name: len(fns) for name, fns in registry._points.items()} == dict.fromkeys(POINTS, 1)
    assert registry.wrap("encoder", enc := object()) is enc  # no call log asked for: not wrapped


def test_the_tests_plugin_logs_a_real_encoders_image_batches(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The worker's wiring (`Models.encoder_wrapper` through the registry) with the tests' plugin:
    one line ``<pid> <images>`` per image batch, and the embeddings the encoder gives unwrapped."""
    from bayesian_fields_core.perception.models import load_models

    log = tmp_path / "calls.log"
    monkeypatch.setenv(service_hooks.ENCODER_CALL_LOG_ENV, str(log))
    registry = HookRegistry()
    registry.install(ServiceSettings(hooks_plugins=[service_hooks.__name__]))
    plain, hooked = load_models(device="cpu"), load_models(device="cpu")  # the bundled tiny CLIP
    hooked.encoder_wrapper = lambda encoder: registry.wrap("encoder", encoder)
    images = [np.full((32, 32, 3), v, dtype=np.uint8) for v in (40, 200)]
    np.testing.assert_allclose(hooked.encoder.encode_images(images), plain.encoder.encode_images(images))
    hooked.encoder.encode_texts(["a red cup"])  # texts are not image batches: no line
    assert log.read_text() == f"{os.getpid()} 2\n"
    assert not plain.encoder_wrapper


def test_a_plugin_without_install_or_not_installed_stops_the_start() -> None:
    with pytest.raises(RuntimeError, match="BFIELDS_HOOKS_PLUGINS names json, which defines no install"):
        HookRegistry().install(ServiceSettings(hooks_plugins=["json"]))
    with pytest.raises(ModuleNotFoundError):
        HookRegistry().install(ServiceSettings(hooks_plugins=["no_such_plugin_module"]))


@pytest.mark.parametrize("name", ["/tmp/plugin.py", "../plugin", "plugin.py/x", "a..b", "1abc", "a-b", ""])
def test_a_plugin_is_named_by_module_never_by_path(name: str) -> None:
    with pytest.raises(ValidationError, match="hooks_plugins takes Python module names"):
        ServiceSettings(hooks_plugins=[name])


def test_the_setting_reads_a_json_list(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BFIELDS_HOOKS_PLUGINS", '["tests.services.support.service_hooks", "a.b"]')
    assert ServiceSettings().hooks_plugins == ["tests.services.support.service_hooks", "a.b"]
