"""Readers trust only what the store recorded (issue 62): exact numbers out of ``eha query``
and ``eha export``; the ``traces`` view lists the recorded, checksummed files by name (no
glob, glob characters in the results path, stray and copied files never read, listed by
``eha campaign verify``); every reader checks the files it reads, a damaged one fails only
the reads that need it; a file of another engine saved as ``eha.duckdb`` is refused before
DuckDB looks for an extension; killed exports leave nothing behind for long."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import textwrap

import duckdb
import pytest
from helpers import Inline, error_line, invoke_eha, small_campaign, write_campaign

from eha.campaigns.runner import run_campaign

EXACT_SQL = ("SELECT 1.4e-13::DOUBLE AS clk, 0.1::DOUBLE AS tenth, 1/3 AS third, "
             "'nan'::DOUBLE AS n, 'inf'::DOUBLE AS pinf, '-inf'::DOUBLE AS ninf, "
             "170141183460469231731687303715884105727::HUGEINT AS huge, "
             "18446744073709551615::UBIGINT AS ubig, 9007199254740993::BIGINT AS odd, "
             "'\\x00\\xFFa'::BLOB AS blob, 12345678901234567.891::DECIMAL(20,3) AS dec, "
             "NULL::DOUBLE AS missing, [1.4e-13, 'nan'::DOUBLE] AS list")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A results folder with the 6 runs of the small campaign (one file per run)."""
    root = tmp_path_factory.mktemp("reads")
    s = run_campaign(small_campaign(root), root / "results", executor=Inline(), progress=False)
    assert (s.done, s.failed) == (6, 0)
    return root / "results"


def fresh(recorded, tmp_path, name="results"):
    shutil.copytree(recorded, tmp_path / name)
    return tmp_path / name


def files(results):
    return sorted((results / "traces" / "small").glob("*.parquet"))


def count(results, sql="SELECT count(*) FROM traces"):
    proc = invoke_eha("query", sql, "--results", results, "--format", "json")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)[0]


# -- exact numbers


def test_query_json_keeps_every_value_exact(recorded):
    proc = invoke_eha("query", EXACT_SQL, "--results", recorded, "--format", "json")
    assert proc.returncode == 0, proc.stderr
    row, = json.loads(proc.stdout)      # strict JSON: no NaN token
    assert row["clk"] == 1.4e-13 and row["tenth"] == 0.1 and row["third"] == 1 / 3
    assert (row["n"], row["pinf"], row["ninf"]) == ("NaN", "Infinity", "-Infinity")
    assert row["huge"] == 2 ** 127 - 1 and row["ubig"] == 2 ** 64 - 1
    assert row["odd"] == 9007199254740993           # not a float's 9007199254740992
    assert row["blob"] == "00ff61" and row["missing"] is None
    assert '"dec":12345678901234567.891' in proc.stdout
    assert row["list"] == [1.4e-13, "NaN"]


def test_query_csv_keeps_every_value_exact(recorded):
    proc = invoke_eha("query", EXACT_SQL, "--results", recorded, "--format", "csv")
    assert proc.returncode == 0, proc.stderr
    header, values = proc.stdout.strip().splitlines()
    got = dict(zip(header.split(","), values.split(",", 12)))
    assert got["clk"] == "1.4e-13" and got["third"] == repr(1 / 3)
    assert (got["n"], got["pinf"], got["ninf"]) == ("nan", "inf", "-inf")
    assert got["huge"] == str(2 ** 127 - 1) and got["odd"] == "9007199254740993"
    assert got["blob"] == "\\x00\\xFFa" and got["missing"] == ""


def test_an_integer_column_with_a_null_keeps_its_digits(recorded):
    sql = "SELECT x::HUGEINT AS x FROM (VALUES (1267650600228229401496703205377), (NULL)) t(x)"
    for fmt, want in (("json", '[{"x":1267650600228229401496703205377},{"x":null}]'),
                      ("csv", 'x\n1267650600228229401496703205377\n""')):   # a lone NULL field
        proc = invoke_eha("query", sql, "--results", recorded, "--format", fmt)
        assert proc.stdout.strip() == want.strip(), proc.stdout


