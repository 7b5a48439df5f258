"""Every pipeline default is written once, in `PipelineParams`.

Found by introspection, not by a list of known places: every public function and class of the
library is read (its signature where the module imports, its source always) and any default or
module constant that restates a `PipelineParams` field is a failure. The documentation's table
is checked to be generated from the model too.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
from pathlib import Path
from typing import Any

import pytest

import bayesian_fields_core
from bayesian_fields_core.cli.params_table import markdown_table
from bayesian_fields_core.fusion.likelihood import LikelihoodParams, resolve_likelihood
from bayesian_fields_core.params import PipelineParams, default

PACKAGE = Path(bayesian_fields_core.__file__).parent
DOCS = PACKAGE.parent / "docs"
FIELDS = PipelineParams.model_fields
# Words too common to tie a name to one field on their own.
GENERIC = {"default", "max", "min", "num", "n", "size", "count"}


def _tokens(name: str) -> set[str]:
    return {t for t in name.lower().split("_") if t and t not in GENERIC}


def _restates(name: str, value: Any = None) -> str | None:
    """The `PipelineParams` field that a constant or parameter `name` with literal `value` restates.

    By name alone: the field's own name (also after `DEFAULT_`), or two or more of its words
    (`DEFAULT_RELATIVE_TOLERANCE` for `depth_tolerance_relative`). By name and value: one shared
    word and the very same number (`DEFAULT_K = 20` for `knn_k`, `atol=1e-6` for
    `identical_tolerance`)."""
    bare = re.sub(r"^default_", "", name.lower())
    words = _tokens(bare)
    for field in FIELDS:
        if bare == field or (len(words) >= 2 and words <= _tokens(field)):
            return field
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    for field, info in FIELDS.items():
        same = number and type(info.default) in (int, float) and info.default == value
        if same and words & _tokens(field):
            return field
    return None


def _library_files() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if p.name != "params.py")


def _literal(node: ast.expr | None) -> Any:
    """The value of a literal number / bool / string node (a negative number too), else a sentinel."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool)):
        return node.value
    if (
        isinstance(node, ast.UnaryOp)
        and isinstance(node.op, ast.USub)
        and isinstance(node.operand, ast.Constant)
    ):
        return -node.operand.value
    return _NOT_LITERAL


_NOT_LITERAL = object()


