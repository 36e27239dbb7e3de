"""Speed of the residual loop as a user meets it (issue 42, item 6): ``eha explain`` on each
record of the foreign set, one at a time, with its command's healthy null cached; the first
record of a library command; the calibration of a new command's null.

1. **First use on a library command**: a record of the preset ``mixed`` (1 s at 1 kHz, HF with
   BKL 0.1 mm, FDJ 800 N and an undeclared 1500 N load, 1 µm noise) explained by ``eha explain``
   in a fresh process with an empty null cache and an empty numba cache (a fresh install: the
   kernels compile), then again with both warm. The first-use cost is the difference; the
   preset's null is shipped (:mod:`eha.explain.library_nulls`), so neither run calibrates one.
2. **New commands' nulls**: for each command of the foreign set (another simulator's commands,
   none a preset), its null calibrated into this run's own cache (``EHA_CACHE_DIR``), timed:
   what the first record of a custom command pays before the loop.
3. **The foreign set with the nulls cached**: ``eha explain RECORD --json OUT/NAME.json`` for
   each record in turn (a fresh process each, as a user runs it), timed; median and max. The
   JSON files are the scorer's (``_seconds`` added): ``score.py --out OUT`` and
   ``bench_explain_foreign.py --out OUT --jobs 1`` read them without running the records again.

    python benchmarks/bench_explain_speed.py --first-use --json           # step 1
    python benchmarks/bench_explain_speed.py --foreign ../shared/foreign --out DIR --json

Each step keeps the other's figures in the result file, each part with its own provenance. A
record whose JSON is already in ``--out`` is not run again (its time is kept). Every figure
comes with the load average before and after it and the CPU time: the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

TRUTH = {"BKL": 1e-4, "FDJ": 800.0, "FRC": 1500.0}


def _load() -> float:
    return round(os.getloadavg()[0], 2)


def _explain(record: Path, out: Path, env: dict[str, str]) -> tuple[float, dict]:
    """Wall time of ``eha explain record`` in a fresh process, and its JSON (with
    ``_seconds``, the wall time, and ``_cpu_seconds``, the CPU time of the process and its
    workers: what a shared machine's load inflates less than the wall time)."""
    js = out / f"{record.stem}.json"
    cmd = ["eha", "explain", str(record), "--json", str(js), "--out",
           str(out / "explain" / record.stem), "--results", str(out / "results"),
           "--no-progress"]
    (out / "logs").mkdir(parents=True, exist_ok=True)
    with open(out / "logs" / f"{record.stem}.txt", "w") as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - t0
    proc.returncode = rc = os.waitstatus_to_exitcode(status)
    if rc != 0:
        tail = (out / "logs" / f"{record.stem}.txt").read_text().strip().splitlines()[-1:]
        raise SystemExit(f"{record}: eha explain exit {rc}: {tail}")
    doc = json.loads(js.read_text())
    doc["_seconds"] = seconds
    doc["_cpu_seconds"] = usage.ru_utime + usage.ru_stime
    js.write_text(json.dumps(doc))
    return seconds, doc


def first_use(work: Path) -> dict:
    """Step 1: a preset record explained with empty null and numba caches, then warm."""
    from eha.explain.null import SHIPPED_DIR
    from eha.identification.synthetic import synthetic_record

    record = work / "mixed.csv"
    synthetic_record("mixed", TRUTH, t_end=1.0, noise=1e-6, seed=1).to_csv(record, index=False)
    env = {**os.environ, "EHA_CACHE_DIR": str(work / "cache"),
           "NUMBA_CACHE_DIR": str(work / "numba")}
    runs = []
    for phase in ("cold", "warm"):
        (work / phase).mkdir()
        load = _load()
        seconds, doc = _explain(record, work / phase, env)
        runs.append({"phase": phase, "seconds": seconds, "cpu_seconds": doc["_cpu_seconds"],
                     "load_before": load,
                     "load_after": _load(), "verdict": doc["verdict"],
                     "null_shipped": (SHIPPED_DIR / f"{doc['null']['key']}.json").exists(),
                     "null_calibrated": bool(list((work / "cache").rglob("*.json")))})
        print(f"first use, {phase}: {seconds:.1f} s (load {load}); null shipped: "
              f"{runs[-1]['null_shipped']}; {doc['verdict'][:70]}", flush=True)
    return {"record": "mixed, 1 s at 1 kHz, BKL 0.1 mm, FDJ 800 N, load 1500 N, 1 µm noise",
            "runs": runs, "first_use_cost_s": runs[0]["seconds"] - runs[1]["seconds"]}


def calibrate(records: list[Path], out: Path) -> list[dict]:
    """Step 2: each new command's null, calibrated into ``EHA_CACHE_DIR`` and timed; the
    times are kept in ``out/calibrations.json``, and a null found cached reports the time
    kept there when it was calibrated."""
    from eha.explain.api import healthy_null
    from eha.explain.null import cache_dir
    from eha.explain.settings import LoopSettings
    from eha.identification.measured import load

    kept_file = out / "calibrations.json"
    kept = {r["key"]: r for r in json.loads(kept_file.read_text())} \
        if kept_file.exists() else {}
    rows, seen = [], set()
    for path in records:
        data = load(path)
        before = set(cache_dir().glob("*.json"))
        load_before, t0 = _load(), time.perf_counter()
        null = healthy_null(data, None, None, None, LoopSettings(), (), "simulate")
        seconds = time.perf_counter() - t0
        if null.key in seen:
            continue
        seen.add(null.key)
        fresh = cache_dir() / f"{null.key}.json" not in before
        row = {"first_record": path.stem, "key": null.key, "calibrated": fresh,
               "seconds": seconds if fresh else None, "load_before": load_before,
               "load_after": _load()}
        if fresh:
            kept[null.key] = row
        rows.append(kept.get(null.key, row))
        print(f"null of {path.stem}'s command: {seconds:.1f} s "
              f"({'calibrated' if fresh else 'cached'} in {cache_dir()})", flush=True)
    kept_file.write_text(json.dumps(list(kept.values()), indent=1))
    return rows


def foreign(records: list[Path], out: Path, jobs: int = 1, run: bool = True) -> list[dict]:
    """Step 3: each record explained with its null cached, ``jobs`` at a time (1: one at a
    time, the issue's measure); without ``run``, only the records already in ``out``."""
    from concurrent.futures import ThreadPoolExecutor

    def one(path: Path) -> dict:
        js = out / f"{path.stem}.json"
        load = _load()
        if js.exists():
            doc = json.loads(js.read_text())
            seconds, load = doc.get("_seconds"), doc.get("_load_before")
            if seconds is None:         # written, but its run did not end (not timed)
                return {"record": path.stem, "seconds": None,
                        "verdict_kind": doc.get("verdict_kind")}
        elif run:
            seconds, doc = _explain(path, out, dict(os.environ))
            doc.update(_load_before=load, _load_after=_load(), _jobs=jobs,
                       _numba_threads=os.environ.get("NUMBA_NUM_THREADS"))
            js.write_text(json.dumps(doc))
        else:
            return {"record": path.stem, "seconds": None}
        row = {"record": path.stem, "seconds": seconds,
               "cpu_seconds": doc.get("_cpu_seconds"), "load_before": load,
               "load_after": doc.get("_load_after", _load()), "jobs": doc.get("_jobs", jobs),
               "numba_threads": doc.get("_numba_threads"),
               "verdict_kind": doc.get("verdict_kind")}
        print(f"{path.stem}: {seconds:.1f} s, CPU {doc.get('_cpu_seconds') or 0:.1f} s "
              f"(load {load}) {doc.get('verdict_kind')}", flush=True)
        return row

    with ThreadPoolExecutor(jobs) as pool:
        return list(pool.map(one, records))


def _summary(rows: list[dict]) -> dict:
    rows = [r for r in rows if r["seconds"] is not None]
    times = [r["seconds"] for r in rows]
    cpu = [r["cpu_seconds"] for r in rows if r.get("cpu_seconds") is not None]
    out = {"records": rows, "count": len(rows), "median_s": statistics.median(times), "max_s": max(times),
           "max_record": rows[times.index(max(times))]["record"]}
    if cpu:
        out.update(median_cpu_s=statistics.median(cpu), max_cpu_s=max(cpu))
    print(f"foreign set, null cached: median {out['median_s']:.1f} s, max {out['max_s']:.1f} s "
          f"({out['max_record']})" + (f"; CPU median {out['median_cpu_s']:.1f} s, max "
                                       f"{out['max_cpu_s']:.1f} s" if cpu else ""))
    return out


def main() -> None:
    from _results import provenance

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--foreign", help="folder of the foreign records (steps 2 and 3)")
    ap.add_argument("--out", help="folder of the records' JSON and the nulls' cache")
    ap.add_argument("--first-use", action="store_true", help="step 1")
    ap.add_argument("--jobs", type=int, default=1, help="records at a time in step 3 "
                    "(default 1: the issue's measure; 2 on a machine too busy for it)")
    ap.add_argument("--no-run", action="store_true", help="step 3: summarise the records "
                    "already in --out, run none")
    ap.add_argument("--note", default="", help="what the result file should say of the run")
    ap.add_argument("--json", nargs="?", const=str(result_path("bench_explain_speed")),
                    default=None, metavar="PATH",
                    help="write the figures (default: the result file); the steps not run "
                         "this time are kept from it, each with its own provenance")
    args = ap.parse_args()
    doc: dict = {}
    if args.first_use:
        load_start = os.getloadavg()
        with tempfile.TemporaryDirectory() as tmp:
            doc["first_use"] = first_use(Path(tmp))
        doc["first_use"]["provenance"] = {**provenance(load_start=load_start),
                                          "note": args.note}
    if args.foreign:
        if not args.out:
            ap.error("--foreign needs --out")
        load_start = os.getloadavg()
        out = Path(args.out).resolve()
        out.mkdir(parents=True, exist_ok=True)
        os.environ["EHA_CACHE_DIR"] = str(out / "cache")
        records = sorted(Path(args.foreign).glob("f[0-9][0-9].csv"))
        doc["calibrations"] = calibrate(records, out)
        doc["foreign"] = _summary(foreign(records, out, args.jobs, not args.no_run))
        cal = [r["seconds"] for r in doc["calibrations"] if r["seconds"]]
        if cal:
            print(f"new commands' nulls: {len(cal)}, median {statistics.median(cal):.0f} s, "
                  f"max {max(cal):.0f} s")
        doc["foreign"]["provenance"] = {**provenance(load_start=load_start),
                                        "note": args.note}
    if args.json:
        path = Path(args.json)
        old = json.loads(path.read_text()) if path.exists() else {}
        keep = {k: old[k] for k in ("first_use", "calibrations", "foreign")
                if k in old and k not in doc and "provenance" in old[k]}
        write_result(path, {"benchmark": "bench_explain_speed", **keep, **doc})


if __name__ == "__main__":
    main()
