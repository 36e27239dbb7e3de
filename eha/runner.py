"""Run campaigns: executors (local spawn pool, Dask), worker job functions, run metrics.

The parent process plans the jobs (:mod:`eha.campaign`), opens ``DIR/eha.duckdb`` (it is the
only writer, :class:`eha.store.ResultStore`), skips runs already done, and hands the rest to an
:class:`Executor`. Workers simulate, compute the run's metrics and write one Parquet trace each
(atomically, :func:`eha.store.write_trace`); they never touch the database. The parent records
results in batches, shows a progress bar, and computes the HF-vs-LF metrics of a case as soon
as its two runs are back (from signals the workers return; traces are read back only for pairs
split across sessions).

Resume
------
A run is recorded ``done`` only after its trace file has been renamed into place, in the same
transaction as its metrics. Killing everything at any moment (``kill -9`` of the process group)
loses at most the runs not yet committed; the next ``eha campaign run`` of the same file removes
stray temporary files, re-runs every run not ``done`` (or whose trace is missing) and ends with
the same rows as an uninterrupted run.

Job kinds
---------
:data:`JOB_RUNNERS` maps a job kind to ``fn(spec, run_key, campaign, trace_file) -> dict`` run
in the worker. It returns ``{"rows": {table: row}, ...runs columns...}``; every table must be
in :data:`eha.store.RESULT_TABLES` (declared in :data:`eha.store.SCHEMA`). To add FDI: an
expander in :data:`eha.campaign.SECTION_KINDS` (``[fdi]`` section → jobs of kind ``"fdi"``),
``JOB_RUNNERS["fdi"]`` here, and the ``fdi_results`` table in the store's schema.

This module imports nothing heavy at import time: spawn workers unpickle functions from it,
and :func:`_init_worker` must set ``NUMBA_NUM_THREADS`` before numba is first imported.
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

#: Numba threads per worker process (one process per core already).
WORKER_NUMBA_THREADS = 1
#: Results are committed at least this often [s] (and every :data:`BATCH_ROWS` runs): a
#: commit costs tens of milliseconds whatever its rows, the parent shares the cores with the
#: workers, and a crash loses at most this much finished work.
BATCH_SECONDS = 0.5
BATCH_ROWS = 5000


class CampaignChanged(ValueError):
    """The campaign was recorded from a different definition under the same name."""


def _now() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


# Metrics live in eha.run_metrics (vectorised over a chunk); the names stay importable here.
from eha.run_metrics import (MAX_LAG, SETTLING_BAND, lag, max_abs_error,  # noqa: E402,F401
                             pair_metrics, rmse, settling_time, trace_metrics)


# =========================================================================== worker side
def _init_worker() -> None:
    """Pool-worker initialiser: one numba thread per process, exit when the parent dies, then
    :func:`warm_worker`."""
    import signal

    os.environ["NUMBA_NUM_THREADS"] = str(WORKER_NUMBA_THREADS)
    # Ctrl-C goes to the whole terminal process group: the parent handles it (commits what is
    # finished, stops the pool); workers would only print tracebacks.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    warm_worker()


def _exit_with_parent() -> None:
    """Exit this worker as soon as its parent process is gone (killed with SIGKILL, say).

    An idle worker waits on the task queue, whose write end every worker also holds, so it
    would never see end-of-file and would block for good (and the resource tracker with it).
    A daemon thread waits on the parent's sentinel instead and ends the process; a run it
    interrupts is not recorded and is re-run by the next ``eha campaign run``.
    """
    import multiprocessing
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:
        return

    def watch() -> None:
        wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="eha-parent-watch", daemon=True).start()


def warm_worker() -> str:
    """Run a tiny HF and LF job end to end in this process (not recorded anywhere).

    Imports happen once per worker instead of inside the first task, numba loads and links the
    cached kernels (``cache=True``: nothing is recompiled per task), and pyarrow's Parquet
    writer is initialised. Returns ``host:pid``.
    """
    import tempfile

    from eha.batch import run_chunk

    with tempfile.TemporaryDirectory(prefix="eha-warm-") as tmp:
        runs = [{"run_key": f"{i:016x}", "case_key": "warm", "model": model,
                 "spec": {"model": model, "command": {"name": "step_1mm", "set": {}},
                          "params": {}, "seed": 0, "t_end": 2e-3}}
                for i, model in enumerate(("hf", "lf"))]
        run_chunk({"campaign": "warm-up", "trace_file": str(Path(tmp) / "w.parquet"),
                   "trace_path": "w.parquet", "signals": ["t", "com", "xu"], "runs": runs})
    return f"{socket.gethostname()}:{os.getpid()}"


def worker_info() -> dict[str, Any]:
    """Diagnostics of the calling worker: ``worker`` (host:pid), ``numba_threads`` and the
    numba cache statistics of the kernels (``cache_misses`` stays 0 when nothing recompiles)."""
    import numba

    from eha.models.hf import run_hf
    from eha.models.lf import run_lf

    misses = sum(sum(k.stats.cache_misses.values()) for k in (run_hf, run_lf))
    hits = sum(sum(k.stats.cache_hits.values()) for k in (run_hf, run_lf))
    return {"worker": f"{socket.gethostname()}:{os.getpid()}",
            "numba_threads": numba.config.NUMBA_NUM_THREADS,
            "cache_hits": hits, "cache_misses": misses}


def _run_simulation(spec: Mapping[str, Any], run_key: str, campaign: str, trace_file: str,
                    want_signals: bool = False) -> dict[str, Any]:
    from eha.commands import make_command
    from eha.simulate import simulate
    from eha.simulate import Trace
    from eha.campaigns.traces import write_trace

    cmd = make_command(spec["command"]["name"], **spec["command"]["set"])
    t0 = time.perf_counter()
    trace = simulate(spec["model"], cmd, spec["params"], t_end=spec["t_end"], seed=spec["seed"])
    sim_s = time.perf_counter() - t0
    import numpy as np

    if not np.all(np.isfinite(trace.data)):
        raise FloatingPointError("the simulation produced NaN/inf (unstable parameter set)")
    metrics = trace_metrics(trace)
    trace = Trace(trace.data, {**trace.meta, "run_key": run_key, "campaign": campaign})
    write_trace(trace, trace_file, columns=spec["signals"])
    out = {"rows": {"metrics": metrics}, "sim_s": sim_s, "trace_rows": len(trace)}
    if want_signals:  # the parent pairs HF and LF of a case without reading the files back
        out["signals"] = {"xu": trace.xu.copy(), "p12": trace["p12"].copy()}
    return out


#: Worker function of each job kind (see the module docstring).
def _run_fdi(spec: Mapping[str, Any], run_key: str, campaign: str,
             trace_file: str) -> dict[str, Any]:
    """Fault identification (:func:`eha.fdi_cases.run_job`): an ``fdi_results`` row and the trace of
    the identified LF model."""
    from eha.fdi_cases import run_job
    from eha.simulate import Trace
    from eha.campaigns.traces import write_trace

    row, fitted = run_job(spec)
    write_trace(Trace(fitted.data, {**fitted.meta, "run_key": run_key, "campaign": campaign}),
                trace_file)
    return {"rows": {"fdi_results": row}, "sim_s": row["seconds"], "trace_rows": len(fitted)}


def _run_health(spec: Mapping[str, Any], run_key: str, campaign: str,
                trace_file: str) -> dict[str, Any]:
    """Health assessment of a simulated actuator (:func:`eha.detection.run_health_job`): a
    ``health_assessments`` row and the record (t, com, xu) as the trace."""
    from eha.detection import run_health_job
    from eha.simulate import Trace
    from eha.campaigns.traces import write_trace

    row, record = run_health_job(spec)
    write_trace(Trace(record.data, {**record.meta, "run_key": run_key, "campaign": campaign}),
                trace_file, columns=["t", "com", "xu"])
    return {"rows": {"health_assessments": row}, "sim_s": row["seconds"]}


JOB_RUNNERS: dict[str, Callable[..., dict[str, Any]]] = {"simulate": _run_simulation,
                                                         "fdi": _run_fdi,
                                                         "health_assessment": _run_health}


def _lazy(module: str, name: str) -> Callable[..., dict[str, Any]]:
    """A job function imported from ``module`` only when a worker first runs it."""
    def call(*args, **kwargs):
        import importlib

        return getattr(importlib.import_module(module), name)(*args, **kwargs)
    call.__name__ = name
    return call


# prognostics (eha rul: assess one record; eha fleet simulate: write one record)
JOB_RUNNERS["health"] = _lazy("eha.prognostics_jobs", "run_health_job")
JOB_RUNNERS["fleet_record"] = _lazy("eha.fleet", "run_record_job")


def execute_job(payload: Mapping[str, Any]) -> dict[str, Any]:
    """Run one job in a worker; never raises for a failing job (status ``failed``).

    ``payload``: ``kind``, ``spec``, ``run_key``, ``campaign``, ``trace_file`` (absolute path),
    ``trace_path`` (relative, recorded in the database).
    """
    started = _now()
    t0 = time.perf_counter()
    result: dict[str, Any] = {"run_key": payload["run_key"], "started_at": started,
                              "worker": f"{socket.gethostname()}:{os.getpid()}",
                              "trace_path": None, "error": None, "rows": {}}
    try:
        extra = {"want_signals": True} if payload.get("want_signals") else {}
        out = JOB_RUNNERS[payload["kind"]](payload["spec"], payload["run_key"],
                                           payload["campaign"], payload["trace_file"], **extra)
        result.update(out)
        result["status"] = "done"
        if Path(payload["trace_file"]).exists():
            result["trace_path"] = payload["trace_path"]
            # recorded with the run: the resume checks the file against it (docs/reliability.md)
            result["trace_bytes"] = Path(payload["trace_file"]).stat().st_size
    except Exception as exc:  # recorded, the campaign goes on
        result["status"] = "failed"
        result["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        result["rows"] = {}
    result["finished_at"] = _now()
    result["elapsed_s"] = time.perf_counter() - t0
    return result


# =========================================================================== executors
class Executor:
    """Runs a function over payloads on some workers; yields results as they complete.

    Subclasses implement :meth:`_submit` and :meth:`_wait_one`; at most ``in_flight`` tasks
    are outstanding so that a huge campaign does not sit in memory as futures.
    """

    workers: int = 1

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        # Ctrl-C, SIGTERM or exit: what is finished is committed already (the runner's
        # ``finally``); the runs still in the workers are not, so stop them now rather than
        # wait for them.
        if exc_type is not None and not issubclass(exc_type, Exception):
            self.abort()
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        pass

    def abort(self) -> None:
        """Stop the running jobs at once (their runs stay pending and are re-run)."""

    def warm_up(self) -> None:
        """Start the workers and load the kernels before timing or submitting jobs."""

    def map_unordered(self, fn: Callable, payloads: Iterable[Any]) -> Iterator[Any]:
        pending: set = set()
        in_flight = max(4, 4 * self.workers)
        it = iter(payloads)
        exhausted = False
        while True:
            while not exhausted and len(pending) < in_flight:
                try:
                    pending.add(self._submit(fn, next(it)))
                except StopIteration:
                    exhausted = True
            if not pending:
                return
            done, pending = self._wait(pending)
            for fut in done:
                yield fut.result()

    def _submit(self, fn, payload):  # pragma: no cover - overridden
        raise NotImplementedError

    def _wait(self, pending: set) -> tuple[set, set]:  # pragma: no cover - overridden
        raise NotImplementedError


class _MainHidden:
    """Hide ``__main__`` from multiprocessing while workers are spawned.

    A spawned worker normally re-imports the parent's main script (the ``eha`` entry point,
    a notebook kernel, a script without an ``if __name__ == "__main__"`` guard, or fails for
    ``python - < script``). The pool only runs functions of this module, so the workers need
    nothing from ``__main__``: skipping it starts them faster and from anywhere.
    """

    def __enter__(self):
        import sys

        self.main = sys.modules.get("__main__")
        self.saved = {k: getattr(self.main, k) for k in ("__spec__", "__file__")
                      if self.main is not None and hasattr(self.main, k)}
        if self.main is not None:
            self.main.__spec__ = None
            if "__file__" in self.saved:
                del self.main.__file__
        return self

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            setattr(self.main, k, v)


class LocalPoolExecutor(Executor):
    """A pool of ``workers`` spawned processes (one numba thread each).

    All workers are started by :meth:`warm_up` (the runner calls it before the first job).
    """

    def __init__(self, workers: int = 2):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        self.workers = max(1, int(workers))
        self._pool = ProcessPoolExecutor(self.workers,
                                         mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_init_worker)

    def warm_up(self) -> None:
        # Every worker runs the initialiser (warm_worker) as it starts; these no-op tasks only
        # make all of them start now.
        if getattr(self, "_warm", False):
            return
        self._warm = True
        # One task per worker, submitted back to back: each submit spawns a process (none is
        # idle yet), so every worker starts here, inside _MainHidden.
        with _MainHidden():
            futs = [self._pool.submit(time.sleep, 0.02) for _ in range(self.workers)]
        for f in futs:
            f.result()

    def _submit(self, fn, payload):
        return self._pool.submit(fn, payload)

    def _wait(self, pending):
        from concurrent.futures import FIRST_COMPLETED, wait

        done, rest = wait(pending, return_when=FIRST_COMPLETED)
        return set(done), set(rest)

    def close(self) -> None:
        # The workers exit on their own once told to; the parent goes on meanwhile.
        self._pool.shutdown(wait=False, cancel_futures=True)

    def abort(self) -> None:
        for proc in list((getattr(self._pool, "_processes", None) or {}).values()):
            try:
                proc.terminate()
            except (OSError, ValueError, AttributeError):  # already gone
                pass


class DaskExecutor(Executor):
    """Jobs on a Dask distributed cluster (``scheduler``: ``tcp://HOST:PORT`` or a Client).

    Workers must see the results folder at the same absolute path (shared file system) and
    have ``eha`` installed; see docs/scaling.md.
    """

    def __init__(self, scheduler: Any):
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - depends on the install
            raise RuntimeError("--scheduler needs Dask: pip install 'eha[dask]'") from None
        if isinstance(scheduler, Client):
            self.client, self._own = scheduler, False
        else:
            try:
                self.client, self._own = Client(scheduler, timeout="10s"), True
            except (OSError, TimeoutError, ValueError, TypeError) as exc:
                raise RuntimeError(f"--scheduler {scheduler}: cannot connect "
                                   f"({type(exc).__name__}: {exc})") from None
        self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                  self.client.scheduler_info()["workers"].values()))

    def warm_up(self) -> None:
        self.client.run(warm_worker)

    def _submit(self, fn, payload):
        return self.client.submit(fn, payload, pure=False)

    def _wait(self, pending):
        from distributed import wait

        res = wait(list(pending), return_when="FIRST_COMPLETED")
        return set(res.done), set(res.not_done)

    def close(self) -> None:
        if self._own:
            self.client.close()


def check_scheduler(address: str) -> str:
    """Refuse a ``--scheduler`` that is not a Dask address (``tcp://HOST:PORT``) before any
    work starts; returns it.

    Raises
    ------
    ValueError
        One line naming the option and the expected form.
    """
    import re

    ok = re.fullmatch(r"(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                      r":(\d{1,5})", address.strip())
    if not ok or not 0 < int(ok.group(1)) < 65536:
        raise ValueError(f"--scheduler {address!r}: not a scheduler address; expected "
                         "tcp://HOST:PORT (PORT in [1, 65535])")
    return address


def make_executor(workers: int = 2, scheduler: Any = None) -> Executor:
    """The local spawn pool, or a :class:`DaskExecutor` when ``scheduler`` is given."""
    if scheduler is not None:
        return DaskExecutor(scheduler)
    return LocalPoolExecutor(workers)


# =========================================================================== parent side
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
        A :class:`eha.campaign.Campaign` or a campaign TOML file.
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
    eha.campaign.CampaignError
        Invalid campaign file (nothing runs).
    CampaignChanged
        The campaign name is recorded with a different definition and ``replace`` is false.
    eha.store.StoreError
        The database is locked by another process.
    """
    from eha.campaigns.files import Campaign, load_campaign
    from eha.simulate import MODEL_VERSION
    from eha.campaigns.store import ResultStore
    from eha.campaigns.traces import clean_temp_files

    t_start = time.perf_counter()
    camp = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    summary = RunSummary(camp.name, len(camp.jobs))
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
                    "common); give it a new name, or pass --replace to discard the recorded runs")
            # Runs of the new definition already recorded are the same runs (same key): kept.
            summary.changed = True
            summary.replaced = db.discard_runs(camp.name, {j.run_key for j in camp.jobs})
        now = _now()
        db.register_campaign({
            "name": camp.name, "description": camp.description, "source": camp.source,
            "spec_hash": camp.spec_hash, "model_version": MODEL_VERSION,
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
                         **{k: v for k, v in j.columns.items() if k in _RUN_COLUMNS}}
                        for j in todo])
        payloads = _tasks(camp, todo, db.results)
        if payloads:
            _execute(payloads, db, summary, workers, scheduler, progress, executor)
        _finish_pairs(db, camp.name)
        counts = db.status_counts(camp.name)
        summary.failed = counts.get("failed", 0)
    summary.wall_s = time.perf_counter() - t_start
    return summary


