"""The job registry: each job kind registers its worker function; the worker's dispatch.

The runner knows job kinds by name only. A domain module registers its kinds when it is
imported (:func:`register_job`, :func:`register_section`; its result tables with
:func:`register_table`), and the package metadata says which module provides which kind: the
entry points of ``pyproject.toml``::

    [project.entry-points."eha.jobs"]             # job kind -> module that registers it
    simulate = "eha.simulations.batch"
    [project.entry-points."eha.campaign_sections"]  # [section] of a campaign file -> module
    fdi = "eha.identification.cases"
    [project.entry-points."eha.campaign_keys"]    # kind of a file's top-level keys -> module
    simulate = "eha.simulations.expand"
    [project.entry-points."eha.worker_warm_up"]   # run once in every worker as it starts
    simulate = "eha.simulations.batch:warm_up"
    [project.entry-points."eha.tables"]           # result table -> module that declares it
    fdi_results = "eha.identification.cases"

:func:`job_kind` imports the module of a kind the first time it meets the kind, in the parent
and in every worker process (spawned pool, Dask), so a worker loads only the domain it runs.
The entry points come from the installed metadata (``pip install -e .``; run it again after
editing them); where they declare none of a group, the source tree's ``pyproject.toml`` is
read instead.

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

#: Entry-point groups: job kinds, campaign-file sections, worker warm-ups, result tables.
JOB_GROUP = "eha.jobs"
SECTION_GROUP = "eha.campaign_sections"
WARM_UP_GROUP = "eha.worker_warm_up"
TABLE_GROUP = "eha.tables"
KEYS_GROUP = "eha.campaign_keys"


class UnknownJobKind(EhaError, KeyError):
    """No module registers this job kind (or campaign section)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


#: Target work per task [s]: well above what a task round trip costs on the local pool
#: (~1 ms) or Dask (2-5 ms of the scheduler's and client's CPU, on the cores the workers
#: use), well below a campaign's wall time (the last tasks run alone). Job kinds size their
#: chunks with it; the runner bundles shorter chunks up to it.
TASK_SECONDS = 0.5


@dataclass(frozen=True)
class JobKind:
    """A job kind's functions; only ``run`` is required.

    Attributes
    ----------
    name : str
        The kind (``runs.kind``).
    run : callable
        ``run(spec, run_key, campaign, trace_file, **extra) -> dict``, in the worker: returns
        ``{"rows": {table: row}, ...runs columns...}`` (every table one of its own, declared
        with :func:`register_table` and ``per_run``); ``extra`` may hold ``want_signals``.
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
    plan_chunks: Callable[[Sequence[Any]], list[list[Any]]] | None = None
    run_chunk: Callable[[Mapping[str, Any]], dict[str, Any]] | None = None
    chunk_fields: Callable[[Sequence[Any]], dict[str, Any]] | None = None
    estimate_s: Callable[[Mapping[str, Any]], float] | None = None
    collect: Callable[[list[dict]], Any] | None = None
    finish: Callable[[Any, str], int] | None = None


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
class FileKeys:
    """A job kind whose part of a campaign file is top-level keys, not a ``[section]`` (the
    ``simulate`` kind: ``models``, ``commands``, ...; :func:`register_keys`)."""

    kind: str
    keys: tuple[str, ...]
    expand: Callable[..., list]


_KINDS: dict[str, JobKind] = {}
_SECTIONS: dict[str, Callable[..., list]] = {}
_TABLES: dict[str, Table] = {}
_KEYS: dict[str, FileKeys] = {}


def register_job(kind: str, run: Callable[..., dict[str, Any]], **hooks: Any) -> JobKind:
    """Register the worker function (and optional hooks, see :class:`JobKind`) of a job kind;
    returns it. Registering a kind again replaces it."""
    entry = JobKind(kind, run, **hooks)
    _KINDS[kind] = entry
    return entry


def register_section(name: str, expand: Callable[..., list]) -> None:
    """Register the expander of a campaign-file section ``[name]``:
    ``expand(section, campaign_table, problems) -> list[JobDraft]`` validates the section
    (one line per problem appended to ``problems``) and returns the drafts of its jobs."""
    _SECTIONS[name] = expand


def register_keys(kind: str, keys: Sequence[str], expand: Callable[..., list]) -> FileKeys:
    """Register a kind's top-level keys of a campaign file and their expander:
    ``expand(table, name, problems, chosen) -> list[JobDraft]`` reads the whole file
    (``chosen``: the file's ``kind`` is this one), validates its keys (one line per problem
    appended to ``problems``) and returns the drafts of its jobs (none when the file does not
    use them)."""
    entry = FileKeys(kind, tuple(keys), expand)
    _KEYS[kind] = entry
    return entry


def register_table(name: str, ddl: str, added: Sequence[tuple[str, str]] = (),
                   per_run: bool = False) -> Table:
    """Declare a result table (see :class:`Table`); returns it. The store creates it, and adds
    its ``added`` columns, on every writable connection opened after this call and before it
    writes rows there; a module declares its tables next to its :func:`register_job`, and the
    entry points ``eha.tables`` name the module of each table (so that a writer that names a
    table finds it, :func:`table`)."""
    entry = Table(name, ddl, tuple((c, t) for c, t in added), per_run)
    _TABLES[name] = entry
    return entry


@lru_cache(maxsize=None)
def _entry_points(group: str) -> dict[str, Any]:
    """``name -> entry point`` of ``group``, in declaration order, from the installed metadata
    or, when that has none (a source tree not installed, or installed before the group was
    declared), from the source tree's ``pyproject.toml``."""
    from importlib import metadata

    found = {ep.name: ep for ep in metadata.entry_points(group=group)}
    return found or _source_entry_points(group)


