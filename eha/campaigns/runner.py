"""Run campaigns: the resumable runner (parent side).

The parent process plans the jobs (:mod:`eha.campaigns.files`), opens ``DIR/eha.duckdb`` (it is
the only writer, :class:`eha.campaigns.store.ResultStore`), skips runs already done, and hands
the rest to an :class:`~eha.campaigns.executors.Executor`. Workers run the jobs and write their
traces (atomically, :mod:`eha.campaigns.traces`); they never touch the database. The parent
records results in batches, shows a progress bar, and lets each job kind collect what spans
several tasks as results arrive (e.g. the HF-vs-LF metrics of a case whose two runs ran in
different tasks).

Resume
------
A run is recorded ``done`` only after its trace file has been renamed into place, in the same
transaction as its metrics. Killing everything at any moment (``kill -9`` of the process group)
loses at most the runs not yet committed; the next ``eha campaign run`` of the same file removes
stray temporary files, re-runs every run not ``done`` (or whose trace is missing) and ends with
the same rows as an uninterrupted run.

Job kinds
---------
The runner knows job kinds by name only: each kind is one declaration
(:class:`eha.campaigns.jobs.JobKind`: its worker function and hooks, its campaign-file section
or keys, its result tables, its warm-up), found through the ``eha.job_kinds`` entry points.
A worker's result rows go to the kind's own tables (:attr:`eha.campaigns.jobs.JobKind.tables`, rows per run). To
add a kind (as FDI was): in its module, one ``JobKind``; in ``pyproject.toml``, one line under
``eha.job_kinds`` naming it.

This module imports no domain module: the runner and its workers import the module of a job
kind when they first meet the kind.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from eha.campaigns.executors import Executor, make_executor
from eha.campaigns.jobs import TASK_SECONDS, JobKind, execute_task, find_job_kind
from eha.campaigns.schema import DESCRIPTIVE_COLUMNS
from eha.errors import InputError

#: Results are committed at least this often [s] (and every :data:`BATCH_ROWS` runs): a
#: commit costs tens of milliseconds whatever its rows, the parent shares the cores with the
#: workers, and a crash loses at most this much finished work.
BATCH_SECONDS = 0.5
BATCH_ROWS = 5000


class CampaignChanged(InputError):
    """The campaign was recorded from a different definition under the same name."""


def _now() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


@dataclass
class RunSummary:
    """What :func:`run_campaign` did."""

    campaign: str
    total: int
    skipped: int = 0
    done: int = 0
    failed: int = 0
    wall_s: float = 0.0       # s, everything (validation, database, pool, jobs, HF-vs-LF)
    startup_s: float = 0.0    # s, starting and warming the workers
    jobs_s: float = 0.0       # s, from warm workers to the last result committed
    changed: bool = False     # recorded from another definition (and --replace given)
    replaced: int = 0         # recorded runs discarded because the definition changed
    errors: list[str] = field(default_factory=list)
    results: str = ""


def _progress(enabled: bool):
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TimeRemainingColumn(),
                    console=Console(stderr=True), disable=not enabled, transient=False)


def run_campaign(campaign, results: str | Path = "results", workers: int = 2,
                 scheduler: Any = None, replace: bool = False, progress: bool = True,
                 executor: Executor | None = None) -> RunSummary:
    """Run (or resume) a campaign into ``results``.

    Parameters
    ----------
    campaign : Campaign or path
        A :class:`eha.campaigns.files.Campaign` or a campaign TOML file.
    results : path
        Results folder (database ``eha.duckdb`` and ``traces/``).
    workers : int
        Local worker processes (ignored with ``scheduler``).
    scheduler : str or distributed.Client, optional
        Dask scheduler address (``tcp://HOST:PORT``) to run the jobs on instead.
    replace : bool
        When the campaign is recorded with a different definition: discard the recorded runs
        that the new definition does not have (runs it shares are kept, not re-run).
    progress : bool
        Show a rich progress bar on stderr.
    executor : Executor, optional
        An open executor to reuse (several campaigns, one pool); not closed here.

    Raises
    ------
    eha.campaigns.files.CampaignError
        Invalid campaign file (nothing runs).
    CampaignChanged
        The campaign name is recorded with a different definition and ``replace`` is false.
    eha.campaigns.store.StoreError
        The database is locked by another process, or ``RESULTS/traces`` is not a folder.
    """
    from eha.campaigns.files import Campaign, load_campaign
    from eha.campaigns.schema import TRACES
    from eha.campaigns.store import StoreError

    traces = Path(results) / TRACES
    if traces.exists() and not traces.is_dir():  # every run would fail on it, one line each
        raise StoreError(f"{traces}: a file, not the folder of the traces; move it away")
    from eha.campaigns.store import ResultStore
    from eha.campaigns.traces import clean_temp_files

    t_start = time.perf_counter()
    camp = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    summary = RunSummary(camp.name, len(camp.jobs))
    kinds = _kinds(camp)  # their modules imported: the store creates their result tables
    with ResultStore(results) as db:
        summary.results = str(db.results)
        old = db.campaign(camp.name)
        if old is not None and old["spec_hash"] != camp.spec_hash:
            if not replace:
                recorded = db.run_keys(camp.name)
                common = len(set(recorded) & {j.run_key for j in camp.jobs})
                raise CampaignChanged(
                    f"campaign {camp.name!r} in {db.results / 'eha.duckdb'} was recorded from a "
                    f"different definition (file edited or model version changed: "
                    f"{len(recorded)} recorded runs, {len(camp.jobs)} planned, {common} in "
                    "common); give it a new name, or pass `replace` to discard the recorded runs")
            # Runs of the new definition already recorded are the same runs (same key): kept.
            summary.changed = True
            summary.replaced = db.discard_runs(camp.name, {j.run_key for j in camp.jobs})
        now = _now()
        db.register_campaign({
            "name": camp.name, "description": camp.description, "source": camp.source,
            "spec_hash": camp.spec_hash, "model_version": camp.model_version,
            "n_runs": len(camp.jobs), "definition": camp.definition,
            "created_at": old["created_at"] if old else now, "updated_at": now})
        trace_dir = db.results / "traces" / camp.name
        done, intact = db.verify_traces(camp.name)
        # we hold the database lock: no other writer is active; files no intact done run
        # refers to (a crash before a commit, a damaged chunk) are removed, not shown twice
        clean_temp_files(trace_dir, {Path(p).name for p in intact})
        todo = [j for j in camp.jobs if j.run_key not in done]
        summary.skipped = len(camp.jobs) - len(todo)
        db.add_pending([{"run_key": j.run_key, "campaign": j.campaign, "kind": j.kind,
                         "status": "pending", "spec": j.spec, "queued_at": now,
                         **{k: v for k, v in j.columns.items() if k in DESCRIPTIVE_COLUMNS}}
                        for j in todo])
        payloads = _tasks(camp, todo, db.results, kinds)
        if payloads:
            _execute(payloads, db, summary, workers, scheduler, progress, executor, kinds)
        for kind in kinds:  # e.g. pairs of runs whose partner was done in an earlier session
            if kind.finish is not None:
                kind.finish(db, camp.name)
        counts = db.status_counts(camp.name)
        summary.failed = counts.get("failed", 0)
    summary.wall_s = time.perf_counter() - t_start
    return summary


@dataclass
class Verified:
    """What :func:`verify_results` found (and repaired) in a results folder."""

    files: int
    runs: int
    damaged: dict[str, str]                 # path -> reason
    by_campaign: dict[str, list[str]]       # campaign -> its damaged paths
    repaired: dict[str, int] = field(default_factory=dict)   # campaign -> runs re-run
    strays: list[str] = field(default_factory=list)  # trace files no done run records


def verify_results(results: str | Path, repair: bool = False, workers: int | None = None,
                   progress: bool = False) -> Verified:
    """Check every trace file of every campaign of ``results`` against its recorded size and
    checksum, reading every byte, without running anything; with ``repair``, run each
    campaign with a damaged file again from the definition stored with it (the resume
    re-runs the runs of the damaged files, and only those).

    Raises
    ------
    eha.campaigns.store.StoreError
        No database, or it is locked (a campaign is running).
    """
    import json

    from eha.campaigns.integrity import check_files, recorded_files
    from eha.campaigns.store import connect

    results = Path(results).resolve()
    con = connect(results, read_only=True)
    try:
        files = recorded_files(con)
        definitions = {n: (d, s) for n, d, s in con.execute(
            "SELECT name, definition, source FROM campaigns").fetchall()}
    finally:
        con.close()
    check = check_files(results, files, full=True)
    by_campaign: dict[str, list[str]] = {}
    for f in files:
        if f.path in check.damaged:
            by_campaign.setdefault(f.campaign, []).append(f.path)
    out = Verified(len(files), sum(len(f.keys) for f in files), check.damaged, by_campaign,
                   strays=stray_files(results, {f.path for f in files}))
    if repair:
        from eha.campaigns.files import CampaignError, build_campaign

        for name in sorted(by_campaign):
            definition, source = definitions[name]
            try:
                camp = build_campaign(json.loads(definition), source=source or "<stored>")
            except CampaignError as exc:  # e.g. a command file edited or moved since
                raise CampaignError([f"repair {name}: the campaign cannot be rebuilt from the "
                                     f"definition stored with it ({p}); run its file again "
                                     f"with: eha campaign run FILE --results {results}"
                                     for p in exc.problems]) from None
            summary = run_campaign(camp, results, workers=workers, progress=progress)
            out.repaired[name] = summary.done
    return out


def stray_files(results: Path, recorded: set[str]) -> list[str]:
    """The Parquet files under ``DIR/traces`` that no done run records (a copy, a file of a
    discarded run or of another database), relative to ``results``: never read (the
    ``traces`` view lists the recorded files only), listed by ``eha campaign verify``."""
    from eha.campaigns.schema import TRACES

    base = results / TRACES
    if not base.is_dir():
        return []
    return sorted(p for f in base.rglob("*.parquet")
                  if (p := str(f.relative_to(results))) not in recorded)


def _kinds(camp) -> list[JobKind]:
    """The registrations of the campaign's job kinds, in order of first appearance (a kind
    nothing registers is left out: its jobs fail in the workers, each recorded)."""
    kinds = [find_job_kind(k) for k in dict.fromkeys(j.kind for j in camp.jobs)]
    return [k for k in kinds if k is not None]


def _tasks(camp, todo: list, results: Path, kinds: list[JobKind]) -> list[dict]:
    """The tasks of the runs ``todo``: the runs of a kind that plans chunks by chunk (planned
    on the whole campaign so that a resume writes the same files), other kinds one run per
    task."""
    from eha.campaigns.traces import chunk_name, trace_path

    wanted = {j.run_key for j in todo}
    tasks: list[dict] = []
    chunked: set[str] = set()
    for kind in kinds:
        if kind.plan_chunks is None:
            continue
        chunked.add(kind.name)
        for chunk in kind.plan_chunks(camp.jobs):
            runs = [j for j in chunk if j.run_key in wanted]
            if not runs:
                continue
            path = trace_path(results, camp.name, "x").with_name(
                chunk_name([j.run_key for j in runs]))
            tasks.append({"kind": "chunk", "job_kind": kind.name, "campaign": camp.name,
                          "trace_file": str(path), "trace_path": str(path.relative_to(results)),
                          **(kind.chunk_fields(runs) if kind.chunk_fields else {}),
                          # a run's descriptive columns travel with it: a kind's worker
                          # reads its own (the simulation pairs HF and LF by case_key)
                          "runs": [{**j.columns, "run_key": j.run_key, "spec": j.spec}
                                   for j in runs]})
    for j in todo:
        if j.kind in chunked:
            continue
        path = trace_path(results, camp.name, j.run_key)
        tasks.append({**j.columns, "kind": j.kind, "spec": j.spec, "run_key": j.run_key,
                      "campaign": camp.name, "trace_file": str(path),
                      "trace_path": str(path.relative_to(results))})
    return tasks


def _execute(payloads, db, summary: RunSummary, workers, scheduler, progress: bool,
             executor: Executor | None, kinds: list[JobKind]) -> None:
    import contextlib

    t0 = time.perf_counter()
    own = executor is None
    n_runs = sum(len(p["runs"]) if p["kind"] == "chunk" else 1 for p in payloads)
    by_name = {k.name: k for k in kinds}
    with (make_executor(workers, scheduler) if own else contextlib.nullcontext(executor)) as ex, \
            _progress(progress) as bar:
        task = bar.add_task(f"{summary.campaign} (starting {ex.workers} workers)",
                            total=n_runs)
        ex.warm_up([k.name for k in kinds])
        summary.startup_s = time.perf_counter() - t0
        bar.update(task, description=f"{summary.campaign} ({ex.workers} workers)")
        buffer: list[dict] = []     # results of single jobs (dicts)
        batches: list[dict] = []    # results of chunks (Arrow tables)
        pending_runs = 0
        # what spans several tasks (e.g. a case's HF and LF runs in two chunks)
        collectors = [k.collect(payloads) for k in kinds if k.collect is not None]
        last = time.perf_counter()
        try:
            for res in _unbundled(ex.map_unordered(
                    execute_task, bundle_tasks(payloads, by_name, ex.workers,
                                               ex.tasks_per_worker))):
                for c in collectors:
                    c.add(res)
                if "runs" in res:   # a chunk
                    batches.append(res)
                    n = res["n"]
                    summary.done += n - len(res["errors"])
                    errors = [f"{k}: {e}" for k, e in res["errors"]]
                else:
                    buffer.append(res)
                    n = 1
                    summary.done += res["status"] == "done"
                    errors = [] if res["status"] == "done" else [
                        f"{res['run_key']}: {res['error']}"]
                summary.errors += errors[:max(0, 20 - len(summary.errors))]
                bar.advance(task, n)
                pending_runs += n
                if pending_runs >= BATCH_ROWS or time.perf_counter() - last > BATCH_SECONDS:
                    db.record(buffer, _collected(collectors), batches)
                    buffer, batches, pending_runs, last = [], [], 0, time.perf_counter()
        finally:
            # on Ctrl-C too: keep what is done
            db.record(buffer, _collected(collectors), batches)
            summary.jobs_s = time.perf_counter() - t0 - summary.startup_s


def bundle_tasks(payloads: list[dict], kinds: dict[str, JobKind], workers: int,
                 tasks_per_worker: int | None) -> list[dict]:
    """The tasks to send: on an executor whose tasks cost more (``tasks_per_worker``, Dask's
    :attr:`~eha.campaigns.executors.Executor.tasks_per_worker`), the chunk tasks of a kind
    whose chunks are short grouped into bundles of consecutive chunks
    (``{"kind": "bundle", "tasks": [...]}``, run in turn by one worker); other tasks as
    they are.

    A kind's chunks (its files) depend on the campaign only; how many of them one task runs
    depends on the executor: ``max(tasks_per_worker x workers, work / TASK_SECONDS)`` tasks,
    the work estimated with the kind's ``estimate_s``, chunks shared out evenly in campaign
    order. A kind without an estimate, chunks long enough already, or ``tasks_per_worker``
    None: one chunk per task.
    """
    import math

    if tasks_per_worker is None:
        return payloads
    chunks: dict[str, list[dict]] = {}
    out: list[dict] = []
    for p in payloads:
        kind = kinds.get(p.get("job_kind", "")) if p["kind"] == "chunk" else None
        if kind is None or kind.estimate_s is None:
            out.append(p)
        else:
            chunks.setdefault(kind.name, []).append(p)
    for name, tasks in chunks.items():
        work = sum(kinds[name].estimate_s(r["spec"]) for t in tasks for r in t["runs"])
        n = max(tasks_per_worker * max(1, workers), math.ceil(work / TASK_SECONDS))
        if n >= len(tasks):
            out.extend(tasks)
            continue
        edges = [round(i * len(tasks) / n) for i in range(n + 1)]
        out.extend({"kind": "bundle", "tasks": tasks[a:b]} for a, b in zip(edges, edges[1:]))
    return out


def _unbundled(results):
    """The results of the tasks, a bundle's one per chunk."""
    for res in results:
        if "bundle" in res:
            yield from res["bundle"]
        else:
            yield res


def _collected(collectors: list) -> dict[str, list[dict]]:
    """The rows the collectors hold now, by result table."""
    rows: dict[str, list[dict]] = {}
    for c in collectors:
        for table, part in c.take().items():
            rows.setdefault(table, []).extend(part)
    return rows


__all__ = ["run_campaign", "RunSummary", "CampaignChanged", "BATCH_ROWS", "BATCH_SECONDS",
           "verify_results", "Verified"]
