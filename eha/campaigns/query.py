"""Read-only queries of a results folder: SQL over ``DIR/eha.duckdb`` and the Parquet traces
(the view ``traces``), the list of tables, CSV export."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.campaigns.schema import TRACES
from eha.campaigns.store import DatabaseDamaged, StoreError, StoreWriteError, connect
from eha.errors import BAD_INPUT, FAILURE
from eha.campaigns.traces import COPY_FLAG, COPY_OF, FILE_MODE, TEMP_SUFFIX
from eha.trace import OUTPUTS


def _create_traces_view(con, results: Path) -> None:
    """Temporary view ``traces``: every stored trace with its ``campaign`` and ``run_key``, and
    every signal of :data:`eha.trace.OUTPUTS` (NULL where a campaign did not store it)."""
    if next((results / TRACES).glob("*/*.parquet"), None) is not None:
        pattern = str(results / TRACES / "*" / "*.parquet").replace("'", "''")
        con.execute(f"""
            CREATE OR REPLACE TEMP VIEW _traces_raw AS
            SELECT * FROM read_parquet('{pattern}', filename = true, union_by_name = true)""")
        present = {r[0] for r in con.execute("DESCRIBE _traces_raw").fetchall()}
        cols = {c: c if c in present else "NULL::DOUBLE" for c in OUTPUTS}
        if COPY_FLAG in present:  # chunks store xu only where it differs from xj
            xu, xj = COPY_OF
            cols[xu] = f"CASE WHEN {COPY_FLAG} THEN {xj} ELSE {cols[xu]} END"
        signals = ", ".join(c if v == c else f"{v} AS {c}" for c, v in cols.items())
        # chunk files carry the run key in a column; a file of the one-file-per-run layout
        # (a campaign run before issue 25) only in its name
        by_name = "regexp_extract(filename, '([0-9a-f]{16})\\.parquet$', 1)"
        key = f"coalesce(run_key, {by_name})" if "run_key" in present else by_name
        con.execute(f"""
            CREATE OR REPLACE TEMP VIEW traces AS
            SELECT regexp_extract(filename, '([^/\\\\]+)[/\\\\][^/\\\\]+$', 1) AS campaign,
                   {key} AS run_key,
                   {signals}
            FROM _traces_raw""")
    else:
        cols = ", ".join(f"NULL::DOUBLE AS {c}" for c in OUTPUTS)
        con.execute("CREATE OR REPLACE TEMP VIEW traces AS SELECT NULL::VARCHAR AS campaign, "
                    f"NULL::VARCHAR AS run_key, {cols} WHERE false")


#: Statement types that only read (DuckDB's parser: ``con.extract_statements``); DESCRIBE,
#: SHOW, SUMMARIZE, FROM-first and WITH are SELECT statements to it. EXPLAIN passes when the
#: statement it explains does, PRAGMA when it is one of :data:`READ_PRAGMAS`.
READ_STATEMENTS = ("SELECT", "EXPLAIN", "PRAGMA")
#: The PRAGMAs that only read the catalogue (the others set options or write files).
READ_PRAGMAS = frozenset({"table_info", "show", "show_tables", "show_tables_expanded",
                          "database_list", "database_size", "storage_info", "metadata_info",
                          "version", "platform", "functions", "collations", "user_agent"})


class TraceDamaged(StoreError):
    """A trace file a query or an export would read is not the file recorded (exit 1)."""

    exit_code = FAILURE


def check_traces(con, results: Path, what: str) -> None:
    """Refuse to read the traces while one of them is damaged: a file whose size or time
    differs from the recorded ones is hashed (:func:`eha.campaigns.integrity.check_files`,
    not ``full``); the message names the file and the command that repairs it."""
    from eha.campaigns.integrity import check_files, damaged_message, recorded_files

    files = recorded_files(con)
    check = check_files(results, files, full=False)
    if check.damaged:
        raise TraceDamaged(damaged_message(results, files, check, what))


def _reads_traces(sql: str) -> bool:
    return re.search(r"\btraces\b|_traces_raw", sql, flags=re.IGNORECASE) is not None


class QueryRefused(StoreError):
    """A statement of ``eha query`` that could write or reach outside the results folder."""

    exit_code = BAD_INPUT


def check_read_only(con, sql: str) -> None:
    """Refuse ``sql`` unless every statement in it only reads (:data:`READ_STATEMENTS`).

    DuckDB's own parser classifies the statements (no regular expression over the SQL);
    ``SET``, ``ATTACH``, ``COPY``, ``EXPORT``, ``INSTALL``/``LOAD``, ``CREATE``, ``INSERT``,
    ``CALL``, transactions, ... are refused with one line. The connection's own guards
    (:func:`_connect_guarded`) hold even if a statement slipped through.

    Raises
    ------
    QueryRefused
        A statement that is not a read; StoreError: SQL that does not parse.
    """
    import duckdb

    try:
        statements = con.extract_statements(sql)
    except duckdb.Error as exc:
        raise StoreError(f"query: {str(exc).splitlines()[0]}") from None
    for st in statements:
        kind = st.type.name
        text = st.query.strip()
        if kind == "EXPLAIN":  # what it explains (EXPLAIN ANALYZE runs it)
            inner = re.sub(r"^EXPLAIN\s+(ANALY[SZ]E\s+|\([^)]*\)\s*)?", "", text,
                           flags=re.IGNORECASE)
            if inner != text and inner:
                check_read_only(con, inner)
                continue
        if kind == "PRAGMA":
            name = re.match(r"PRAGMA\s+(\w+)\s*(=)?", text, flags=re.IGNORECASE)
            if name and name.group(2) is None and name.group(1).lower() in READ_PRAGMAS:
                continue
            kind = f"PRAGMA {name.group(1) if name else ''}".strip()
        elif kind in READ_STATEMENTS:
            continue
        raise QueryRefused(f"query: {kind} statements are refused: eha query only reads "
                           "(SELECT, WITH, EXPLAIN, DESCRIBE, SHOW, SUMMARIZE, PRAGMA "
                           "table_info/show_tables/...)")


def _connect_guarded(results: Path):
    """A read-only connection whose configuration is locked: no file outside the results
    folder's ``traces`` can be read or written (``enable_external_access`` false,
    ``allowed_directories`` the traces folder), no extension installed or loaded, no setting
    changed (``lock_configuration``); a statement that slipped past :func:`check_read_only`
    meets these."""
    import duckdb

    con = connect(results, read_only=True)
    try:
        con.execute("SET autoinstall_known_extensions = false")
        con.execute("SET autoload_known_extensions = false")
        con.execute("SET allowed_directories = ?", [[str(results / TRACES) + os.sep]])
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
    except duckdb.Error as exc:
        con.close()
        raise StoreError(f"query: {str(exc).splitlines()[0]}") from None
    return con


def query(results: str | Path, sql: str,
          params: Sequence[Any] | Mapping[str, Any] | None = None):
    """Run ``sql`` on a read-only connection to ``DIR/eha.duckdb``; returns a pandas DataFrame.

    The Parquet traces are visible as the view ``traces`` (columns ``campaign``, ``run_key``
    and the stored signals). Values go in ``params``, never into the SQL text: ``?``
    placeholders with a sequence, ``$name`` with a mapping, e.g.
    ``query(results, "SELECT * FROM runs WHERE campaign = ?", ["thesis-matrix"])``.

    Only statements that read pass (:func:`check_read_only`), on a connection that cannot
    write, reach files outside the traces or change its settings (:func:`_connect_guarded`).

    Raises
    ------
    StoreError
        No database, database locked, or an SQL error (first line of DuckDB's message);
        :class:`QueryRefused` a statement that is not a read.
    """
    import duckdb

    results = Path(results).resolve()
    con = _connect_guarded(results)
    try:
        check_read_only(con, sql)
        if _reads_traces(sql):
            check_traces(con, results, "query")
        _create_traces_view(con, results)
        return _interruptible(con, lambda: (con.execute(sql, params) if params is not None
                                            else con.execute(sql)).df())
    except duckdb.Error as exc:
        first = str(exc).splitlines()[0]
        if ".parquet" in first:  # a stored trace is damaged: the resume re-runs it
            from eha.campaigns.integrity import repair_hint

            first += f"; a stored trace is damaged, repair it with: {repair_hint(results)}"
        elif "Corrupt" in first or "checksum" in first:
            raise DatabaseDamaged(f"query: {first}; the database file is damaged: move it "
                                  "away and run the campaigns again") from None
        raise StoreError(f"query: {first}{_not_written(first)}") from None
    finally:
        con.close()


def _interruptible(con, work):
    """``work()`` (a query on ``con``) on a helper thread, the main thread waiting: Ctrl-C and
    SIGTERM run their handlers in the main thread only, never while it sits inside a DuckDB
    call (a long query ran to its end before a SIGTERM was seen). On either, DuckDB is told
    to stop (``interrupt``) and the signal's exception goes on."""
    import threading

    out: dict[str, Any] = {}
    finished = threading.Event()

    def run() -> None:
        try:
            out["value"] = work()
        except BaseException as exc:  # handed to the main thread
            out["error"] = exc
        finally:
            finished.set()

    threading.Thread(target=run, name="eha-query", daemon=True).start()
    # an Event, not Thread.join: a join that a handler interrupts marks the thread as ended
    # (CPython 3.11), and the exit then aborts DuckDB in the middle of its query
    try:
        while not finished.wait(0.05):
            pass
    except BaseException:
        con.interrupt()
        finished.wait(10.0)
        raise
    if "error" in out:
        raise out["error"]
    return out["value"]


def _io_reason(text: str) -> str:
    """The reason of a DuckDB I/O error, without its JSON wrapping: ``File too large`` of
    ``IO Error: ... {"exception_type":"IO","exception_message":"Could not write file
    \"x\": File too large",...}``."""
    import json

    found = re.search(r"\{.*\}", text)
    if found:
        try:
            text = json.loads(found.group(0)).get("exception_message", text)
        except ValueError:
            pass
    return text.splitlines()[0].rsplit(": ", 1)[-1]


def _not_written(message: str) -> str:
    """For DuckDB's "Table with name X does not exist" of a table a job kind declares (entry
    points ``eha.tables``): what it means here; else nothing."""
    from eha.campaigns.jobs import TABLE_GROUP, _entry_points

    found = re.search(r"Table with name (\w+) does not exist", message)
    if found is None or found.group(1) not in _entry_points(TABLE_GROUP):
        return ""
    return (f" ({found.group(1)} is created when {_entry_points(TABLE_GROUP)[found.group(1)].value}"
            " first writes to this results folder; nothing has yet)")


def tables(results: str | Path) -> list[str]:
    """Names of the tables and views that :func:`export_csv` accepts."""
    con = connect(results, read_only=True)
    try:
        names = [r[0] for r in con.execute("SELECT table_name FROM information_schema.tables "
                                           "ORDER BY table_name").fetchall()]
    finally:
        con.close()
    return names + ["traces"]


def export_csv(results: str | Path, table: str, path: str | Path) -> int:
    """Write a table (or the ``traces`` view) of ``DIR/eha.duckdb`` to CSV; returns the rows.

    Streams with DuckDB's ``COPY`` (no copy in memory) to a temporary name, then renames, so a
    failed export leaves nothing behind.
    """
    import duckdb

    allowed = tables(results)
    if table not in allowed:
        raise StoreError(f"export: unknown table {table!r}; allowed: {', '.join(allowed)}"
                         f"{_not_written(f'Table with name {table} does not exist')}")
    results = Path(results).resolve()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    con = connect(results, read_only=True)
    try:
        if table == "traces":
            check_traces(con, results, "export traces")
        _create_traces_view(con, results)
        target = tmp.replace("'", "''")
        con.execute(f"COPY (SELECT * FROM \"{table}\") TO '{target}' (HEADER, DELIMITER ',')")
        n = con.execute(f'SELECT count(*) FROM "{table}"').fetchall()[0][0]
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except duckdb.IOException as exc:  # the CSV could not be written (a full disk)
        raise StoreWriteError(f"export {table}: {path}: could not be written "
                              f"({_io_reason(str(exc))}); nothing was written") from None
    except duckdb.Error as exc:
        raise StoreError(f"export {table}: {str(exc).splitlines()[0]}") from None
    finally:
        con.close()
        Path(tmp).unlink(missing_ok=True)
    return int(n)