def _source_entry_points(group: str) -> dict[str, Any]:
    import tomllib
    from importlib.metadata import EntryPoint

    path = Path(__file__).resolve().parents[2] / "pyproject.toml"
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return {}
    found = table.get("project", {}).get("entry-points", {}).get(group, {})
    return {name: EntryPoint(name, value, group) for name, value in found.items()}


def _load(group: str, name: str, registry: Mapping[str, Any]) -> Any:
    if name not in registry:
        ep = _entry_points(group).get(name)
        if ep is not None:
            ep.load()  # imports the module, which registers its kinds
    try:
        return registry[name]
    except KeyError:
        raise UnknownJobKind(f"{name!r} is not registered (entry points {group}: "
                             f"{', '.join(_entry_points(group)) or 'none; is eha installed?'})"
                             ) from None


def job_kind(kind: str) -> JobKind:
    """The registration of ``kind``, its module imported on first use.

    Raises
    ------
    UnknownJobKind
        No module registers it.
    """
    return _load(JOB_GROUP, kind, _KINDS)


def find_job_kind(kind: str) -> JobKind | None:
    """:func:`job_kind`, or None when nothing registers ``kind``."""
    try:
        return job_kind(kind)
    except UnknownJobKind:
        return None


def table(name: str) -> Table:
    """The declaration of result table ``name``, the module that registers it (entry points
    ``eha.tables``) imported on first use.

    Raises
    ------
    UnknownJobKind
        No module declares it.
    """
    return _load(TABLE_GROUP, name, _TABLES)


def tables() -> dict[str, Table]:
    """The result tables registered in this process so far (``name -> Table``)."""
    return dict(_TABLES)


def file_keys() -> dict[str, FileKeys]:
    """The kinds whose part of a campaign file is top-level keys (entry points
    ``eha.campaign_keys``, each module imported: a file's keys are validated against them)."""
    for name in _entry_points(KEYS_GROUP):
        _load(KEYS_GROUP, name, _KEYS)
    return dict(_KEYS)


def section_names() -> tuple[str, ...]:
    """Names of the campaign-file sections (``[fdi]``, ...), without importing their
    modules: those of the entry points, then any registered at run time."""
    return tuple(dict.fromkeys([*_entry_points(SECTION_GROUP), *_SECTIONS]))


def section(name: str) -> Callable[..., list]:
    """The expander of section ``[name]``, its module imported on first use."""
    return _load(SECTION_GROUP, name, _SECTIONS)


def warm_ups() -> list[Callable[[], Any]]:
    """The functions every worker runs once as it starts (entry points
    ``eha.worker_warm_up``), e.g. loading the simulation kernels."""
    return [ep.load() for ep in _entry_points(WARM_UP_GROUP).values()]


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
        return job_kind(task["job_kind"]).run_chunk(task)
    return execute_job(task)


__all__ = ["TASK_SECONDS", "JobKind", "Table", "FileKeys", "UnknownJobKind", "register_job",
           "register_section", "register_keys", "register_table", "job_kind", "find_job_kind",
           "table", "tables", "file_keys", "section_names", "section", "warm_ups",
           "execute_job", "execute_task"]
