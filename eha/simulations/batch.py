"""The campaign runner's ``simulate`` job kind: a chunk of runs per task, one chunk file per
task (issue 25).

A 1-s HF run simulates in about 5 ms; sent one per task, its bookkeeping (a task round trip, a
Parquet file, per-run metrics, a row-by-row commit) cost more than the run. The runner therefore
groups a campaign's simulations into *chunks* (:func:`plan_chunks`): consecutive runs of the
campaign, whole HF/LF cases kept together, sized to about :data:`TASK_SECONDS` of work. A worker
runs a chunk (:func:`run_chunk`): it simulates each run, computes the metrics of all of them at
once (:func:`eha.models.run_metrics.batch_metrics`) and the HF-vs-LF metrics of the cases inside the
chunk, writes one chunk file (:mod:`eha.campaigns.traces`) and returns Arrow tables that the
parent inserts in bulk.

The chunks depend only on the campaign (its jobs and their estimated cost), never on the
workers or on what is already done: after a crash the runs left of a chunk are re-run into the
file named after exactly those runs, and an uninterrupted campaign and a resumed one end with
the same files and the same rows.

The kind is declared here, whole (:data:`SIMULATE`, a :class:`eha.campaigns.jobs.JobKind`
found through the ``eha.job_kinds`` entry point ``simulate``): its part of a campaign file (the
top-level keys and their expander, :mod:`eha.simulations.expand`), its chunks, a one-run job
(:func:`run_simulation_job`), the plan's estimate, its ``metrics`` table, the HF-vs-LF pairs of
a case split across tasks (:class:`Pairs`, :func:`finish_pairs`) and the worker warm-up
(:func:`warm_up`).
"""

from __future__ import annotations

import os
import socket
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.campaigns.jobs import TASK_SECONDS, JobKind, Table
from eha.simulations.expand import KEYS, expand

#: A campaign of N simulations is split into at least min(N, MIN_CHUNKS) chunks, so that up
#: to 16 workers get 4 each whatever their number (the chunks never depend on the workers; on
#: fewer workers the runner sends several short chunks as one task); a small campaign keeps
#: one file per run.
MIN_CHUNKS = 64
#: Most rows of one chunk file (a chunk of long runs is smaller).
MAX_CHUNK_ROWS = 1_000_000
#: Cost of simulating one second at DT = 1e-5 s [s], per model (2-core reference machine).
SIM_COST = {"hf": 5e-3, "lf": 3e-3}


def estimated_run_s(spec: Mapping[str, Any]) -> float:
    """Estimated simulation time [s] of one ``simulate`` job (spec of
    :mod:`eha.simulations.expand`)."""
    dt = spec["params"].get("DT", 1e-5)
    return SIM_COST[spec["model"]] * spec["t_end"] * (1e-5 / dt)


def chunk_size(jobs: Sequence[Any]) -> int:
    """Runs per chunk for the ``simulate`` jobs ``jobs`` (see the module docstring)."""
    if not jobs:
        return 1
    per_run = sum(estimated_run_s(j.spec) for j in jobs) / len(jobs)
    rows = max(int(round(j.spec["t_end"] / 1e-3)) + 1 for j in jobs)  # 1 kHz output
    k = min(TASK_SECONDS / max(per_run, 1e-6), len(jobs) / MIN_CHUNKS, MAX_CHUNK_ROWS / rows)
    return max(1, int(k))


def plan_chunks(jobs: Sequence[Any]) -> list[list[Any]]:
    """The chunks of a campaign's ``simulate`` jobs: consecutive jobs in campaign order, about
    :func:`chunk_size` runs each; chunks of more than one run never split a case (same
    ``case_key``: its HF and LF), so its worker pairs them."""
    sims = [j for j in jobs if j.kind == "simulate"]
    k = chunk_size(sims)
    chunks: list[list[Any]] = []
    current: list[Any] = []
    for i, job in enumerate(sims):
        current.append(job)
        nxt = sims[i + 1] if i + 1 < len(sims) else None
        same_case = (k > 1 and nxt is not None and job.columns.get("case_key") is not None
                     and nxt.columns.get("case_key") == job.columns.get("case_key"))
        if len(current) >= k and not same_case:
            chunks.append(current)
            current = []
    if current:
        chunks.append(current)
    return chunks


def _now() -> datetime:
    return datetime.now(timezone.utc).replace(tzinfo=None)


