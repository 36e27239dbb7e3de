"""A job kind is one plug-in (issues 40, 63): one :class:`eha.campaigns.jobs.JobKind` declares
its campaign-file section, its drafts, its worker, its result table and its warm-up; nothing in
eha/campaigns changes and no registry is patched. In this process it is registered with one
call; in another package it is one entry point (``eha.job_kinds``), found by the parent and by
every spawned worker."""

from __future__ import annotations

import json
import os
import textwrap
from typing import Any, Mapping

import pytest
from helpers import Inline, run_eha

from eha.campaigns import jobs
from eha.campaigns.drafts import JobDraft
from eha.campaigns.files import CampaignError, build_campaign
from eha.campaigns.query import query
from eha.campaigns.runner import run_campaign

TOY_RESULTS = """
        CREATE TABLE IF NOT EXISTS toy_results (
            run_key VARCHAR PRIMARY KEY,
            square  BIGINT)"""

#: The toy kind's whole module: what another package would ship (also written to a file for
#: the entry-point test below).
TOY_MODULE = textwrap.dedent('''
    import os

    from eha.campaigns.drafts import JobDraft
    from eha.campaigns.jobs import JobKind, Table

    def drafts(section, table, problems):
        n = section.get("n")
        if not isinstance(n, int) or isinstance(n, bool) or n < 1:
            problems.append("toy.n: a positive integer")
            return []
        return [JobDraft("toy", {"i": i}, columns={"label": f"toy {i}"}, version="toy-1")
                for i in range(n)]

    def run(spec, run_key, campaign, trace_file, **extra):
        return {"rows": {"toy_results": {"square": spec["i"] ** 2, "pid": os.getpid()}}}

    def warm_up():
        # one line per process that warmed the kind up
        with open(os.environ["TOY_WARM_LOG"], "a") as fh:
            fh.write(f"{os.getpid()}\\n")

    TOY = JobKind("toy", run, section="toy", drafts=drafts, warm_up=warm_up,
                  tables=(Table("toy_results", """
                      CREATE TABLE IF NOT EXISTS toy_results (
                          run_key VARCHAR PRIMARY KEY,
                          square  BIGINT,
                          pid     BIGINT)""", per_run=True),))
''')


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


WARMED: list[int] = []


@pytest.fixture
def toy():
    """The toy kind, registered with one call and forgotten after the test."""
    kind = jobs.register(jobs.JobKind(
        "toy", run_toy, section="toy", drafts=expand_toy, warm_up=lambda: WARMED.append(1),
        tables=(jobs.Table("toy_results", TOY_RESULTS, per_run=True),)))
    WARMED.clear()
    yield kind
    jobs.unregister("toy")


def test_a_new_kind_runs_and_stores_its_rows_in_its_own_table(toy, tmp_path):
    camp = build_campaign({"name": "toys", "kind": "toy", "toy": {"n": 3}})
    assert [j.kind for j in camp.jobs] == ["toy"] * 3 and camp.model_version == "toy-1"
    summary = run_campaign(camp, tmp_path, executor=Inline(), progress=False)
    assert summary.done == 3 and summary.failed == 0
    rows = query(tmp_path, "SELECT r.label, t.square FROM runs r JOIN toy_results t "
                           "USING (run_key) ORDER BY t.square")
    assert list(rows["square"]) == [0, 1, 4] and list(rows["label"]) == ["toy 0", "toy 1",
                                                                         "toy 2"]
    assert WARMED == [1]  # its warm-up ran once in this "worker" (the process), not per job


def test_a_kind_forgotten_is_gone_from_the_file_format(tmp_path):
    kind = jobs.register(jobs.JobKind("toy", run_toy, section="toy", drafts=expand_toy))
    assert "toy" in jobs.section_names() and jobs.section("toy") is kind.drafts
    jobs.unregister("toy")
    assert "toy" not in jobs.section_names()
    with pytest.raises(CampaignError, match="toy: unknown key"):
        build_campaign({"name": "toys", "toy": {"n": 1}})


def test_a_declaration_is_checked_when_it_is_made():
    with pytest.raises(ValueError, match="section or top-level keys, not both"):
        jobs.JobKind("x", run_toy, section="x", keys=("a",), drafts=expand_toy)
    with pytest.raises(ValueError, match="give both or neither"):
        jobs.JobKind("x", run_toy, section="x")
    with pytest.raises(TypeError, match="takes a JobKind"):
        jobs.register(run_toy)


@pytest.mark.slow
def test_a_kind_of_another_package_is_one_entry_point_found_by_spawned_workers(tmp_path):
    """A package that is not eha adds the kind ``toy``: its module and one entry point in its
    installed metadata (a ``.dist-info`` folder on the path), nothing else. ``eha campaign
    run`` in a new process runs it on two spawned workers, each of which finds the kind
    through the entry point and warms it up once; the rows are in its own table."""
    site = tmp_path / "site"
    (site / "toy_kind-0.1.dist-info").mkdir(parents=True)
    (site / "toy_kind.py").write_text(TOY_MODULE)
    (site / "toy_kind-0.1.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: toy_kind\nVersion: 0.1\n")
    (site / "toy_kind-0.1.dist-info" / "entry_points.txt").write_text(
        "[eha.job_kinds]\ntoy = toy_kind:TOY\n")
    (tmp_path / "toys.toml").write_text('name = "toys"\nkind = "toy"\n[toy]\nn = 6\n')
    log = tmp_path / "warm.log"
    env = {"PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")]),
           "TOY_WARM_LOG": str(log)}
    results = tmp_path / "results"
    proc = run_eha("campaign", "run", tmp_path / "toys.toml", "--results", results,
                   "--workers", "2", env=env)
    assert proc.returncode == 0, proc.stderr
    proc = run_eha("query", "SELECT t.square, t.pid FROM runs r JOIN toy_results t "
                   "USING (run_key) WHERE r.kind = 'toy' ORDER BY t.square", "--results",
                   results, "--format", "json", env=env)
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert [r["square"] for r in rows] == [0, 1, 4, 9, 16, 25]
    workers = {r["pid"] for r in rows}
    warmed = [int(p) for p in log.read_text().split()]
    # every process that ran a job had warmed the kind up, each once
    assert workers <= set(warmed) and len(warmed) == len(set(warmed)) <= 2
    proc = run_eha("campaign", "validate", tmp_path / "toys.toml", env=env)
    assert proc.returncode == 0, proc.stderr
    proc = run_eha("campaign", "validate", tmp_path / "toys.toml")  # without the package
    assert proc.returncode == 2 and "toy: unknown key" in proc.stderr


def test_every_declared_table_is_found_through_its_entry_point():
    for name in jobs.declared_tables():
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
