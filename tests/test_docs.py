"""The documentation stays true to the code and complete in the repository: the CLI reference
is the one the application generates, and no page points at files outside the repository."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: What a reference to a file outside the repository looks like (the specification and the
#: thesis text the project started from, the shared folder they lived in).
OUTSIDE = re.compile(r"SPEC\b|\.\./shared|\bshared/SPEC|\bseed/|EHA_Dat\.m\s*§")


def test_cli_reference_is_current():
    from eha.docgen import render

    checked_in = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert checked_in == render(), ("docs/cli.md is stale: regenerate it with "
                                    "`python -m eha.docgen > docs/cli.md`")


def test_docgen_runs_as_a_module():
    proc = subprocess.run([sys.executable, "-m", "eha.docgen"], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("# Command-line reference")
    assert "### `eha rul`" in proc.stdout and "#### `eha report thesis`" in proc.stdout


def test_docs_refer_to_nothing_outside_the_repository():
    pages = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
             for p in pages for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             if OUTSIDE.search(line)]
    assert not found, "references to files outside the repository:\n" + "\n".join(found)


# ---- the README's snippets run as written --------------------------------------------------

FENCE = re.compile(r"```(bash|python)\n(.*?)```", re.S)
#: README command lines not run, by design (each checked against the CLI instead, when it is an
#: ``eha`` command): what it does takes minutes or needs what the README assumes the user has.
NOT_RUN = {
    "pip install": "installs the package (the test runs in the installed environment)",
    "eha reproduce": "the whole thesis reproduction (many minutes on 2 cores)",
    "pytest": "the test suite itself",
    "xdg-open": "opens a browser",
    "python -m venv": "creates a virtual environment",
    "python benchmarks/": "a benchmark (minutes; its result is benchmarks/results/<name>.json)",
    "eha ": "reads the user's record.csv / a results folder, or runs minutes of simulations: "
            "its command and options are checked against the CLI",
}
#: README command lines the test runs (cheap, no input file).
RUN = ("eha params", "eha commands", "python -m eha --help")


def _readme_blocks(lang: str) -> list[str]:
    return [code for kind, code in FENCE.findall((ROOT / "README.md").read_text("utf-8"))
            if kind == lang]


def _command_lines() -> list[str]:
    """The README's shell command lines, continuations joined, comments dropped."""
    lines = []
    for block in _readme_blocks("bash"):
        text = re.sub(r"\\\n\s*", " ", block)
        joined, buf = [], ""
        for line in text.splitlines():  # a quoted SQL string spanning lines is one command
            buf = f"{buf} {line.strip()}" if buf else line.strip()
            if buf.count('"') % 2 == 0:
                joined.append(buf)
                buf = ""
        lines += [re.sub(r"\s+#.*$", "", ln).strip() for ln in joined if ln]
    return [ln for ln in lines if ln and not ln.startswith("#")]


