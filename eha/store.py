"""Storage: the only module that reads or writes Parquet and DuckDB.

Traces are Parquet files written atomically: a temporary name in the same directory, then
``os.replace``, so a reader never sees a file half-written. A campaign's simulations are stored
many runs per file (:mod:`eha.chunks`: a ``run_key`` column, sorted); a single trace
(:func:`write_trace`) and a campaign run before issue 25 have one file per run, whose run key is
in its name and its metadata (key ``eha``). Both layouts are read alike.

Campaign results live in ``DIR/eha.duckdb`` (DuckDB). The campaign's parent process is its only
writer (:class:`ResultStore`); queries go through a read-only connection (:func:`query`) that
also sees every Parquet trace as the view ``traces``. The SQL schema is declared once, in
:data:`SCHEMA`; a new kind of result (e.g. FDI) adds its table there and, when its rows belong
to runs, its name to :data:`RESULT_TABLES`.

Layout of a results directory::

    DIR/eha.duckdb                          campaigns, runs, metrics (+ other result tables)
    DIR/traces/<campaign>/chunk-<hash>.parquet  the runs of one task (column run_key)
    DIR/traces/<campaign>/<run_key>.parquet     a task of one run, or an older campaign
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

# No simulation code at import time (eha.simulate loads numba): `eha query` starts fast.
from eha.chunks import FILE_MODE as _FILE_MODE, TEMP_SUFFIX, read_run
from eha.models import OUTPUTS


def write_trace(trace, path: str | Path, columns: Sequence[str] | None = None) -> Path:
    """Write ``trace`` to ``path`` (Parquet) atomically; returns the path.

    Parameters
    ----------
    trace : Trace
        Its ``meta`` goes into the file metadata (key ``eha``).
    path : path
        Destination; written under a temporary name in the same folder, then renamed.
    columns : sequence of str, optional
        Signals to keep (subset of :data:`eha.models.OUTPUTS`); default all.
    """
    import pyarrow.parquet as pq

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table = trace.to_arrow()
    if columns is not None:
        table = table.select([c for c in OUTPUTS if c in columns])
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    try:
        pq.write_table(table, tmp)
        os.chmod(tmp, _FILE_MODE)  # mkstemp makes 0600; traces are shared like any output
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_trace(path: str | Path, run_key: str | None = None):
    """Read one run's :class:`~eha.simulate.Trace` from a file of :func:`write_trace` or a
    chunk file (``run_key`` needed when it holds several runs); signals not stored come back
    as NaN."""
    from eha.simulate import Trace

    data, meta = read_run(path, run_key)
    return Trace(data, meta)


#: A resume reads the Parquet footer (row count) of every trace file of the done runs up to
#: this many files (about 0.2 ms each); beyond, it checks sizes and the Parquet magic bytes
#: (about 20 µs each), so that verifying a 200 000-file campaign takes seconds, not minutes.
DEEP_VERIFY_MAX = 5000


def trace_intact(path: str | Path, size: int | None = None, rows: int | None = None,
                 deep: bool = True) -> bool:
    """Whether a stored trace is the file that was committed.

    Checks that it exists, has the recorded ``size`` [bytes] (when recorded), starts and ends
    with the Parquet magic ``PAR1`` around a footer that fits in the file, and (``deep``)
    that its footer reads and holds the recorded ``rows``. A truncated file, one overwritten
    with other bytes at either end, or one of another length fails it.
    """
    path = Path(path)
    try:
        actual = path.stat().st_size
        if (size is not None and actual != size) or actual < 12:
            return False
        with open(path, "rb") as fh:
            head = fh.read(4)
            fh.seek(-8, os.SEEK_END)
            tail = fh.read(8)
        footer = int.from_bytes(tail[:4], "little")
        if head != b"PAR1" or tail[4:] != b"PAR1" or footer + 12 > actual:
            return False
        if not deep:
            return True
        import pyarrow.parquet as pq

        meta = pq.read_metadata(path)
    except Exception:  # missing, unreadable, not Parquet (ArrowInvalid), ...
        return False
    return rows is None or meta.num_rows == rows


def read_table_file(path: str | Path):
    """Read a measured-data table (CSV/TSV/TXT or Parquet) into a pandas DataFrame, as is.

    Text files: the separator is sniffed (comma, semicolon, tab, spaces); lines starting with
    ``#`` are comments. Validation of the columns is :mod:`eha.measured`'s job.
    """
    import pandas as pd

    path = Path(path)
    if path.suffix.lower() in (".parquet", ".pq"):
        import pyarrow.parquet as pq

        return pq.read_table(path).to_pandas()
    # The C parser (a 600k-row file in 0.3 s instead of 5.8 s with the Python engine); it takes
    # the sniffed one-character separator or r"\s+" (runs of whitespace).
    return pd.read_csv(path, sep=_sniff_separator(path), engine="c", comment="#",
                       skipinitialspace=True)


def _sniff_separator(path: Path) -> str:
    """Column separator of a text table: comma, semicolon, tab or whitespace (default comma)."""
    import csv

    with open(path, newline="", errors="replace") as fh:
        lines = [ln for ln in fh.read(65536).splitlines() if ln.strip()
                 and not ln.lstrip().startswith("#")][:20]
    try:
        sep = csv.Sniffer().sniff("\n".join(lines), delimiters=",;\t ").delimiter
    except csv.Error:
        # columns aligned with runs of spaces (a printed table): the sniffer sees no single
        # delimiter, but every line splits on whitespace into the same number of fields
        widths = {len(ln.split()) for ln in lines}
        return r"\s+" if len(widths) == 1 and widths.pop() > 1 else ","
    return r"\s+" if sep == " " else sep


# =========================================================================== result database
#: File name of the result database inside a results directory.
DB_NAME = "eha.duckdb"
#: Folder of the Parquet traces inside a results directory.
TRACES = "traces"

#: The SQL schema, in one place: table name -> CREATE statement. Units are SI (cor in mA).
SCHEMA: dict[str, str] = {
    "campaigns": """
        CREATE TABLE IF NOT EXISTS campaigns (
            name          VARCHAR PRIMARY KEY,
            description   VARCHAR,
            source        VARCHAR,      -- campaign file it was first run from
            spec_hash     VARCHAR NOT NULL,  -- hash of the sorted run keys
            model_version VARCHAR,
            n_runs        INTEGER,
            definition    JSON,         -- the parsed campaign file
            created_at    TIMESTAMP,
            updated_at    TIMESTAMP)""",
    "runs": """
        CREATE TABLE IF NOT EXISTS runs (
            run_key     VARCHAR PRIMARY KEY,  -- hash of the resolved job spec + model version
            campaign    VARCHAR NOT NULL,
            kind        VARCHAR NOT NULL,     -- 'simulate' (others: see eha.campaign)
            status      VARCHAR NOT NULL,     -- 'pending', 'done', 'failed'
            model       VARCHAR,
            command     VARCHAR,
            faults      JSON,                 -- fault overrides, e.g. {"BKL": 0.0001}
            fault_label VARCHAR,
            seed        BIGINT,
            t_end       DOUBLE,               -- s
            case_key    VARCHAR,              -- same command/faults/seed/t_end across models
            label       VARCHAR,
            trace_path  VARCHAR,              -- relative to the results directory
            error       VARCHAR,
            worker      VARCHAR,              -- host:pid that ran it
            queued_at   TIMESTAMP,
            started_at  TIMESTAMP,
            finished_at TIMESTAMP,
            sim_s       DOUBLE,               -- s of simulation
            elapsed_s   DOUBLE,               -- s in the worker (simulation + metrics + write)
            spec        JSON,
            trace_bytes BIGINT,               -- size of the trace file at commit (integrity)
            trace_rows  BIGINT)               -- samples in the trace file at commit""",
    "metrics": """
        CREATE TABLE IF NOT EXISTS metrics (
            run_key          VARCHAR PRIMARY KEY,
            rmse_xu_com      DOUBLE,  -- m, RMS of xu - com
            max_err_xu_com   DOUBLE,  -- m, max |xu - com|
            final_err_xu_com DOUBLE,  -- m, xu - com at t_end
            settling_time    DOUBLE,  -- s, from which |xu - com| stays within 2 % of max|com|
            lag              DOUBLE,  -- s, shift of xu best matching com (0 to 0.2 s)
            xu_min           DOUBLE,  -- m
            xu_max           DOUBLE,  -- m
            xs_abs_max       DOUBLE,  -- m, spool peak
            p12_min          DOUBLE,  -- Pa
            p12_max          DOUBLE,  -- Pa
            p12_abs_max      DOUBLE,  -- Pa
            cor_abs_max      DOUBLE,  -- mA
            rmse_xu_hf_lf    DOUBLE,  -- m, HF vs LF of the same case (both runs get it)
            max_err_xu_hf_lf DOUBLE,  -- m
            rmse_p12_hf_lf   DOUBLE)  -- Pa""",
    "fdi_results": """
        CREATE TABLE IF NOT EXISTS fdi_results (
            run_key        VARCHAR PRIMARY KEY,
            case_id        INTEGER,   -- case number (thesis Figure 6.17 numbering)
            command        VARCHAR,
            seed           BIGINT,    -- HF dither and optimizer seed
            method         VARCHAR,   -- 'ga' (thesis) or 'ga+ps' (eha.fdi.METHODS)
            objective_name VARCHAR,   -- 'rmse' or 'objfcn' (thesis' mean absolute error)
            fit            JSON,      -- fitted LF parameters, e.g. ["BKL", "FDJ"]
            truth          JSON,      -- injected values (SI)
            estimates      JSON,      -- identified values (SI)
            errors_pct     JSON,      -- (input - output)/input*100, 0 when input is 0
            bounds         JSON,      -- search bounds {name: [lo, hi]}
            bkl_true DOUBLE, bkl_est DOUBLE, err_bkl_pct DOUBLE,  -- m, m, %
            fdj_true DOUBLE, fdj_est DOUBLE, err_fdj_pct DOUBLE,  -- N, N, %
            mean_err_pct   DOUBLE,    -- mean of the absolute percent errors
            objective      DOUBLE,    -- m, at the estimate
            evaluations    INTEGER,   -- LF simulations
            seconds        DOUBLE,    -- s, identification wall time in the worker
            pop            INTEGER,   -- GA population
            history        JSON,      -- best objective per generation/poll [m]
            level          DOUBLE,    -- nominal coverage of the intervals (0.9)
            intervals      JSON,      -- {name: [lo, hi]} at level (SI)
            flagged        BOOLEAN,   -- residual well above the noise: not a confident fit
            noise_rmse     DOUBLE)    -- m, sensor noise estimated from the reference""",
    "explain_runs": """
        CREATE TABLE IF NOT EXISTS explain_runs (
            run_id          VARCHAR PRIMARY KEY,  -- hash of the inputs and settings
            source          VARCHAR,   -- measured-data file
            created_at      TIMESTAMP,
            fit             JSON,      -- declared faults and bounds {name: [lo, hi]}
            holdout         VARCHAR,   -- what the held-out data was
            settings        JSON,      -- loop settings, method, pop, seed
            rmse_before     DOUBLE,    -- m, whole record, declared faults only
            rmse_after      DOUBLE,    -- m, whole record, with the added effects
            noise_rmse      DOUBLE,    -- m, measurement noise estimated from the record
            unexplained_rmse DOUBLE,   -- m, sqrt(max(rmse_after^2 - noise^2, 0))
            faults_before   JSON,
            faults_after    JSON,
            effects         JSON,      -- added effects, in order
            stop_reason     VARCHAR,
            seconds         DOUBLE)""",
    "explain_steps": """
        CREATE TABLE IF NOT EXISTS explain_steps (
            run_id            VARCHAR,
            step              INTEGER,  -- 1, 2, ... in the order the effects were added
            effect            VARCHAR,  -- effect name (docs/model.md §6)
            params            JSON,     -- estimated effect parameters (SI)
            rmse_before       DOUBLE,   -- m, whole record
            rmse_after        DOUBLE,
            rmse_fit_before   DOUBLE,   -- m, fitted part
            rmse_fit_after    DOUBLE,
            rmse_hold_before  DOUBLE,   -- m, held-out part or validation record
            rmse_hold_after   DOUBLE,
            faults_before     JSON,
            faults_after      JSON,
            gain              DOUBLE,   -- relative held-out RMSE reduction
            score             DOUBLE,   -- gain minus the parameter penalty
            PRIMARY KEY (run_id, step))""",
}
#: Columns added to tables after their first release: (table, column, type). A database from an
#: older version gets them when it is opened for writing (its rows keep NULL there).
ADDED_COLUMNS: tuple[tuple[str, str, str], ...] = (("fdi_results", "level", "DOUBLE"),
                                                   ("fdi_results", "intervals", "JSON"),
                                                   ("fdi_results", "flagged", "BOOLEAN"),
                                                   ("fdi_results", "noise_rmse", "DOUBLE"),
                                                   ("runs", "trace_bytes", "BIGINT"),
                                                   ("runs", "trace_rows", "BIGINT"),
                                                   # residual loop: its verdict (issue 11)
                                                   ("explain_runs", "unexplained", "BOOLEAN"),
                                                   ("explain_runs", "verdict", "VARCHAR"),
                                                   ("explain_runs", "command_hold", "VARCHAR"),
                                                   ("explain_runs", "leads", "JSON"))
#: Tables whose rows belong to one run each (key ``run_key``); filled from worker results.
RESULT_TABLES: tuple[str, ...] = ("metrics", "fdi_results")

# prognostics (eha rul; docs/prognostics.md): one health assessment per record (a runner job
# of kind "health"), and the RUL predictions made from them (written by the parent).
SCHEMA["health_checks"] = """
        CREATE TABLE IF NOT EXISTS health_checks (
            run_key    VARCHAR PRIMARY KEY,
            campaign   VARCHAR,   -- rul-<manifest>-<hash>
            actuator   VARCHAR,
            cycle      DOUBLE,    -- manifest unit (cycles or hours)
            record     VARCHAR,   -- absolute path of the record
            record_sha VARCHAR,   -- SHA-256 (16 hex) of the record file
            fit        JSON,      -- fitted faults and bounds {name: [lo, hi]}
            estimates  JSON,      -- identified values {name: value} (SI)
            intervals  JSON,      -- {name: [lo, hi]} at level (SI)
            level      DOUBLE,    -- probability of the intervals (0.9)
            flagged    BOOLEAN,   -- residual well above noise: the model misses something
            objective  DOUBLE,    -- m, RMSE at the estimate
            seed       BIGINT,    -- optimizer seed
            method     VARCHAR,
            seconds    DOUBLE)    -- s, identification wall time in the worker"""
SCHEMA["rul_predictions"] = """
        CREATE TABLE IF NOT EXISTS rul_predictions (
            run_id      VARCHAR,   -- the health campaign (rul-<manifest>-<hash>)
            actuator    VARCHAR,
            cycle       DOUBLE,    -- check, manifest unit
            rul         DOUBLE,    -- median RUL from the checks up to this one (NULL: none)
            rul_lo      DOUBLE,    -- 5 % quantile
            rul_hi      DOUBLE,    -- 95 % quantile (NULL: beyond the horizon)
            driver      VARCHAR,   -- fault that reaches its limit first (most draws)
            estimates   JSON,
            intervals   JSON,
            flagged     BOOLEAN,
            crossings   JSON,      -- per limited fault {median, lo, hi} crossing cycle
            law_weights JSON,      -- per fault posterior weight of each law
            limits      JSON,
            n_used      INTEGER,   -- checks used in the fit
            seed        BIGINT,    -- seed of this check's draws
            created_at  TIMESTAMP,
            PRIMARY KEY (run_id, actuator, cycle))"""
RESULT_TABLES = RESULT_TABLES + ("health_checks",)
SCHEMA["health_assessments"] = """
        CREATE TABLE IF NOT EXISTS health_assessments (
            run_key       VARCHAR PRIMARY KEY,
            command       VARCHAR,
            grp           VARCHAR,   -- 'healthy' or the injected fault 'NAME=value'
            seed          BIGINT,    -- actuator draw, dither, noise and optimizer seed
            t_end         DOUBLE,    -- s
            noise         DOUBLE,    -- m, sensor noise std of the record
            base_model    VARCHAR,   -- LF of the assessment ('calibrated' or 'plain')
            level         DOUBLE,    -- nominal coverage of the intervals
            truth         JSON,      -- true value of every fault (SI)
            hf            JSON,      -- HF parameters of the actuator (dispersion + fault)
            estimates     JSON,      -- assessed value of every fault (SI)
            means         JSON,      -- posterior mean over the hypotheses (detection input)
            spread        JSON,      -- std of each fault in the hypothesis that fits it
            intervals     JSON,      -- {name: [lo, hi]} at level
            weights       JSON,      -- posterior weight of each hypothesis ('none' = H0)
            best          VARCHAR,   -- most probable hypothesis' extra fault or 'none'
            flagged       BOOLEAN,   -- residual well above the noise
            residual_rmse DOUBLE,    -- m
            noise_rmse    DOUBLE,    -- m, estimated from the record
            n_eff         DOUBLE,    -- effective samples of the evidence
            seconds       DOUBLE)    -- s, assessment wall time in the worker"""
SCHEMA["health_verdicts"] = """
        CREATE TABLE IF NOT EXISTS health_verdicts (
            check_id    VARCHAR,   -- hash of the record, calibration and settings
            record      VARCHAR,   -- the record's path
            created_at  TIMESTAMP,
            calibration VARCHAR,   -- calibration file (NULL: none)
            fault       VARCHAR,
            estimate    DOUBLE,
            lo          DOUBLE,    -- interval at level
            hi          DOUBLE,
            level       DOUBLE,
            healthy     DOUBLE,    -- value of a healthy actuator
            threshold   DOUBLE,    -- of the detection statistic (NULL without calibration)
            statistic   DOUBLE,    -- deviation from healthy in the direction of degradation
            degraded    BOOLEAN,   -- NULL without calibration
            weight      DOUBLE,    -- posterior weight of the fault's hypothesis
            isolated    BOOLEAN,
            flagged     BOOLEAN,
            PRIMARY KEY (check_id, fault))"""
SCHEMA["health_thresholds"] = """
        CREATE TABLE IF NOT EXISTS health_thresholds (
            calibration VARCHAR,   -- calibration file
            command     VARCHAR,
            t_end       DOUBLE,
            fault       VARCHAR,
            threshold   DOUBLE,    -- of the detection statistic (fault unit)
            mean        DOUBLE,    -- healthy fleet, statistic
            std         DOUBLE,
            n           INTEGER,
            alpha       DOUBLE,    -- probability that a healthy check raises any alarm
            created_at  TIMESTAMP,
            PRIMARY KEY (calibration, fault))"""
RESULT_TABLES = RESULT_TABLES + ("health_assessments",)

_LOCK_RE = re.compile(r"Conflicting lock is held in (.*?) \(PID (\d+)\)")


class StoreError(RuntimeError):
    """The result database cannot be used (locked, missing, bad query); one-line message."""


class StoreWriteError(StoreError):
    """The result database could not be written (disk full, I/O error): a failure of the
    machine, not of the input (the CLI exits 1, not 2); committed results are kept."""


def db_path(results: str | Path) -> Path:
    """``DIR/eha.duckdb``."""
    return Path(results) / DB_NAME


def trace_path(results: str | Path, campaign: str, run_key: str) -> Path:
    """Where the trace of a run lives: ``DIR/traces/<campaign>/<run_key>.parquet``."""
    return Path(results) / TRACES / campaign / f"{run_key}.parquet"


def clean_temp_files(folder: str | Path, keep: set[str] | None = None) -> int:
    """Remove temporary files left by interrupted writes, and (``keep`` given) every trace
    file of ``folder`` whose name is not in ``keep``; returns how many files went.

    A file no committed run refers to is left by a crash between its rename and the commit,
    or by runs discarded or re-run elsewhere; its rows would show twice in the ``traces``
    view. Only call this while no writer can be active in ``folder`` (the runner does it
    while it holds the database lock, before starting its workers).
    """
    folder = Path(folder)
    n = 0
    if folder.is_dir():
        for tmp in folder.glob(f".*{TEMP_SUFFIX}"):
            tmp.unlink(missing_ok=True)
            n += 1
        if keep is not None:
            for f in folder.glob("*.parquet"):
                if f.name not in keep:
                    f.unlink(missing_ok=True)
                    n += 1
    return n


def connect(results: str | Path, read_only: bool = False):
    """Open ``DIR/eha.duckdb``; the schema is created on a writable connection.

    Raises
    ------
    StoreError
        The database is held by another process, or (read-only) does not exist.
    """
    import duckdb

    path = db_path(results)
    if read_only and not path.exists():
        raise StoreError(f"{path}: no result database yet; run a campaign first "
                         "(eha campaign run FILE)")
    try:
        if not read_only:
            path.parent.mkdir(parents=True, exist_ok=True)
        con = duckdb.connect(str(path), read_only=read_only)
    except OSError as exc:
        raise StoreError(f"{path.parent}: cannot create the results folder "
                         f"({exc.strerror})") from None
    except duckdb.Error as exc:
        match = _LOCK_RE.search(str(exc))
        if match:
            raise StoreError(f"{path} is locked by another process (PID {match.group(2)}, "
                             f"{Path(match.group(1)).name}), probably a running campaign; "
                             "wait for it to finish or use another --results folder") from None
        raise StoreError(f"{path}: {str(exc).splitlines()[0]}") from None
    if not read_only:
        try:
            for ddl in SCHEMA.values():
                con.execute(ddl)
            for table, column, sql_type in ADDED_COLUMNS:
                con.execute(f"ALTER TABLE {table} ADD COLUMN IF NOT EXISTS {column} {sql_type}")
        except duckdb.Error as exc:  # e.g. a damaged file that opened but cannot be read
            con.close()
            raise StoreError(f"{path}: {str(exc).splitlines()[0]}; if the file is damaged, "
                             "move it away and run the campaign again") from None
    return con


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

    def __enter__(self) -> "ResultStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.con is not None:
            con, self.con = self.con, None
            try:
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
            self.con.execute("BEGIN")
            try:
                for table in RESULT_TABLES + ("runs",):
                    self.con.execute(f"DELETE FROM {table} WHERE run_key IN "
                                     "(SELECT run_key FROM _gone)")
                self.con.execute("UPDATE runs SET status = 'pending', trace_path = NULL "
                                 "WHERE run_key IN (SELECT run_key FROM _reset)")
                self.con.execute("COMMIT")
            except BaseException:
                self.con.execute("ROLLBACK")
                raise
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

        A file is checked once for all the runs it holds (:func:`trace_intact`): its size is
        the one recorded at commit and its footer holds the sum of the rows recorded for its
        runs (footers read up to :data:`DEEP_VERIFY_MAX` files).
        """
        rows = self.con.execute("""
            SELECT trace_path, list(run_key), max(trace_bytes), min(trace_bytes),
                   CASE WHEN count(trace_rows) = count(*) THEN sum(trace_rows) END
            FROM runs WHERE campaign = ? AND status = 'done' GROUP BY trace_path""",
                                [campaign]).fetchall()
        deep = len(rows) <= DEEP_VERIFY_MAX
        done: set[str] = set()
        files: set[str] = set()
        for path, keys, size, size_lo, n in rows:
            if path is None or (size == size_lo and
                                trace_intact(self.results / path, size,
                                             None if n is None else int(n), deep=deep)):
                done.update(keys)
                files.add(path)
        files.discard(None)
        return done, files

    def add_pending(self, rows: Sequence[Mapping[str, Any]]) -> None:
        """Insert ``pending`` runs; runs already recorded are left as they are."""
        if not rows:
            return
        self.con.register("_p", _arrow(rows))
        try:
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
                    "elapsed_s", "trace_path", "trace_bytes", "trace_rows"}
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
        for table, _ in parts:
            if table not in RESULT_TABLES:
                raise StoreError(f"result table {table!r} is not in the schema "
                                 f"({', '.join(RESULT_TABLES)})")
        self.con.execute("BEGIN")
        try:
            for obj in runs:
                self.con.register("_u", obj)
                cols = [c for c in _columns(obj) if c != "run_key"]
                sets = ", ".join(f"{c} = _u.{c}" for c in sorted(cols))
                self.con.execute(f"UPDATE runs SET {sets} FROM _u "
                                 "WHERE runs.run_key = _u.run_key")
                self.con.unregister("_u")
            for table, obj in parts:
                self._upsert(table, obj)
            self.con.execute("COMMIT")
        except BaseException:
            self.con.execute("ROLLBACK")
            raise

    def upsert(self, table: str, rows: Sequence[Mapping[str, Any]]) -> None:
        """Insert or replace rows of a result table (by ``run_key``); columns by name."""
        if table not in RESULT_TABLES:
            raise StoreError(f"{table!r} is not a result table ({', '.join(RESULT_TABLES)})")
        if rows:
            self._upsert(table, _frame(rows))

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

    def hf_lf_pairs(self, campaign: str) -> list[tuple[str, str, str, str]]:
        """``(hf_key, hf_trace, lf_key, lf_trace)`` of done HF/LF runs of the same case whose
        HF-vs-LF metrics are still missing (trace paths relative to the results folder)."""
        return self.con.execute("""
            SELECT h.run_key, h.trace_path, l.run_key, l.trace_path
            FROM runs h JOIN runs l ON h.case_key = l.case_key AND h.campaign = l.campaign
            JOIN metrics mh ON mh.run_key = h.run_key
            JOIN metrics ml ON ml.run_key = l.run_key
            WHERE h.campaign = ? AND h.kind = 'simulate' AND l.kind = 'simulate'
              AND h.model = 'hf' AND l.model = 'lf'
              AND h.status = 'done' AND l.status = 'done'
              AND (mh.rmse_xu_hf_lf IS NULL OR ml.rmse_xu_hf_lf IS NULL)
            ORDER BY h.run_key""", [campaign]).fetchall()

    def status_counts(self, campaign: str) -> dict[str, int]:
        return dict(self.con.execute("SELECT status, count(*) FROM runs WHERE campaign = ? "
                                     "GROUP BY status", [campaign]).fetchall())


