"""The job registry: each job kind is one :class:`JobKind`; the worker's dispatch.

The runner knows job kinds by name only. A job kind is one declaration in its own module: its
worker (``run`` and the chunk hooks), its campaign-file part (a ``[section]`` or top-level
``keys``, and the expander that turns it into drafts), its result tables and its worker
warm-up, all in one :class:`JobKind` value. The package metadata names that value, one entry
point per kind (``pyproject.toml``)::

    [project.entry-points."eha.job_kinds"]   # job kind -> its JobKind declaration
    simulate = "eha.simulations.batch:SIMULATE"
    fdi = "eha.identification.cases:FDI"
    [project.entry-points."eha.tables"]      # a table written outside any job kind -> module
    explain_runs = "eha.explain.tables"

:func:`job_kind` loads the declaration of a kind the first time it meets the kind, in the
parent and in every worker process (spawned pool, Dask), so a worker loads only the domain it
runs; :func:`register` adds one in this process (a program, a test). The second group is for
the tables of writers that are not job kinds (a check, a calibration, the residual loop),
declared with :func:`register_table` in their module. The entry points come from the installed
metadata (``pip install -e .``; run it again after editing them) and, for the names it lacks,
from the source tree's ``pyproject.toml`` (a source tree not installed, or installed before an
entry point was added).

This module imports nothing of the domain at import time.
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence
from eha.errors import EhaError

#: Entry-point groups: job kinds (each a :class:`JobKind`), and the result tables of the
#: writers that are not job kinds (each the module that declares it).
KIND_GROUP = "eha.job_kinds"
TABLE_GROUP = "eha.tables"


class UnknownJobKind(EhaError, KeyError):
    """No module declares this job kind (or campaign section, or table)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


#: Target work per task [s]: well above what a task round trip costs on the local pool
#: (~1 ms) or Dask (2-5 ms of the scheduler's and client's CPU, on the cores the workers
#: use), well below a campaign's wall time (the last tasks run alone). Job kinds size their
#: chunks with it; the runner bundles shorter chunks up to it.
TASK_SECONDS = 0.5


@dataclass(frozen=True)
class Table:
    """A result table that a job kind (or another writer) declares in its own module.

    Attributes
    ----------
    name : str
    ddl : str
        Its ``CREATE TABLE IF NOT EXISTS`` statement (SI units, one comment per column).
    added : tuple of (column, type)
        Columns added after its first release: a database written by an older version gets
        them when it is opened for writing (its rows keep NULL there).
    per_run : bool
        Its rows belong to runs (primary key ``run_key``): workers return rows for it
        (:meth:`eha.campaigns.store.ResultStore.record`) and a discarded run loses them.
    """

    name: str
    ddl: str
    added: tuple[tuple[str, str], ...] = ()
    per_run: bool = False


