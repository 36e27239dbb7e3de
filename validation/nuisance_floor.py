"""What the test-day differences cost the change check (issue 60): the detectable changes on a
command with sensor noise and the servo valve's dither alone, beside those with the default
nuisances (``validation/results/baseline.json``) and the fleet check's.

The same measurement as ``validation/baseline.py`` (:func:`eha.design.change.measure`: a
change calibration on 30 healthy pairs, per fault 9 actuators at each size a factor sqrt(2)
apart, the detectable change the smallest size from which every larger one is detected 9 of
9), with every nuisance's half-width set to zero: both records of a pair on the same test
day. Where a fault's floor falls far below its floor with the nuisances, the test-day
differences, not the noise, set it.

Beside it, which difference costs what: the healthy pairs' spread of each fault's estimate (its
std, read back through the fault's gain curve into the fault's unit) in calibrations with no
test-day difference, with each one alone at its default half-width, and with all of them.

Usage::

    python validation/nuisance_floor.py            # prints the table
    python validation/nuisance_floor.py --json     # validation/results/nuisance_floor.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from _results import result_path, write_result  # noqa: E402

from baseline import fleet_figures  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--command", default="chirp_1cm")
    ap.add_argument("--held-out", type=int, default=50,
                    help="Held-out healthy pairs (the false alarms are baseline.py's study).")
    ap.add_argument("--per-level", type=int, default=9)
    ap.add_argument("--calibration", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true",
                    help="write validation/results/nuisance_floor.json")
    args = ap.parse_args(argv)
    from eha.design.change import measure
    from eha.health.change import NUISANCES

    start = time.perf_counter()
    m = measure(args.command, 1.0, held_out=args.held_out, per_level=args.per_level,
                calibration=args.calibration, seed=args.seed,
                nuisances={n: 0.0 for n in NUISANCES},
                on_progress=lambda s: print(s, flush=True))
    with_file = result_path("baseline")
    with_nuisances = {}
    if with_file.is_file():
        doc = json.loads(with_file.read_text())
        with_nuisances = doc.get("measured", {}).get(args.command, {}).get("faults", {})
    fleet = fleet_figures().get(args.command, {})
    faults = {}
    print(f"{args.command}: detectable change without / with the test-day differences "
          "(fleet check's)")
    for name, f in m["faults"].items():
        without = f["min_detectable"]
        with_ = (with_nuisances.get(name) or {}).get("min_detectable")
        fl = (fleet.get(name) or {}).get("min_detectable")
        faults[name] = {"without_nuisances": without, "with_nuisances": with_,
                        "fleet": fl,
                        "without_to_fleet": without / fl if without and fl else None,
                        "with_to_fleet": with_ / fl if with_ and fl else None}
        print(f"  {name}: {without if without else '-'} / {with_ if with_ else '-'} "
              f"({fl if fl else 'not detected'})", flush=True)
    spread = spread_by_nuisance(args.command, args.calibration, args.seed)
    out = {"settings": vars(args), "command": args.command, "faults": faults,
           "spread_by_nuisance": spread,
           "false_alarms_without_nuisances": m["false_alarms"],
           "with_nuisances_from": "validation/results/baseline.json",
           "seconds": time.perf_counter() - start}
    if args.json:
        write_result("nuisance_floor", out)
    return 0


def spread_by_nuisance(command: str, pairs: int, seed: int) -> dict[str, dict[str, float]]:
    """``{calibration: {fault: std in SI}}``: the healthy pairs' spread of each fault's
    estimate in a change calibration of ``pairs`` pairs with no test-day difference
    (``none``), each one alone (its name) and all of them (``all``); printed in display
    units."""
    from eha.health.change import NUISANCES
    from eha.health.change_calibration import calibrate_change
    from eha.health.change_runs import sign_of
    from eha.models.units import show

    zero = {n: 0.0 for n in NUISANCES}
    cases = {"none": zero, **{n: {**zero, n: v.width} for n, v in NUISANCES.items()},
             "all": None}
    out: dict[str, dict[str, float]] = {}
    for label, widths in cases.items():
        cal, _ = calibrate_change(command, actuators=pairs, seed=seed, t_end=1.0,
                                  nuisances=widths)
        out[label] = {}
        for name, f in cal.faults.items():
            sign, curve = sign_of(name), cal.gain(name)
            out[label][name] = float(abs(curve.invert(sign * f["std"], sign)))
        print(f"  spread, {label}: " + ", ".join(show(n, v) for n, v in out[label].items()),
              flush=True)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
