"""Storage: the only module that reads or writes Parquet and DuckDB.

Traces are Parquet files (one per run, metadata under the key ``eha``), written atomically:
a temporary name in the same directory, then ``os.replace``, so a reader never sees a file
half-written.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from eha.models import OUTPUTS
from eha.simulate import Trace


def write_trace(trace: Trace, path: str | Path) -> Path:
    """Write ``trace`` to ``path`` (Parquet) atomically; returns the path."""
    import pyarrow.parquet as pq

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        pq.write_table(trace.to_arrow(), tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def read_trace(path: str | Path) -> Trace:
    """Read a trace written by :func:`write_trace`."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    meta_raw = (table.schema.metadata or {}).get(b"eha", b"{}")
    data = np.column_stack([table.column(n).to_numpy() for n in OUTPUTS])
    return Trace(np.ascontiguousarray(data, dtype=np.float64), json.loads(meta_raw))


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
    return pd.read_csv(path, sep=_sniff_separator(path), engine="python", comment="#",
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
        return ","
    return r"\s+" if sep == " " else sep
