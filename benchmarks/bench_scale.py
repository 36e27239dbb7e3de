"""Campaign throughput (issue 25): efficiency, parent throughput, bytes per run, query times,
the local pool against Dask.

For each size (``--runs``) and run length (``--t-end``), on one set of warm workers:

* **ideal**: the same simulations as a bare loop of ``simulate()`` on those workers (the
  simulate seconds measured in the workers, summed, divided by the workers);
* **campaign wall**: :func:`eha.campaigns.runner.run_campaign` on the same warm workers into a fresh
  results folder (validation, database, tasks, chunk files, metrics, commits, HF-vs-LF);
* **efficiency** = ideal / campaign wall, both measured in this run (the bare loop just
  before and just after the campaign, averaged: a shared machine's load drifts; the load
  average is recorded), and ``sim_share``: the simulate seconds recorded by the campaign's own
  workers / (workers x wall), measured at the same moment as the wall;
* bytes per run (trace files), files, and the time of two queries over every run's trace:
  ``count(*)``, ``avg(xu)`` and an ``avg(xu)`` filtered on a fault value joined with ``runs``,
  inside DuckDB (view built) and ``eha query "select count(*) from traces"`` end to end (a new
  process, CLI start included).

Also the parent's throughput with jobs that do nothing (a fake executor in this process returns
finished chunks at once: validation, database, commits and progress only; runs/s), and, with
``--dask``, the first size (``--dask all``: every size) on a Dask ``LocalCluster`` of the same number of single-threaded
worker processes against the pool: both kept open, the bare loop and the campaign on the pool
and on Dask alternately, ``--rounds`` times (the best of each; a shared machine's load drifts
within minutes, so only walls taken side by side are compared).

Campaigns: HF runs of the ``mixed`` command, five fault sets (nominal and BKL in {1, 2, 5,
10} x 1e-4 m) x N/5 seeds, all nine signals.

Usage::

    python benchmarks/bench_scale.py                      # 2000 and 20000 runs, 1 s and 0.2 s
    python benchmarks/bench_scale.py --runs 2000 --t-end 1.0 --dask --json

``--json`` writes ONE current result file, ``benchmarks/results/bench_scale.json`` (or
``--out``), with the provenance (commit, date, machine, cores, load average).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FAULTS = [1e-4, 2e-4, 5e-4, 1e-3]


def campaign_table(n: int, t_end: float) -> dict:
    """N HF runs of `mixed`: nominal + 4 BKL values, N/5 seeds each."""
    return {"name": f"scale-{n}-{t_end:g}", "models": ["hf"], "commands": ["mixed"],
            "seeds": list(range(max(1, n // 5))), "t_end": t_end,
            "faults": {"nominal": True, "single": {"BKL": FAULTS}}}


def ideal_seconds(camp, ex) -> float:
    """Bare-simulate time of the campaign on the executor's workers: the simulate seconds
    measured in the workers, summed, over the number of workers."""
    from eha.simulations.batch import bare_simulate, plan_chunks

    chunks = [[j.spec for j in c] for c in plan_chunks(camp.jobs)]
    return sum(ex.map_unordered(bare_simulate, chunks)) / ex.workers


def trace_stats(results: Path) -> dict:
    files = [p for p in (results / "traces").rglob("*.parquet")]
    return {"files": len(files), "bytes": sum(p.stat().st_size for p in files)}


def query_times(results: Path, fault: float) -> dict:
    """Seconds of the queries over every trace: in DuckDB (view built first) and end to end
    through the CLI."""
    from eha.campaigns.query import _create_traces_view
    from eha.campaigns.store import connect

    out = {}
    con = connect(results, read_only=True)
    try:
        t0 = time.perf_counter()
        _create_traces_view(con, results.resolve())
        out["view_s"] = time.perf_counter() - t0
        sqls = {"count_avg": "SELECT count(*), avg(xu) FROM traces",
                "avg_filtered": ("SELECT avg(t.xu) FROM traces t JOIN runs r USING (run_key) "
                                 f"WHERE r.fault_label = 'BKL={fault:g}'")}
        for name, sql in sqls.items():
            t0 = time.perf_counter()
            con.execute(sql).fetchall()
            out[f"{name}_s"] = time.perf_counter() - t0
    finally:
        con.close()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "eha", "query", "select count(*) from traces",
                           "--results", str(results)], capture_output=True, text=True)
    out["cli_count_s"] = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stderr
    return out


def campaign_run(camp, ex, tmp: Path) -> dict:
    from eha.campaigns.runner import run_campaign

    from eha.campaigns.query import query

    # the bare loop just before and just after the campaign, averaged: the other users of a
    # shared machine change its load within minutes
    before = ideal_seconds(camp, ex)
    results = Path(tempfile.mkdtemp(dir=tmp))
    t0 = time.perf_counter()
    s = run_campaign(camp, results, executor=ex, progress=False)
    wall = time.perf_counter() - t0
    after = ideal_seconds(camp, ex)
    ideal = (before + after) / 2
    assert s.done == s.total and s.failed == 0, s
    st = trace_stats(results)
    sim = float(query(results, "SELECT sum(sim_s) AS s FROM runs")["s"][0])
    return {"runs": s.total, "ideal_s": round(ideal, 3),
            "ideal_before_after_s": [round(before, 3), round(after, 3)],
            "wall_s": round(wall, 3), "jobs_s": round(s.jobs_s, 3),
            "efficiency": round(ideal / wall, 3),
            # simulate() seconds inside the campaign's own workers / (workers x wall): the
            # same ratio, measured at the same moment as the wall
            "sim_share": round(sim / ex.workers / wall, 3),
            "files": st["files"], "bytes_per_run": round(st["bytes"] / s.total),
            "results": str(results)}


class NoopExecutor:
    """Returns each chunk as finished at once, in this process: the parent's own costs."""

    workers = 2
    tasks_per_worker = None     # one chunk per task, as the local pool

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def warm_up(self):
        pass

    def map_unordered(self, fn, tasks):
        import pyarrow as pa

        from eha.simulations.batch import _runs_schema, _table
        from eha.models.run_metrics import RUN_METRICS

        now = datetime.now(timezone.utc).replace(tzinfo=None)
        for task in tasks:
            keys = [r["run_key"] for r in task["runs"]]
            rows = [{"run_key": k, "status": "done", "error": None, "worker": "noop",
                     "started_at": now, "finished_at": now, "sim_s": 0.0, "elapsed_s": 0.0,
                     "trace_path": task["trace_path"], "trace_bytes": 0, "trace_rows": 0}
                    for k in keys]
            metrics = {"run_key": keys, **{m: [0.0] * len(keys) for m in RUN_METRICS}}
            yield {"n": len(keys), "runs": pa.Table.from_pylist(rows, schema=_runs_schema()),
                   "parts": [("metrics", _table(metrics))], "signals": {}, "errors": []}


