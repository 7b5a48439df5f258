"""The `bfields` parser: built from one module per verb without importing any verb's machinery
(so `--help` and argument errors are quick), no abbreviated options, and the job verbs' shared
arguments (`cli.job_options`) the same in `run`, `submit`, `batch` and `eval`."""

from __future__ import annotations

import ast
import os
import resource
import statistics
import subprocess
import sys
from pathlib import Path

import pytest

from bayesian_fields_core.cli.main import VERBS, build_parser

ROOT = Path(__file__).resolve().parents[3]
HEAVY = ("torch", "scipy", "numpy", "numba", "httpx", "pydantic", "bayesian_fields_core.job.pipeline")
"""What building the parser must not import (the first three cost seconds on a busy machine)."""
FAST_S = 0.5


def _fresh(code: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120, check=False,
        env={**os.environ, "COLUMNS": "100"},
    )  # fmt: skip


def test_building_the_parser_imports_nothing_heavy() -> None:
    code = "import sys\nfrom bayesian_fields_core.cli.main import build_parser\nbuild_parser()\n"
    code += f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    done = _fresh(code)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]", done.stdout


def _median_cpu_s(code: str, *argv: str) -> float:
    """Median CPU seconds (user + system) of 5 fresh interpreters running `code` with `argv`:
    what the command costs, which a busy shared machine does not stretch as it does wall time."""
    times = []
    for _ in range(5):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = _fresh(code, *argv)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        times.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
        assert done.returncode in (0, 2), done.stderr
    return statistics.median(times)


@pytest.mark.parametrize(
    "argv", [["--help"], ["run", "--help"], ["run", "--no-such-flag"], ["submit", "--help"]]
)
@pytest.mark.slow
def test_help_and_argument_errors_are_quick(argv: list[str]) -> None:
    """`bfields ... --help` and an argument error cost under half a second, interpreter start
    included (importing torch for them cost seconds)."""
    cpu = _median_cpu_s("import sys\nfrom bayesian_fields_core.cli.main import main\nsys.exit(main())", *argv)
    assert cpu < FAST_S, cpu


def test_run_help_still_lists_every_parameter(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--help"])
    assert "top_k  (int, default" in capsys.readouterr().out


def test_every_verb_module_has_register_and_run() -> None:
    for verb in VERBS:
        assert callable(verb.register) and callable(verb.run), verb.__name__


@pytest.mark.slow
def test_no_module_imports_a_private_name_of_another_package() -> None:
    """`from a.b import _name` across packages couples to what a package keeps to itself."""
    offenders = []
    for base in (ROOT / "bayesian_fields_core", ROOT / "services"):
        for path in base.rglob("*.py"):
            package = ".".join(path.relative_to(ROOT).parts[:2])
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                    private = [
                        a.name for a in node.names if a.name.startswith("_") and not a.name.startswith("__")
                    ]
                    home = ".".join(node.module.split(".")[:2]).replace("bayesian_fields_service", "services")
                    if private and home != package:
                        offenders.append(f"{path.relative_to(ROOT)}: {node.module} {private}")
    assert offenders == []


def test_task_is_never_read_as_tasks() -> None:
    parser = build_parser()
    args = parser.parse_args(["submit", "scene", "--task", "the mug"])
    assert args.task == ["the mug"] and args.tasks is None
    args = parser.parse_args(["run", "scene", "--task", "a", "--task", "b"])
    assert args.task == ["a", "b"] and args.tasks is None
    for verb in (["run", "scene"], ["submit", "scene"]):
        with pytest.raises(SystemExit):
            parser.parse_args([*verb, "--tas", "x"])  # no abbreviations
        with pytest.raises(SystemExit):
            parser.parse_args([*verb, "--task", "x", "--tasks", "f.yaml"])  # one or the other


@pytest.mark.parametrize("verb", [["run", "scene"], ["submit", "scene"], ["batch", "m.yaml"], ["eval"]])
def test_the_job_verbs_share_param_and_params(verb: list[str]) -> None:
    args = build_parser().parse_args(
        [*verb, "--params", "p.yaml", "--param", "top_k=3", "--param", "fusion=bayes"]
    )
    assert args.params == "p.yaml" and args.param == ["top_k=3", "fusion=bayes"]


def test_submit_parameters_is_a_deprecated_alias_of_params(capsys: pytest.CaptureFixture[str]) -> None:
    args = build_parser().parse_args(["submit", "scene", "--parameters", "p.yaml"])
    assert args.params == "p.yaml"
    assert "--parameters is deprecated" in capsys.readouterr().err
    assert "--parameters" not in build_parser()._subparsers._group_actions[0].choices["submit"].format_help()  # type: ignore[union-attr]


def test_eval_refuses_a_bad_parameter_before_any_work(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from bayesian_fields_core.cli.main import main

    assert main(["eval", "--suite-dir", str(tmp_path / "s"), "--param", "top_k=0"]) == 2
    assert "top_k" in capsys.readouterr().err and not (tmp_path / "s").exists()


@pytest.mark.parametrize("verb", [["eval"], ["calibrate", "--scene", "s", "--out", "c.json"]])
def test_eval_and_calibrate_take_the_same_regimes(
    verb: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    parser = build_parser()
    assert parser.parse_args([*verb, "--regime", "realistic"]).regime == "realistic"
    with pytest.raises(SystemExit) as exc:
        parser.parse_args([*verb, "--regime", "weak"])
    assert exc.value.code == 2
    assert "expected one of realistic, strong, got 'weak'" in capsys.readouterr().err


def test_calibrate_defaults_to_the_strong_regime_and_eval_to_none() -> None:
    """calibrate fits the encoder as it is unless asked; eval's None means its own default."""
    assert build_parser().parse_args(["calibrate", "--scene", "s", "--out", "c.json"]).regime == "strong"
    assert build_parser().parse_args(["eval"]).regime is None
