"""Trace files: Parquet I/O of simulated traces and measured-data tables.

Traces are Parquet files written atomically: a temporary name in the same directory, then
``os.replace``, so a reader never sees a file half-written. A campaign's simulations are stored
many runs per file, in *chunk files* (issue 25): one file per task of the runner, holding every
run of the task, a ``run_key`` column first (dictionary-encoded, rows sorted by run key, then
time), the stored signals as float64 columns with the ``BYTE_STREAM_SPLIT`` encoding and zstd
compression in one data page per column (lossless; about 39-40 kB per 1-s run with all nine
signals instead of 74 kB; ``xu`` only where it differs from ``xj``, :data:`COPY_OF`), and one
row group per file up to :data:`ROW_GROUP_ROWS` rows. Query engines read a few large files much
faster than many small ones (DuckDB's advice: row groups of 100k rows or more). A single trace
(:func:`write_trace`) and a campaign run before issue 25 have one file per run, whose run key is
in its name and its metadata (key ``eha``). Both layouts are read alike (:func:`read_run`).

Each run's metadata (model, command, parameters, seed, ...) is in the footer's key-value
metadata under ``eha_runs`` (JSON ``{run_key: meta}``; not in the Arrow schema that pyarrow
also stores there, so ``pq.read_metadata(path).metadata``, not ``pq.read_schema``); a file of
one run also carries it under ``eha`` in its schema metadata, the key of the one-file-per-run
layout, so tools written for that layout still read it.

A chunk is written under a temporary name and renamed into place (:func:`write_chunk`). The
runner records for each run the file, its size and the run's own row count; a file is intact
when its size is the recorded one and its footer holds the sum of its runs' rows
(:func:`trace_intact`).

This module imports only numpy, pyarrow and the trace's columns (:mod:`eha.trace`; no simulation
code): the store and the CLI's query path use it without loading numba.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eha.campaigns.schema import TRACES
from eha.trace import OUTPUT_UNITS, OUTPUTS, Trace

#: Suffix of temporary files (removed by :func:`clean_temp_files`).
TEMP_SUFFIX = ".tmp"
#: A chunk stores the position ``xu`` only where it differs from the jack's ``xj``: without
#: output backlash or sensor effects it is ``xj`` bit for bit (5 kB of a run's 40 kB). Where
#: they are equal (bitwise) ``xu`` is NULL and the boolean column :data:`COPY_FLAG` is true;
#: readers (:func:`read_run`, the ``traces`` view) take ``xj`` there. Only when both are stored.
COPY_OF = ("xu", "xj")
COPY_FLAG = "xu_is_xj"
#: Largest row group [rows]; a chunk of more rows gets several.
ROW_GROUP_ROWS = 1_048_576
#: Largest data page [bytes, before compression]: one page per column and row group (8 MiB
#: for a full row group). Parquet C++ otherwise cuts a page every 20 000 rows (its
#: ``max_rows_per_page``) or 1 MiB; each page is compressed on its own, and the byte streams of
#: ``BYTE_STREAM_SPLIT`` compress better in one long page: 40.2 kB instead of 41.7 kB per
#: 1-s run with nine signals (the time column 35 B instead of 180 B).
PAGE_BYTES = 1 << 30
#: zstd level: with the 20 000-row pages of Parquet C++'s default, 1 and 3 gave 41.7 kB per
#: 1-s run (0.4 and 0.5 ms), 9 gave 41.4 kB in 1.2 ms, 19 40.5 kB in 13 ms (50 HF runs of
#: `mixed`; without byte-stream-split 49.8 kB, snappy 58.5 kB); in one page, 3 saves 1 % for
#: 1.6x the time: the low bits of simulated signals are noise, higher levels buy almost
#: nothing.
ZSTD_LEVEL = 1


#: Seconds to wait between writing a chunk and renaming it into place: 0, except in the kill
#: test (tests/test_chunks.py), which sets EHA_TEST_PAUSE_BEFORE_RENAME to kill there.
_PAUSE_BEFORE_RENAME = float(os.environ.get("EHA_TEST_PAUSE_BEFORE_RENAME", "0") or 0)


def _file_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


FILE_MODE = _file_mode()


def chunk_name(run_keys: Sequence[str]) -> str:
    """File name of the chunk holding ``run_keys``: ``<run_key>.parquet`` for one run (the
    one-file-per-run layout), else ``chunk-<16 hex of the SHA-256 of the sorted keys>.parquet``.

    The name depends only on the set of runs, so a chunk re-run after a crash replaces its own
    file, and the ``runs`` rows of a resumed campaign equal those of an uninterrupted one.
    """
    import hashlib

    keys = sorted(run_keys)
    if len(keys) == 1:
        return f"{keys[0]}.parquet"
    digest = hashlib.sha256(",".join(keys).encode()).hexdigest()[:16]
    return f"chunk-{digest}.parquet"


def chunk_table(runs: Sequence[tuple[str, np.ndarray, Mapping[str, Any]]],
                signals: Sequence[str] | None = None):
    """Arrow table of a chunk (its runs' metadata: :func:`chunk_metadata`; a one-run table
    also carries it under the schema metadata key ``eha``).

    Parameters
    ----------
    runs : sequence of (run_key, data, meta)
        ``data``: float64 array (n, 9), columns :data:`eha.trace.OUTPUTS` (SI, cor in mA);
        ``meta``: JSON-serialisable metadata of the run.
    signals : sequence of str, optional
        Signals to store (subset of OUTPUTS, stored in OUTPUTS order); default all.
    """
    import pyarrow as pa

    keep = [i for i, n in enumerate(OUTPUTS) if signals is None or n in signals]
    runs = sorted(runs, key=lambda r: r[0])
    data = (np.concatenate([r[1] for r in runs]) if runs
            else np.empty((0, len(OUTPUTS))))
    counts = [len(r[1]) for r in runs]
    keys = pa.DictionaryArray.from_arrays(
        pa.array(np.repeat(np.arange(len(runs), dtype=np.int32), counts)),
        pa.array([r[0] for r in runs], pa.string()))
    meta = {"eha": json.dumps(runs[0][2], default=float)} if len(runs) == 1 else None
    fields = [pa.field("run_key", keys.type)] + [
        pa.field(OUTPUTS[i], pa.float64(), metadata={"unit": OUTPUT_UNITS[OUTPUTS[i]]})
        for i in keep]
    cols = {OUTPUTS[i]: np.ascontiguousarray(data[:, i]) for i in keep}
    copy = None
    if COPY_OF[0] in cols and COPY_OF[1] in cols:
        # bit for bit (not ==: -0.0 and 0.0 differ, NaN equals itself)
        copy = cols[COPY_OF[0]].view(np.int64) == cols[COPY_OF[1]].view(np.int64)
        if not copy.any():
            copy = None
    arrays = [keys] + [pa.array(v, mask=copy if n == COPY_OF[0] else None)
                       for n, v in cols.items()]
    if copy is not None:
        fields.append(pa.field(COPY_FLAG, pa.bool_()))
        arrays.append(pa.array(copy))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))


def chunk_metadata(runs: Sequence[tuple[str, Any, Mapping[str, Any]]]) -> dict[str, str]:
    """The file metadata of a chunk: ``eha_runs``, JSON ``{run_key: meta}`` (compact)."""
    metas = {r[0]: r[2] for r in runs}
    return {"eha_runs": json.dumps(metas, default=float, sort_keys=True,
                                   separators=(",", ":"))}


def write_table_atomic(table, path: str | Path,
                       file_metadata: Mapping[str, str] | None = None) -> int:
    """Write an Arrow table to ``path`` (Parquet, zstd, byte-stream-split floats, one data page
    per column and row group) under a temporary name in the same folder, then rename; returns
    the file size [bytes].

    ``file_metadata`` goes into the Parquet footer's key-value metadata only. The table's
    schema metadata is written there too, and a second time inside the serialised Arrow schema
    that pyarrow also stores (``ARROW:schema``, base64): large metadata, such as a chunk's
    ``eha_runs``, belongs in ``file_metadata`` (read it with ``pq.read_metadata(path).metadata``).
    """
    import pyarrow.parquet as pq

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    floats = [f.name for f in table.schema if f.type == "double"]
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
    os.close(fd)
    try:
        with pq.ParquetWriter(tmp, table.schema, compression="zstd",
                              compression_level=ZSTD_LEVEL,
                              use_dictionary=[f.name for f in table.schema
                                              if f.name not in floats
                                              and f.type != "bool"],
                              use_byte_stream_split=floats or False,
                              max_rows_per_page=ROW_GROUP_ROWS,
                              write_page_checksum=True,
                              data_page_size=PAGE_BYTES) as writer:
            writer.write_table(table, row_group_size=ROW_GROUP_ROWS)
            if file_metadata:
                writer.add_key_value_metadata(dict(file_metadata))
        os.chmod(tmp, FILE_MODE)  # mkstemp makes 0600; traces are shared like any output
        size = os.stat(tmp).st_size
        if _PAUSE_BEFORE_RENAME:  # tests only: a kill -9 with the chunk half-way to its place
            import time

            time.sleep(_PAUSE_BEFORE_RENAME)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return size


def write_chunk(runs: Sequence[tuple[str, np.ndarray, Mapping[str, Any]]], path: str | Path,
                signals: Sequence[str] | None = None) -> int:
    """Write the traces of ``runs`` (see :func:`chunk_table`) to one chunk file, atomically;
    returns its size [bytes]."""
    return write_table_atomic(chunk_table(runs, signals), path, chunk_metadata(runs))


def read_run(path: str | Path, run_key: str | None = None) -> tuple[np.ndarray, dict]:
    """``(data, meta)`` of one run of a trace file (a chunk or a one-run file).

    ``data`` has the nine columns of :data:`eha.trace.OUTPUTS` (NaN where not stored).

    Raises
    ------
    KeyError
        ``run_key`` is not in the file, or is None and the file holds several runs.
    """
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(path)
    # the footer's key-value metadata: ``eha_runs`` is there in every layout (in chunks of
    # issue 25's first version also inside the Arrow schema)
    raw = pf.metadata.metadata or {}
    table = pf.read()
    if "run_key" in table.column_names:
        keys = table.column("run_key")
        present = pc.unique(keys.combine_chunks().dictionary_decode()
                            if hasattr(keys.type, "value_type") else keys).to_pylist()
        if run_key is None:
            if len(present) != 1:
                raise KeyError(f"{path}: holds {len(present)} runs; give a run key")
            run_key = present[0]
        elif run_key not in present:
            raise KeyError(f"{path}: no run {run_key}")
        table = table.filter(pc.equal(pc.cast(table.column("run_key"), "string"), run_key))
    metas = json.loads(raw.get(b"eha_runs", b"{}"))
    meta = metas.get(run_key) if run_key in metas else json.loads(raw.get(b"eha", b"{}"))
    names = set(table.column_names)
    data = np.column_stack([table.column(n).to_numpy() if n in names
                            else np.full(table.num_rows, np.nan) for n in OUTPUTS])
    if COPY_FLAG in names:  # xu left out where it equals xj
        copy = table.column(COPY_FLAG).to_numpy()
        src, dst = OUTPUTS.index(COPY_OF[1]), OUTPUTS.index(COPY_OF[0])
        data[copy, dst] = data[copy, src]
    return np.ascontiguousarray(data, dtype=np.float64), meta


def write_trace(trace, path: str | Path, columns: Sequence[str] | None = None) -> Path:
    """Write ``trace`` to ``path`` (Parquet) atomically; returns the path.

    Parameters
    ----------
    trace : Trace
        Its ``meta`` goes into the file metadata (key ``eha``).
    path : path
        Destination; written under a temporary name in the same folder, then renamed.
    columns : sequence of str, optional
        Signals to keep (subset of :data:`eha.trace.OUTPUTS`); default all.
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
        os.chmod(tmp, FILE_MODE)  # mkstemp makes 0600; traces are shared like any output
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_trace(path: str | Path, run_key: str | None = None):
    """Read one run's :class:`~eha.trace.Trace` from a file of :func:`write_trace` or a
    chunk file (``run_key`` needed when it holds several runs); signals not stored come back
    as NaN."""
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
    ``#`` are comments. Validation of the columns is :mod:`eha.identification.measured`'s job.
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



def write_table_file(frame, path: Path, fmt: str) -> None:
    """Write a measured-data table (a DataFrame; ``fmt`` ``csv`` or ``parquet``) under a
    temporary name in the same folder, then rename: the counterpart of
    :func:`read_table_file`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        if fmt == "csv":
            frame.to_csv(tmp, index=False, float_format="%.9g")
        else:
            frame.to_parquet(tmp, index=False)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise

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


__all__ = ["chunk_name", "chunk_table", "chunk_metadata", "write_chunk", "write_table_atomic", "read_run",
           "write_trace", "read_trace", "trace_intact", "read_table_file", "write_table_file",
           "trace_path", "clean_temp_files", "TEMP_SUFFIX", "ROW_GROUP_ROWS", "FILE_MODE",
           "COPY_OF", "COPY_FLAG"]
