"""Campaign runner wall times: thesis-matrix on 1 and 2 workers, and the chapter-5 reproduction.

Prints, median of ``--repeat`` runs, each into a fresh results folder with a warm numba cache:

* a machine check: how much faster two processes finish two pure-Python loops than one process
  does (2.0x on an idle 2-core machine): the ceiling for any 2-worker speed-up right now;

* ``thesis-matrix`` (60 runs of 1 s) with 1 and 2 local spawn workers: the end-to-end wall time
  of :func:`eha.campaigns.runner.run_campaign` (validation, database, starting the pool, the jobs, the
  HF-vs-LF metrics), the pool start-up and the job phase, and the 2-worker speed-ups.
  Targets: matrix <= 10 s on 2 workers; speed-up >= 1.7x.
* the same matrix at ``t_end = --long`` seconds (the same 60 runs, 10x longer each), where the
  jobs rather than the fixed costs dominate, to show how the pool scales;
* ``eha reproduce`` (nominal + single-fault + matrix campaigns, figures and reports) as a
  subprocess, cold (empty results folder).

Usage: ``python benchmarks/bench_campaign.py [--repeat N] [--long S] [--skip-reproduce]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run(table_or_path, workers: int, tmp: Path):
    from eha.campaigns.files import build_campaign, load_campaign
    from eha.campaigns.runner import run_campaign

    camp = (load_campaign(table_or_path) if isinstance(table_or_path, Path)
            else build_campaign(table_or_path))
    out = Path(tempfile.mkdtemp(dir=tmp))
    s = run_campaign(camp, out, workers=workers, progress=False)
    assert s.done == s.total and s.failed == 0, s
    return s


def median_runs(campaign, workers: int, repeat: int, tmp: Path) -> dict[str, float]:
    rows = [run(campaign, workers, tmp) for _ in range(repeat)]
    return {k: statistics.median(getattr(s, k) for s in rows)
            for k in ("wall_s", "startup_s", "jobs_s")}


def machine_speedup(repeat: int) -> float:
    """Speed-up this machine gives two processes right now: 2 units of a pure-Python loop
    on 1 process vs on 2 (2.0 on an idle 2-core machine; ~1.0 when it is saturated)."""
    loop = [sys.executable, "-c", "sum(range(2 * 10**7))"]

    def wall(n_parallel: int, n_units: int) -> float:
        t0 = time.perf_counter()
        for _ in range(n_units // n_parallel):
            procs = [subprocess.Popen(loop) for _ in range(n_parallel)]
            for p in procs:
                p.wait()
        return time.perf_counter() - t0

    return statistics.median(wall(1, 2) / wall(2, 2) for _ in range(repeat))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--long", type=float, default=10.0, help="t_end [s] of the long variant")
    ap.add_argument("--skip-reproduce", action="store_true")
    ap.add_argument("--json", action="store_true",
                    help="write the figures to benchmarks/results/bench_campaign.json "
                         "(replacing it)")
    args = ap.parse_args()

    from eha.models.simulate import simulate

    for model in ("hf", "lf"):  # warm (or build) the on-disk numba cache
        simulate(model, "mixed", t_end=0.01)
    matrix = ROOT / "campaigns" / "thesis-matrix.toml"
    long_table = tomllib.loads(matrix.read_text()) | {"t_end": args.long,
                                                     "name": "thesis-matrix-long"}
    with tempfile.TemporaryDirectory(prefix="eha-bench-") as tmp:
        tmp = Path(tmp)
        load_start = os.getloadavg()
        ceiling = machine_speedup(args.repeat)
        print(f"machine check: 2 CPU loops on 2 processes vs 1 -> "
              f"{ceiling:.2f}x available speed-up right now")
        figures = {"repeat": args.repeat, "machine_speedup": ceiling, "runs": []}
        print(f"thesis-matrix: 60 runs x 1 s, median of {args.repeat}")
        res = {}
        for label, camp in (("matrix", matrix), (f"matrix t_end={args.long:g} s", long_table)):
            for w in (1, 2):
                res[label, w] = r = median_runs(camp, w, args.repeat, tmp)
                figures["runs"].append({"campaign": label, "workers": w, **r})
                print(f"  {label:<22} {w} worker{'s' if w > 1 else ' '}: wall {r['wall_s']:6.2f} s"
                      f"  (pool start {r['startup_s']:5.2f} s, jobs {r['jobs_s']:6.2f} s)")
            one, two = res[label, 1], res[label, 2]
            print(f"  {label:<22} speed-up 2 vs 1 worker: wall {one['wall_s'] / two['wall_s']:.2f}x,"
                  f" job phase {one['jobs_s'] / two['jobs_s']:.2f}x")
        if not args.skip_reproduce:
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "eha", "reproduce", "--results",
                                   str(tmp / "reproduce")], capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if proc.returncode != 0:
                sys.exit(f"eha reproduce failed: {proc.stderr.strip()}")
            n_png = len(list((tmp / "reproduce" / "plots").rglob("*.png")))
            print(f"eha reproduce (cold results folder, {n_png} PNGs): {wall:.1f} s")
            figures["reproduce_s"] = wall
        if args.json:
            write_result("bench_campaign", figures, load_start=load_start)


if __name__ == "__main__":
    main()
