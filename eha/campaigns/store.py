"""The result database ``DIR/eha.duckdb``: connections, the campaign parent's writer.

Campaign results live in ``DIR/eha.duckdb`` (DuckDB). The campaign's parent process is its only
writer (:class:`ResultStore`); queries go through a read-only connection
(:func:`eha.campaigns.query.query`) that also sees every Parquet trace as the view ``traces``.
The store keeps campaigns, runs and chunk files (:data:`eha.campaigns.schema.SCHEMA`) and the
transactions; each job kind (or other writer) declares its own result tables
(:func:`eha.campaigns.jobs.register_table`), which :func:`connect` creates, with their added
columns, on a writable connection once they are registered. Writers outside a campaign (a
check, a calibration, a residual-loop run) replace their rows in one transaction
(:func:`replace_rows`, :func:`replace_parts`).

Layout of a results directory::

    DIR/eha.duckdb                          campaigns, runs, metrics (+ other result tables)
    DIR/traces/<campaign>/chunk-<hash>.parquet  the runs of one task (column run_key)
    DIR/traces/<campaign>/<run_key>.parquet     a task of one run, or an older campaign

Trace files are :mod:`eha.campaigns.traces`'.
"""

from __future__ import annotations

import json
import logging
import os
import re
from pathlib import Path
from typing import Any, Mapping, Sequence

# No simulation code at import time (eha.models.simulate loads numba): `eha query` starts fast.
from eha.campaigns.jobs import Table, UnknownJobKind, table as declared_table, tables
from eha.campaigns.migrations import migrate as _migrate, schema_version
from eha.campaigns.schema import DB_NAME, SCHEMA, SCHEMA_VERSION
from eha.campaigns.transactions import signals_held as _signals_held, transaction as _transaction
from eha.errors import BAD_INPUT, FAILURE, EhaError
from eha.outputs import pid_alive

_LOCK_RE = re.compile(r"Conflicting lock is held in (.*?) \(PID (\d+)\)")
#: Where :func:`connect` says that it upgraded a database's schema (a WARNING: with no logging
#: configured, as on the command line, Python prints it on stderr as one line).
log = logging.getLogger(__name__)


class StoreError(EhaError, RuntimeError):
    """The result database cannot be used (locked, missing, bad query); one-line message.
    The command line exits 2: the results folder or the query given is at fault."""

    exit_code = BAD_INPUT


class StoreWriteError(StoreError):
    """The result database could not be written (disk full, I/O error): a failure of the
    machine, not of the input (the CLI exits 1, not 2); committed results are kept."""

    exit_code = FAILURE


class DatabaseDamaged(StoreError):
    """The result database file is damaged (DuckDB reports corruption): a failure, exit 1."""

    exit_code = FAILURE


def _damaged(text: str) -> bool:
    return any(w in text for w in ("Corrupt", "checksum", "not a valid DuckDB"))


#: DuckDB's configuration at every connect: no extension loaded or installed on its own. Given
#: a file of another engine (a SQLite file saved as ``eha.duckdb``), DuckDB otherwise
#: downloads the extension that reads it, a network request from a local tool.
NO_EXTENSIONS = {"autoload_known_extensions": False, "autoinstall_known_extensions": False}
#: DuckDB's file magic, at byte 8 of its database file.
DUCKDB_MAGIC = (8, b"DUCK")


def _check_magic(path: Path) -> None:
    """Refuse a file that is not a DuckDB database before DuckDB opens it (it would look for
    an extension to read a SQLite file, say); a missing or empty file is DuckDB's to handle."""
    at, magic = DUCKDB_MAGIC
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise StoreError(f"{path}: cannot be read ({exc.strerror})") from None
    if head and head[at:at + len(magic)] != magic:
        kind = " (a SQLite database)" if head.startswith(b"SQLite format 3") else ""
        raise DatabaseDamaged(f"{path}: not a DuckDB database file{kind}; move it away and "
                              "run the campaigns again")


def db_path(results: str | Path) -> Path:
    """``DIR/eha.duckdb``."""
    return Path(results) / DB_NAME