@dataclass(frozen=True)
class JobKind:
    """A job kind, whole: its worker, its part of a campaign file, its tables, its warm-up.
    Only ``name`` and ``run`` are required.

    Attributes
    ----------
    name : str
        The kind (``runs.kind``).
    run : callable
        ``run(spec, run_key, campaign, trace_file, **extra) -> dict``, in the worker: returns
        ``{"rows": {table: row}, ...runs columns...}`` (every table one of ``tables``, with
        ``per_run``); ``extra`` may hold ``want_signals``.
    section : str, optional
        The ``[section]`` of a campaign file whose jobs are of this kind (``[health]`` makes
        ``health_assessment`` jobs), expanded by ``drafts``.
    keys : tuple of str, optional
        Or: the top-level keys of a campaign file that are this kind's (``simulate``:
        ``models``, ``commands``, ...), expanded by ``drafts``.
    drafts : callable, optional
        The expander of ``section``: ``drafts(section, campaign_table, problems) ->
        list[JobDraft]``; or of ``keys``: ``drafts(campaign_table, name, problems, chosen) ->
        list[JobDraft]`` (``chosen``: the file's ``kind`` is this one; none when the file does
        not use the keys). Each validates its part, one line per problem appended to
        ``problems``. A kind without it gets its jobs from a program
        (:func:`eha.campaigns.files.make_campaign`).
    tables : tuple of Table
        The result tables its workers write (created on a writable connection once the kind
        is loaded, :func:`register`).
    warm_up : callable, optional
        ``warm_up()``: run once in a worker process before its first job of this kind (e.g.
        loading the simulation kernels, a tiny run end to end).
    plan_chunks : callable, optional
        ``plan_chunks(jobs) -> list[list[Job]]``: the kind's jobs of a campaign grouped into
        tasks of several runs each (one chunk file per task), planned on the whole campaign
        so that a resume writes the same files. Without it, one run per task.
    run_chunk : callable, optional
        ``run_chunk(task) -> dict``, in the worker: runs a chunk task (see
        :func:`eha.simulations.batch.run_chunk` for its fields and result).
    chunk_fields : callable, optional
        ``chunk_fields(jobs) -> dict``: extra fields of a chunk task.
    estimate_s : callable, optional
        ``estimate_s(spec) -> float``: seconds a job takes (``eha campaign plan``); default the
        job's ``estimated_s`` column, else 1 s.
    collect : callable, optional
        ``collect(tasks) -> collector``, in the parent before the tasks are sent: a collector
        has ``add(result)`` (every result, as it arrives) and ``take() -> {table: rows}``
        (rows upserted with each commit), e.g. metrics of pairs of runs split across tasks.
    finish : callable, optional
        ``finish(store, campaign) -> int``, in the parent at the end of every run of a
        campaign that has jobs of this kind (e.g. what a crash left unpaired).
    """

    name: str
    run: Callable[..., dict[str, Any]]
    section: str | None = None
    keys: tuple[str, ...] = ()
    drafts: Callable[..., list] | None = None
    tables: tuple[Table, ...] = ()
    warm_up: Callable[[], Any] | None = None
    plan_chunks: Callable[[Sequence[Any]], list[list[Any]]] | None = None
    run_chunk: Callable[[Mapping[str, Any]], dict[str, Any]] | None = None
    chunk_fields: Callable[[Sequence[Any]], dict[str, Any]] | None = None
    estimate_s: Callable[[Mapping[str, Any]], float] | None = None
    collect: Callable[[list[dict]], Any] | None = None
    finish: Callable[[Any, str], int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "keys", tuple(self.keys))
        object.__setattr__(self, "tables", tuple(self.tables))
        if self.section is not None and self.keys:
            raise ValueError(f"job kind {self.name!r}: a campaign-file section or top-level "
                             "keys, not both")
        if (self.section is not None or bool(self.keys)) != (self.drafts is not None):
            raise ValueError(f"job kind {self.name!r}: `drafts` expands its section or keys; "
                             "give both or neither")


#: The two registries: job kinds, and every result table (the kinds' and the other writers').
_KINDS: dict[str, JobKind] = {}
_TABLES: dict[str, Table] = {}
#: The kinds whose warm-up has run in this process.
_WARM: set[str] = set()


def register(kind: JobKind) -> JobKind:
    """Register a job kind and its tables in this process; returns it. Registering a kind of
    the same name again replaces it (its tables stay registered). A kind named by an entry
    point is registered when first met (:func:`job_kind`); this is for a program or a test
    that declares one at run time (run on an executor of this process's own, its workers do
    not see it: an installed kind has an entry point)."""
    if not isinstance(kind, JobKind):
        raise TypeError(f"register() takes a JobKind, not {type(kind).__name__}")
    _KINDS[kind.name] = kind
    for entry in kind.tables:
        _TABLES[entry.name] = entry
    return kind


def unregister(name: str) -> None:
    """Forget job kind ``name`` and its tables in this process (a test's clean-up); one that an
    entry point names is loaded again when next met."""
    kind = _KINDS.pop(name, None)
    for entry in kind.tables if kind is not None else ():
        if _TABLES.get(entry.name) is entry:
            del _TABLES[entry.name]
    _WARM.discard(name)


def register_table(name: str, ddl: str, added: Sequence[tuple[str, str]] = (),
                   per_run: bool = False) -> Table:
    """Declare a result table of a writer that is not a job kind (see :class:`Table`; a job
    kind lists its own in :attr:`JobKind.tables`); returns it. The store creates it, and adds
    its ``added`` columns, on every writable connection opened after this call and before it
    writes rows there; the entry points ``eha.tables`` name the module of each such table (so
    that a writer that names a table finds it, :func:`table`)."""
    entry = Table(name, ddl, tuple((c, t) for c, t in added), per_run)
    _TABLES[name] = entry
    return entry