def test_export_json_and_csv_give_back_the_stored_floats_bit_for_bit(recorded, tmp_path):
    con = duckdb.connect(str(recorded / "eha.duckdb"), read_only=True)
    stored = con.execute("SELECT * FROM metrics ORDER BY run_key").fetchall()
    names = [d[0] for d in con.description]
    con.close()
    out = tmp_path / "m.json"
    proc = invoke_eha("export", "metrics", "--json", out, "--results", recorded)
    assert proc.returncode == 0, proc.stderr
    rows = sorted(json.loads(out.read_text()), key=lambda r: r["run_key"])
    floats = 0
    for want, got in zip(stored, rows):
        for name, v in zip(names, want):
            if isinstance(v, float):
                floats += 1
                g = got[name]
                assert (math.isnan(v) and g == "NaN") or g == v, (name, v, g)
    assert floats > 20
    csv_out = tmp_path / "m.csv"
    assert invoke_eha("export", "metrics", "--csv", csv_out, "--results",
                      recorded).returncode == 0
    back = duckdb.sql(f"SELECT * FROM read_csv('{csv_out}') ORDER BY run_key").fetchall()
    assert [[v for v in r if isinstance(v, float)] for r in back] == \
        [[v for v in r if isinstance(v, float)] for r in stored]


def test_export_wants_one_of_csv_or_json(recorded, tmp_path):
    assert "one of --csv FILE or --json FILE" in error_line(
        invoke_eha("export", "runs", "--results", recorded), 2)


@pytest.mark.parametrize("sql", ["", "   ", ";", " ; ;", "/* only a comment */"])
def test_an_empty_query_is_one_line_exit_2(recorded, sql):
    assert "holds no statement" in error_line(invoke_eha("query", sql, "--results", recorded),
                                              2)


# -- one read path for traces


def test_a_copied_or_empty_unrecorded_file_is_never_read_and_verify_lists_it(recorded,
                                                                               tmp_path):
    results = fresh(recorded, tmp_path)
    before = count(results)
    shutil.copy(files(results)[0], results / "traces" / "small" / "copy.parquet")
    (results / "traces" / "other").mkdir()
    (results / "traces" / "other" / "zero.parquet").write_bytes(b"")
    assert count(results) == before                                  # not 2x a run's rows
    assert count(results, "SELECT count(DISTINCT campaign) FROM traces") == \
        {"count(DISTINCT campaign)": 1}
    proc = invoke_eha("campaign", "verify", "--results", results)
    assert proc.returncode == 0 and "2 not recorded" in proc.stdout
    assert "copy.parquet" in proc.stderr and "zero.parquet" in proc.stderr


def test_after_the_database_is_moved_away_the_old_traces_are_not_in_the_view(recorded,
                                                                           tmp_path):
    """The recovery the tool recommends: move eha.duckdb away, run one campaign again; the
    other campaign's files stay on disk but no run records them."""
    results = fresh(recorded, tmp_path)
    os.replace(results / "eha.duckdb", tmp_path / "old.duckdb")
    camp = write_campaign(tmp_path, """
        name = "fresh"
        models = ["lf"]
        commands = ["step_1mm"]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    assert run_campaign(camp, results, executor=Inline(), progress=False).done == 1
    got = count(results, "SELECT list(DISTINCT campaign) AS c FROM traces")
    assert got == {"c": ["fresh"]}


def test_glob_characters_in_the_results_path_read_that_folder_only(recorded, tmp_path):
    """With folders g[1] and g1, g[1]'s traces are its own (a glob read g1's)."""
    bracket = fresh(recorded, tmp_path, "g[1]")
    other = tmp_path / "g1"
    camp = write_campaign(tmp_path, """
        name = "other"
        models = ["lf"]
        commands = ["step_1mm"]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    run_campaign(camp, other, executor=Inline(), progress=False)
    out = tmp_path / "t.json"
    proc = invoke_eha("export", "traces", "--json", out, "--results", bracket)
    assert proc.returncode == 0, proc.stderr
    assert {r["campaign"] for r in json.loads(out.read_text())} == {"small"}
    assert count(bracket) == count(recorded)
    weird = fresh(recorded, tmp_path, "it's *?[x]")
    assert count(weird) == count(recorded)


def flip(path, at=0.5):
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.seek(int(size * at))
        b = fh.read(1)[0] ^ 0x80
        fh.seek(int(size * at))
        fh.write(bytes([b]))


