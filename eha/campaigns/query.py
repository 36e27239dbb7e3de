"""Read-only queries of a results folder: SQL over ``DIR/eha.duckdb`` and the Parquet traces
(the view ``traces``), the list of tables, CSV export."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.campaigns.schema import TRACES
from eha.campaigns.store import StoreError, connect
from eha.campaigns.traces import COPY_FLAG, COPY_OF, FILE_MODE, TEMP_SUFFIX
from eha.models import OUTPUTS


def _create_traces_view(con, results: Path) -> None:
    """Temporary view ``traces``: every stored trace with its ``campaign`` and ``run_key``, and
    every signal of :data:`eha.models.OUTPUTS` (NULL where a campaign did not store it)."""
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


def query(results: str | Path, sql: str,
          params: Sequence[Any] | Mapping[str, Any] | None = None):
    """Run ``sql`` on a read-only connection to ``DIR/eha.duckdb``; returns a pandas DataFrame.

    The Parquet traces are visible as the view ``traces`` (columns ``campaign``, ``run_key``
    and the stored signals). Values go in ``params``, never into the SQL text: ``?``
    placeholders with a sequence, ``$name`` with a mapping, e.g.
    ``query(results, "SELECT * FROM runs WHERE campaign = ?", ["thesis-matrix"])``.

    Raises
    ------
    StoreError
        No database, database locked, or an SQL error (first line of DuckDB's message).
    """
    import duckdb

    results = Path(results).resolve()
    con = connect(results, read_only=True)
    try:
        _create_traces_view(con, results)
        return _interruptible(con, lambda: (con.execute(sql, params) if params is not None
                                            else con.execute(sql)).df())
    except duckdb.Error as exc:
        first = str(exc).splitlines()[0]
        if ".parquet" in first:  # a stored trace is damaged: the resume re-runs it
            first += ("; a stored trace is damaged, run its campaign again (eha campaign run) "
                      "to re-run it")
        elif "Corrupt" in first or "checksum" in first:
            first += "; the database file is damaged: move it away and run the campaigns again"
        raise StoreError(f"query: {first}") from None
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
        raise StoreError(f"export: unknown table {table!r}; allowed: {', '.join(allowed)}")
    results = Path(results).resolve()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    con = connect(results, read_only=True)
    try:
        _create_traces_view(con, results)
        target = tmp.replace("'", "''")
        con.execute(f"COPY (SELECT * FROM \"{table}\") TO '{target}' (HEADER, DELIMITER ',')")
        n = con.execute(f'SELECT count(*) FROM "{table}"').fetchall()[0][0]
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except duckdb.Error as exc:
        raise StoreError(f"export {table}: {str(exc).splitlines()[0]}") from None
    finally:
        con.close()
        Path(tmp).unlink(missing_ok=True)
    return int(n)