def noop_throughput(n: int, tmp: Path) -> dict:
    from eha.campaigns.files import build_campaign
    from eha.campaigns.runner import run_campaign

    table = campaign_table(n, 1.0)
    t0 = time.perf_counter()
    camp = build_campaign(table)
    validate = time.perf_counter() - t0
    s = run_campaign(camp, Path(tempfile.mkdtemp(dir=tmp)), executor=NoopExecutor(),
                     progress=True)
    wall = validate + s.wall_s
    return {"runs": n, "validate_s": round(validate, 3), "wall_s": round(wall, 3),
            "runs_per_s": round(n / wall)}


def provenance(load_start) -> dict:
    def git(*args):
        try:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True,
                                  text=True).stdout.strip()
        except OSError:
            return ""

    return {"commit": git("rev-parse", "HEAD"), "dirty": bool(git("status", "--porcelain")),
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "machine": f"{platform.node()} {platform.machine()} {platform.processor()}".strip(),
            "python": platform.python_version(), "cores": os.cpu_count(),
            "loadavg_start": [round(x, 2) for x in load_start],
            "loadavg_end": [round(x, 2) for x in os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="2000,20000", help="campaign sizes (comma-separated)")
    ap.add_argument("--t-end", default="1.0,0.2", help="run lengths [s] (comma-separated)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--noop-runs", type=int, default=20000)
    ap.add_argument("--dask", nargs="?", const="first", choices=("first", "all"), default=None,
                    help="also on Dask: the first size (default) or all sizes")
    ap.add_argument("--rounds", type=int, default=2,
                    help="alternating pool/Dask rounds of the Dask comparison")
    ap.add_argument("--no-queries", action="store_true")
    ap.add_argument("--json", action="store_true", help="write the result file")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "bench_scale.json"))
    args = ap.parse_args(argv)
    os.environ["NUMBA_NUM_THREADS"] = "1"   # Dask worker processes inherit it
    from eha.campaigns.executors import LocalPoolExecutor

    load_start = os.getloadavg()
    sizes = [int(x) for x in args.runs.split(",")]
    lengths = [float(x) for x in args.t_end.split(",")]
    out: dict = {"workers": args.workers, "pool": [], "dask": []}
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmpdir:
        tmp = Path(tmpdir)
        out["noop"] = noop_throughput(args.noop_runs, tmp)
        print(f"no-op parent: {out['noop']}", flush=True)
        with LocalPoolExecutor(args.workers) as pool:
            pool.warm_up()
            run_pool_rows(args, sizes, lengths, pool, tmp, out)
            for n in (sizes if args.dask == "all" else sizes[:1] if args.dask else []):
                run_dask_rows(args, n, lengths, pool, tmp, out)
    out["provenance"] = provenance(load_start)
    if args.json:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