_RUN_COLUMNS = {"model", "command", "faults", "fault_label", "seed", "t_end", "case_key", "label"}


def _tasks(camp, todo: list, results: Path) -> list[dict]:
    """The tasks of the runs ``todo``: simulations by chunk (:func:`eha.batch.plan_chunks`,
    planned on the whole campaign so that a resume writes the same files), other kinds one
    run per task."""
    from eha.batch import plan_chunks
    from eha.campaigns.traces import chunk_name
    from eha.campaigns.traces import trace_path

    wanted = {j.run_key for j in todo}
    tasks: list[dict] = []
    for chunk in plan_chunks(camp.jobs):
        runs = [j for j in chunk if j.run_key in wanted]
        if not runs:
            continue
        path = trace_path(results, camp.name, "x").with_name(
            chunk_name([j.run_key for j in runs]))
        tasks.append({"kind": "chunk", "campaign": camp.name, "trace_file": str(path),
                      "trace_path": str(path.relative_to(results)),
                      "signals": runs[0].spec["signals"],
                      "runs": [{"run_key": j.run_key, "spec": j.spec,
                                "case_key": j.columns.get("case_key"),
                                "model": j.columns.get("model")} for j in runs]})
    for j in todo:
        if j.kind == "simulate":
            continue
        path = trace_path(results, camp.name, j.run_key)
        tasks.append({"kind": j.kind, "spec": j.spec, "run_key": j.run_key,
                      "campaign": camp.name, "trace_file": str(path),
                      "trace_path": str(path.relative_to(results)),
                      "case_key": j.columns.get("case_key"), "model": j.columns.get("model")})
    return tasks