def test_a_query_checks_the_traces_whatever_its_text(recorded, tmp_path):
    results = fresh(recorded, tmp_path)
    victim = files(results)[2]
    flip(victim)
    for sql in ("SELECT count(*), sum(xu) FROM query_table('tra'||'ces')",
                "SELECT sum(xu) FROM TRACES"):
        line = error_line(invoke_eha("query", sql, "--results", results), 1)
        assert victim.name in line and "eha campaign verify --repair" in line


def test_a_truncated_chunk_fails_only_the_reads_that_need_it(recorded, tmp_path):
    results = fresh(recorded, tmp_path)
    victim = files(results)[1]
    with open(victim, "r+b") as fh:
        fh.truncate(100)
    assert count(results, "SELECT 42 AS x") == {"x": 42}
    out = tmp_path / "runs.csv"
    assert invoke_eha("export", "runs", "--csv", out, "--results", results).returncode == 0
    assert len(out.read_text().splitlines()) == 7
    line = error_line(invoke_eha("export", "traces", "--csv", tmp_path / "t.csv",
                                 "--results", results), 1)
    assert victim.name in line and "No magic bytes" not in line
    assert not (tmp_path / "t.csv").exists()


def test_a_query_of_another_campaign_is_not_stopped_by_a_damaged_one(recorded, tmp_path):
    results = fresh(recorded, tmp_path)
    camp = write_campaign(tmp_path, """
        name = "second"
        models = ["lf"]
        commands = ["step_1mm"]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    run_campaign(camp, results, executor=Inline(), progress=False)
    flip(files(results)[0])
    assert count(results, "SELECT count(*) AS n FROM traces WHERE campaign = 'second'") == \
        {"n": 51}
    error_line(invoke_eha("query", "SELECT count(*) FROM traces", "--results", results), 1)


def test_plot_refuses_a_damaged_trace_and_names_it(recorded, tmp_path):
    """A flipped byte drew a 1.68 m spike with exit 0; the plot reads the first seed's runs."""
    results = fresh(recorded, tmp_path)
    con = duckdb.connect(str(results / "eha.duckdb"), read_only=True)
    path, = con.execute("SELECT trace_path FROM runs WHERE seed = 0 AND model = 'hf'"
                        ).fetchone()
    con.close()
    flip(results / path)
    line = error_line(invoke_eha("plot", "small", "--results", results), 1)
    assert os.path.basename(path) in line and "eha campaign verify --repair" in line
    assert not list((results / "plots").rglob("*.png")) if (results / "plots").exists() \
        else True


# -- the database file, exports killed


def test_a_sqlite_file_as_the_database_is_refused_before_duckdb_opens_it(tmp_path):
    import sqlite3

    sqlite3.connect(tmp_path / "eha.duckdb").execute("CREATE TABLE t (x)").connection.commit()
    proc = invoke_eha("query", "SELECT 1", "--results", tmp_path)
    line = error_line(proc, 1)
    assert "not a DuckDB database file (a SQLite database)" in line
    assert "download" not in line.lower() and "extension" not in line.lower()


def test_every_connection_has_extension_autoloading_off(recorded):
    from eha.campaigns.store import connect

    con = connect(recorded, read_only=True)
    got = dict(con.execute("SELECT name, value FROM duckdb_settings() WHERE name IN "
                           "('autoload_known_extensions', 'autoinstall_known_extensions')"
                           ).fetchall())
    con.close()
    assert got == {"autoload_known_extensions": "false", "autoinstall_known_extensions": "false"}


def test_the_leftovers_of_a_killed_export_are_removed_by_the_next(recorded, tmp_path):
    """kill -9 of `eha export traces` left its temporary file (44-125 MB) for ever."""
    out = tmp_path / "t.csv"
    code = textwrap.dedent(f"""
        import os, signal
        from eha.campaigns import query
        def die(cursor, tmp):
            os.kill(os.getpid(), signal.SIGKILL)
        query._write_json = die
        query.export_table({str(recorded)!r}, "traces", {str(tmp_path / 't.json')!r}, "json")
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    assert proc.returncode == -9
    left = list(tmp_path.glob(".t.json.*"))
    assert len(left) == 1
    live = tmp_path / f".t.json.eha-{os.getpid()}-live.tmp"   # a running export's: kept
    live.write_text("")
    assert invoke_eha("export", "traces", "--json", tmp_path / "t.json", "--results",
                      recorded).returncode == 0
    assert list(tmp_path.glob(".t.json.*")) == [live]
    assert invoke_eha("export", "runs", "--csv", out, "--results", recorded).returncode == 0
