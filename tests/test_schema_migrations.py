"""The result database's schema version (issue 63): numbered migrations recorded in
``schema_migrations``; an older database is upgraded once and says so, a newer one is refused
with one line and nothing written, and a reader never writes a migration."""

from __future__ import annotations

import hashlib
import logging
import textwrap
from pathlib import Path

import duckdb
import pytest
from helpers import error_line, invoke_eha, run_eha

from eha.campaigns import migrations
from eha.campaigns.migrations import schema_version
from eha.campaigns.schema import DB_NAME, MIGRATIONS, SCHEMA, SCHEMA_VERSION
from eha.campaigns.store import ResultStore, StoreError, connect

#: ``runs`` as the first releases wrote it: before the trace's size, rows, checksum and time
#: (migrations 2 and 3).
OLD_RUNS = """
    CREATE TABLE runs (
        run_key VARCHAR PRIMARY KEY, campaign VARCHAR NOT NULL, kind VARCHAR NOT NULL,
        status VARCHAR NOT NULL, model VARCHAR, command VARCHAR, faults JSON,
        fault_label VARCHAR, seed BIGINT, t_end DOUBLE, case_key VARCHAR, label VARCHAR,
        trace_path VARCHAR, error VARCHAR, worker VARCHAR, queued_at TIMESTAMP,
        started_at TIMESTAMP, finished_at TIMESTAMP, sim_s DOUBLE, elapsed_s DOUBLE,
        spec JSON)"""


def old_database(folder: Path, runs_ddl: str = OLD_RUNS) -> Path:
    """A results folder whose database an eha before schema versions wrote: ``campaigns``,
    ``runs`` (``runs_ddl``) and one failed run, no ``schema_migrations``."""
    folder.mkdir(parents=True, exist_ok=True)
    con = duckdb.connect(str(folder / DB_NAME))
    con.execute(SCHEMA["campaigns"])
    con.execute(runs_ddl)
    con.execute("INSERT INTO runs (run_key, campaign, kind, status, error) VALUES "
                "('00000000000000aa', 'old', 'simulate', 'failed', 'x')")
    con.close()
    return folder


def fingerprint(folder: Path) -> tuple:
    """The folder's files with their size, modification time and content hash."""
    return tuple((p.name, p.stat().st_size, p.stat().st_mtime_ns,
                  hashlib.sha256(p.read_bytes()).hexdigest())
                 for p in sorted(folder.rglob("*")) if p.is_file())


def columns(folder: Path, table: str) -> set[str]:
    con = duckdb.connect(str(folder / DB_NAME), read_only=True)
    try:
        return {c for c, in con.execute("SELECT column_name FROM information_schema.columns "
                                        "WHERE table_name = ?", [table]).fetchall()}
    finally:
        con.close()


def recorded(folder: Path) -> list[tuple[int, str]]:
    con = duckdb.connect(str(folder / DB_NAME), read_only=True)
    try:
        return con.execute("SELECT version, name FROM schema_migrations ORDER BY version"
                           ).fetchall()
    finally:
        con.close()


def upgrade_notes(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == "eha.campaigns.store" and "schema upgraded" in r.getMessage()]


def test_the_migrations_are_numbered_one_by_one_and_the_version_is_the_last():
    assert [m[0] for m in MIGRATIONS] == list(range(1, len(MIGRATIONS) + 1))
    assert SCHEMA_VERSION == MIGRATIONS[-1][0] >= 3
    assert len({m[1] for m in MIGRATIONS}) == len(MIGRATIONS)


