"""The change check measured: each actuator against its own earlier record (issue 60, item 4).

    python validation/baseline.py --json                      # the library commands
    python validation/baseline.py --design results/design-baseline/design.csv --json
    python validation/baseline.py --quick                     # a smoke run (seconds)

Per command (chirp_1cm, mixed, test, sine and optionally a designed command; 1 s, position
only, 1 µm noise, alpha 0.01, the default test-day nuisances: viscous and jack friction ±5 %,
flow gain ±1 %, supply pressure ±2 %, valve null ±0.002 mA): a change calibration on 30
healthy pairs, then on fresh seeds (:func:`eha.design.change.measure`)

- false alarms on ``--held-out`` healthy pairs with the nuisances, with the one-sided 95 %
  binomial (Clopper-Pearson) bound;
- per fault, the detection rate at sqrt(2) steps of size around the predicted detectable
  change (``--per-level`` actuators each), the detectable change (the smallest size from
  which every larger one is detected at P_D >= 0.95), isolation at twice it (the share whose
  isolated group holds the fault, and the group's size) and the coverage of the change's
  90 % interval;
- beside it, the fleet check's detectable deviation from the health-detection campaign
  (``validation/results/health-detection/performance.json``: coarse levels, so the fleet's
  true figure lies between the level below and the one quoted), and their ratio.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from _results import write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("chirp_1cm", "mixed", "test", "sine")
FLEET = ROOT / "validation" / "results" / "health-detection" / "performance.json"


def fleet_figures() -> dict[str, dict[str, dict]]:
    """Per command and fault the fleet check's measured detectable deviation and the largest
    level below it (None: not detected at any level)."""
    perf = json.loads(FLEET.read_text())
    out = {}
    for command, c in perf.items():
        out[command] = {}
        for name, f in c["faults"].items():
            md = f["min_detectable_deviation"]
            below = [lv["deviation"] for lv in f["levels"] if md is None or lv["deviation"] < md]
            out[command][name] = {"min_detectable": md,
                                  "largest_level": max(lv["deviation"] for lv in f["levels"]),
                                  "level_below": max(below) if below else None}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(LIBRARY))
    ap.add_argument("--design", type=Path, default=None, help="A command file designed for the "
                    "change check (eha design --check baseline), measured beside the library.")
    ap.add_argument("--held-out", type=int, default=200)
    ap.add_argument("--per-level", type=int, default=9)
    ap.add_argument("--calibration", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="chirp_1cm, 20 held-out pairs, 3 "
                    "actuators a level (a smoke run, not a result)")
    ap.add_argument("--json", action="store_true", help="write validation/results/baseline.json")
    args = ap.parse_args(argv)
    from eha.design.change import measure

    commands = [c for c in args.commands.split(",") if c]
    if args.quick:
        commands, args.held_out, args.per_level = ["chirp_1cm"], 20, 3
    if args.design is not None:
        commands.append(str(args.design))
    fleet = fleet_figures()
    start = time.perf_counter()
    measured = {}
    for c in commands:
        t0 = time.perf_counter()
        m = measure(c, 1.0, held_out=args.held_out, per_level=args.per_level,
                    calibration=args.calibration, seed=args.seed,
                    on_progress=lambda s: print(s, flush=True))
        m["seconds"] = time.perf_counter() - t0
        name = "design" if c == str(args.design) else c
        ref = fleet.get(name, {})
        for n, f in m["faults"].items():
            fl = ref.get(n)
            f["fleet"] = fl
            md = f["min_detectable"]
            f["ratio_to_fleet"] = (md / fl["min_detectable"]) if (
                fl and fl["min_detectable"] and md) else None
        measured[name] = m
        fa = m["false_alarms"]
        print(f"{name}: false alarms {fa['alarms']}/{fa['n']} (95 % bound {fa['upper_95']:.3f}); "
              + ", ".join(f"{n} {f['min_detectable']:.3g}" if f["min_detectable"] else f"{n} -"
                          for n, f in m["faults"].items()), flush=True)
    out = {"settings": vars(args) | {"design": str(args.design) if args.design else None},
           "measured": measured, "seconds": time.perf_counter() - start}
    if args.json and not args.quick:
        write_result("baseline", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