def run_pool_rows(args, sizes, lengths, pool, tmp: Path, out: dict) -> None:
    from eha.campaigns.files import build_campaign

    for n in sizes:
        for t_end in lengths:
            camp = build_campaign(campaign_table(n, t_end))
            row = {"t_end": t_end, **campaign_run(camp, pool, tmp),
                   "loadavg": round(os.getloadavg()[0], 2)}
            if not args.no_queries:
                row["queries"] = {k: round(v, 3) for k, v in
                                  query_times(Path(row["results"]), FAULTS[1]).items()}
            del row["results"]
            out["pool"].append(row)
            print(f"pool: {row}", flush=True)


def run_dask_rows(args, n: int, lengths, pool, tmp: Path, out: dict) -> None:
    """Dask against the pool, side by side: per round, the bare loop on the pool then on
    Dask, the campaign on the pool then on Dask; the best of ``--rounds`` of each."""
    from distributed import Client, LocalCluster

    from eha.campaigns.executors import DaskExecutor
    from eha.campaigns.files import build_campaign
    from eha.campaigns.runner import run_campaign

    with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        dask = DaskExecutor(client)
        dask.warm_up()
        for t_end in lengths:
            camp = build_campaign(campaign_table(n, t_end))
            bare: dict[str, list[float]] = {"pool": [], "dask": []}
            wall: dict[str, list[float]] = {"pool": [], "dask": []}
            load = []
            for _ in range(args.rounds):
                for name, ex in (("pool", pool), ("dask", dask)):
                    bare[name].append(ideal_seconds(camp, ex))
                for name, ex in (("pool", pool), ("dask", dask)):
                    t0 = time.perf_counter()
                    s = run_campaign(camp, Path(tempfile.mkdtemp(dir=tmp)), executor=ex,
                                     progress=False)
                    wall[name].append(time.perf_counter() - t0)
                    assert s.done == s.total and s.failed == 0, s
                load.append(round(os.getloadavg()[0], 2))
            row = {"t_end": t_end, "runs": len(camp.jobs),
                   "bare_s": {k: [round(x, 3) for x in v] for k, v in bare.items()},
                   "wall_s": {k: [round(x, 3) for x in v] for k, v in wall.items()},
                   "bare_vs_pool": round(min(bare["dask"]) / min(bare["pool"]), 3),
                   "wall_vs_pool": round(min(wall["dask"]) / min(wall["pool"]), 3),
                   "loadavg": load}
            out["dask"].append(row)
            print(f"dask: {row}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
