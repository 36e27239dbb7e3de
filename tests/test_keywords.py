"""The library speaks keywords, the command line flags (issue 40, part 3).

A library error or note names the keyword argument that set a value, in backticks
(`holdout`); the command line's guard shows the flag of the running command instead
(``--holdout``, :func:`eha.cli.guard.as_flags`). No string of the library names a flag, except
inside a whole shell command it suggests (``eha params --model lf``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FLAG = re.compile(r"(?<![\w`-])--[a-z][a-z0-9-]*")
#: A suggested shell command: ``eha`` and its words up to the flag, no sentence between.
SHELL_COMMAND = re.compile(r"\beha(?: [^;,()]*)?$")


def _library_strings():
    """``(file, line, text)`` of every string constant of the library that is not a
    docstring (the command line and its reference generator are not the library)."""
    for path in sorted((ROOT / "eha").rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[1] == "cli" or rel.name == "docgen.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        docstrings = {id(node.value) for node in ast.walk(tree)
                      if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)}
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str)
                    and id(node) not in docstrings):
                yield str(rel), node.lineno, node.value


def test_no_library_string_names_a_flag():
    found = [f"{path}:{line}: {match.group(0)} in {text[:70]!r}"
             for path, line, text in _library_strings()
             for match in FLAG.finditer(text)
             if not SHELL_COMMAND.search(text[:match.start()].rstrip())]
    assert found == [], "\n".join(found)


def test_the_scan_sees_a_flag_and_spares_a_shell_command():
    """The rule above can fail: a flag in a sentence is found, one in a command is not."""
    sentence = "at least 20 are required (lower --holdout)"
    command = "unknown parameter (see `eha params --model lf`)"
    def flagged(text):
        return [m.group(0) for m in FLAG.finditer(text)
                if not SHELL_COMMAND.search(text[:m.start()].rstrip())]
    assert flagged(sentence) == ["--holdout"]
    assert flagged(command) == []


def test_a_library_error_names_the_keyword(tmp_path):
    from eha.explain.settings import ExplainError, LoopSettings

    with pytest.raises(ExplainError) as err:
        LoopSettings(holdout=0.95).check()
    assert "`holdout` 0.95" in str(err.value)
    assert "--" not in str(err.value)


def test_the_command_line_shows_the_flag(tmp_path):
    """The same error through ``eha explain`` names ``--holdout``; a keyword whose flag is
    named otherwise (``fixed`` is ``--set``) is shown as that flag."""
    from typer.testing import CliRunner

    from eha.cli import app

    record = tmp_path / "r.csv"
    rows = "\n".join(f"{i / 1000},{0.001},{0.0}" for i in range(400))
    record.write_text("t,com,xu\n" + rows + "\n")
    runner = CliRunner()
    res = runner.invoke(app, ["explain", str(record), "--holdout", "0.95"])
    assert res.exit_code == 2
    assert "--holdout 0.95: allowed range [0, 0.8]" in res.output
    assert "`" not in res.output
    res = runner.invoke(app, ["explain", str(record), "--set", "BKL=1e-5", "--fit", "BKL"])
    assert res.exit_code == 2
    assert "--set BKL: also a fitted fault (--fit)" in res.output


def test_as_flags_keeps_what_it_cannot_map():
    from eha.cli.guard import STATE, as_flags

    STATE["flags"] = {"holdout": "--holdout"}
    try:
        assert as_flags("`holdout` 2; see `other`") == "--holdout 2; see `other`"
    finally:
        STATE.pop("flags")


def test_the_steps_table_has_its_columns_when_nothing_was_added():
    """``ExplainResult.to_pandas()`` of a run that added nothing still names its columns
    (a notebook selects them), and they are the CSV's columns when something was."""
    from eha.explain.results import STEP_COLUMNS, ExplainResult

    res = ExplainResult.__new__(ExplainResult)
    res.steps = []
    assert list(res.to_pandas().columns) == list(STEP_COLUMNS)