def run_chunk(task: Mapping[str, Any]) -> dict[str, Any]:
    """Run a chunk of simulations in a worker; never raises for a failing run.

    Parameters
    ----------
    task : mapping
        ``campaign``, ``trace_file`` (absolute path of the chunk file), ``trace_path``
        (relative, recorded), ``signals`` (stored columns) and ``runs``: dicts with
        ``run_key``, ``spec``, ``case_key``, ``model`` and ``want_signals`` (the run's HF/LF
        partner is in another task: return its xu and P12 for the parent to pair).

    Returns
    -------
    dict
        ``n`` (runs), ``runs`` (Arrow table of the ``runs`` columns to update), ``parts``
        (``[(table, Arrow table)]`` to upsert), ``signals`` (``{run_key: {"xu", "p12"}}``)
        and ``errors`` (``[(run_key, message)]``).
    """
    import numpy as np
    import pyarrow as pa

    from eha.campaigns.integrity import file_stamp
    from eha.campaigns.traces import write_chunk
    from eha.models.commands import make_command
    from eha.models.run_metrics import PAIR_METRICS, RUN_METRICS, batch_metrics, batch_pair_metrics
    from eha.models.simulate import simulate

    t_task = time.perf_counter()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    done: list[tuple[dict, Any, float, datetime]] = []   # (run, trace, sim_s, started_at)
    failed: dict[str, tuple[str, datetime]] = {}
    for run in task["runs"]:
        started = _now()
        spec = run["spec"]
        try:
            cmd = make_command(spec["command"]["name"], **spec["command"]["set"])
            t0 = time.perf_counter()
            trace = simulate(spec["model"], cmd, spec["params"], t_end=spec["t_end"],
                             seed=spec["seed"])
            sim_s = time.perf_counter() - t0
            if not np.all(np.isfinite(trace.data)):
                raise FloatingPointError("the simulation produced NaN/inf (unstable "
                                         "parameter set)")
            done.append((run, trace, sim_s, started))
        except Exception as exc:  # recorded, the chunk goes on
            failed[run["run_key"]] = (_error(exc), started)

    metric_rows: dict[str, list] = {n: [] for n in ("run_key",) + RUN_METRICS}
    pair_rows: dict[str, list] = {n: [] for n in ("run_key",) + PAIR_METRICS}
    by_len: dict[int, list] = {}
    for item in done:
        by_len.setdefault(len(item[1]), []).append(item)
    for items in by_len.values():  # one vectorised pass per run length
        t = items[0][1].t
        stack = {n: np.stack([it[1][n] for it in items]) for n in ("xu", "com", "xs", "p12",
                                                                  "cor")}
        values = batch_metrics(t, stack)
        metric_rows["run_key"] += [it[0]["run_key"] for it in items]
        for n in RUN_METRICS:
            metric_rows[n] += values[n].tolist()
        _pairs_inside(items, stack, pair_rows, batch_pair_metrics)

    trace_bytes = trace_hash = trace_mtime = None
    if done:
        try:
            trace_bytes = write_chunk(
                [(it[0]["run_key"], it[1].data,
                  {**it[1].meta, "run_key": it[0]["run_key"], "campaign": task["campaign"]})
                 for it in done], task["trace_file"], task["signals"])
            # recorded with the runs: the resume and queries check the file against it
            trace_hash, trace_mtime = file_stamp(task["trace_file"])
        except Exception as exc:  # e.g. a full disk: every run of the chunk failed
            failed.update({it[0]["run_key"]: (_error(exc), it[3]) for it in done})
            done = []
            metric_rows = {n: [] for n in metric_rows}
            pair_rows = {n: [] for n in pair_rows}
    finished = _now()
    overhead = (time.perf_counter() - t_task - sum(it[2] for it in done)) / max(
        1, len(task["runs"]))
    rows = [{"run_key": it[0]["run_key"], "status": "done", "error": None, "worker": worker,
             "started_at": it[3], "finished_at": finished, "sim_s": it[2],
             "elapsed_s": it[2] + overhead, "trace_path": task["trace_path"],
             "trace_bytes": trace_bytes, "trace_rows": len(it[1]), "trace_hash": trace_hash,
             "trace_mtime": trace_mtime} for it in done]
    rows += [{"run_key": k, "status": "failed", "error": e, "worker": worker,
              "started_at": s, "finished_at": finished, "sim_s": None, "elapsed_s": overhead,
              "trace_path": None, "trace_bytes": None, "trace_rows": None,
              "trace_hash": None, "trace_mtime": None}
             for k, (e, s) in failed.items()]
    signals = {it[0]["run_key"]: {"xu": it[1].xu.copy(), "p12": it[1]["p12"].copy()}
               for it in done if it[0].get("want_signals")}
    return {"n": len(task["runs"]), "runs": pa.Table.from_pylist(rows, schema=_runs_schema()),
            "parts": [("metrics", _table(metric_rows)), ("metrics", _table(pair_rows))],
            "signals": signals, "errors": [(k, e) for k, (e, _) in failed.items()]}