def connect(results: str | Path, read_only: bool = False):
    """Open ``DIR/eha.duckdb``; the schema is created, or upgraded, on a writable connection.

    A writable connection applies the migrations the database lacks (:func:`eha.campaigns.migrations.migrate`); one
    that had runs says so, one line logged (:data:`log`; on the command line, on stderr). A
    read-only connection never writes: it reads an older database as it is.

    Raises
    ------
    StoreError
        The database is held by another process, or (read-only) does not exist, or its schema
        is newer than this code knows (nothing is written to it).
    """
    import duckdb

    path = db_path(results)
    if read_only and not path.exists():
        raise StoreError(f"{path}: no result database yet; run a campaign first "
                         "(eha campaign run FILE)")
    try:
        if not read_only:
            path.parent.mkdir(parents=True, exist_ok=True)
            _create_whole(path, duckdb)
        _check_magic(path)
        con = duckdb.connect(str(path), read_only=read_only, config=NO_EXTENSIONS)
    except OSError as exc:
        raise StoreError(f"{path.parent}: cannot create the results folder "
                         f"({exc.strerror})") from None
    except duckdb.Error as exc:
        match = _LOCK_RE.search(str(exc))
        if match:
            raise StoreError(f"{path} is locked by another process (PID {match.group(2)}, "
                             f"{Path(match.group(1)).name}), probably a running campaign; "
                             "wait for it to finish or use another `results` folder") from None
        first = str(exc).splitlines()[0]
        if _damaged(first):
            raise DatabaseDamaged(f"{path}: {first}; the file is damaged: move it away and run "
                                  "the campaigns again") from None
        raise StoreError(f"{path}: {first}") from None
    try:
        version, had_runs = schema_version(con)
        if version > SCHEMA_VERSION:
            con.close()
            raise StoreError(f"{path}: its schema is version {version}, newer than this eha "
                             f"knows ({SCHEMA_VERSION}); it was written by a newer eha: "
                             "upgrade eha, or use another results folder")
        if not read_only:
            done = _migrate(con, version)
            if done and had_runs:
                log.warning(f"note: {path}: database schema upgraded from version {version} "
                            f"to {SCHEMA_VERSION} ({'; '.join(done)})")
            for entry in tables().values():
                _create(con, entry)
    except duckdb.Error as exc:  # e.g. a damaged file that opened but cannot be read
        con.close()
        raise StoreError(f"{path}: {str(exc).splitlines()[0]}; if the file is damaged, "
                         "move it away and run the campaign again") from None
    return con


def _create_whole(path: Path, duckdb) -> None:
    """Create a missing database under a temporary name and link it into place.

    DuckDB creates a new file before it writes its header: a process killed in between leaves an
    empty file that DuckDB then refuses ("not a valid DuckDB database file"), and every later
    run would stop on it. Made under a temporary name (``creating-<pid>`` after the file's) and
    hard-linked (which never replaces a file another process made first), the database appears
    whole or not at all; the temporary files of processes no longer alive are removed here.
    """
    for stale in path.parent.glob(f"{path.name}.creating-*"):
        pid = stale.name.rsplit("-", 1)[-1].split(".")[0]
        if pid.isdigit() and (int(pid) == os.getpid() or not pid_alive(int(pid))):
            stale.unlink(missing_ok=True)
    if path.exists():
        return
    tmp = path.with_name(f"{path.name}.creating-{os.getpid()}")
    duckdb.connect(str(tmp), config=NO_EXTENSIONS).close()
    try:
        os.link(tmp, path)
    except FileExistsError:  # another process created it meanwhile: theirs is kept
        pass
    except OSError:  # a file system without hard links
        if not path.exists():
            os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
        tmp.with_name(tmp.name + ".wal").unlink(missing_ok=True)


def _create(con, entry: Table) -> None:
    """Create a registered result table and add the columns it gained since its first release
    (a database written by an older version gets them; its rows keep NULL there)."""
    con.execute(entry.ddl)
    for column, sql_type in entry.added:
        con.execute(f"ALTER TABLE {entry.name} ADD COLUMN IF NOT EXISTS {column} {sql_type}")


def _run_tables(con) -> list[str]:
    """The tables of the database whose rows belong to runs (a ``run_key`` column), ``runs``
    left out: every kind's, registered in this process or not."""
    return [t for t, in con.execute(
        "SELECT DISTINCT c.table_name FROM information_schema.columns c JOIN "
        "information_schema.tables t USING (table_schema, table_name) WHERE c.column_name = "
        "'run_key' AND t.table_type = 'BASE TABLE' AND c.table_name <> 'runs' "
        "ORDER BY c.table_name").fetchall()]