def test_a_new_database_records_every_migration_and_says_nothing(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    with ResultStore(tmp_path):
        pass
    assert recorded(tmp_path) == [(m[0], m[1]) for m in MIGRATIONS]
    assert upgrade_notes(caplog) == []


def test_an_older_database_is_upgraded_once_and_says_so(tmp_path, caplog):
    folder = old_database(tmp_path / "r")
    assert "trace_hash" not in columns(folder, "runs")
    caplog.set_level(logging.INFO)
    with ResultStore(folder) as db:
        assert schema_version(db.con) == (SCHEMA_VERSION, True)
    notes = upgrade_notes(caplog)
    assert len(notes) == 1
    assert notes[0].startswith(f"note: {folder.resolve() / DB_NAME}: database schema upgraded "
                               f"from version 0 to {SCHEMA_VERSION} (1: ")
    assert {"trace_bytes", "trace_rows", "trace_hash", "trace_mtime"} <= columns(folder, "runs")
    assert [v for v, _ in recorded(folder)] == list(range(1, SCHEMA_VERSION + 1))
    # the run written before is kept, NULL in the columns added since
    con = duckdb.connect(str(folder / DB_NAME), read_only=True)
    assert con.execute("SELECT status, trace_hash FROM runs").fetchall() == [("failed", None)]
    con.close()
    caplog.clear()
    con = connect(folder)  # any writer, the next time: nothing more to do, nothing said
    con.close()
    with ResultStore(folder):
        pass
    assert upgrade_notes(caplog) == [] and len(recorded(folder)) == SCHEMA_VERSION


def test_a_database_of_the_version_before_the_last_gets_only_the_last(tmp_path, caplog):
    folder = old_database(tmp_path / "r")
    con = duckdb.connect(str(folder / DB_NAME))
    con.execute("CREATE TABLE schema_migrations (version INTEGER PRIMARY KEY, name VARCHAR "
                "NOT NULL, applied_at TIMESTAMP NOT NULL)")
    con.execute("INSERT INTO schema_migrations VALUES (1, 'a', now()::TIMESTAMP), "
                "(2, 'b', now()::TIMESTAMP)")
    con.execute("ALTER TABLE runs ADD COLUMN trace_bytes BIGINT")
    con.execute("ALTER TABLE runs ADD COLUMN trace_rows BIGINT")
    con.close()
    caplog.set_level(logging.INFO)
    ResultStore(folder).close()
    (note,) = upgrade_notes(caplog)
    assert f"from version 2 to {SCHEMA_VERSION} (3: runs: trace file checksum" in note
    assert "1: " not in note and recorded(folder)[:2] == [(1, "a"), (2, "b")]


def test_a_migration_that_fails_leaves_the_database_as_it_was(tmp_path, monkeypatch, caplog):
    """One transaction: a migration whose second statement fails adds nothing, records
    nothing; the error is one line and the next writer (fixed) upgrades it."""
    folder = old_database(tmp_path / "r")
    broken = MIGRATIONS[:2] + ((3, "broken", (MIGRATIONS[2][2][0], "ALTER TABLE nowhere ADD "
                                              "COLUMN x INTEGER")),)
    monkeypatch.setattr(migrations, "MIGRATIONS", broken)
    caplog.set_level(logging.INFO)
    with pytest.raises(StoreError, match="nowhere"):
        ResultStore(folder)
    assert "trace_bytes" not in columns(folder, "runs")
    assert "schema_migrations" not in {t for t, in duckdb.connect(
        str(folder / DB_NAME), read_only=True).execute("SHOW TABLES").fetchall()}
    assert upgrade_notes(caplog) == []
    monkeypatch.undo()
    ResultStore(folder).close()
    assert len(recorded(folder)) == SCHEMA_VERSION and len(upgrade_notes(caplog)) == 1


def newer_database(folder: Path) -> Path:
    ResultStore(folder).close()
    con = duckdb.connect(str(folder / DB_NAME))
    con.execute("INSERT INTO schema_migrations VALUES (?, 'from the future', now()::TIMESTAMP)",
                [SCHEMA_VERSION + 1])
    con.close()
    return folder


@pytest.mark.parametrize("read_only", [False, True])
def test_a_newer_database_is_refused_and_nothing_is_written(tmp_path, read_only):
    folder = newer_database(tmp_path / "r")
    before = fingerprint(folder)
    with pytest.raises(StoreError) as err:
        connect(folder, read_only=read_only)
    assert err.value.exit_code == 2
    assert str(err.value) == (f"{folder / DB_NAME}: its schema is version {SCHEMA_VERSION + 1},"
                              f" newer than this eha knows ({SCHEMA_VERSION}); it was written "
                              "by a newer eha: upgrade eha, or use another results folder")
    assert fingerprint(folder) == before


def test_a_newer_database_is_one_line_and_exit_2_for_readers_and_writers(tmp_path):
    folder = newer_database(tmp_path / "r")
    (tmp_path / "tiny.toml").write_text(TINY)
    before = fingerprint(folder)
    for args in (["query", "SELECT count(*) FROM runs"], ["export", "runs", "--csv",
                                                         tmp_path / "runs.csv"],
                 ["campaign", "run", tmp_path / "tiny.toml"]):
        line = error_line(invoke_eha(*args, "--results", folder), 2)
        assert f"newer than this eha knows ({SCHEMA_VERSION})" in line
    assert fingerprint(folder) == before and not (tmp_path / "runs.csv").exists()


def test_a_reader_of_an_older_database_writes_nothing(tmp_path, caplog):
    folder = old_database(tmp_path / "r")
    before = fingerprint(folder)
    caplog.set_level(logging.INFO)
    proc = invoke_eha("query", "SELECT status FROM runs", "--results", folder, "--format",
                      "csv")
    assert proc.returncode == 0 and proc.stdout.split() == ["status", "failed"]
    proc = invoke_eha("campaign", "verify", "--results", folder)
    assert proc.returncode == 0, proc.stderr
    assert fingerprint(folder) == before and upgrade_notes(caplog) == []
    assert columns(folder, "schema_migrations") == set()  # no such table


TINY = textwrap.dedent("""
    name = "tiny"
    models = ["lf"]
    commands = ["step_1mm"]
    t_end = 0.01
    [faults]
    nominal = true
""")


@pytest.mark.slow
def test_the_command_that_upgrades_says_so_in_one_line_once(tmp_path):
    """``eha campaign run`` on a folder an older eha wrote: one ``note:`` line on stderr the
    first time, none the second; the campaign runs and the folder's old run is kept."""
    folder = old_database(tmp_path / "r")
    (tmp_path / "tiny.toml").write_text(TINY)
    first = run_eha("campaign", "run", tmp_path / "tiny.toml", "--results", folder,
                    "--workers", "1")
    assert first.returncode == 0, first.stderr
    notes = [ln for ln in first.stderr.splitlines() if "schema upgraded" in ln]
    assert notes == [f"note: {folder.resolve() / DB_NAME}: database schema upgraded from "
                     f"version 0 to {SCHEMA_VERSION} ("
                     + "; ".join(f"{v}: {n}" for v, n, _ in MIGRATIONS) + ")"]
    second = run_eha("campaign", "run", tmp_path / "tiny.toml", "--results", folder,
                     "--workers", "1")
    assert second.returncode == 0 and "schema upgraded" not in second.stderr + second.stdout
    assert len(recorded(folder)) == SCHEMA_VERSION
    proc = run_eha("query", "SELECT campaign, status FROM runs ORDER BY campaign",
                   "--results", folder, "--format", "csv")
    assert proc.stdout.split() == ["campaign,status", "old,failed", "tiny,done"]
