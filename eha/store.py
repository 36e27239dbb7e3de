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
