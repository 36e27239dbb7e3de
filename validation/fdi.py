"""Fault-identification benchmark: the thesis' 12 cases (campaigns/thesis-fdi.toml).

Runs every case for several seeds (HF dither and optimizer seed), and prints per case the
median and spread of the thesis mean error (ours against the thesis'), the median time and
evaluations, then the goals of issue 4: every case at least as accurate as the thesis,
median time per case <= 5 s, whole table <= 2 min (on this 2-core machine).

    python validation/fdi.py                    # default method, 5 seeds
    python validation/fdi.py --method ga        # the thesis' GA
    python validation/fdi.py --json             # machine-readable figures
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    from rich.console import Console
    from rich.progress import Progress

    from eha.identification import cases as fdi_cases, problem

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", default=problem.DEFAULT_METHOD, choices=problem.METHODS)
    ap.add_argument("--objective", default="rmse", choices=list(problem.OBJECTIVES))
    ap.add_argument("--seeds", type=int, default=5, help="seeds 0..N-1 per case")
    ap.add_argument("--cases", default="", help="comma-separated case numbers (default all)")
    ap.add_argument("--campaign", default=str(ROOT / "campaigns" / "thesis-fdi.toml"))
    ap.add_argument("--base", action="append", default=[],
                    help="LF parameter held fixed, NAME=VALUE (e.g. orifice_law=1); repeatable")
    ap.add_argument("--json", action="store_true",
                    help="print figures as JSON only and write them to the result file, "
                         "validation/results/fdi.json (replacing it)")
    args = ap.parse_args()

    from eha.models.params import parse_assignments, resolve

    camp = fdi_cases.load_fdi_campaign(args.campaign)
    base = resolve("lf", {**camp.base, **parse_assignments(args.base)})
    cases = [int(c) for c in args.cases.split(",") if c] or None
    # JIT warm-up (numba cache load) outside the timing, as a long-running service would be
    fdi_cases.run_case(camp.cases[0], 0, args.method, args.objective, camp.t_end, base=base,
                 max_gen=2)

    console = Console(stderr=True)
    n_runs = len(cases or camp.cases) * args.seeds
    start = time.perf_counter()
    with Progress(console=console, transient=True, disable=args.json) as bar:
        task = bar.add_task(f"FDI {args.method}", total=n_runs)
        rows = fdi_cases.run_campaign(camp, seeds=range(args.seeds), method=args.method,
                                objective=args.objective, cases=cases, base=base,
                                on_row=lambda r: bar.advance(task))
    total = time.perf_counter() - start

    per_case = {}
    for case in camp.cases:
        rs = [r for r in rows if r["case"] == case.case]
        if not rs:
            continue
        errs = [r["mean_err_pct"] for r in rs]
        secs = [r["seconds"] for r in rs]
        per_case[case.case] = {
            "command": case.command,
            "mean_err_pct_median": statistics.median(errs),
            "mean_err_pct_min": min(errs), "mean_err_pct_max": max(errs),
            "thesis_mean_err_pct": case.thesis.get("mean_err_pct", float("nan")),
            "seconds_median": statistics.median(secs),
            "evaluations_median": statistics.median(r["evaluations"] for r in rs),
            "objective_median": statistics.median(r["objective"] for r in rs),
            "estimates_median": {n: statistics.median(r["estimates"][n] for r in rs)
                                 for n in rs[0]["estimates"]},
        }
    med_time = statistics.median(v["seconds_median"] for v in per_case.values())
    better = {c: v["mean_err_pct_median"] <= v["thesis_mean_err_pct"]
              for c, v in per_case.items()}
    summary = {"method": args.method, "objective": args.objective, "seeds": args.seeds,
               "base": {k: v for k, v in base.as_dict().items()
                        if v != getattr(type(base)(), k)},
               "runs": len(rows), "total_seconds": total,
               "median_seconds_per_case": med_time,
               "cases_at_least_as_accurate": sum(better.values()),
               "cases": len(per_case),
               "goal_accuracy_met": all(better.values()),
               "goal_time_per_case_met": med_time <= 5.0,
               "goal_table_2min_met": total <= 120.0,
               "per_case": per_case}
    if args.json:
        print(json.dumps(summary, indent=2))
        write_result("fdi", {"settings": {"argv": sys.argv[1:]}, "summary": summary})
        return
    print(f"method {args.method}, objective {args.objective}, seeds 0..{args.seeds - 1}, "
          f"LF base {summary['base'] or 'nominal'}")
    print(f"{'case':>4} {'command':<10} {'ours median':>11} {'[min, max]':>20} "
          f"{'thesis':>8} {'ok':>3} {'s/run':>6} {'evals':>6}  estimates (median)")
    for c, v in per_case.items():
        est = ", ".join(f"{n}={x:.5g}" for n, x in v["estimates_median"].items())
        print(f"{c:>4} {v['command']:<10} {v['mean_err_pct_median']:>11.3f} "
              f"[{v['mean_err_pct_min']:>8.3f}, {v['mean_err_pct_max']:>8.3f}] "
              f"{v['thesis_mean_err_pct']:>8.2f} {'yes' if better[c] else 'NO':>3} "
              f"{v['seconds_median']:>6.2f} {v['evaluations_median']:>6.0f}  {est}")
    print(f"cases at least as accurate as the thesis (median): "
          f"{summary['cases_at_least_as_accurate']}/{summary['cases']}"
          f"  -> goal {'met' if summary['goal_accuracy_met'] else 'NOT met'}")
    print(f"median time per case run: {med_time:.2f} s (goal <= 5 s: "
          f"{'met' if summary['goal_time_per_case_met'] else 'NOT met'})")
    print(f"whole table ({len(rows)} runs): {total:.1f} s (goal <= 120 s: "
          f"{'met' if summary['goal_table_2min_met'] else 'NOT met'})")


if __name__ == "__main__":
    main()