def bare_simulate(specs: Sequence[Mapping[str, Any]]) -> float:
    """Seconds [s] of a bare loop of ``simulate()`` (command built and run) over ``specs``:
    the ideal against which the benchmarks measure a campaign's efficiency; nothing stored."""
    from eha.models.commands import make_command
    from eha.models.simulate import simulate

    t0 = time.perf_counter()
    for s in specs:
        simulate(s["model"], make_command(s["command"]["name"], **s["command"]["set"]),
                 s["params"], t_end=s["t_end"], seed=s["seed"])
    return time.perf_counter() - t0


def _pairs_inside(items: list, stack: dict, pair_rows: dict, pair_fn) -> None:
    """HF-vs-LF metrics of the cases whose HF and LF runs are both in ``items``."""
    import numpy as np

    index: dict[str, dict[str, int]] = {}
    for i, it in enumerate(items):
        if it[0].get("case_key"):
            index.setdefault(it[0]["case_key"], {})[it[0].get("model")] = i
    pairs = [(m["hf"], m["lf"]) for m in index.values() if "hf" in m and "lf" in m]
    if not pairs:
        return
    h, lo = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    values = pair_fn({"xu": stack["xu"][h], "p12": stack["p12"][h]},
                     {"xu": stack["xu"][lo], "p12": stack["p12"][lo]})
    keys = [items[i][0]["run_key"] for i in h] + [items[i][0]["run_key"] for i in lo]
    pair_rows["run_key"] += keys
    for n, v in values.items():  # both runs of a case get the case's values
        v = [None if not np.isfinite(x) else float(x) for x in v]
        pair_rows[n] += v + v


def _table(columns: dict[str, list]):
    """Arrow table of metric columns; NaN (undefined: no settling, constant command) is
    stored as NULL, as the one-run-per-task runner stored None."""
    import pyarrow as pa

    return pa.table({n: pa.array(v, type=pa.string() if n == "run_key" else pa.float64(),
                                 from_pandas=True) for n, v in columns.items()})


def _error(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}"


def _runs_schema():
    import pyarrow as pa

    return pa.schema([("run_key", pa.string()), ("status", pa.string()),
                      ("error", pa.string()), ("worker", pa.string()),
                      ("started_at", pa.timestamp("us")), ("finished_at", pa.timestamp("us")),
                      ("sim_s", pa.float64()), ("elapsed_s", pa.float64()),
                      ("trace_path", pa.string()), ("trace_bytes", pa.int64()),
                      ("trace_rows", pa.int64()), ("trace_hash", pa.string()),
                      ("trace_mtime", pa.int64())])


# =========================================================================== the runner's kind
def run_simulation_job(spec: Mapping[str, Any], run_key: str, campaign: str, trace_file: str,
                       want_signals: bool = False) -> dict[str, Any]:
    """One ``simulate`` job on its own (the runner sends them by chunk, :func:`run_chunk`):
    its ``metrics`` row and its trace file."""
    import numpy as np

    from eha.campaigns.traces import write_trace
    from eha.models.commands import make_command
    from eha.models.run_metrics import trace_metrics
    from eha.models.simulate import Trace, simulate

    cmd = make_command(spec["command"]["name"], **spec["command"]["set"])
    t0 = time.perf_counter()
    trace = simulate(spec["model"], cmd, spec["params"], t_end=spec["t_end"], seed=spec["seed"])
    sim_s = time.perf_counter() - t0
    if not np.all(np.isfinite(trace.data)):
        raise FloatingPointError("the simulation produced NaN/inf (unstable parameter set)")
    metrics = trace_metrics(trace)
    trace = Trace(trace.data, {**trace.meta, "run_key": run_key, "campaign": campaign})
    write_trace(trace, trace_file, columns=spec["signals"])
    out = {"rows": {"metrics": metrics}, "sim_s": sim_s, "trace_rows": len(trace)}
    if want_signals:  # the parent pairs HF and LF of a case without reading the files back
        out["signals"] = {"xu": trace.xu.copy(), "p12": trace["p12"].copy()}
    return out


