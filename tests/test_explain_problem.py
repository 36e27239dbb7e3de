"""One problem per record and one settings object (issue 63, items 1 and 2).

An ``explain`` call builds its record's :class:`~eha.explain.problem.Problem` once (the
record processed, the bounds, the effect pool, the base, the noise and its reference, the
P12 weight) and every part of the run takes it: the healthy null's probe, both passes and
the flow gain's second run. Before, each of them built a ``ResidualLoop`` of its own (up to
5 on one record, 7 construction sites), and ``noise_reference`` of the record was computed at
every stop test (9 to 15 times on a short record). The settings are one
:class:`~eha.explain.settings.LoopSettings`, declared once with their defaults and checks:
``explain(data, settings, **overrides)``, an unknown name refused by name.
"""

from __future__ import annotations

import inspect
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from typer.testing import CliRunner

from eha.explain import ExplainError, LoopSettings, Problem, explain
from eha.identification.measured import load, synthetic_record

FAULTS = {"BKL": 1e-4, "FDJ": 800.0}
#: The cheapest real run: the declared faults fitted by a tiny GA, nothing re-simulated.
CHEAP = {"pop": 6, "max_gen": 3, "stall": 2, "seed": 0, "null": None, "max_steps": 0,
         "interval_replicates": 0, "rival_replicates": 0}


@pytest.fixture(scope="module")
def lf_record(tmp_path_factory):
    path = tmp_path_factory.mktemp("problem") / "lf.csv"
    synthetic_record("mixed", FAULTS, t_end=0.3, noise=1e-6, seed=1,
                     model="lf").to_csv(path, index=False)
    return path


class _Counts:
    """Calls of ``Problem.build`` and of ``noise_reference`` (from ``eha.explain``), split by
    whether they are on the record ``data``."""

    def __init__(self, monkeypatch, data):
        import eha.identification.intervals as intervals

        self.builds, self.references = [], []
        build, reference = Problem.build.__func__, intervals.noise_reference

        def counted_build(cls, record, *args, **kwargs):
            self.builds.append(record is data)
            return build(cls, record, *args, **kwargs)

        def counted_reference(noise, xu):
            caller = sys._getframe(1).f_globals.get("__name__", "")
            if caller.startswith("eha.explain"):
                self.references.append(xu is data.xu)
            return reference(noise, xu)

        monkeypatch.setattr(Problem, "build", classmethod(counted_build))
        monkeypatch.setattr(intervals, "noise_reference", counted_reference)


def test_one_explain_call_builds_its_records_problem_once(lf_record, monkeypatch):
    """A real run on an LF record: one problem, one noise reference of the record computed by
    the loop's package (the stop tests, the verdict and the intervals' flag read it), and the
    settings given by keyword (``significance`` among them) kept in the result."""
    data = load(lf_record)
    counts = _Counts(monkeypatch, data)
    res = explain(data, significance=0.02, **CHEAP)
    assert counts.builds == [True]
    assert counts.references == [True]
    assert res.settings["significance"] == 0.02 and res.settings["max_gen"] == 3
    assert res.settings["pop"] == 6 and "options" not in res.settings


@dataclass
class _Facts:
    passes: int = 1
    flow_gain_released: str | None = None


@dataclass
class _Result:
    beyond_healthy: bool = True
    seconds: float = 1.0
    settings: dict = field(default_factory=dict)
    facts: _Facts = field(default_factory=_Facts)


