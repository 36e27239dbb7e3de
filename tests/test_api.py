"""The public API (``eha/__init__.py``, ``docs/api.md``): every exported name loads, each has
a runnable example in docs/api.md, and the examples run as written, in order, in an empty
folder (the blocks after an ``<!-- api-test: slow -->`` line are the slow ones; all run in
one slow test)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
API_DOC = ROOT / "docs" / "api.md"
BLOCK = re.compile(r"(<!-- api-test: slow -->\n)?```python\n(.*?)```", re.S)


def _blocks() -> list[tuple[bool, str]]:
    """``(slow, code)`` of every python block of docs/api.md, in order."""
    return [(bool(m.group(1)), m.group(2)) for m in BLOCK.finditer(API_DOC.read_text("utf-8"))]


def _run(code: str, cwd: Path, timeout: float = 300) -> str:
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    return proc.stdout


def _fresh(code: str) -> dict:
    return json.loads(_run(code, ROOT, 120).strip().splitlines()[-1])


def test_import_eha_loads_nothing_else_until_a_name_is_used():
    got = _fresh("import json, sys, eha\n"
                 "before = sorted(m for m in sys.modules if m.startswith('eha'))\n"
                 "numba = 'numba' in sys.modules or 'duckdb' in sys.modules\n"
                 "eha.query\n"
                 "print(json.dumps([before, numba, 'numba' in sys.modules]))")
    assert got == [["eha"], False, False]


def test_every_exported_name_loads_and_is_listed():
    import eha

    got = _fresh("import json, eha\n"
                 "print(json.dumps({n: callable(getattr(eha, n)) for n in eha.__all__ "
                 "if n != '__version__'}))")
    assert got and all(got.values()), got
    assert set(eha.__all__) <= set(dir(eha))
    with pytest.raises(AttributeError):
        eha.no_such_name  # noqa: B018


def test_eha_explain_is_the_package_and_runs_the_loop(monkeypatch):
    import eha
    import eha.explain.api
    import eha.explain.loop

    assert eha.explain is sys.modules["eha.explain"] and eha.explain.loop.ResidualLoop
    monkeypatch.setattr(eha.explain.api, "explain", lambda data, **kw: ("ran", data, kw))
    assert eha.explain("record", max_steps=1) == ("ran", "record", {"max_steps": 1})


def test_every_exported_function_has_an_example():
    import eha

    code = "\n".join(c for _, c in _blocks())
    missing = [n for n in eha.__all__ if n != "__version__" and f"eha.{n}(" not in code]
    assert missing == []


@pytest.mark.slow   # end to end: the examples run as written (a campaign, a pool, the loop)
def test_api_doc_examples_run(tmp_path):
    """Every block in order, in one process (the quick blocks, then the slow ones: what
    test_api_doc_quick_examples_run ran on its own before is the start of this run, so it
    was merged into this test: the suite ran those blocks twice)."""
    blocks = _blocks()
    assert sum(not slow for slow, _ in blocks) >= 4
    out = _run("\n".join(c for _, c in blocks), tmp_path, 600)
    assert "runs done" in out and "RUL" in out


def test_identification_and_assessment_go_to_pandas_with_units():
    """The results of ``identify_source`` and ``assess_record`` are objects with a
    ``.to_pandas()`` (issue 40, part 3): one row per fitted parameter or fault, its SI unit
    from the parameter table, the estimate inside its interval."""
    import eha

    ident = eha.identify_source(command="chirp_1cm", faults={"BKL": 2e-4, "FDJ": 800.0},
                                fit=("BKL", "FDJ"), method="lm", t_end=0.3)
    df = ident.to_pandas()
    assert list(df["parameter"]) == ["BKL", "FDJ"] and list(df["unit"]) == ["m", "N"]
    assert (df["truth"] == [2e-4, 800.0]).all()
    assert (df["lo"] <= df["estimate"]).all() and (df["estimate"] <= df["hi"]).all()
    assert df.loc[df.parameter == "FDJ", "error_pct"].abs().iloc[0] < 10

    trace = eha.simulate("hf", "chirp_1cm", {"BKL": 2e-4}, t_end=0.3)
    health = eha.assess(trace.xu, "chirp_1cm", t_end=0.3, faults=(), pop=6)
    hf = health.to_pandas()
    assert {"BKL", "FDJ"} <= set(hf["fault"])
    row = hf.set_index("fault").loc["BKL"]
    assert row["unit"] == "m" and row["lo"] <= row["estimate"] <= row["hi"]
    assert row["weight"] == 1.0          # a core fault: every hypothesis fits it
    assert ((hf["weight"] >= 0) & (hf["weight"] <= 1)).all()
