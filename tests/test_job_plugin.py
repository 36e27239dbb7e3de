"""A job kind is one plug-in (issue 40): a module that registers its campaign-file section, its
worker and its result table runs through the campaign runner without a line of
eha/campaigns changed, and the store creates its table. The registrations here are the ones
a kind's module makes at import (its entry points in pyproject.toml are what a worker process
would need: this runs in-process)."""

from __future__ import annotations

from typing import Any, Mapping

import pytest

from eha.campaigns import jobs
from eha.campaigns.drafts import JobDraft
from eha.campaigns.executors import Executor
from eha.campaigns.files import build_campaign
from eha.campaigns.query import query
from eha.campaigns.runner import run_campaign

TOY_RESULTS = """
        CREATE TABLE IF NOT EXISTS toy_results (
            run_key VARCHAR PRIMARY KEY,
            square  BIGINT)"""


def expand_toy(section: Mapping[str, Any], table: Mapping[str, Any],
               problems: list[str]) -> list[JobDraft]:
    n = section.get("n")
    if not isinstance(n, int) or n < 1:
        problems.append("toy.n: a positive integer")
        return []
    return [JobDraft("toy", {"i": i}, columns={"label": f"toy {i}"}, version="toy-1")
            for i in range(n)]


def run_toy(spec, run_key, campaign, trace_file, **extra) -> dict:
    return {"rows": {"toy_results": {"square": spec["i"] ** 2}}}


class InProcess(Executor):
    """Runs the tasks here, one after the other (a spawned worker would import the kind's
    module through its entry point)."""

    def map_unordered(self, fn, payloads):
        for p in payloads:
            yield fn(p)


@pytest.fixture
def toy(monkeypatch):
    monkeypatch.setitem(jobs._SECTIONS, "toy", expand_toy)
    monkeypatch.setitem(jobs._KINDS, "toy", jobs.JobKind("toy", run_toy))
    monkeypatch.setitem(jobs._TABLES, "toy_results",
                        jobs.Table("toy_results", TOY_RESULTS, per_run=True))


def test_a_new_kind_runs_and_stores_its_rows_in_its_own_table(toy, tmp_path):
    camp = build_campaign({"name": "toys", "kind": "toy", "toy": {"n": 3}})
    assert [j.kind for j in camp.jobs] == ["toy"] * 3 and camp.model_version == "toy-1"
    summary = run_campaign(camp, tmp_path, executor=InProcess(), progress=False)
    assert summary.done == 3 and summary.failed == 0
    rows = query(tmp_path, "SELECT r.label, t.square FROM runs r JOIN toy_results t "
                           "USING (run_key) ORDER BY t.square")
    assert list(rows["square"]) == [0, 1, 4] and list(rows["label"]) == ["toy 0", "toy 1",
                                                                         "toy 2"]


def test_every_declared_table_is_found_through_its_entry_point():
    for name in jobs._entry_points(jobs.TABLE_GROUP):
        assert jobs.table(name).name == name
    assert jobs.table("metrics").per_run and not jobs.table("rul_predictions").per_run
    assert "models" in jobs.file_keys()["simulate"].keys


def test_a_declared_table_not_yet_written_is_named_with_its_module(tmp_path):
    import duckdb

    from eha.campaigns.schema import DB_NAME, SCHEMA
    from eha.campaigns.store import StoreError

    con = duckdb.connect(str(tmp_path / DB_NAME))  # a folder only a simulation campaign wrote
    for ddl in SCHEMA.values():
        con.execute(ddl)
    con.close()
    with pytest.raises(StoreError, match="fdi_results is created when "
                                         "eha.identification.cases first writes"):
        query(tmp_path, "SELECT * FROM fdi_results")