@lru_cache(maxsize=None)
def _entry_points(group: str) -> dict[str, Any]:
    """``name -> entry point`` of ``group``: those of the source tree's ``pyproject.toml``
    (when eha runs from one) in declaration order, then those of the installed metadata that
    it lacks (another package's kinds), the installed ones taking precedence."""
    from importlib import metadata

    found = dict(_source_entry_points(group))
    found.update({ep.name: ep for ep in metadata.entry_points(group=group)})
    return found


def _source_entry_points(group: str) -> dict[str, Any]:
    import tomllib
    from importlib.metadata import EntryPoint

    path = Path(__file__).resolve().parents[2] / "pyproject.toml"
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return {}
    if table.get("project", {}).get("name") != "eha":
        return {}  # eha installed inside another project's tree
    found = table.get("project", {}).get("entry-points", {}).get(group, {})
    return {name: EntryPoint(name, value, group) for name, value in found.items()}


def _missing(name: str, group: str) -> UnknownJobKind:
    return UnknownJobKind(f"{name!r} is not registered (entry points {group}: "
                          f"{', '.join(_entry_points(group)) or 'none; is eha installed?'})")


def job_kind(kind: str) -> JobKind:
    """The declaration of ``kind``, loaded through its entry point on first use.

    Raises
    ------
    UnknownJobKind
        No entry point names it and nothing registered it, or its entry point names something
        that is not a :class:`JobKind` of that name.
    """
    if kind not in _KINDS:
        ep = _entry_points(KIND_GROUP).get(kind)
        if ep is None:
            raise _missing(kind, KIND_GROUP)
        found = ep.load()  # imports the kind's module
        if not isinstance(found, JobKind) or found.name != kind:
            raise UnknownJobKind(f"entry point {KIND_GROUP} {kind} = {ep.value}: not the "
                                 f"JobKind {kind!r} ({type(found).__name__})")
        register(found)
    return _KINDS[kind]


def find_job_kind(kind: str) -> JobKind | None:
    """:func:`job_kind`, or None when nothing declares ``kind``."""
    try:
        return job_kind(kind)
    except UnknownJobKind:
        return None


def job_kinds() -> dict[str, JobKind]:
    """Every job kind: those of the entry points (each loaded) in declaration order, then those
    registered at run time."""
    for name in _entry_points(KIND_GROUP):
        job_kind(name)
    order = [*_entry_points(KIND_GROUP), *_KINDS]
    return {name: _KINDS[name] for name in dict.fromkeys(order)}


def kind_module(kind: str) -> str:
    """The module that declares ``kind`` (its entry point's), or that of its registration."""
    ep = _entry_points(KIND_GROUP).get(kind)
    return ep.module if ep is not None else job_kind(kind).run.__module__


def table(name: str) -> Table:
    """The declaration of result table ``name``: registered, or of the module its entry point
    ``eha.tables`` names (imported), or of a job kind (every kind loaded).

    Raises
    ------
    UnknownJobKind
        Nothing declares it.
    """
    if name not in _TABLES:
        ep = _entry_points(TABLE_GROUP).get(name)
        if ep is not None:
            ep.load()  # imports the module, which registers its tables
        else:
            job_kinds()
    if name not in _TABLES:
        raise UnknownJobKind(f"{name!r} is not a declared table (entry points {TABLE_GROUP}: "
                             f"{', '.join(_entry_points(TABLE_GROUP)) or 'none'}; or a job "
                             "kind's tables)")
    return _TABLES[name]


def tables() -> dict[str, Table]:
    """The result tables registered in this process so far (``name -> Table``)."""
    return dict(_TABLES)


def declared_tables() -> dict[str, str]:
    """Every declared result table -> the module that declares it, without importing the
    other writers' modules (the job kinds are loaded: their tables are in their
    declarations)."""
    found = {name: ep.module for name, ep in _entry_points(TABLE_GROUP).items()}
    for kind in job_kinds().values():
        for entry in kind.tables:
            found.setdefault(entry.name, kind_module(kind.name))
    return found