def execute_task(task: Mapping[str, Any]) -> dict[str, Any]:
    """Run one task in a worker: a chunk of simulations (:func:`eha.batch.run_chunk`) or a
    single job of another kind (:func:`execute_job`)."""
    if task["kind"] == "chunk":
        from eha.batch import run_chunk

        return run_chunk(task)
    return execute_job(task)


def _execute(payloads, db, summary: RunSummary, workers, scheduler, progress: bool,
             executor: Executor | None) -> None:
    import contextlib

    t0 = time.perf_counter()
    own = executor is None
    n_runs = sum(len(p["runs"]) if p["kind"] == "chunk" else 1 for p in payloads)
    with (make_executor(workers, scheduler) if own else contextlib.nullcontext(executor)) as ex, \
            _progress(progress) as bar:
        task = bar.add_task(f"{summary.campaign} (starting {ex.workers} workers)",
                            total=n_runs)
        ex.warm_up()
        summary.startup_s = time.perf_counter() - t0
        bar.update(task, description=f"{summary.campaign} ({ex.workers} workers)")
        buffer: list[dict] = []     # results of single jobs (dicts)
        batches: list[dict] = []    # results of chunks (Arrow tables)
        pending_runs = 0
        pairs = _Pairs(payloads)
        last = time.perf_counter()
        try:
            for res in ex.map_unordered(execute_task, payloads):
                pairs.add(res)
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
                    db.record(buffer, {"metrics": pairs.take()}, batches)
                    buffer, batches, pending_runs, last = [], [], 0, time.perf_counter()
        finally:
            # on Ctrl-C too: keep what is done
            db.record(buffer, {"metrics": pairs.take()}, batches)
            summary.jobs_s = time.perf_counter() - t0 - summary.startup_s