def test_the_null_both_passes_and_the_flow_gain_rerun_share_one_problem(lf_record,
                                                                         monkeypatch):
    """Control flow without a fit: the simulated null's probe, the first and second pass and
    both passes again with GQ at nominal all take the problem built once (the rerun's is the
    same problem without the flow gain: same record, same noise, same pool)."""
    import eha.explain.api as api

    data = load(lf_record)
    counts = _Counts(monkeypatch, data)
    seen, nulls = [], []

    class Loop:
        def __init__(self, problem, settings, null=None, on_progress=None,
                     pin_structure=False, first_excluded=None):
            seen.append((problem, settings, pin_structure, null))

        def run(self):
            return _Result()

    def fake_null(record, bounds, names, settings, **kwargs):
        nulls.append((record, bounds, names))
        return "the null"

    edges = iter(["GQ at the edge", None])
    monkeypatch.setattr(api, "ResidualLoop", Loop)
    monkeypatch.setattr(api, "simulated_null", fake_null)
    monkeypatch.setattr(api, "better_pass", lambda first, second, settings: first)
    monkeypatch.setattr(api, "flow_gain_at_edge", lambda result: next(edges))
    res = explain(data, pop=6, seed=3)
    assert counts.builds == [True] and counts.references == [True]
    assert len(seen) == 4 and [s[2] for s in seen] == [False, True, False, True]
    first = seen[0][0]
    assert nulls == [(data, first.bounds, [e.name for e in first.pool])]
    assert all(s[3] == "the null" for s in seen)
    assert seen[1][0] is first and "GQ" in first.bounds
    again = seen[2][0]
    assert seen[3][0] is again and "GQ" not in again.bounds
    assert again.record is first.record and again.noise_ref == first.noise_ref
    assert again.pool == first.pool
    assert seen[2][1].flow_gain_spread == 0.0 and seen[0][1].flow_gain_spread == 0.04
    assert res.facts.flow_gain_released == "GQ at the edge" and res.facts.passes == 2
    assert res.settings["flow_gain_spread"] == 0.04


def test_explain_takes_one_settings_object_and_refuses_an_unknown_name(lf_record):
    """At most six parameters; ``settings`` overridden by keyword; an unknown name (a typo of
    ``significance``, which before fell into the optimizer's options and failed at the first
    fit) refused by name, on one line, before any work."""
    assert len(inspect.signature(explain).parameters) <= 6
    data = load(lf_record)
    with pytest.raises(ExplainError) as err:
        explain(data, signifcance=0.05)
    text = str(err.value)
    assert "\n" not in text and text.startswith("`signifcance`: not a setting")
    assert "significance" in text and "max_gen" in text       # what is allowed
    with pytest.raises(ExplainError, match=r"significance 2: allowed range \(0, 1\)"):
        explain(data, LoopSettings(), significance=2)
    with pytest.raises(ExplainError, match="`step0`: not an option of method ga "):
        explain(data, method="ga", step0=0.1)
    settings = LoopSettings(holdout=0.2).override({"significance": 0.05, "max_gen": 7,
                                                   "alpha": None})
    assert (settings.holdout, settings.significance, settings.alpha) == (0.2, 0.05, 0.05)
    assert settings.options == {"max_gen": 7}
    assert settings.as_dict()["max_gen"] == 7 and "options" not in settings.as_dict()


def test_the_cli_builds_the_settings_the_library_reads(lf_record, monkeypatch, tmp_path):
    """``eha explain`` builds one LoopSettings from its options and hands it to the file
    reader, which hands the same object to the loop; a value out of range exits 2 with one
    line naming the option and nothing run."""
    import eha.explain.api as api
    import eha.explain.from_file as from_file

    got = []

    def fake_explain(record, settings=None, **inputs):
        got.append(settings)
        raise SystemExit(0)         # stop after the hand-over: nothing to run or write

    monkeypatch.setattr(from_file, "explain", fake_explain)
    from eha.cli import app

    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["explain", str(lf_record), "--pop", "7", "--seed", "2",
                                      "--min-gain", "0.2", "--out", str(out),
                                      "--results", str(tmp_path / "r"), "--no-progress"])
    assert result.exit_code == 0, result.output
    (settings,) = got
    assert settings == LoopSettings(pop=7, seed=2, min_gain=0.2)
    result = CliRunner().invoke(app, ["explain", str(lf_record), "--alpha", "1.5",
                                      "--out", str(out), "--no-progress"])
    assert result.exit_code == 2 and "--alpha 1.5: allowed range (0, 1)" in result.output
    assert len(got) == 1 and not out.exists()
    assert api.INPUTS["null"] == "simulate"


def test_no_object_writes_into_another_ones_dict():
    """``git grep __dict__ eha/explain`` is empty: no stash on a candidate, no cache kept in a
    loop's ``__dict__`` (issue 63)."""
    folder = Path(__file__).resolve().parents[1] / "eha" / "explain"
    users = [p.name for p in folder.rglob("*.py") if "__dict__" in p.read_text("utf-8")]
    assert users == []