def warm_up() -> None:
    """Run a tiny HF and LF chunk end to end in this worker (not recorded anywhere): imports
    happen once per worker instead of inside the first task, numba loads and links the cached
    kernels (``cache=True``: nothing is recompiled per task), and pyarrow's Parquet writer is
    initialised."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="eha-warm-") as tmp:
        runs = [{"run_key": f"{i:016x}", "case_key": "warm", "model": model,
                 "spec": {"model": model, "command": {"name": "step_1mm", "set": {}},
                          "params": {}, "seed": 0, "t_end": 2e-3}}
                for i, model in enumerate(("hf", "lf"))]
        run_chunk({"campaign": "warm-up", "trace_file": str(Path(tmp) / "w.parquet"),
                   "trace_path": "w.parquet", "signals": ["t", "com", "xu"], "runs": runs})


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


class Pairs:
    """HF-vs-LF metrics of the cases split across tasks, as results arrive.

    A case whose HF and LF runs are in one chunk is paired by its worker. One split across
    two tasks of this session is paired here from the signals the workers send back for those
    runs only; one whose other run was done in an earlier session is paired at the end
    (:func:`finish_pairs`).
    """

    def __init__(self, payloads: list[dict]):
        where: dict[str, dict[str, tuple[int, dict]]] = {}
        for i, p in enumerate(payloads):
            for run in (p["runs"] if p["kind"] == "chunk" else [p]):
                if (p.get("job_kind", p["kind"]) == "simulate" and run.get("case_key")
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
        from eha.models.run_metrics import pair_metrics

        case, model = self.case[run_key]
        mine = self.waiting.setdefault(case, {})
        mine[model] = (run_key, signals)
        if "hf" in mine and "lf" in mine:
            (hf_key, hf), (lf_key, lf) = mine.pop("hf"), mine.pop("lf")
            del self.waiting[case]
            if len(hf["xu"]) == len(lf["xu"]):
                m = pair_metrics(hf, lf)
                self.rows += [{"run_key": hf_key, **m}, {"run_key": lf_key, **m}]

    def take(self) -> dict[str, list[dict]]:
        """The ``metrics`` rows paired since the last call."""
        rows, self.rows = self.rows, []
        return {"metrics": rows}


def finish_pairs(db, campaign: str) -> int:
    """HF-vs-LF metrics of every case whose HF and LF runs are both done but not yet paired
    (e.g. one of them ran in an earlier session): reads their traces; returns how many.
    ``db``: the runner's :class:`eha.campaigns.store.ResultStore`."""
    from eha.campaigns.traces import read_trace
    from eha.models.run_metrics import pair_metrics

    rows = []
    for hf_key, hf_path, lf_key, lf_path in hf_lf_pairs(db.con, campaign):
        try:
            hf = read_trace(db.results / hf_path, hf_key)
            lf = read_trace(db.results / lf_path, lf_key)
        except Exception:  # vanished or damaged (ArrowInvalid): not paired now; the resume
            continue       # re-runs a damaged trace (eha.campaigns.traces.trace_intact)
        if len(hf) != len(lf):
            continue
        m = pair_metrics(hf, lf)
        rows += [{"run_key": hf_key, **m}, {"run_key": lf_key, **m}]
    if rows:
        db.record([], {"metrics": rows})  # one transaction
    return len(rows) // 2


def hf_lf_pairs(con, campaign: str) -> list[tuple[str, str, str, str]]:
    """``(hf_key, hf_trace, lf_key, lf_trace)`` of done HF/LF runs of the same case whose
    HF-vs-LF metrics are still missing (trace paths relative to the results folder); ``con``:
    a connection to the result database."""
    return con.execute("""
        SELECT h.run_key, h.trace_path, l.run_key, l.trace_path
        FROM runs h JOIN runs l ON h.case_key = l.case_key AND h.campaign = l.campaign
        JOIN metrics mh ON mh.run_key = h.run_key
        JOIN metrics ml ON ml.run_key = l.run_key
        WHERE h.campaign = ? AND h.kind = 'simulate' AND l.kind = 'simulate'
          AND h.model = 'hf' AND l.model = 'lf'
          AND h.status = 'done' AND l.status = 'done'
          AND (mh.rmse_xu_hf_lf IS NULL OR ml.rmse_xu_hf_lf IS NULL)
        ORDER BY h.run_key""", [campaign]).fetchall()


def _chunk_fields(runs: Sequence[Any]) -> dict[str, Any]:
    return {"signals": runs[0].spec["signals"]}


def _estimate_s(spec: Mapping[str, Any]) -> float:
    # plus about 0.5 ms per run for metrics, its share of a chunk file and the commit
    return estimated_run_s(spec) + 5e-4


#: The ``simulate`` kind's result table: one row of metrics per run.
METRICS = """
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
            rmse_p12_hf_lf   DOUBLE)  -- Pa"""

#: The ``simulate`` job kind, whole (entry point ``eha.job_kinds`` ``simulate``).
SIMULATE = JobKind("simulate", run_simulation_job, keys=KEYS, drafts=expand,
                   tables=(Table("metrics", METRICS, per_run=True),), warm_up=warm_up,
                   plan_chunks=plan_chunks, run_chunk=run_chunk, chunk_fields=_chunk_fields,
                   estimate_s=_estimate_s, collect=Pairs, finish=finish_pairs)


__all__ = ["plan_chunks", "chunk_size", "run_chunk", "estimated_run_s", "TASK_SECONDS",
           "MIN_CHUNKS", "run_simulation_job", "warm_up", "worker_info", "Pairs", "finish_pairs",
           "METRICS", "SIMULATE"]