class _Pairs:
    """HF-vs-LF metrics of the cases split across tasks, as results arrive.

    A case whose HF and LF runs are in one chunk is paired by its worker. One split across
    two tasks of this session is paired here from the signals the workers send back for those
    runs only; one whose other run was done in an earlier session is paired at the end
    (:func:`_finish_pairs`).
    """

    def __init__(self, payloads: list[dict]):
        where: dict[str, dict[str, tuple[int, dict]]] = {}
        for i, p in enumerate(payloads):
            for run in (p["runs"] if p["kind"] == "chunk" else [p]):
                if (p["kind"] in ("chunk", "simulate") and run.get("case_key")
                        and run.get("model")):
                    where.setdefault(run["case_key"], {})[run["model"]] = (i, run)
        self.case: dict[str, tuple[str, str]] = {}
        for case, models in where.items():
            if "hf" in models and "lf" in models and models["hf"][0] != models["lf"][0]:
                for model in ("hf", "lf"):
                    run = models[model][1]
                    run["want_signals"] = True
                    self.case[run["run_key"]] = (case, model)
        self.waiting: dict[str, dict[str, tuple[str, dict]]] = {}
        self.rows: list[dict] = []

    def add(self, result: dict) -> None:
        if "runs" in result:
            signals = result.pop("signals", {})
        else:
            one = result.pop("signals", None)
            signals = {result["run_key"]: one} if one is not None and \
                result["status"] == "done" else {}
        for key, sig in signals.items():
            if key in self.case:
                self._add(key, sig)

    def _add(self, run_key: str, signals: dict) -> None:
        case, model = self.case[run_key]
        mine = self.waiting.setdefault(case, {})
        mine[model] = (run_key, signals)
        if "hf" in mine and "lf" in mine:
            (hf_key, hf), (lf_key, lf) = mine.pop("hf"), mine.pop("lf")
            del self.waiting[case]
            if len(hf["xu"]) == len(lf["xu"]):
                m = pair_metrics(hf, lf)
                self.rows += [{"run_key": hf_key, **m}, {"run_key": lf_key, **m}]

    def take(self) -> list[dict]:
        rows, self.rows = self.rows, []
        return rows