@pytest.mark.slow   # end to end: the README run as written in a real process
def test_readme_python_snippets_run(tmp_path):
    blocks = _readme_blocks("python")
    assert blocks
    proc = subprocess.run([sys.executable, "-c", "\n".join(blocks)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]


@pytest.mark.slow   # end to end: the README run as written in a real process
def test_readme_cheap_commands_run(tmp_path):
    lines = _command_lines()
    for cmd in RUN:
        assert cmd in lines, f"{cmd!r} is no longer in the README: update RUN"
        argv = cmd.split()
        argv = ([sys.executable] + argv[1:] if argv[0] == "python"
                else [sys.executable, "-m", "eha"] + argv[1:])
        proc = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, (cmd, proc.stderr[-2000:])
        assert proc.stdout.strip(), cmd


def test_readme_commands_exist_with_their_options():
    """Every ``eha`` line of the README names a command and options the CLI has (the lines
    not run, :data:`NOT_RUN`, are at least spelled right); every other line is skipped for a
    stated reason."""
    import shlex

    import typer

    from eha.cli import app

    root = typer.main.get_command(app)
    problems = []
    for line in _command_lines():
        first = line.split("&&")[0].strip()
        if not first.startswith("eha "):
            if first in RUN:
                continue
            assert any(first.startswith(p) for p in NOT_RUN), f"no reason to skip: {line}"
            continue
        words = shlex.split(first)[1:]
        cmd = root
        while getattr(cmd, "commands", None) and words and not words[0].startswith("-"):
            sub = cmd.commands.get(words[0])  # a group's subcommands by name
            if sub is None:
                problems.append(f"{line}: no command {words[0]!r}")
                break
            cmd, words = sub, words[1:]
        known = {o for p in cmd.params for o in getattr(p, "opts", [])}
        known |= {o for p in cmd.params for o in getattr(p, "secondary_opts", [])}
        problems += [f"{line}: no option {w}" for w in words
                     if w.startswith("--") and w.split("=")[0] not in known]
    assert problems == [], "\n".join(problems)


# ---- benchmarks/results: one current file per benchmark, quoted by the docs -------------------

RESULTS = ROOT / "benchmarks" / "results"
#: Result files not named after a benchmark script, and why.
NOT_A_SCRIPT = {
    "explain_foreign.json": "bench_explain_foreign.py's result (the independent simulator's "
                            "records, scored outside the repository): it keeps the name the "
                            "docs quote",
    "health-detection": "`eha report health` on campaigns/health-detection.toml (a folder)",
}


def test_every_result_file_is_the_current_file_of_a_benchmark():
    scripts = {p.stem for p in (ROOT / "benchmarks").glob("*.py")}
    stray = [p.name for p in RESULTS.iterdir()
             if p.name not in NOT_A_SCRIPT and not (p.suffix == ".json" and p.stem in scripts)]
    assert stray == [], f"not <benchmark script>.json: {stray}"


def test_every_result_file_has_its_provenance():
    import json

    missing = {}
    for path in sorted(RESULTS.glob("*.json")):
        if path.name in NOT_A_SCRIPT:
            continue
        prov = json.loads(path.read_text(encoding="utf-8")).get("provenance") or {}
        keys = {"commit", "date", "machine", "cores"} - set(prov)
        if not {"load", "loadavg_start"} & set(prov):
            keys.add("load")
        if keys:
            missing[path.name] = sorted(keys)
    assert missing == {}


def test_docs_link_result_files_that_exist():
    """Every result file a page links exists (a script's `--json` output not yet run is named
    in backticks, not linked)."""
    pages = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    # a quoted figure links its file: [...](../benchmarks/results/NAME.json)
    named = {m for p in pages
             for m in re.findall(r"\]\((?:\.\./)?benchmarks/results/([\w.-]+\.json)\)",
                                 p.read_text("utf-8"))}
    assert len(named) >= 5, f"the docs link few result files: {sorted(named)}"
    assert sorted(n for n in named if not (RESULTS / n).is_file()) == []


#: Dotted names that are not Python objects: entry-point groups (pyproject.toml) and the
#: results database's file name.
NOT_OBJECTS = {"eha.jobs", "eha.campaign_sections", "eha.worker_warm_up", "eha.duckdb",
               "eha.tables", "eha.campaign_keys"}


def _resolves(dotted: str) -> bool:
    """Does ``eha.x.y.Z.attr`` name a module, or an attribute (a dataclass field too) of
    one?"""
    import importlib

    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for name in parts[i:]:
            fields = getattr(obj, "__dataclass_fields__", {})
            if hasattr(obj, name):
                obj = getattr(obj, name)
            elif name in fields:
                obj = fields[name]
            else:
                return False
        return True
    return False


def test_every_dotted_reference_resolves():
    """Every ``eha.x.y`` a page, a help text or a docstring names exists (issue 40: stale
    references after the package move). History (CHANGELOG.md, docs/decisions.md) may name
    what was."""
    files = [p for p in sorted((ROOT / "docs").glob("*.md")) if p.name != "decisions.md"]
    files += [ROOT / "README.md", *sorted((ROOT / "eha").rglob("*.py")),
              *sorted((ROOT / "campaigns").glob("*.toml"))]
    stale = {}
    for path in files:
        for ref in set(re.findall(r"\beha(?:\.[A-Za-z_]\w*)+", path.read_text("utf-8"))):
            if ref not in NOT_OBJECTS and not _resolves(ref):
                stale.setdefault(ref, str(path.relative_to(ROOT)))
    assert stale == {}, stale
