"""``eha query`` cannot write (issue 43): only reading statements pass DuckDB's own parser,
and the connection's guards (no file access outside the traces, no extensions, settings
locked) hold for a statement that would slip through. Each hostile case of the audit leaves
every file of both results folders as it was."""

from __future__ import annotations

import shutil

import pytest
from helpers import Inline, error_line, invoke_eha, small_campaign

from eha.campaigns.query import QueryRefused, _connect_guarded, check_read_only, query
from eha.campaigns.runner import run_campaign


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    root = tmp_path_factory.mktemp("guard")
    small_campaign(root, 0.02)
    s = run_campaign(root / "small.toml", root / "a", executor=Inline(), progress=False)
    assert s.failed == 0
    shutil.copytree(root / "a", root / "b")
    return root


def snapshot(root):
    return {str(p.relative_to(root)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(root.rglob("*")) if p.is_file()}


def hostile(root):
    a, b = root / "a", root / "b"
    chunk = next((a / "traces" / "small").glob("*.parquet"))
    return [
        f"SET log_query_path='{a / 'eha.duckdb'}'; SELECT 42",
        f"ATTACH '{b / 'eha.duckdb'}' AS o (READ_WRITE); DROP TABLE o.metrics",
        f"COPY (SELECT 1 AS x) TO '{chunk}' (FORMAT parquet)",
        f"EXPORT DATABASE '{root / 'exported'}'",
        "INSTALL httpfs",
        "LOAD httpfs",
        f"ATTACH '{root / 'new.duckdb'}' AS n",
        "CREATE TABLE x AS SELECT 1",
        "INSERT INTO runs (run_key) VALUES ('x')",
        "DELETE FROM runs",
        "PRAGMA enable_profiling",
        f"PRAGMA profiling_output='{root / 'p.txt'}'",
        "CALL pragma_version()",
        "CHECKPOINT",
        "BEGIN TRANSACTION",
        f"EXPLAIN ANALYZE COPY (SELECT 1) TO '{root / 'e.csv'}'",
        "SELECT 1; DROP TABLE runs",
    ]


def test_every_writing_statement_is_refused_with_one_line_and_no_file_changes(two):
    before = snapshot(two)
    for sql in hostile(two):
        proc = invoke_eha("query", sql, "--results", two / "a")
        line = error_line(proc, 2)
        assert "refused" in line and "only reads" in line, (sql, line)
    assert snapshot(two) == before


@pytest.mark.parametrize("sql", ["SELECT count(*) FROM runs", "WITH a AS (SELECT 1 AS x) "
                                 "SELECT * FROM a", "FROM metrics LIMIT 1", "DESCRIBE runs",
                                 "SHOW TABLES", "SUMMARIZE runs", "EXPLAIN SELECT * FROM runs",
                                 "PRAGMA table_info('runs')", "PRAGMA show_tables",
                                 "SELECT count(*) FROM traces"])
def test_reading_statements_pass(two, sql):
    assert len(query(two / "a", sql)) >= 1


def test_the_connections_own_guards_hold_without_the_parser(two):
    """Statements sent straight to the guarded connection, as if the parser had let them by."""
    import duckdb

    before = snapshot(two)
    con = _connect_guarded((two / "a").resolve())
    try:
        for sql in [f"SET log_query_path='{two / 'a' / 'eha.duckdb'}'",
                    f"ATTACH '{two / 'b' / 'eha.duckdb'}' AS o (READ_WRITE)",
                    f"EXPORT DATABASE '{two / 'exported'}'", "INSTALL httpfs", "LOAD httpfs",
                    "SELECT * FROM read_csv('/etc/passwd')",
                    f"COPY (SELECT 1) TO '{two / 'x.csv'}'",
                    "SET enable_external_access = true", "SET allowed_directories = ['/']",
                    "CREATE TABLE x AS SELECT 1"]:
            with pytest.raises(duckdb.Error):
                con.execute(sql)
    finally:
        con.close()
    assert snapshot(two) == before


def test_a_statement_that_does_not_parse_is_one_line(two):
    con = _connect_guarded((two / "a").resolve())
    try:
        with pytest.raises(Exception, match="query: Parser Error"):
            check_read_only(con, "SELEC 1")
        with pytest.raises(QueryRefused, match="SET statements are refused"):
            check_read_only(con, "SET threads = 1")
    finally:
        con.close()


def test_table_format_shows_a_limited_number_of_rows_and_says_how_many_more(two):
    sql = "SELECT * FROM range(2500) t(i)"
    proc = invoke_eha("query", sql, "--results", two / "a")
    assert proc.returncode == 0
    assert "1500 more rows not shown" in proc.stdout
    proc = invoke_eha("query", sql, "--results", two / "a", "--limit", "10")
    assert "2490 more rows not shown" in proc.stdout
    proc = invoke_eha("query", sql, "--results", two / "a", "--format", "csv")
    assert len(proc.stdout.splitlines()) == 2501 and "not shown" not in proc.stdout


def test_user_text_in_a_query_result_is_not_console_markup(two):
    proc = invoke_eha("query", "SELECT 'x[/]' AS \"[bold]a\", '[bold]b' AS c",
                      "--results", two / "a")
    assert proc.returncode == 0, proc.stderr
    assert "x[/]" in proc.stdout and "[bold]b" in proc.stdout and "[bold]a" in proc.stdout


def test_an_actuator_id_with_brackets_is_printed_as_it_is(capsys):
    """The audit's `x[/]` actuator ended `eha rul` with a MarkupError after the work was
    saved, and `[bold]` in a name vanished: the console prints text, tables included."""
    from types import SimpleNamespace

    from eha.cli.prognostics import _render_rul

    pred = SimpleNamespace(cycle=3.0, rul=10.0, rul_lo=5.0, rul_hi=20.0, driver="[bold]BKL")
    res = SimpleNamespace(predictions={"x[/]": [pred], "[bold]a1": [pred]}, metrics=None,
                          assessed=2, reused=0, seconds={"total": 1.0}, run_id="r[/]",
                          paths={"json": "out/[red]x.json"}, failed=[], output={})
    _render_rul(res, "results[/]")
    out = capsys.readouterr().out
    for text in ("x[/]", "[bold]a1", "[bold]BKL", "results[/]", "out/[red]x.json"):
        assert text in out, (text, out)
