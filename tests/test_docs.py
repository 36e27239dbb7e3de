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



#: What a lab notebook leaves in a user page: a commit hash (7-40 hex digits with a digit and a
#: letter), a seed block, "the run before". History lives in docs/decisions.md and CHANGELOG.md;
#: a figure's commit and date in its result file's provenance.
NOTEBOOK = re.compile(r"\b(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b|seed blocks?\b"
                      r"|the run before", re.I)
#: Pages that keep history (the generated docs/cli.md is a user page: it is checked).
HISTORY = {"decisions.md", "CHANGELOG.md"}


def _user_pages() -> list[Path]:
    return [p for p in sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
            if p.name not in HISTORY]


def test_user_docs_are_in_the_present_tense():
    """No commit hash, seed block or "the run before" in README.md and docs/*.md (issue 40):
    a page states the current figures and links the result file that records where they come
    from."""
    found = [f"{p.relative_to(ROOT)}:{i}: {m.group(0)!r} in {line.strip()[:100]}"
             for p in _user_pages()
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             for m in NOTEBOOK.finditer(line)]
    assert not found, "history in a user page (move it to docs/decisions.md):\n" + "\n".join(found)


def test_the_notebook_pattern_catches_what_it_should():
    for text in ("at commit 316c94d", "the loop of c23899f", "seed block 13", "seed blocks 0 and 1",
                 "the run before the change", "6babbf6cffc03725dd3b8f9f6367cef9e2624b1"):
        assert NOTEBOOK.search(text), text
    for text in ("deadbeef", "1234567", "a 1.1e-12 leak", "9.66e-14", "blocks 6 and 7",
                 "a feedback loop", "`eha.explain.P12_NOISE_FLOOR`", "run before 5 s"):
        assert not NOTEBOOK.search(text), text

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
    "python validation/": "a validation study (minutes to hours; its result is "
                          "validation/results/<name>.json)",
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


# ---- benchmarks/ and validation/: one current result file per script, quoted by the docs ------

#: The folders of scripts with result files: the speed benchmarks and the validation studies,
#: each script writing ``<folder>/results/<script>.json`` (tools/_results.py).
FOLDERS = ("benchmarks", "validation")
#: Result files not named after a script of their folder, and why.
NOT_A_SCRIPT = {
    "validation/results/health-detection": "`eha report health` on "
                                           "campaigns/health-detection.toml (a folder)",
}


def _result_files():
    return [p for folder in FOLDERS for p in sorted((ROOT / folder / "results").iterdir())]


def test_every_result_file_is_the_current_file_of_a_script():
    stray = []
    for folder in FOLDERS:
        scripts = {p.stem for p in (ROOT / folder).glob("*.py")}
        stray += [str(p.relative_to(ROOT)) for p in sorted((ROOT / folder / "results").iterdir())
                  if str(p.relative_to(ROOT)) not in NOT_A_SCRIPT
                  and not (p.suffix == ".json" and p.stem in scripts)]
    assert stray == [], f"not <folder>/results/<script of the folder>.json: {stray}"


def test_the_validation_studies_and_the_speed_benchmarks_are_apart():
    """benchmarks/ keeps the speed benchmarks (``bench_*``), validation/ the studies; the
    helper they share lives in tools/, in neither."""
    assert sorted(p.name for p in (ROOT / "benchmarks").glob("*.py")
                  if not p.name.startswith("bench_")) == []
    assert sorted(p.name for p in (ROOT / "validation").glob("*.py")
                  if p.name.startswith("bench_")) == []
    assert sorted(p.relative_to(ROOT).as_posix() for p in ROOT.glob("*/_results.py")) \
        == ["tools/_results.py"]


