"""Integrity of stored traces (issue 43): each trace file's content hash, recorded with its
runs, and the checks that use it.

A worker hashes every trace file it writes (:func:`file_stamp`: SHA-256 of the bytes, the
first 128 bits in hex, and the file's modification time in ns); both are recorded with the
file's runs (``runs.trace_hash``, ``runs.trace_mtime``) in the transaction that marks them
``done``. A hash covers every byte, the Parquet footer and page headers included, which page
checksums do not.

:func:`check_files` checks the files of done runs:

* ``full`` (the resume, ``eha campaign verify``): every file is hashed (threads: hashlib
  releases the GIL) and compared; a file whose hash matches but whose modification time
  changed (a copy that did not keep times) gets its new time recorded (``restamp``);
* not ``full`` (``eha query`` and ``eha export`` of ``traces``, which must stay fast): only a
  file whose size or modification time differs from the recorded ones is hashed. Bytes changed
  with the time put back are found by the next resume or ``eha campaign verify``.

Files recorded before the hash (older databases) keep the checks of
:func:`eha.campaigns.traces.trace_intact` (size, magic, footer rows).
"""

from __future__ import annotations

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from eha.campaigns.traces import DEEP_VERIFY_MAX, trace_intact

#: Hex digits of the SHA-256 kept (128 bits).
HASH_HEX = 32
#: Threads hashing files (hashlib releases the GIL while it hashes).
HASH_THREADS = 4


def file_stamp(path: str | Path) -> tuple[str, int]:
    """``(hash, mtime_ns)`` of a file: the first :data:`HASH_HEX` hex digits of the SHA-256 of
    its bytes, and its modification time [ns]."""
    with open(path, "rb") as fh:
        mtime = os.fstat(fh.fileno()).st_mtime_ns
        digest = hashlib.file_digest(fh, "sha256").hexdigest()[:HASH_HEX]
    return digest, mtime


@dataclass
class TraceFile:
    """A trace file as recorded with its done runs."""

    path: str                 # relative to the results folder
    campaign: str
    keys: list[str]
    size: int | None          # None: recorded differently by its runs, or not recorded
    rows: int | None
    hash: str | None          # None: recorded before the hash, or differently by its runs
    mtime: int | None
    consistent: bool = True   # its runs agree on its size and hash


@dataclass
class Check:
    """What :func:`check_files` found."""

    damaged: dict[str, str] = field(default_factory=dict)   # path -> reason
    restamp: dict[str, int] = field(default_factory=dict)   # path -> new mtime_ns
    hashed: int = 0


def _runs_columns(con) -> set[str]:
    return {r[0] for r in con.execute("SELECT column_name FROM information_schema.columns "
                                      "WHERE table_name = 'runs'").fetchall()}


def recorded_files(con, campaign: str | None = None) -> list[TraceFile]:
    """The trace files of the done runs (of ``campaign``, or of every campaign) as recorded;
    works on a database of any version (columns it lacks read as NULL)."""
    have = _runs_columns(con)

    def col(name: str, kind: str) -> str:
        return name if name in have else f"NULL::{kind}"

    rows_sum = ("CASE WHEN count(trace_rows) = count(*) THEN sum(trace_rows) END"
                if "trace_rows" in have else "NULL")
    sql = f"""
        SELECT trace_path, any_value(campaign), list(run_key),
               max({col('trace_bytes', 'BIGINT')}), min({col('trace_bytes', 'BIGINT')}),
               {rows_sum},
               max({col('trace_hash', 'VARCHAR')}), min({col('trace_hash', 'VARCHAR')}),
               count({col('trace_hash', 'VARCHAR')}) = count(*),
               max({col('trace_mtime', 'BIGINT')})
        FROM runs WHERE status = 'done' AND trace_path IS NOT NULL
        {'AND campaign = ?' if campaign is not None else ''}
        GROUP BY trace_path ORDER BY trace_path"""
    out = []
    for (path, camp, keys, size, size_lo, rows, h, h_lo, all_hashed,
         mtime) in con.execute(sql, [campaign] if campaign is not None else []).fetchall():
        consistent = size == size_lo and h == h_lo
        out.append(TraceFile(path, camp, list(keys), size, None if rows is None else int(rows),
                             h if all_hashed else None, mtime, consistent))
    return out


def _reason(results: Path, f: TraceFile, full: bool, deep: bool) -> tuple[str | None, bool]:
    """``(why the file is damaged or None, whether it still has to be hashed)``."""
    if not f.consistent:
        return "its runs record different sizes or hashes", False
    try:
        st = os.stat(results / f.path)
    except OSError as exc:
        return f"cannot be read ({exc.strerror})", False
    if f.size is not None and st.st_size != f.size:
        return f"{st.st_size} bytes, {f.size} recorded", False
    if f.hash is None:  # recorded before the hash: size, magic and footer
        if trace_intact(results / f.path, f.size, f.rows, deep=deep):
            return None, False
        return "not the Parquet file that was recorded (size, magic or footer)", False
    return None, full or st.st_mtime_ns != f.mtime


def check_files(results: str | Path, files: Iterable[TraceFile], full: bool = True) -> Check:
    """Check ``files`` (see the module's notes on ``full``); hashes in threads."""
    results = Path(results)
    files = list(files)
    deep = len(files) <= DEEP_VERIFY_MAX
    out = Check()
    to_hash: list[TraceFile] = []
    for f in files:
        reason, hash_it = _reason(results, f, full, deep)
        if reason is not None:
            out.damaged[f.path] = reason
        elif hash_it:
            to_hash.append(f)

    def stamp(f: TraceFile):
        try:
            return file_stamp(results / f.path)
        except OSError as exc:
            return exc

    with ThreadPoolExecutor(min(HASH_THREADS, max(1, len(to_hash)))) as pool:
        for f, got in zip(to_hash, pool.map(stamp, to_hash)):
            out.hashed += 1
            if isinstance(got, OSError):
                out.damaged[f.path] = f"cannot be read ({got.strerror})"
            elif got[0] != f.hash:
                out.damaged[f.path] = "its bytes differ from the checksum recorded"
            elif got[1] != f.mtime:
                out.restamp[f.path] = got[1]
    return out


def repair_hint(results: str | Path) -> str:
    """The one command that re-runs the runs of damaged trace files."""
    return f"eha campaign verify --repair --results {results}"


def damaged_message(results: str | Path, files: list[TraceFile], check: Check,
                    what: str) -> str:
    """One line naming the first damaged file, how many there are, and the repair."""
    by_path = {f.path: f for f in files}
    first = sorted(check.damaged)[0]
    f = by_path[first]
    more = len(check.damaged) - 1
    return (f"{what}: trace file {Path(results) / first} is damaged "
            f"({check.damaged[first]}; {len(f.keys)} runs of campaign {f.campaign})"
            + (f" and {more} more" if more else "")
            + f"; repair it with: {repair_hint(results)}")


__all__ = ["file_stamp", "recorded_files", "check_files", "TraceFile", "Check",
           "repair_hint", "damaged_message", "HASH_HEX"]

