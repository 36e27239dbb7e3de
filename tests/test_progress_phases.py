"""No silent phase (issue 42, item 3): the healthy null says how far it is and how long is
left from its first second, and the exclusion check after the final estimates is named as what
it is, not "round 1" again. Each test failed before the change."""

from __future__ import annotations

import time

import pytest


def test_the_healthy_null_says_k_of_n_and_the_time_left():
    from eha.explain.null import _fleet_progress

    said: list[str] = []
    t0 = time.perf_counter() - 30.0            # 30 s spent when the 3rd actuator ends
    say = _fleet_progress(said.append, 12, t0)
    say(0)
    say(3)
    say(12)
    assert said[0].endswith("simulating and fitting 12 healthy actuators")
    assert "once, then cached" in said[0]
    assert said[1].endswith("actuator 3 of 12 done, about 1 min 30 s left"), said[1]
    assert said[2].endswith("actuator 12 of 12 done")


def test_the_exclusion_check_is_not_labelled_as_a_round():
    from eha.explain.final_check import FinalCheck
    from eha.explain.rounds import Rounds

    labels: list[str] = []

    class Probe(Rounds, FinalCheck):
        phase = ""
        rounds = [object()]

        def fit_with_cost(self, start, free, label, **kwargs):
            labels.append(label)
            raise StopIteration

    loop = Probe()
    with pytest.raises(StopIteration):
        loop.local_test(None, {}, [])
    loop.phase = "exclusion check (does another effect fit as well?)"
    with pytest.raises(StopIteration):
        loop.local_test(None, {}, [])
    assert labels[0].startswith("round 1: local test")
    assert labels[1].startswith("exclusion check (does another effect fit as well?): local")


def test_a_rerun_keeps_the_record_of_the_run_that_did_the_work(tmp_path):
    """``reports/summary.md``'s campaigns table: a later ``eha reproduce`` that finds every
    run done (0 run now) keeps the counts and the wall time of the call that ran them."""
    from eha.campaigns.runner import RunSummary
    from eha.reports.thesis import _work_record

    first = [RunSummary("thesis-nominal", total=12, done=12, wall_s=61.5)]
    (work,) = _work_record(tmp_path, first)
    assert work["done"] == 12 and work["wall_s"] == 61.5
    again = [RunSummary("thesis-nominal", total=12, skipped=12, wall_s=0.4)]
    (kept,) = _work_record(tmp_path, again)
    assert kept == work
    resumed = [RunSummary("thesis-nominal", total=12, done=2, skipped=10, wall_s=9.0)]
    assert _work_record(tmp_path, resumed)[0]["done"] == 2


def test_reproduce_names_its_phases_after_the_campaigns(tmp_path, monkeypatch):
    """The figures, the reports and the HTML page (20 s and more after the campaigns, silent
    before) are each announced."""
    import contextlib

    import pandas as pd

    import eha.campaigns.executors as executors
    import eha.campaigns.runner as runner
    import eha.reports.html as html
    import eha.reports.thesis as thesis

    monkeypatch.setattr(executors, "LocalPoolExecutor", lambda n: contextlib.nullcontext())
    monkeypatch.setattr(runner, "run_campaign", lambda *a, **k: runner.RunSummary("x", 0))
    monkeypatch.setattr(thesis, "campaign_runs", lambda results, name: pd.DataFrame(
        {"command": [], "model": [], "trace_path": [], "run_key": []}))
    monkeypatch.setattr(thesis, "plot_campaign", lambda results, name: [])
    monkeypatch.setattr(thesis, "campaign_report", lambda results, name: tmp_path / "r.csv")
    monkeypatch.setattr(thesis, "_summary_markdown", lambda *a: tmp_path / "s.md")
    monkeypatch.setattr(thesis, "thesis_report", lambda results: {
        "plot": tmp_path / "p.png", "table": tmp_path / "t.csv", "summary": tmp_path / "f.md"})
    monkeypatch.setattr(html, "build_report", lambda *a: type("R", (), {"path": tmp_path})())
    said: list[str] = []
    thesis.reproduce_thesis(tmp_path, on_phase=said.append)
    assert any(m.startswith("figures and CSV of campaign thesis-nominal") for m in said)
    assert said[-2].startswith("thesis fault identification report")
    assert said[-1].startswith("HTML report")