#: ``python -c HELP_OF_EACH SCRIPT...`` (from the root): each script's ``--help`` as ``python
#: SCRIPT --help`` runs it (its folder first on sys.path, the shared helper and its siblings
#: imported afresh, none left from the script before), in one process: a process per script
#: imported numpy, pandas and the package 25 times, a tenth of the quick suite's CPU.
HELP_OF_EACH = """
import contextlib, io, json, runpy, sys
from pathlib import Path

root = Path.cwd().resolve()
folders = [root / f for f in ("benchmarks", "validation", "tools")]
path0, known = list(sys.path), set(sys.modules)


def a_script(module):
    file = getattr(module, "__file__", None) or ""
    return any(Path(file).resolve().is_relative_to(f) for f in folders)


out = {}
for script in sys.argv[1:]:
    for name in [m for m in sys.modules if m not in known and a_script(sys.modules[m])]:
        del sys.modules[name]
    sys.path[:] = [str((root / script).parent), *path0[1:]]
    sys.argv = [script, "--help"]
    stdout, stderr, code = io.StringIO(), io.StringIO(), 0
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            runpy.run_path(script, run_name="__main__")
    except SystemExit as exc:
        code = exc.code or 0
    except BaseException as exc:
        code = f"{type(exc).__name__}: {exc}"
    out[script] = [code, stdout.getvalue()[:1000], stderr.getvalue()[-2000:]]
print(json.dumps(out))
"""


def _scripts() -> list[str]:
    return sorted(f"{folder}/{p.name}" for folder in FOLDERS for p in (ROOT / folder).glob("*.py"))