def _defaults(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> list[tuple[str, ast.expr]]:
    a = fn.args
    positional = a.posonlyargs + a.args
    pairs = list(
        zip([x.arg for x in positional[len(positional) - len(a.defaults) :]], a.defaults, strict=True)
    )
    pairs += [(x.arg, d) for x, d in zip(a.kwonlyargs, a.kw_defaults, strict=True) if d is not None]
    return pairs


def _source_findings() -> list[str]:
    """Literal defaults of parameters named like a field, and constants that restate one."""
    found = []
    for path in _library_files():
        tree = ast.parse(path.read_text(), filename=str(path))
        where = path.relative_to(PACKAGE.parent)
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for name, value in _defaults(node):
                    lit = _literal(value)
                    field = None if lit is _NOT_LITERAL else _restates(name, lit)
                    if field and FIELDS[field].default is not None:
                        found.append(f"{where}:{value.lineno} {node.name}({name}={lit!r}) restates {field}")
        for node in tree.body:  # module constants
            targets = (
                node.targets
                if isinstance(node, ast.Assign)
                else [node.target]
                if isinstance(node, ast.AnnAssign)
                else []
            )
            lit = _literal(getattr(node, "value", None))
            for t in targets:
                if isinstance(t, ast.Name) and t.id.isupper() and lit is not _NOT_LITERAL:
                    if field := _restates(t.id, lit):
                        found.append(f"{where}:{node.lineno} {t.id} = {lit!r} restates {field}")
    return found


@pytest.mark.slow
def test_no_library_source_restates_a_default() -> None:
    assert _source_findings() == []


def _public_callables() -> list[tuple[str, Any]]:
    out = []
    for info in pkgutil.walk_packages([str(PACKAGE)], prefix="bayesian_fields_core."):
        try:
            module = importlib.import_module(info.name)
        except ModuleNotFoundError as exc:  # an optional extra (gsplat, viser...) is not installed
            if exc.name and exc.name.startswith("bayesian_fields_core"):
                raise
            continue
        for name, obj in vars(module).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != module.__name__:
                continue
            if inspect.isfunction(obj):
                out.append((f"{info.name}.{name}", obj))
            elif inspect.isclass(obj) and obj is not PipelineParams:
                out.append((f"{info.name}.{name}", obj))
                for mname, member in vars(obj).items():
                    if inspect.isfunction(member) and (not mname.startswith("_") or mname == "__init__"):
                        out.append((f"{info.name}.{name}.{mname}", member))
    return out


def test_every_signature_default_named_like_a_field_equals_the_model() -> None:
    callables = _public_callables()
    assert len(callables) > 300  # the walk really reached the library
    wrong = []
    for qualname, obj in callables:
        try:
            sig = inspect.signature(obj)
        except (TypeError, ValueError):
            continue
        for p in sig.parameters.values():
            if p.default is inspect.Parameter.empty or p.default is None:  # required, or "not given"
                continue
            field = _restates(p.name, p.default)
            if field is None or FIELDS[field].default is None:
                continue
            if p.default != FIELDS[field].default:
                wrong.append(
                    f"{qualname}({p.name}={p.default!r}) but PipelineParams.{field} = {FIELDS[field].default!r}"
                )
    assert wrong == []


def test_the_paper_likelihood_is_the_fallback_of_an_uncalibrated_run() -> None:
    assert resolve_likelihood(PipelineParams(), None) == LikelihoodParams()
    assert resolve_likelihood(PipelineParams(mu1=0.3), None).mu1 == 0.3


def test_default_names_a_field() -> None:
    assert default("depth_tolerance") == FIELDS["depth_tolerance"].default
    with pytest.raises(KeyError, match="no field 'depth_tolerence'"):
        default("depth_tolerence")


def test_docs_parameter_table_is_generated_from_the_model() -> None:
    """One docs page carries the block of `bfields params --markdown`'s table, committed between
    markers (`docs/_build/generated.py`; `tests/docs/test_generated_tables.py` keeps it current);
    rendered as the build renders it (in a fresh process, through the `bfields` entry point), the
    page holds the model's table, one row per field, and nothing else that looks like one."""
    import subprocess
    import sys

    marker = "<!-- generated: bfields params --markdown ("
    pages = [p for p in DOCS.rglob("*.md") if marker in p.read_text()]
    assert len(pages) == 1, f"the parameter table's block should be on one page, found {pages}"
    body = (
        pages[0].read_text().split(marker, 1)[1].split("<!-- end generated: bfields params --markdown -->")[0]
    )
    outside = pages[0].read_text().replace(body, "")
    assert not [line for line in outside.splitlines() if line.startswith("| `")], (
        "the parameters page holds a hand-written table outside the generated block"
    )
    script = (
        "import sys; sys.path.insert(0, sys.argv[1]); import hooks; "
        "sys.stdout.write(hooks.render(open(sys.argv[2]).read()))"
    )
    rendered = subprocess.run(
        [sys.executable, "-c", script, str(DOCS / "_build"), str(pages[0])],
        capture_output=True,
        text=True,
        check=True,
        cwd=DOCS.parent,
    ).stdout
    # GitHub's tables escape a pipe even inside a code span (`bayes\|average`); Python-Markdown
    # splits no cell inside one and would print the backslash, so the site's table has none there.
    table = re.sub(r"`[^`\n]*`", lambda m: m.group(0).replace("\\|", "|"), markdown_table())
    assert "`bayes|average`" in table and table in rendered
    rows = [line for line in rendered.splitlines() if line.startswith("| `")]
    assert [row.split("`")[1] for row in rows] == list(FIELDS)