def _finish_pairs(db, campaign: str) -> int:
    """HF-vs-LF metrics of every case whose HF and LF runs are both done but not yet paired
    (e.g. one of them ran in an earlier session): reads their traces; returns how many."""
    from eha.campaigns.traces import read_trace

    rows = []
    for hf_key, hf_path, lf_key, lf_path in db.hf_lf_pairs(campaign):
        try:
            hf = read_trace(db.results / hf_path, hf_key)
            lf = read_trace(db.results / lf_path, lf_key)
        except Exception:  # vanished or damaged (ArrowInvalid): not paired now; the resume
            continue       # re-runs a damaged trace (eha.store.trace_intact)
        if len(hf) != len(lf):
            continue
        m = pair_metrics(hf, lf)
        rows += [{"run_key": hf_key, **m}, {"run_key": lf_key, **m}]
    if rows:
        db.con.execute("BEGIN")
        db.upsert("metrics", rows)
        db.con.execute("COMMIT")
    return len(rows) // 2


__all__ = ["run_campaign", "RunSummary", "CampaignChanged", "Executor", "LocalPoolExecutor",
           "DaskExecutor", "make_executor", "execute_job", "execute_task", "JOB_RUNNERS", "trace_metrics",
           "pair_metrics", "rmse", "max_abs_error", "settling_time", "lag"]