def test_every_script_runs_from_the_repository_root():
    """``python <folder>/<script>.py --help`` from the root, for every script: its imports
    (the shared helper, a sibling script) resolve and it prints its usage."""
    import json

    scripts = _scripts()
    proc = subprocess.run([sys.executable, "-c", HELP_OF_EACH, *scripts], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    assert sorted(runs) == scripts
    failed = {s: (code, err or out) for s, (code, out, err) in runs.items()
              if code != 0 or "usage" not in out.lower()}
    assert failed == {}


def test_a_script_that_imports_what_is_not_there_fails_the_help_check(tmp_path):
    """The one-process ``--help`` check sees a failing import, a sibling only another
    script's folder holds (nothing leaks from one script to the next), and a missing
    usage."""
    import json

    for folder, files in {"a": {"one.py": "import argparse\nargparse.ArgumentParser()"
                                          ".parse_args()\n",
                                "sibling.py": "X = 1\n"},
                          "b": {"two.py": "import sibling\n",
                                "three.py": "from eha.no_such_module import x\n",
                                "four.py": "print('no parser')\n"}}.items():
        (tmp_path / folder).mkdir()
        for name, text in files.items():
            (tmp_path / folder / name).write_text(text)
    (tmp_path / "tools").mkdir()
    scripts = ["a/one.py", "b/two.py", "b/three.py", "b/four.py"]
    proc = subprocess.run([sys.executable, "-c", HELP_OF_EACH.replace(
        '("benchmarks", "validation", "tools")', '("a", "b", "tools")'), *scripts],
        cwd=tmp_path, capture_output=True, text=True, timeout=120)
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    assert runs["a/one.py"][0] == 0 and "usage" in runs["a/one.py"][1]
    assert runs["b/two.py"][0].startswith("ModuleNotFoundError")
    assert runs["b/three.py"][0].startswith("ModuleNotFoundError")
    assert runs["b/four.py"][0] == 0 and "usage" not in runs["b/four.py"][1]


def _defined_at_top(path: Path) -> set[str]:
    """The names a script defines at its top level (functions, classes, assignments,
    imports): what a sibling may import from it."""
    import ast

    names = set()
    for node in ast.parse(path.read_text("utf-8")).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                names |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
    return names


def _stale_names(script: Path) -> list[str]:
    """What ``script`` takes from the package or a sibling script and no longer exists: every
    ``from eha.x import y`` and ``import eha.x`` (at the top or inside a function: most scripts
    import the package only where a study needs it, so ``--help`` never reaches them), every
    ``from sibling import y``, and every ``alias.attr.attr`` read through a name so imported
    (``loop_module.ResidualLoop.result``)."""
    import ast

    tree = ast.parse(script.read_text("utf-8"))
    siblings = {p.stem: p for p in [*script.parent.glob("*.py"), ROOT / "tools" / "_results.py"]}
    aliases: dict[str, str] = {}   # local name -> the dotted eha name it is bound to
    stale = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            root = node.module.split(".")[0]
            for a in node.names:
                if root == "eha":
                    ref = f"{node.module}.{a.name}"
                    aliases[a.asname or a.name] = ref
                    if not _resolves(ref):
                        stale.append(ref)
                elif node.module in siblings and a.name not in _defined_at_top(
                        siblings[node.module]):
                    stale.append(f"{node.module}.{a.name}")
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "eha":
                    if not _resolves(a.name):
                        stale.append(a.name)
                    aliases[a.asname or "eha"] = a.name if a.asname else "eha"
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and not isinstance(node.value, ast.Attribute):
            continue   # only the outermost attribute of a chain is resolved
        if not isinstance(node, ast.Attribute):
            continue
        parts, inner = [], node
        while isinstance(inner, ast.Attribute):
            parts.append(inner.attr)
            inner = inner.value
        if isinstance(inner, ast.Name) and inner.id in aliases:
            ref = ".".join([aliases[inner.id], *reversed(parts)])
            if not _resolves(ref):
                stale.append(ref)
    return sorted(set(stale))


@pytest.mark.parametrize("script", _scripts())
def test_every_name_a_script_takes_from_the_package_exists(script):
    """The scripts are run by hand, for minutes to hours, so a renamed or removed function of
    the package (many reach into the loop's internals) would break one silently: every name a
    script imports from ``eha`` or from a sibling script, wherever the import is, and every
    attribute it reads through such a name, exists (a static check: nothing is run)."""
    assert _stale_names(ROOT / script) == []


def test_the_script_check_catches_a_stale_name_wherever_it_is(tmp_path):
    (tmp_path / "sibling.py").write_text("A = 1\n\ndef helper():\n    pass\n")
    script = tmp_path / "study.py"
    script.write_text(
        "from eha.explain import explain\n"
        "from sibling import A, helper, gone\n"
        "def main():\n"
        "    from eha.explain.loop import _no_such_function\n"
        "    from eha.explain import loop as loop_module\n"
        "    import eha.no_such_module\n"
        "    loop_module.ResidualLoop.run\n"
        "    loop_module.ResidualLoop.no_such_method\n")
    assert _stale_names(script) == ["eha.explain.loop.ResidualLoop.no_such_method",
                                    "eha.explain.loop._no_such_function",
                                    "eha.no_such_module", "sibling.gone"]


def test_every_result_file_has_its_provenance():
    import json

    missing = {}
    for path in _result_files():
        if path.suffix != ".json":
            continue
        prov = json.loads(path.read_text(encoding="utf-8")).get("provenance") or {}
        keys = {"commit", "date", "machine", "cores"} - set(prov)
        if not {"load", "loadavg_start"} & set(prov):
            keys.add("load")
        if keys:
            missing[str(path.relative_to(ROOT))] = sorted(keys)
    assert missing == {}


def test_docs_link_result_files_that_exist():
    """Every result file a page links exists (a script's `--json` output not yet run is named
    in backticks, not linked)."""
    pages = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
    # a quoted figure links its file: [...](../validation/results/NAME.json)
    named = {m for p in pages
             for m in re.findall(r"\]\((?:\.\./)?((?:benchmarks|validation)/results/[\w./-]+)\)",
                                 p.read_text("utf-8"))}
    assert len(named) >= 5, f"the docs link few result files: {sorted(named)}"
    assert sorted(n for n in named if not (ROOT / n).exists()) == []


#: Dotted names that are not Python objects: entry-point groups (pyproject.toml) and the
#: results database's file name.
NOT_OBJECTS = {"eha.job_kinds", "eha.duckdb", "eha.tables"}


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
