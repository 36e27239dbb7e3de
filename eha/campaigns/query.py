"""Read-only queries of a results folder: SQL over ``DIR/eha.duckdb`` and the Parquet traces
(the view ``traces``), the list of tables, CSV export."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.campaigns.schema import TRACES
from eha.campaigns.store import DatabaseDamaged, StoreError, StoreWriteError, connect
from eha.errors import BAD_INPUT, FAILURE
from eha.campaigns.traces import COPY_FLAG, COPY_OF, TEMP_SUFFIX
from eha.trace import OUTPUTS


#: Marker of the error a ``traces`` query meets when it reads a damaged campaign's part.
DAMAGED_MARK = "eha-trace-damaged:"


def glob_pattern(path: str | Path) -> str:
    """A glob pattern that DuckDB's file functions match to ``path`` alone: the glob
    characters ``*``, ``?`` and ``[`` each in a character class of its own (``[[]``). A
    folder ``g[1]`` would otherwise match ``g1``."""
    return re.sub(r"([*?\[])", r"[\1]", str(path))


def glob_escaped(path: str | Path) -> str:
    """:func:`glob_pattern` as the text of an SQL string literal (the quote doubled)."""
    return glob_pattern(path).replace("'", "''")


def _create_traces_view(con, results: Path, files: Sequence[Any] = (),
                        damaged: Mapping[str, str] | None = None) -> None:
    """Temporary view ``traces``: the runs of the recorded trace files ``files``
    (:func:`eha.campaigns.integrity.recorded_files`) with their ``campaign`` and ``run_key``,
    and every signal of :data:`eha.trace.OUTPUTS` (NULL where a campaign did not store it).

    The view lists the recorded files by name (no glob): a file no done run records (a copy,
    a stray, another database's) is never read. A campaign with a file in ``damaged`` is not
    read at all: its part of the view raises an error naming it (:data:`DAMAGED_MARK`) when a
    query reads it, so that a query of the other campaigns, or of no trace, still runs.
    """
    damaged = damaged or {}
    bad = sorted({f.campaign for f in files if f.path in damaged})
    intact = [glob_escaped(results / f.path) for f in files if f.campaign not in bad]
    empty = ", ".join(f"NULL::DOUBLE AS {c}" for c in OUTPUTS)
    parts = []
    if intact:
        listed = ", ".join(f"'{p}'" for p in intact)
        con.execute(f"""
            CREATE OR REPLACE TEMP VIEW _traces_raw AS
            SELECT * FROM read_parquet([{listed}], filename = true, union_by_name = true)""")
        present = {r[0] for r in con.execute("DESCRIBE _traces_raw").fetchall()}
        cols = {c: c if c in present else "NULL::DOUBLE" for c in OUTPUTS}
        if COPY_FLAG in present:  # chunks store xu only where it differs from xj
            xu, xj = COPY_OF
            cols[xu] = f"CASE WHEN {COPY_FLAG} THEN {xj} ELSE {cols[xu]} END"
        signals = ", ".join(f"{v}::DOUBLE AS {c}" for c, v in cols.items())
        # chunk files carry the run key in a column; a file of the one-file-per-run layout
        # (a campaign run before issue 25) only in its name
        by_name = "regexp_extract(filename, '([0-9a-f]{16})\\.parquet$', 1)"
        key = f"coalesce(run_key, {by_name})" if "run_key" in present else by_name
        parts.append(f"""
            SELECT regexp_extract(filename, '([^/\\\\]+)[/\\\\][^/\\\\]+$', 1) AS campaign,
                   {key}::VARCHAR AS run_key, {signals}
            FROM _traces_raw""")
    for name in bad:
        text = f"{DAMAGED_MARK}{name}".replace("'", "''")
        parts.append(f"SELECT '{name.replace(chr(39), chr(39) * 2)}'::VARCHAR AS campaign, "
                     f"NULL::VARCHAR AS run_key, {empty} FROM range(1) "
                     f"WHERE error('{text}') IS NULL")
    if not parts:
        parts.append(f"SELECT NULL::VARCHAR AS campaign, NULL::VARCHAR AS run_key, {empty} "
                     "WHERE false")
    con.execute("CREATE OR REPLACE TEMP VIEW traces AS " + " UNION ALL ".join(parts))


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


def traces_view(con, results: Path):
    """Check the recorded trace files (:func:`eha.campaigns.integrity.check_files`, not
    ``full``: a file whose size or time changed is hashed) and create the view ``traces`` of
    the intact ones (:func:`_create_traces_view`); returns ``(files, check)`` for
    :func:`_damaged_read`. Every reader of ``traces`` opens it through here."""
    from eha.campaigns.integrity import check_files, recorded_files

    files = recorded_files(con)
    check = check_files(results, files, full=False)
    _create_traces_view(con, results, files, check.damaged)
    return files, check


def _damaged_read(message: str, results: Path, files, check, what: str) -> TraceDamaged | None:
    """The one-line error of a query that reached a damaged campaign's part of ``traces``
    (DuckDB's message holds :data:`DAMAGED_MARK`), naming the damaged file; else None."""
    from eha.campaigns.integrity import Check, damaged_message

    found = re.search(re.escape(DAMAGED_MARK) + r"(.*?)(?:\n|$)", message)
    if found is None:
        return None
    name = found.group(1).strip()
    mine = [f for f in files if f.campaign == name]
    sub = Check({p: r for p, r in check.damaged.items() if p in {f.path for f in mine}})
    if not sub.damaged:
        return None
    return TraceDamaged(damaged_message(results, mine, sub, what))


def check_trace_files(results: str | Path, paths, what: str) -> None:
    """Refuse to read the trace files ``paths`` (relative to ``results``, as recorded) while
    one of them is damaged or no done run records it: for readers that open trace files
    themselves (``eha plot``, the reports). Only a file whose size or time changed is hashed.

    Raises
    ------
    TraceDamaged
        Names the first damaged file and the command that repairs it.
    """
    from eha.campaigns.integrity import check_files, damaged_message, recorded_files

    results = Path(results)
    wanted = {str(p) for p in paths}
    if not wanted:          # nothing to read, nothing to check
        return
    con = connect(results, read_only=True)
    try:
        files = [f for f in recorded_files(con) if f.path in wanted]
    finally:
        con.close()
    missing = sorted(wanted - {f.path for f in files})
    if missing:
        raise TraceDamaged(f"{what}: trace file {results / missing[0]} is not recorded by a "
                           f"done run; check the folder with: eha campaign verify --results "
                           f"{results}")
    check = check_files(results, files, full=False)
    if check.damaged:
        raise TraceDamaged(damaged_message(results, files, check, what))


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
    if not statements:  # "", blanks, ";" or a comment
        raise StoreError("query: the SQL holds no statement; give one, e.g. "
                         "eha query \"SELECT * FROM campaigns\"")
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
        # the traces folder by name, and as the pattern the view names its files with
        # (glob_pattern), which matches that folder alone
        folders = dict.fromkeys([str(results / TRACES) + os.sep,
                                 glob_pattern(results / TRACES) + os.sep])
        con.execute("SET allowed_directories = ?", [list(folders)])
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
    return _query(results, sql, params, lambda cur: cur.df())


def query_rows(results: str | Path, sql: str,
               params: Sequence[Any] | Mapping[str, Any] | None = None):
    """:func:`query`'s result as ``(columns, rows)``: the column names and the rows as
    tuples of the Python values DuckDB gives (every digit of an integer or a DECIMAL, floats
    as stored, bytes for a BLOB); for output that must keep them exactly
    (:mod:`eha.campaigns.values`)."""
    return _query(results, sql, params,
                  lambda cur: ([d[0] for d in cur.description], cur.fetchall()))


def _query(results, sql: str, params, fetch):
    import duckdb

    results = Path(results).resolve()
    con = _connect_guarded(results)
    files = check = None
    try:
        check_read_only(con, sql)
        files, check = traces_view(con, results)
        return _interruptible(con, lambda: fetch(con.execute(sql, params) if params is not None
                                                 else con.execute(sql)))
    except duckdb.Error as exc:
        first = str(exc).splitlines()[0]
        damaged = _damaged_read(str(exc), results, files or [], check, "query") \
            if check is not None else None
        if damaged is not None:
            raise damaged from None
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
    """For DuckDB's "Table with name X does not exist" of a table a job kind or another writer
    declares (:func:`eha.campaigns.jobs.declared_tables`): what it means here; else nothing."""
    from eha.campaigns.jobs import declared_tables

    found = re.search(r"Table with name (\w+) does not exist", message)
    if found is None:
        return ""
    module = declared_tables().get(found.group(1))
    if module is None:
        return ""
    return (f" ({found.group(1)} is created when {module}"
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
    """Write a table (or the ``traces`` view) of ``DIR/eha.duckdb`` to CSV; returns the rows
    (:func:`export_table`)."""
    return export_table(results, table, path, "csv")


#: Rows fetched at a time by a JSON export (memory bounded whatever the table's size).
EXPORT_BATCH = 50_000


def export_table(results: str | Path, table: str, path: str | Path,
                 format: str = "csv") -> int:
    """Write a table (or the ``traces`` view) of ``DIR/eha.duckdb`` to a CSV or JSON file;
    returns the rows.

    CSV streams with DuckDB's ``COPY`` (floats in their shortest round-trip text, NaN and
    infinities as ``nan``/``inf``), JSON in batches through :mod:`eha.campaigns.values` (a list
    of records; the same exact values, NaN and infinities as strings), never a copy of the
    table in memory. Written to a temporary name of its own (:func:`eha.outputs.temp_beside`,
    which first removes those of killed exports), then renamed, so a failed export leaves
    nothing behind. ``traces`` reads only intact recorded files (:func:`traces_view`); a
    damaged one fails the export of ``traces``, never of another table.
    """
    import duckdb

    from eha.outputs import FILE_MODE as OUT_MODE, temp_beside

    allowed = tables(results)
    if table not in allowed:
        raise StoreError(f"export: unknown table {table!r}; allowed: {', '.join(allowed)}"
                         f"{_not_written(f'Table with name {table} does not exist')}")
    results = Path(results).resolve()
    path = Path(path)
    tmp = temp_beside(path, TEMP_SUFFIX)
    con = connect(results, read_only=True)
    files = check = None
    try:
        files, check = traces_view(con, results)
        if format == "csv":
            target = str(tmp).replace("'", "''")
            con.execute(f"COPY (SELECT * FROM \"{table}\") TO '{target}' "
                        "(HEADER, DELIMITER ',')")
            n = con.execute(f'SELECT count(*) FROM "{table}"').fetchall()[0][0]
        else:
            n = _write_json(con.execute(f'SELECT * FROM "{table}"'), tmp)
        os.chmod(tmp, OUT_MODE)
        os.replace(tmp, path)
    except duckdb.IOException as exc:  # the CSV could not be written (a full disk)
        raise StoreWriteError(f"export {table}: {path}: could not be written "
                              f"({_io_reason(str(exc))}); nothing was written") from None
    except duckdb.Error as exc:
        damaged = _damaged_read(str(exc), results, files or [], check, f"export {table}") \
            if check is not None else None
        if damaged is not None:
            raise damaged from None
        raise StoreError(f"export {table}: {str(exc).splitlines()[0]}") from None
    except OSError as exc:
        raise StoreWriteError(f"export {table}: {path}: could not be written "
                              f"({exc.strerror or exc}); nothing was written") from None
    finally:
        con.close()
        Path(tmp).unlink(missing_ok=True)
    return int(n)


def _write_json(cursor, tmp: Path) -> int:
    """The cursor's rows as a JSON list of records in ``tmp``, :data:`EXPORT_BATCH` rows at a
    time; returns how many."""
    from eha.campaigns.values import json_records

    columns = [d[0] for d in cursor.description]
    n = 0

    def rows():
        nonlocal n
        while batch := cursor.fetchmany(EXPORT_BATCH):
            n += len(batch)
            yield from batch

    with open(tmp, "w", encoding="utf-8") as fh:
        for piece in json_records(columns, rows()):
            fh.write(piece)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())
    return n
