"""How much earlier the change check first detects each fault on a degrading fleet, and what
that does to RUL (issue 60, item 2 and "Done when": the fleet-validation fleet).

Simulates the fleet (default ``examples/fleet-validation.toml``: 20 actuators, BKL and FDJ
degrading together, a 1-s chirp_1cm record with 3 µm noise every 120 cycles), calibrates the
change check for that command, length and noise (``calibrate_baseline(noise=3e-6)``, 30
healthy pairs with the default test-day nuisances, alpha 0.01), and runs ``eha rul --check
change --trend changes`` on the manifest (each actuator's first record its baseline; the
baselines identified as ``eha rul`` does; RUL on baseline + change).

Per actuator and fault it compares

- the change check's first alarm (the first check at which the fault alarms and the change is
  isolated to it, or the baseline's own cycle where the baseline record is screened unlike
  the healthy fleet, farthest in this fault), the first by a change alone, its first
  confirmed alarm (two such checks in a row) and the first check at which anything alarms;
- the fleet check's first detection: the first check at which the true deviation from healthy
  reaches the fleet check's detectable size on chirp_1cm (docs/health.md section 5, measured on
  1 µm records: BKL 20 µm, FDJ +100 N; on these 3 µm records the fleet check would need more,
  so this favours the fleet check),

in cycles, and the lead time at each (true end of life minus the cycle). The RUL metrics of the
change check's histories are put beside the fleet check's (``validation/results/rul.json``,
this fleet's entry).

Usage::

    python validation/baseline_fleet.py                    # prints the figures
    python validation/baseline_fleet.py --json             # validation/results/baseline_fleet.json
    python validation/baseline_fleet.py --actuators 4 --out /tmp/bf   # a smaller run
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results

from _results import result_path, write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The fleet check's detectable deviation from healthy on chirp_1cm (docs/health.md, section 5).
FLEET_DETECTABLE = {"BKL": 20e-6, "FDJ": 100.0}


def _fleet_first(checks, name: str, size: float) -> float | None:
    """The first check's cycle at which the true deviation of ``name`` from healthy reaches
    ``size`` (the fleet check's first detection)."""
    from eha.models.faults import FAULTS

    healthy = FAULTS[name].healthy
    return next((c["cycle"] for c in checks if c["true"][name] - healthy >= size), None)


def _median(xs):
    import numpy as np

    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def compare(truth: dict, output: dict) -> dict:
    """Per actuator and fault the first detections and lead times; the fleet summary."""
    per, summary = {}, {}
    for aid, t in truth["actuators"].items():
        eol = t["eol"]
        a = output["actuators"].get(aid, {})
        alarms = a.get("first_alarms", {})
        first = {c["cycle"]: c for c in t["checks"]}
        row = {"eol": eol, "driver": t["driver"]}
        for name, size in FLEET_DETECTABLE.items():
            fl = _fleet_first(t["checks"], name, size)
            al = alarms.get(name, {})
            ch, conf = al.get("first_alarm"), al.get("first_confirmed")
            base = t["checks"][0]["true"][name]
            row[name] = {
                "initial": base, "fleet_first": fl, "change_first": ch,
                "change_confirmed": conf, "change_first_any": al.get("first_degraded"),
                # the first alarm by a change alone, and whether the first one is the
                # baseline's own (screened unlike the healthy fleet in this fault)
                "change_only_first": al.get("first_change", ch),
                "at_baseline": bool(al.get("at_baseline")),
                "change_first_statistic": al.get("first_statistic"),
                "true_change_at_first": None if ch is None else first[ch]["true"][name] - base,
                "earlier_by": None if fl is None or ch is None else fl - ch,
                "earlier_by_confirmed": None if fl is None or conf is None else fl - conf,
                "lead_fleet": None if fl is None or eol is None else eol - fl,
                "lead_change": None if ch is None or eol is None else eol - ch,
                "lead_change_confirmed": None if conf is None or eol is None else eol - conf}
        per[aid] = row
    for name in FLEET_DETECTABLE:
        rows = [r[name] for r in per.values()]
        summary[name] = {
            "actuators": len(rows),
            "fleet_detected": sum(r["fleet_first"] is not None for r in rows),
            "fleet_at_first_check": sum(r["fleet_first"] == 0.0 for r in rows),
            "change_detected": sum(r["change_first"] is not None for r in rows),
            "change_confirmed": sum(r["change_confirmed"] is not None for r in rows),
            "change_statistic": sum(r["change_first_statistic"] is not None for r in rows),
            "median_first_fleet": _median([r["fleet_first"] for r in rows]),
            "median_first_change": _median([r["change_first"] for r in rows]),
            "median_first_any": _median([r["change_first_any"] for r in rows]),
            "not_at_baseline": sum(r["fleet_first"] != 0.0 for r in rows),
            "change_earlier": sum((r["earlier_by"] or 0) > 0 for r in rows),
            "change_later": sum((r["earlier_by"] or 0) < 0 for r in rows),
            "at_baseline": sum(r["at_baseline"] for r in rows),
            "change_only_earlier": sum(r["fleet_first"] is not None and
                                       r["change_only_first"] is not None and
                                       r["change_only_first"] < r["fleet_first"] for r in rows),
            "change_only_later": sum(r["fleet_first"] is not None and
                                     (r["change_only_first"] is None or
                                      r["change_only_first"] > r["fleet_first"]) for r in rows),
            "median_earlier_by": _median([r["earlier_by"] for r in rows]),
            "median_earlier_by_confirmed": _median([r["earlier_by_confirmed"] for r in rows]),
            "median_lead_fleet": _median([r["lead_fleet"] for r in rows]),
            "median_lead_change": _median([r["lead_change"] for r in rows]),
            "median_lead_change_confirmed": _median([r["lead_change_confirmed"] for r in rows]),
            "median_true_change_at_first": _median([r["true_change_at_first"] for r in rows])}
    # the actuator: its first detection of anything (the fleet check: either fault at its size)
    rows = []
    for r in per.values():
        fl = [r[n]["fleet_first"] for n in FLEET_DETECTABLE if r[n]["fleet_first"] is not None]
        ch = r[next(iter(FLEET_DETECTABLE))]["change_first_any"]
        rows.append({"fleet": min(fl) if fl else None, "change": ch,
                     "earlier_by": None if not fl or ch is None else min(fl) - ch})
    for name in FLEET_DETECTABLE:
        frows = [r[name] for r in per.values()]
        either = [None if r["fleet_first"] is None and r["change_first"] is None else
                  min(x for x in (r["fleet_first"], r["change_first"]) if x is not None)
                  for r in frows]
        leads = [None if e is None or r["lead_fleet"] is None else
                 r["lead_fleet"] + (r["fleet_first"] - e) for e, r in zip(either, frows)]
        # both checks run (the fleet check also judges each record's absolute level): the
        # first alarm of either, against the fleet check's alone
        summary[name]["either"] = {
            "earlier_than_fleet": sum(e is not None and r["fleet_first"] is not None and
                                      e < r["fleet_first"] for e, r in zip(either, frows)),
            "median_earlier_by": _median([None if e is None or r["fleet_first"] is None else
                                          r["fleet_first"] - e for e, r in zip(either, frows)]),
            "median_lead": _median(leads)}
    summary["any"] = {
        "fleet_detected": sum(x["fleet"] is not None for x in rows),
        "fleet_at_first_check": sum(x["fleet"] == 0.0 for x in rows),
        "change_detected": sum(x["change"] is not None for x in rows),
        "change_earlier": sum((x["earlier_by"] or 0) > 0 for x in rows),
        "change_later": sum((x["earlier_by"] or 0) < 0 for x in rows),
        "median_earlier_by": _median([x["earlier_by"] for x in rows])}
    return {"actuators": per, "summary": summary}


def run_pass(args, table: dict) -> dict:
    """One fleet (``table``) simulated, calibrated, checked and predicted; its figures."""
    from eha.health.change_check import calibrate_baseline
    from eha.models.faults import rul_faults
    from eha.prognostics.change_rul import run_rul_change
    from eha.prognostics.fleet import parse_fleet, simulate_fleet

    table = dict(table)
    table["name"] = f"{table['name']}-n{table['actuators']}-s{table.get('seed', 0)}" + \
        (f"-every{table['check_every']:g}" if args.check_every else "")
    fleet = parse_fleet(table, str(args.fleet))
    out = args.out / fleet.name
    t0 = time.perf_counter()
    fr = simulate_fleet(fleet, out / "fleet", workers=args.workers, progress=False)
    t_fleet = time.perf_counter() - t0
    t1 = time.perf_counter()
    if fleet.command["set"]:
        raise SystemExit(f"{args.fleet}: a command with parameters; calibrate_baseline takes "
                         "a preset")
    command = fleet.command["name"]
    cal = calibrate_baseline(command, actuators=args.pairs, t_end=fleet.t_end,
                             noise=fleet.noise, alpha=args.alpha, out=out / "calibration.json",
                             results=None)["calibration"]
    t_cal = time.perf_counter() - t1
    fit = list(dict.fromkeys([*rul_faults(), *(f.name for f in fleet.faults)]))
    t2 = time.perf_counter()
    # trend "changes": the RUL on baseline + change (the default "identified" trend is the
    # fleet check's identification of every record, its RUL that of validation/rul.py); each
    # actuator's check calibrated at its baseline's identified faults (the default)
    res = run_rul_change(fr.manifest, limits=dict(fleet.limits), fit=fit,
                         calibration=out / "calibration.json", results=out / "results",
                         truth=fr.truth, workers=args.workers, progress=False,
                         trend="changes", operating_point=args.operating_point)
    t_rul = time.perf_counter() - t2
    # the default trend of eha rul --check change: every record identified (the change
    # check's alarms beside the fleet check's RUL); on the fleet's own interval only
    t3 = time.perf_counter()
    mi, ident_failed = {}, []
    if not args.check_every:
        ident = run_rul_change(fr.manifest, limits=dict(fleet.limits), fit=fit,
                               calibration=out / "calibration.json", results=out / "results",
                               truth=fr.truth, workers=args.workers, progress=False,
                               trend="identified", operating_point=args.operating_point)
        mi, ident_failed = (ident.metrics["fleet"] if ident.metrics else {}), ident.failed
    t_ident = time.perf_counter() - t3
    truth = json.loads(Path(fr.truth).read_text())
    figures = compare(truth, res.output)
    m = res.metrics["fleet"] if res.metrics else {}
    fleet_rul = {}
    rul_file = result_path("rul")
    if rul_file.is_file() and not args.check_every:
        entry = json.loads(rul_file.read_text()).get("fleets", {}).get(fleet.name, {})
        fleet_rul = {k: entry.get(k) for k in ("alpha_lambda_fraction", "alpha_lambda_checks",
                                               "alpha_lambda", "coverage",
                                               "median_width_rel_at_0.5", "cra")}
        fleet_rul["commit"] = (entry.get("provenance") or {}).get("commit")
    return {"fleet": fleet.name, "records": fr.records, "command": command,
            "check_every": fleet.check_every, "operating_point": args.operating_point,
            "noise_m": fleet.noise, "t_end": fleet.t_end,
            "fleet_detectable": FLEET_DETECTABLE,
            "calibration": {"pairs": args.pairs, "alpha": args.alpha, "noise": fleet.noise,
                            "nuisances": cal.nuisances, "false_alarms": cal.false_alarms},
            **figures,
            "rul_change": {k: m.get(k) for k in ("alpha_lambda_fraction",
                                                 "alpha_lambda_checks", "alpha_lambda",
                                                 "coverage", "median_width_rel_at_0.5",
                                                 "cra")},
            "rul_change_identified": {k: mi.get(k) for k in (
                "alpha_lambda_fraction", "alpha_lambda_checks", "alpha_lambda", "coverage",
                "median_width_rel_at_0.5", "cra")},
            "rul_fleet_check": fleet_rul, "failed": res.failed + ident_failed,
            "seconds": {"fleet": round(t_fleet, 1), "calibration": round(t_cal, 1),
                        "rul_change": round(t_rul, 1), "rul_identified": round(t_ident, 1),
                        "identify": round(res.seconds["assess"], 1),
                        "predict": round(res.seconds["predict"], 1)},
            "workers": args.workers}


def report(doc: dict) -> None:
    """The figures of one pass on the console."""
    print(f"{doc['fleet']} (a check every {doc['check_every']:g} cycles, calibrated at "
          f"{doc['operating_point']}):")
    for name, s in doc["summary"].items():
        if name == "any":
            print(f"  anything: fleet check {s['fleet_detected']} ({s['fleet_at_first_check']} "
                  f"at the first check), change check {s['change_detected']}; earlier on "
                  f"{s['change_earlier']}, later on {s['change_later']}, median by "
                  f"{s['median_earlier_by']} cycles")
            continue
        print(f"  {name}: fleet check detects {s['fleet_detected']}/{s['actuators']} "
              f"({s['fleet_at_first_check']} at the first check), change check "
              f"{s['change_detected']} (confirmed {s['change_confirmed']}); earlier on "
              f"{s['change_earlier']}, later on {s['change_later']}; median earlier by "
              f"{s['median_earlier_by']} cycles (confirmed {s['median_earlier_by_confirmed']}); "
              f"first alarm at the baseline (screened) on {s['at_baseline']}; by a change "
              f"alone earlier on {s['change_only_earlier']}, later or never on "
              f"{s['change_only_later']}; "
              f"median lead time {s['median_lead_fleet']} -> {s['median_lead_change']} "
              f"(confirmed {s['median_lead_change_confirmed']}); median true change at the "
              f"first alarm {s['median_true_change_at_first']}; either check: earlier than the "
              f"fleet check's on {s['either']['earlier_than_fleet']}, median by "
              f"{s['either']['median_earlier_by']}, median lead {s['either']['median_lead']}")
    print(f"  RUL alpha-lambda fraction: change check on baseline + change "
          f"{doc['rul_change'].get('alpha_lambda_fraction')}, on every record identified "
          f"(eha rul --check change's default) "
          f"{doc['rul_change_identified'].get('alpha_lambda_fraction')}, fleet check "
          f"{doc['rul_fleet_check'].get('alpha_lambda_fraction')} (rul.json at "
          f"{doc['rul_fleet_check'].get('commit')}); {len(doc['failed'])} failed; times "
          f"{doc['seconds']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fleet", type=Path, default=ROOT / "examples" / "fleet-validation.toml")
    ap.add_argument("--actuators", type=int, default=None, help="Override the fleet size.")
    ap.add_argument("--check-every", type=float, default=None,
                    help="Also run the fleet with a check every this many cycles (its own "
                         "interval is coarse next to the faults' growth: both checks then "
                         "alarm at the first check after the baseline).")
    ap.add_argument("--operating-point", default="baseline", choices=("baseline", "calibration"),
                    help="Where each actuator's check is calibrated (eha rul --operating-point).")
    ap.add_argument("--pairs", type=int, default=30, help="Healthy pairs of the calibration.")
    ap.add_argument("--alpha", type=float, default=0.01)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "baseline-fleet")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", type=Path, nargs="?", const=result_path("baseline_fleet"),
                    default=None, help="Write the figures (default: the result file).")
    args = ap.parse_args(argv)

    load_start = os.getloadavg()
    table = tomllib.loads(args.fleet.read_text())
    if args.actuators is not None:
        table["actuators"] = args.actuators
    every, args.check_every = args.check_every, None
    doc = run_pass(args, table)
    report(doc)
    if every:
        args.check_every = every
        doc["dense"] = run_pass(args, {**table, "check_every": every})
        report(doc["dense"])
    if args.json is not None:
        write_result(args.json, doc, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