def file_keys() -> dict[str, JobKind]:
    """The kinds whose part of a campaign file is top-level keys (every kind loaded: a file's
    keys are validated against them)."""
    return {n: k for n, k in job_kinds().items() if k.keys}


def section_names() -> tuple[str, ...]:
    """Names of the campaign-file sections (``[fdi]``, ``[health]``), in the kinds' order."""
    return tuple(k.section for k in job_kinds().values() if k.section is not None)


def section(name: str) -> Callable[..., list]:
    """The expander of section ``[name]`` (its kind's ``drafts``).

    Raises
    ------
    UnknownJobKind
        No kind has that section.
    """
    for kind in job_kinds().values():
        if kind.section == name:
            return kind.drafts
    raise UnknownJobKind(f"[{name}] is not a campaign-file section of any job kind "
                         f"({', '.join(section_names()) or 'none'})")


def warm_up(kinds: Sequence[str] | None = None) -> list[str]:
    """Run, once in this process, the warm-up of each of ``kinds`` (None: of every kind) that
    has one; returns the kinds warmed now. A kind nothing declares is skipped (its jobs fail
    with their own line)."""
    names = list(_entry_points(KIND_GROUP)) + list(_KINDS) if kinds is None else list(kinds)
    warmed = []
    for name in dict.fromkeys(names):
        if name in _WARM:
            continue
        found = find_job_kind(name)
        if found is None:
            continue
        _WARM.add(name)
        if found.warm_up is not None:
            found.warm_up()
            warmed.append(name)
    return warmed


# =========================================================================== worker side
def _now() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


def execute_job(payload: Mapping[str, Any]) -> dict[str, Any]:
    """Run one job in a worker; never raises for a failing job (status ``failed``).

    ``payload``: ``kind``, ``spec``, ``run_key``, ``campaign``, ``trace_file`` (absolute path),
    ``trace_path`` (relative, recorded in the database).
    """
    from eha.campaigns.integrity import file_stamp

    started = _now()
    t0 = time.perf_counter()
    result: dict[str, Any] = {"run_key": payload["run_key"], "started_at": started,
                              "worker": f"{socket.gethostname()}:{os.getpid()}",
                              "trace_path": None, "error": None, "rows": {}}
    try:
        extra = {"want_signals": True} if payload.get("want_signals") else {}
        warm_up([payload["kind"]])  # once per process: done already where it started so
        out = job_kind(payload["kind"]).run(payload["spec"], payload["run_key"],
                                            payload["campaign"], payload["trace_file"], **extra)
        result.update(out)
        result["status"] = "done"
        if Path(payload["trace_file"]).exists():
            result["trace_path"] = payload["trace_path"]
            # recorded with the run: the resume checks the file against it (docs/reliability.md)
            result["trace_bytes"] = Path(payload["trace_file"]).stat().st_size
            result["trace_hash"], result["trace_mtime"] = file_stamp(payload["trace_file"])
    except Exception as exc:  # recorded, the campaign goes on
        result["status"] = "failed"
        result["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        result["rows"] = {}
    result["finished_at"] = _now()
    result["elapsed_s"] = time.perf_counter() - t0
    return result


def execute_task(task: Mapping[str, Any]) -> dict[str, Any]:
    """Run one task in a worker: a chunk of runs of one kind (its ``run_chunk``), a bundle of
    chunks run in turn (``{"bundle": [result, ...]}``) or a single job
    (:func:`execute_job`)."""
    from eha.campaigns.malloc import tune_malloc

    tune_malloc()  # once per process: also a Dask worker restarted without the warm-up
    if task["kind"] == "bundle":
        return {"bundle": [execute_task(t) for t in task["tasks"]]}
    if task["kind"] == "chunk":
        warm_up([task["job_kind"]])  # once per process: done already where it started so
        return job_kind(task["job_kind"]).run_chunk(task)
    return execute_job(task)


__all__ = ["TASK_SECONDS", "KIND_GROUP", "TABLE_GROUP", "JobKind", "Table", "UnknownJobKind",
           "register", "unregister", "register_table", "job_kind", "find_job_kind", "job_kinds",
           "kind_module", "table", "tables", "declared_tables", "file_keys", "section_names",
           "section", "warm_up", "execute_job", "execute_task"]
