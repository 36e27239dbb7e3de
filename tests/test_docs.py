"""The documentation stays true to the code and complete in the repository: the CLI reference
is the one the application generates, and no page points at files outside the repository."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

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
