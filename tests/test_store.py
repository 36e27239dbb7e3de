"""Result store: trace files, DuckDB schema, read-only queries, CSV export, locked database."""

import json
import subprocess
import sys
import textwrap
import time

import pandas as pd
import pyarrow.parquet as pq
import pytest
from helpers import Inline, invoke_eha
from typer.testing import CliRunner

from eha.cli import app
from eha.campaigns.runner import run_campaign
from eha.models.simulate import simulate
from eha.campaigns.query import export_csv, query
from eha.campaigns.schema import SCHEMA
from eha.campaigns.store import ResultStore, StoreError
from eha.campaigns.traces import clean_temp_files, read_trace, write_trace

cli = CliRunner()

SMALL = textwrap.dedent("""
    name = "small"
    models = ["hf", "lf"]
    commands = ["step_1mm", "chirp_1mm"]
    t_end = 0.05
    signals = ["t", "com", "xu", "p12"]
    [faults]
    nominal = true
    single = {BKL = [2e-4]}
""")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    root = tmp_path_factory.mktemp("store")
    (root / "small.toml").write_text(SMALL)
    summary = run_campaign(root / "small.toml", root / "results", executor=Inline(),
                           progress=False)
    assert summary.done == 8 and summary.failed == 0
    return root / "results"


def test_write_trace_keeps_chosen_signals_and_metadata(tmp_path):
    tr = simulate("lf", "ramp", {"BKL": 1e-4}, t_end=0.02)
    tr = type(tr)(tr.data, {**tr.meta, "run_key": "0123456789abcdef"})
    path = write_trace(tr, tmp_path / "a" / "x.parquet", columns=["t", "xu", "com"])
    assert pq.read_schema(path).names == ["t", "com", "xu"]
    back = read_trace(path)
    assert back.meta["run_key"] == "0123456789abcdef" and back.meta["params"] == {"BKL": 1e-4}
    assert (back.xu == tr.xu).all() and back["p12"].size == len(tr)
    assert pd.isna(back["p12"]).all()
    assert [p.name for p in path.parent.iterdir()] == ["x.parquet"]


def test_clean_temp_files_removes_only_temporaries(tmp_path):
    (tmp_path / ".abc.parquet.x1.tmp").write_bytes(b"half")
    (tmp_path / "abc.parquet").write_bytes(b"whole")
    assert clean_temp_files(tmp_path) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["abc.parquet"]


def test_schema_tables_and_rows(results):
    names = set(query(results, "SELECT table_name FROM information_schema.tables")["table_name"])
    assert set(SCHEMA) <= names
    runs = query(results, "SELECT * FROM runs")
    assert len(runs) == 8 and set(runs["status"]) == {"done"}
    assert runs["run_key"].is_unique and (runs["campaign"] == "small").all()
    assert all(f"traces/small/{k}.parquet" == p for k, p in zip(runs["run_key"],
                                                                 runs["trace_path"]))
    faults = {json.dumps(json.loads(f), sort_keys=True) for f in runs["faults"]}
    assert faults == {"{}", '{"BKL": 0.0002}'}
    camp = query(results, "SELECT * FROM campaigns")
    assert list(camp["name"]) == ["small"] and camp["n_runs"][0] == 8


def test_traces_view_joins_runs(results):
    df = query(results, """SELECT r.model, r.command, count(*) AS n, max(t) AS t_end,
                                  count(p12) AS n_p12, count(*) FILTER (xs IS NOT NULL) AS n_xs
                           FROM traces JOIN runs r USING (run_key) GROUP BY ALL""")
    assert len(df) == 4  # 2 models x 2 commands (two fault sets each)
    assert (df["n"] == 2 * 51).all() and (df["n_p12"] == df["n"]).all()
    assert (df["t_end"] - 0.05).abs().max() < 1e-12
    assert "xs" not in df.columns or (df["n_xs"] == 0).all()


def test_query_is_read_only(results):
    with pytest.raises(StoreError, match="read-only|read only|only reads|Cannot execute"):
        query(results, "DELETE FROM runs")
    assert len(query(results, "SELECT * FROM runs")) == 8


def test_cli_query_formats_and_errors(results):
    sql = "SELECT model, count(*) AS n FROM runs GROUP BY model ORDER BY model"
    res = cli.invoke(app, ["query", sql, "--results", str(results), "--format", "csv"])
    assert res.exit_code == 0 and res.output.splitlines() == ["model,n", "hf,4", "lf,4"]
    res = cli.invoke(app, ["query", sql, "--results", str(results), "--format", "json"])
    assert json.loads(res.output) == [{"model": "hf", "n": 4}, {"model": "lf", "n": 4}]
    res = cli.invoke(app, ["query", sql, "--results", str(results)])
    assert res.exit_code == 0 and "hf" in res.output
    res = cli.invoke(app, ["query", "SELEC 1", "--results", str(results)])
    assert res.exit_code == 2 and "query:" in res.output


def test_export_tables_to_csv(results, tmp_path):
    for table, n in (("runs", 8), ("metrics", 8), ("campaigns", 1), ("traces", 8 * 51)):
        out = tmp_path / f"{table}.csv"
        res = cli.invoke(app, ["export", table, "--csv", str(out), "--results", str(results)])
        assert res.exit_code == 0, res.output
        assert len(pd.read_csv(out)) == n
    with pytest.raises(StoreError, match="unknown table 'nope'; allowed: campaigns, .*runs, "
                       "schema_migrations, traces"):
        export_csv(results, "nope", tmp_path / "nope.csv")
    assert not (tmp_path / "nope.csv").exists()


def test_missing_database_is_a_clear_message(tmp_path):
    res = cli.invoke(app, ["query", "SELECT 1", "--results", str(tmp_path)])
    assert res.exit_code == 2 and "no result database yet" in res.output


def test_locked_database_gives_one_line_not_a_traceback(results, tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import duckdb, sys, time; c = duckdb.connect(sys.argv[1]); "
         "print('locked', flush=True); time.sleep(60)", str(results / "eha.duckdb")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(StoreError, match=f"locked by another process \\(PID {holder.pid}"):
            ResultStore(results)
        # the commands in this process (the lock is the other process's, as for a user)
        for args in (["query", "SELECT 1"], ["export", "runs", "--csv", str(tmp_path / "r.csv")]):
            proc = invoke_eha(*args, "--results", str(results))
            lines = proc.stderr.strip().splitlines()
            assert proc.returncode == 2 and len(lines) == 1, proc.stderr
            assert f"is locked by another process (PID {holder.pid}" in lines[0]
        (tmp_path / "c.toml").write_text(SMALL)
        t0 = time.perf_counter()
        proc = invoke_eha("campaign", "run", str(tmp_path / "c.toml"), "--results", str(results))
        assert proc.returncode == 2 and "locked by another process" in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
        assert time.perf_counter() - t0 < 30
    finally:
        holder.kill()
        holder.wait()
    assert not (tmp_path / "r.csv").exists()
