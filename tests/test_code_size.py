"""Code size (issue 26): no module over 600 lines and no function or method over 100 lines in
``eha/``; a longer one is split into helpers."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "eha"
MAX_MODULE = 600
MAX_FUNCTION = 100


def _modules():
    return sorted(PACKAGE.rglob("*.py"))


def test_no_module_over_600_lines():
    long = {str(p.relative_to(PACKAGE)): n for p in _modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE}
    assert long == {}, long


def test_no_function_over_100_lines():
    long = {}
    for p in _modules():
        tree = ast.parse(p.read_text(encoding="utf-8"), filename=str(p))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                # from the def line (decorators excluded) to the last line of the body
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION:
                    long[f"{p.relative_to(PACKAGE)}:{node.lineno} {node.name}"] = n
    assert long == {}, long