def _arrow(rows: Sequence[Mapping[str, Any]]):
    """Arrow table of ``rows`` (dicts with the same keys), JSON columns as text: the campaign
    path's bulk inserts without pandas (importing it alone took 1.4 s of a campaign's start)."""
    import pyarrow as pa

    names = list(rows[0])
    cols = {}
    for n in names:
        values = [r[n] for r in rows]
        if any(isinstance(v, (dict, list)) for v in values):
            values = [json.dumps(v, sort_keys=True) if v is not None else None
                      for v in values]
        cols[n] = values
    return pa.Table.from_pydict(cols)


def _frame(rows: Sequence[Mapping[str, Any]]):
    import pandas as pd

    frame = pd.DataFrame(list(rows))
    for col in frame.columns:  # JSON columns travel as text (only object columns can hold them)
        if frame[col].dtype == object and \
                frame[col].map(lambda v: isinstance(v, (dict, list))).any():
            frame[col] = frame[col].map(lambda v: json.dumps(v, sort_keys=True))
    return frame


def _concat(tables: Sequence[Any]) -> list:
    """Arrow tables of one schema as a list of at most one table (empty ones left out)."""
    import pyarrow as pa

    tables = [t for t in tables if t.num_rows]
    return [pa.concat_tables(tables)] if tables else []


def _columns(obj) -> list[str]:
    """Column names of a pandas frame or an Arrow table."""
    return list(obj.column_names if hasattr(obj, "column_names") else obj.columns)