# =========================================================================== queries
def _create_traces_view(con, results: Path) -> None:
    """Temporary view ``traces``: every stored trace with its ``campaign`` and ``run_key``, and
    every signal of :data:`eha.models.OUTPUTS` (NULL where a campaign did not store it)."""
    if next((results / TRACES).glob("*/*.parquet"), None) is not None:
        pattern = str(results / TRACES / "*" / "*.parquet").replace("'", "''")
        con.execute(f"""
            CREATE OR REPLACE TEMP VIEW _traces_raw AS
            SELECT * FROM read_parquet('{pattern}', filename = true, union_by_name = true)""")
        present = {r[0] for r in con.execute("DESCRIBE _traces_raw").fetchall()}
        signals = ", ".join(c if c in present else f"NULL::DOUBLE AS {c}" for c in OUTPUTS)
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
        return (con.execute(sql, params) if params is not None else con.execute(sql)).df()
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
        os.chmod(tmp, _FILE_MODE)
        os.replace(tmp, path)
    except duckdb.Error as exc:
        raise StoreError(f"export {table}: {str(exc).splitlines()[0]}") from None
    finally:
        con.close()
        Path(tmp).unlink(missing_ok=True)
    return int(n)


def save_explain(results: str | Path, run: Mapping[str, Any],
                 steps: Sequence[Mapping[str, Any]]) -> Path:
    """Store one residual-loop run (``explain_runs``) and its steps (``explain_steps``).

    One transaction; a run with the same ``run_id`` is replaced. Returns the database path.
    """
    return _replace(results, [("explain_runs", [run], {"run_id": run["run_id"]}),
                              ("explain_steps", steps, {"run_id": run["run_id"]})])


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
    return _replace(results, [(table, rows, key)])


def _replace(results: str | Path,
             parts: Sequence[tuple[str, Sequence[Mapping[str, Any]], Mapping[str, Any]]]
             ) -> Path:
    """In ONE transaction, for each ``(table, rows, key)``: delete the rows matching ``key``,
    insert ``rows``."""
    for table, _, _ in parts:
        if table not in SCHEMA:
            raise StoreError(f"{table!r} is not a table of the schema")
    con = connect(results)
    try:
        con.execute("BEGIN")
        try:
            for table, rows, key in parts:
                where = " AND ".join(f"{c} = ?" for c in key)
                con.execute(f"DELETE FROM {table} WHERE {where}", list(key.values()))
                if rows:
                    con.register("_r", _frame(rows))
                    con.execute(f"INSERT INTO {table} BY NAME SELECT * FROM _r")
                    con.unregister("_r")
            con.execute("COMMIT")
        except BaseException:
            con.execute("ROLLBACK")
            raise
    finally:
        con.close()
    return db_path(results)
