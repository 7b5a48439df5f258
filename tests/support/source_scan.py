"""Helpers of the tests that read the project's source with `ast` (the live boundary, the test
hooks): what counts as a docstring, so that a module or function that only *mentions* a name in
its documentation is not taken for one that uses it."""

from __future__ import annotations

import ast


def docstring_nodes(tree: ast.AST) -> set[int]:
    """ids of the string nodes that are docstrings (of the module, a class or a function)."""
    found: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                found.add(id(body[0].value))
    return found