class ResultStore:
    """The campaign parent's read-write connection to ``DIR/eha.duckdb`` (the only writer).

    Use as a context manager; the database stays locked against other processes while open.
    """

    def __init__(self, results: str | Path):
        self.results = Path(results).resolve()
        self.con = connect(self.results)
        self._made = set(tables())  # the result tables created on this connection

    def __enter__(self) -> "ResultStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.con is not None:
            con, self.con = self.con, None
            try:
                with _signals_held():
                    con.execute("CHECKPOINT")
            except Exception as exc:
                # e.g. a full disk: the committed rows are in the write-ahead log, which the
                # next connection replays; say so in one line instead of a traceback
                import duckdb

                con.close()
                if isinstance(exc, duckdb.Error):
                    raise StoreWriteError(f"{db_path(self.results)}: could not checkpoint "
                                     f"({str(exc).splitlines()[0]}); the committed results "
                                     "are kept in its .wal file; free some space and run the "
                                     "same command again") from None
                raise
            con.close()

    # ---- campaigns
    def campaign(self, name: str) -> dict | None:
        """The ``campaigns`` row of ``name`` (dict) or None."""
        cur = self.con.execute("SELECT * FROM campaigns WHERE name = ?", [name])
        rows = cur.fetchall()
        return dict(zip([d[0] for d in cur.description], rows[0])) if rows else None

    def register_campaign(self, row: Mapping[str, Any]) -> None:
        """Insert or update a ``campaigns`` row (keeps ``created_at`` of an existing one)."""
        self.con.register("_c", _arrow([row]))
        try:
            with _signals_held():
                self.con.execute("""
                    INSERT INTO campaigns BY NAME SELECT * FROM _c
                    ON CONFLICT (name) DO UPDATE SET description = excluded.description,
                        source = excluded.source, spec_hash = excluded.spec_hash,
                        model_version = excluded.model_version, n_runs = excluded.n_runs,
                        definition = excluded.definition, updated_at = excluded.updated_at""")
        finally:
            self.con.unregister("_c")

    def discard_runs(self, campaign: str, keep: set[str] | frozenset[str] = frozenset()) -> int:
        """Remove the runs of ``campaign`` whose key is not in ``keep``: their result rows,
        ``runs`` rows and trace files; returns how many.

        A kept run whose chunk file also holds discarded runs goes back to ``pending`` and its
        file is removed (the file would keep the discarded runs' rows in the ``traces`` view);
        the runner re-runs it. Rows go first, in one transaction; a file left by an
        interruption after it is removed by the next run (:func:`clean_temp_files`).
        """
        rows = self.con.execute("SELECT run_key, trace_path FROM runs WHERE campaign = ?",
                                [campaign]).fetchall()
        gone = [k for k, _ in rows if k not in keep]
        files = {p for k, p in rows if k not in keep and p is not None}
        reset = [k for k, p in rows if k in keep and p in files]
        if gone:
            self.con.register("_gone", _frame([{"run_key": k} for k in gone]))
            self.con.register("_reset", _frame([{"run_key": k} for k in reset or ["-"]]))
            try:
                with _transaction(self.con):
                    for table in _run_tables(self.con) + ["runs"]:
                        self.con.execute(f"DELETE FROM {table} WHERE run_key IN "
                                         "(SELECT run_key FROM _gone)")
                    self.con.execute("UPDATE runs SET status = 'pending', trace_path = NULL "
                                     "WHERE run_key IN (SELECT run_key FROM _reset)")
            finally:
                self.con.unregister("_gone")
                self.con.unregister("_reset")
        for path in files:
            (self.results / path).unlink(missing_ok=True)
        return len(gone)

    # ---- runs
    def run_keys(self, campaign: str, status: str | None = None) -> dict[str, str]:
        """``run_key -> status`` of a campaign's recorded runs (optionally one status only)."""
        sql = "SELECT run_key, status FROM runs WHERE campaign = ?"
        args: list[Any] = [campaign]
        if status is not None:
            sql += " AND status = ?"
            args.append(status)
        return dict(self.con.execute(sql, args).fetchall())

    def done_with_trace(self, campaign: str) -> set[str]:
        """Run keys recorded as done whose trace file is intact; the runs of a damaged or
        missing file are re-run (see :meth:`verify_traces`)."""
        return self.verify_traces(campaign)[0]

    def verify_traces(self, campaign: str) -> tuple[set[str], set[str]]:
        """``(run keys, trace paths)`` of the done runs of ``campaign`` whose trace file is
        intact, and those files (relative to the results folder).

        A file is checked once for all the runs it holds: its size is the one recorded at
        commit and its bytes hash to the recorded checksum
        (:func:`eha.campaigns.integrity.check_files`, ``full``); a file recorded before the
        checksum, that its footer holds the sum of the rows recorded for its runs. A file
        whose bytes match but whose modification time changed gets the new time recorded
        (queries then skip hashing it).
        """
        from eha.campaigns.integrity import check_files, recorded_files

        files = recorded_files(self.con, campaign)
        check = check_files(self.results, files, full=True)
        if check.restamp:
            with _transaction(self.con):
                self.con.executemany("UPDATE runs SET trace_mtime = ? WHERE trace_path = ?",
                                     [[m, p] for p, m in check.restamp.items()])
        done = {k for k, in self.con.execute(
            "SELECT run_key FROM runs WHERE campaign = ? AND status = 'done' "
            "AND trace_path IS NULL", [campaign]).fetchall()}
        intact = {f.path for f in files if f.path not in check.damaged}
        for f in files:
            if f.path in intact:
                done.update(f.keys)
        return done, intact

    def add_pending(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Insert ``pending`` runs; runs already recorded are left as they are."""
        if not rows:
            return
        self.con.register("_p", _arrow(rows))
        try:
            with _signals_held():
                self.con.execute("INSERT OR IGNORE INTO runs BY NAME SELECT * FROM _p")
        finally:
            self.con.unregister("_p")

    def record(self, results: Sequence[Mapping[str, Any]],
               extra: Mapping[str, Sequence[Mapping[str, Any]]] | None = None,
               batches: Sequence[Any] = ()) -> None:
        """Store finished runs in one transaction, as bulk updates and inserts.

        Each result has ``run_key``, ``status`` and the other ``runs`` columns to update
        (``error``, ``worker``, timings, ``trace_path``), and ``rows``: result-table name ->
        one row (dict of columns) for that run. ``extra``: result-table name -> rows upserted
        after them (e.g. the HF-vs-LF columns of runs recorded now or before). ``batches``:
        results of whole chunks as Arrow tables, ``{"runs": table, "parts": [(TABLE, table),
        ...]}`` (``runs`` has ``run_key`` and the columns to update; each part is upserted).
        """
        if not results and not extra and not batches:
            return
        run_cols = {"status", "error", "worker", "started_at", "finished_at", "sim_s",
                    "elapsed_s", "trace_path", "trace_bytes", "trace_rows", "trace_hash",
                    "trace_mtime"}
        updates = [{"run_key": r["run_key"], **{k: r.get(k) for k in run_cols}} for r in results]
        per_table: dict[str, list] = {}
        for r in results:
            for table, row in (r.get("rows") or {}).items():
                per_table.setdefault(table, []).append({"run_key": r["run_key"], **row})
        parts: list[tuple[str, Any]] = [(t, _frame(rows)) for t, rows in per_table.items()]
        runs = [_frame(updates)] if updates else []
        # one statement per table for all the chunks of this commit (a statement costs
        # milliseconds whatever its rows)
        runs += _concat([b["runs"] for b in batches])
        same: dict[tuple, list] = {}
        for b in batches:
            for t, v in b.get("parts", ()):
                same.setdefault((t, tuple(v.column_names)), []).append(v)
        parts += [(t, v) for (t, _), vs in same.items() for v in _concat(vs)]
        parts += [(t, _frame(rows)) for t, rows in (extra or {}).items() if rows]
        for table in dict.fromkeys(t for t, _ in parts):
            self._ensure(table)
        with _transaction(self.con):
            for obj in runs:
                self.con.register("_u", obj)
                cols = [c for c in _columns(obj) if c != "run_key"]
                sets = ", ".join(f"{c} = _u.{c}" for c in sorted(cols))
                self.con.execute(f"UPDATE runs SET {sets} FROM _u "
                                 "WHERE runs.run_key = _u.run_key")
                self.con.unregister("_u")
            for table, obj in parts:
                self._upsert(table, obj)

    def upsert(self, table: str, rows: Sequence[Mapping[str, Any]]) -> None:
        """Insert or replace rows of a result table (by ``run_key``); columns by name."""
        self._ensure(table)
        if rows:
            with _signals_held():
                self._upsert(table, _frame(rows))

    def _ensure(self, table: str) -> None:
        """Create result table ``table`` on this connection if it was registered after the
        connection opened.

        Raises
        ------
        StoreError
            No module declares it with rows per run.
        """
        entry = tables().get(table)
        if entry is None or not entry.per_run:
            per_run = [t.name for t in tables().values() if t.per_run]
            raise StoreError(f"result table {table!r} is not in the schema "
                             f"({', '.join(per_run) or 'none registered'})")
        if table not in self._made:
            with _signals_held():
                _create(self.con, entry)
            self._made.add(table)

    def _upsert(self, table: str, obj) -> None:
        """Upsert a pandas frame or Arrow table (one bulk statement)."""
        self.con.register("_r", obj)
        try:
            cols = [c for c in _columns(obj) if c != "run_key"]
            sets = ", ".join(f"{c} = excluded.{c}" for c in cols)
            self.con.execute(f"INSERT INTO {table} BY NAME SELECT * FROM _r ON CONFLICT "
                             f"(run_key) DO UPDATE SET {sets}")
        finally:
            self.con.unregister("_r")

    def status_counts(self, campaign: str) -> dict[str, int]:
        return dict(self.con.execute("SELECT status, count(*) FROM runs WHERE campaign = ? "
                                     "GROUP BY status", [campaign]).fetchall())



def replace_rows(results: str | Path, table: str, rows: Sequence[Mapping[str, Any]],
                 key: Mapping[str, Any]) -> Path:
    """Replace the rows of ``table`` matching ``key`` (column -> value) by ``rows``, in one
    transaction (a re-run of the same check or calibration overwrites its rows, never
    duplicates them). Returns the database path.

    Raises
    ------
    StoreError
        Unknown table, or the database is locked or cannot be written.
    """
    return replace_parts(results, [(table, rows, key)])


def replace_parts(results: str | Path,
                  parts: Sequence[tuple[str, Sequence[Mapping[str, Any]], Mapping[str, Any]]]
                  ) -> Path:
    """In ONE transaction, for each ``(table, rows, key)``: delete the rows of ``table``
    matching ``key`` (column -> value), insert ``rows`` (e.g. a residual-loop run and its
    steps, :func:`eha.explain.tables.save_explain`). Returns the database path.

    Raises
    ------
    StoreError
        A table neither core nor declared (:func:`eha.campaigns.jobs.register_table`), or the
        database is locked or cannot be written.
    """
    for table, _, _ in parts:
        if table not in SCHEMA:
            try:
                declared_table(table)  # its module imported: the connection creates it
            except UnknownJobKind:
                raise StoreError(f"{table!r} is not a table of the schema") from None
    con = connect(results)
    try:
        with _transaction(con):
            for table, rows, key in parts:
                where = " AND ".join(f"{c} = ?" for c in key)
                con.execute(f"DELETE FROM {table} WHERE {where}", list(key.values()))
                if rows:
                    con.register("_r", _frame(rows))
                    con.execute(f"INSERT INTO {table} BY NAME SELECT * FROM _r")
                    con.unregister("_r")
    finally:
        con.close()
    return db_path(results)
