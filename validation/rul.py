"""Benchmark of the prognostics pipeline on a simulated fleet (issue 10, item 7).

Simulates a fleet (default ``examples/fleet-demo.toml``: 20 actuators, BKL and FDJ degrading
along linear / exponential / power laws with process noise, a chirp_1cm check every 100
cycles), runs ``eha rul`` on its manifest with the truth, and prints the prognostic metrics
against the goals and the wall times.

Usage::

    python validation/rul.py                         # the demo fleet, 2 workers
    python validation/rul.py --actuators 6 --out /tmp/bench-rul   # a smaller run
    python validation/rul.py --json --plots results/rul   # the result file
    python validation/rul.py --fleet examples/fleet-validation.toml --json

``--json`` writes the fleet's figures into ``validation/results/rul.json`` (one entry per
fleet, each with its provenance; a run replaces its fleet's entry), ``--json PATH`` elsewhere.

Re-running with the same ``--out`` reuses the records and assessments (resume); pass
``--fresh`` to time everything from scratch.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import provenance, result_path, write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

GOALS = {"alpha_lambda_fraction": (">=", 0.8), "coverage": ("in", (0.8, 0.95)),
         "median_width_rel_at_0.5": ("<=", 1.0), "pipeline_s_per_200_records": ("<=", 600.0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fleet", type=Path, default=ROOT / "examples" / "fleet-demo.toml")
    ap.add_argument("--actuators", type=int, default=None, help="Override the fleet size.")
    ap.add_argument("--seed", type=int, default=None, help="Override the fleet seed.")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "rul")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--fresh", action="store_true", help="Delete --out first.")
    ap.add_argument("--json", type=Path, nargs="?", const=result_path("rul"),
                    default=None, help="Write the figures as JSON (default: the result file, "
                    "this fleet's entry).")
    ap.add_argument("--plots", type=Path, default=None, help="Also write the plots here.")
    ap.add_argument("--base-model", default=None,
                    help="LF base of the assessment (plain or calibrated; default eha fdi's).")
    ap.add_argument("--limit-error", type=float, default=None,
                    help="Relative std of the assessment's systematic error (default 0.02).")
    args = ap.parse_args(argv)

    from eha.prognostics.fleet import parse_fleet, simulate_fleet
    from eha.models.faults import rul_faults
    from eha.prognostics.jobs import run_rul

    table = tomllib.loads(args.fleet.read_text())
    if args.actuators is not None:
        table["actuators"] = args.actuators
    if args.seed is not None:
        table["seed"] = args.seed
    table["name"] = f"{table['name']}-n{table['actuators']}-s{table.get('seed', 0)}"
    fleet = parse_fleet(table, str(args.fleet))
    out = args.out / fleet.name
    if args.fresh and out.exists():
        shutil.rmtree(out)
    load_start = os.getloadavg()
    t0 = time.perf_counter()
    fr = simulate_fleet(fleet, out / "fleet", workers=args.workers, progress=False)
    t_fleet = time.perf_counter() - t0
    limits = dict(fleet.limits)
    t1 = time.perf_counter()
    fit = list(dict.fromkeys([*rul_faults(), *(f.name for f in fleet.faults)]))
    res = run_rul(fr.manifest, limits=limits, fit=fit, results=out / "results",
                  truth=fr.truth, workers=args.workers, progress=False,
                  limit_error=args.limit_error, base_model=args.base_model)
    res.save(out / "rul.json")
    if args.plots:
        res.plot(args.plots)
    t_rul = time.perf_counter() - t1
    f = res.metrics["fleet"]
    truth = json.loads(fr.truth.read_text())
    laws = {}
    for a in truth["actuators"].values():
        for name, law in a["laws"].items():
            laws[f"{name}:{law['law']}"] = laws.get(f"{name}:{law['law']}", 0) + 1
    drivers = {}
    for a in truth["actuators"].values():
        drivers[a["driver"]] = drivers.get(a["driver"], 0) + 1
    fresh = res.assessed == fr.records
    figures = {
        "fleet": fleet.name, "actuators": fr.actuators, "records": fr.records,
        "censored": fr.censored, "laws": laws, "true_drivers": drivers,
        "workers": args.workers, "limit_error": res.output["limit_error"],
        "base_model": res.output["base_model"],
        "fleet_simulation_s": round(t_fleet, 1), "rul_pipeline_s": round(t_rul, 1),
        "assessed_now": res.assessed, "reused": res.reused,
        "assess_s": round(res.seconds["assess"], 1),
        "predict_s": round(res.seconds["predict"], 2),
        "pipeline_s_per_200_records": (round(t_rul * 200 / fr.records, 1) if fresh else None),
        "failed": len(res.failed),
        **{k: f.get(k) for k in ("alpha_lambda_fraction", "alpha_lambda_checks", "alpha_lambda",
                                 "coverage", "coverage_checks", "median_width_rel_at_0.5",
                                 "median_prognostic_horizon_fraction", "ph_not_met",
                                 "relative_accuracy", "cra")},
    }
    print(f"fleet {fleet.name}: {fr.actuators} actuators, {fr.records} records, laws {laws}, "
          f"first fault to its limit {drivers}")
    print(f"fleet simulation {t_fleet:.1f} s; eha rul {t_rul:.1f} s "
          f"({res.assessed} assessed, {res.reused} reused; assessment "
          f"{res.seconds['assess']:.1f} s, predictions {res.seconds['predict']:.2f} s) on "
          f"{args.workers} workers")
    pct = lambda v: "-" if v is None else f"{100 * v:.1f} %"  # noqa: E731
    print(f"alpha-lambda (alpha 0.2, beta 0.5) over lambda in [0.5, 0.95]: "
          f"{pct(f['alpha_lambda_fraction'])} of {f['alpha_lambda_checks']} checks "
          f"(goal >= 80 %)")
    print(f"  at lambda 0.5: {pct(f['alpha_lambda']['0.5'])} of actuators, at 0.75: "
          f"{pct(f['alpha_lambda']['0.75'])}")
    print(f"90 % interval coverage: {pct(f['coverage'])} of {f['coverage_checks']} checks "
          f"(goal 80-95 %)")
    w = f["median_width_rel_at_0.5"]
    print(f"median interval width at lambda 0.5: {w:.2f} x true RUL (goal <= 1)"
          if w is not None else "median interval width at lambda 0.5: -")
    ph = f["median_prognostic_horizon_fraction"]
    print(f"prognostic horizon (alpha 0.2 of the monitored life): median "
          f"{pct(ph)} of the monitored life; never met for {f['ph_not_met']} actuators")
    ra = f["relative_accuracy"]
    print(f"relative accuracy at lambda 0.5: {ra['0.5']:.3f}, at 0.75: {ra['0.75']:.3f}; "
          f"CRA over [0.5, 0.95]: {f['cra']:.3f}")
    if fresh:
        print(f"pipeline time scaled to 200 records: "
              f"{figures['pipeline_s_per_200_records']:.0f} s (goal <= 600 s)")
    if args.json:
        doc = json.loads(args.json.read_text()) if args.json.is_file() else {}
        fleets = doc.get("fleets", {})
        fleets[figures["fleet"]] = {**figures, "provenance": provenance(load_start=load_start)}
        write_result(args.json, {"benchmark": "rul", "fleets": fleets},
                     load_start=load_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
