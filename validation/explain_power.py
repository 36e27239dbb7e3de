"""Detection power of the residual loop's decisions: the smallest size of each library effect
that a record of a given command shows, at the stated false-positive level.

For each command (``mixed``, ``chirp_1cm``, ``sine`` (1 cm, 5 Hz) and ``held_steps``, a
sequence of held steps of +-0.5 to 2 mm), on 1-s records at 1 kHz with 1 µm noise:

1. the healthy null of the command (:func:`eha.explain.null.simulated_null`, ``--actuators``
   healthy HF actuators, cached like ``eha explain``'s), its threshold per effect at
   ``--alpha`` and its predicted minimum detectable effect (``Null.detectable``: the size that
   the local test is predicted to push past the threshold in 90 % of records; for an effect
   tested by its footprint, the supply pressure, the drop whose footprint on the nominal
   model is that size, :func:`parameter_size`);
2. the check of that prediction: ``--records`` new HF records per effect (healthy scatter and
   declared faults drawn as the null draws them, seeds ``100000 + 1000 * command index + k``,
   disjoint from the null's) with the effect injected at its predicted detectable size, each
   put through the loop's local test (:func:`eha.explain.healthy_fleet.healthy_statistics`); the
   fraction whose statistic passes the threshold is the measured power of the gate at that
   size;
3. where that power is below 90 %, the same records again with the effect at 2, 4 and 8 times
   the predicted size (``--escalate``), until 90 % of them pass: the smallest size tried that
   does is the *measured* minimum detectable change (none when even 8 times does not).

The gate is necessary for the loop to add an effect; the full loop also asks for a
significant, specific gain, so the loop's own power can only be lower at a given size
(``explain_loop_power.py`` runs the whole loop on these records at the gate's size).

    python validation/explain_power.py                       # 4 commands, 12 effects
    python validation/explain_power.py --commands mixed --records 3
    python validation/explain_power.py --json --plot docs/img/explain_power.png

``--json`` writes ``validation/results/explain_power.json`` (one current file, with its
provenance: commit, date, machine, cores, load).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("mixed", "chirp_1cm", "sine", "held_steps")
#: held steps: (time [s], level [m]) of a digital controller's step sequence
HELD_STEPS = ((0.0, 0.0), (0.05, 1e-3), (0.2, -1e-3), (0.35, 5e-4), (0.5, -5e-4),
              (0.65, 2e-3), (0.8, 0.0))
#: Direction in which an effect is injected (+1 up from off, -1 down): a supply-pressure
#: drop and a weaker torque motor are the faults of interest.
DIRECTION = {"supply_pressure": -1.0, "motor_gain": -1.0, "sensor_gain": 1.0}
NOISE = 1e-6


def command(name: str):
    from eha.models.commands import array_command, make_command

    if name != "held_steps":
        return make_command(name)
    t = np.arange(1001) * 1e-3
    values = np.zeros_like(t)
    for t0, level in HELD_STEPS:
        values[t >= t0 - 1e-9] = level
    return array_command(t, values, name="held_steps", hold="zoh")


def template(name: str):
    """A nominal HF record of the command (its samples, hold and noise are what the null
    and the test records copy)."""
    from eha.identification.measured import from_arrays, synthetic_record

    hold = "zoh" if name == "held_steps" else "auto"
    df = synthetic_record(command(name), {}, t_end=1.0, noise=NOISE, seed=0,
                          command_hold=hold)
    return from_arrays(df.t, df.com, df.xu, source=name, command_hold=hold)


def injected_value(effect: str, size: float) -> float:
    """The effect's parameter moved ``size`` from off in its direction of interest, within
    the effect's and the parameter table's bounds."""
    from eha.explain.effects import EFFECTS
    from eha.models.params import SPECS

    param = EFFECTS[effect].tested
    off = EFFECTS[effect].off[param]
    lo, hi = EFFECTS[effect].bounds[param]
    return float(np.clip(off + DIRECTION.get(effect, 1.0) * size,
                         max(lo, SPECS[param].lo), min(hi, SPECS[param].hi)))


def parameter_size(data, effect: str, footprint: float) -> float:
    """The size (from off, in the tested parameter's unit) at which an effect tested by its
    footprint (the supply pressure) changes the nominal LF model's position on ``data`` by
    ``footprint`` m RMS, with its other parameters at their probe (the supply pressure's
    law at the listing's, the HF's): :meth:`eha.explain.record.Record.footprint_size`; the
    effect's bound when even it leaves a smaller footprint."""
    from eha.explain.effects import EFFECTS
    from eha.explain.record import Record, initial_position
    from eha.explain.settings import STRUCTURAL
    from eha.models.params import LFParams

    e = EFFECTS[effect]
    base = initial_position(data, LFParams())
    for name in STRUCTURAL:                 # the null's baseline carries the structure
        base = EFFECTS[name].switch_on(base)
    (_, value), *_ = Record(data, base).footprint_size(e, footprint, base)
    off = e.off[e.tested]
    return abs((value if value is not None else e.bounds[e.tested][0]) - off)


def _one(args):
    data, fit, effect, value, seed, settings = args
    from eha.explain.effects import EFFECTS
    from eha.explain.healthy_fleet import healthy_statistics
    from eha.explain.simulated_record import healthy_record

    param = EFFECTS[effect].tested
    rec, _ = healthy_record(data, fit, seed, {param: value})
    shifts, gains, _ = healthy_statistics(rec, fit, [effect], settings)
    second = EFFECTS[effect].shift_key
    return shifts[effect], gains[effect], (shifts[second] if second else None)


def plot(rows, path: Path) -> None:
    from eha.explain.effects import EFFECTS
    from eha.figures import pyplot, save

    plt = pyplot()
    effects = sorted({r["effect"] for r in rows})
    commands = [c for c in COMMANDS if any(r["command"] == c for r in rows)]
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(effects) + 1.8))
    width = 0.8 / max(len(commands), 1)
    for j, c in enumerate(commands):
        y = [i + (j - (len(commands) - 1) / 2) * width for i in range(len(effects))]
        x = []
        for e in effects:
            r = next((r for r in rows if r["effect"] == e and r["command"] == c), None)
            param = EFFECTS[e].tested
            x.append(r["predicted"] / abs(EFFECTS[e].probe[param] - EFFECTS[e].off[param])
                     if r else np.nan)
        bars = ax.barh(y, x, width, label=c)
        for yi, xi, e in zip(y, x, effects):
            r = next((r for r in rows if r["effect"] == e and r["command"] == c), None)
            if not (r and np.isfinite(xi)):
                continue
            ax.text(xi * 1.05, yi, f"{r['power']:.0%}", va="center", fontsize=6)
            if r.get("measured_detectable") and r["measured_multiple"] > 1:
                # the measured size (90 % of the records passed), where the prediction fell short
                param = EFFECTS[e].tested
                ax.plot(r["measured_detectable"] / abs(EFFECTS[e].probe[param]
                                                       - EFFECTS[e].off[param]),
                        yi, marker="d", ms=6, mec="k", mew=0.8, ls="none",
                        color=bars.patches[0].get_facecolor())
    ax.set_xscale("log")
    ax.axvline(1.0, color="k", lw=0.8, ls="--")
    ax.set_yticks(range(len(effects)), effects)
    ax.set_xlabel("minimum detectable change / the effect's probe size (log)")
    ax.grid(True, axis="x", alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("Residual loop: predicted smallest effect a 1-s record shows (alpha 0.05, "
                 "90 % power);\nlabels: the gate's measured power at that size; diamonds: the "
                 "size where 90 % was measured", fontsize=10)
    fig.tight_layout()
    save(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(COMMANDS))
    ap.add_argument("--effects", default="")
    ap.add_argument("--actuators", type=int, default=12, help="healthy actuators of the null")
    ap.add_argument("--records", type=int, default=5, help="records per effect and command")
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--escalate", default="2,4,8",
                    help="multiples of the predicted size tried where it falls short of 90 %%")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_power")))
    ap.add_argument("--plot", default=None)
    a = ap.parse_args(argv)
    from eha.explain.decide import past_any
    from eha.explain.effects import EFFECTS
    from eha.explain import DEFAULT_FAULT_BOUNDS, LoopSettings
    from eha.explain.null import covered_effects, simulated_null

    names = covered_effects(a.effects.split(",") if a.effects else list(EFFECTS))
    settings = LoopSettings(alpha=a.alpha)
    fit = dict(DEFAULT_FAULT_BOUNDS)
    rows, t_start = [], time.perf_counter()
    commands = [c for c in a.commands.split(",") if c]
    for ci, cname in enumerate(commands):
        data = template(cname)
        t0 = time.perf_counter()
        null = simulated_null(data, fit, covered_effects(list(EFFECTS)), settings,
                              actuators=a.actuators, workers=a.workers)
        null_s = time.perf_counter() - t0
        thr, det = null.thresholds(a.alpha), null.detectable(a.alpha)
        # the predicted size in the tested parameter (a footprint's as the change making it)
        predicted = {e: parameter_size(data, e, det[e]) if EFFECTS[e].footprint else det[e]
                     for e in names}
        # level 1 is the predicted size; each further level only for the cells still short
        sizes = {e: [] for e in names}            # (multiple, injected, power, shifts, gains)
        todo = list(names)
        for multiple in [1.0] + [float(m) for m in a.escalate.split(",") if m]:
            jobs, where = [], []
            for effect in todo:
                value = injected_value(effect, multiple * predicted[effect])
                if sizes[effect] and value == sizes[effect][-1][1]:
                    continue                      # clipped at a bound: no larger size exists
                for k in range(a.records):
                    seed = 100000 + 1000 * COMMANDS.index(cname) + k
                    jobs.append((data, fit, effect, value, seed, settings))
                    where.append((effect, value))
            if not jobs:
                break
            with ProcessPoolExecutor(a.workers, mp_context=get_context("spawn")) as pool:
                results = list(pool.map(_one, jobs))
            for effect in {e for e, _ in where}:
                got = [r for (e, _), r in zip(where, results) if e == effect]
                value = next(v for e, v in where if e == effect)
                shifts = np.array([sh for sh, _, _ in got])
                # the loop's gate (eha.explain.decide.past_any): the statistic past its
                # threshold, or (an effect tested by its footprint) its parameter's shift
                second = EFFECTS[effect].shift_key
                passed = [past_any({effect: sh, **({second: other} if second else {})}, thr)
                          for sh, _, other in got]
                sizes[effect].append((multiple, value, float(np.mean(passed)),
                                      shifts, [g for _, g, _ in got]))
            todo = [e for e in todo if sizes[e] and sizes[e][-1][2] < 0.9]
        for effect in names:
            multiple, value, power, shifts, gains = sizes[effect][0]
            reached = next((lv for lv in sizes[effect] if lv[2] >= 0.9), None)
            param = EFFECTS[effect].tested
            row = {"command": cname, "effect": effect, "param": param,
                   "unit": null.units[effect], "threshold": thr[effect],
                   "detectable": det[effect], "predicted": predicted[effect],
                   "predicted_unit": EFFECTS[effect].units()[param], "injected": value,
                   "power": power, "records": len(shifts),
                   "shift_median": float(np.median(shifts)),
                   "gain_median": float(np.median(gains)),
                   "measured_detectable": (abs(reached[1] - EFFECTS[effect].off[param])
                                           if reached else None),
                   "measured_multiple": reached[0] if reached else None,
                   "levels": [{"multiple": m, "injected": v, "power": pw}
                              for m, v, pw, _, _ in sizes[effect]],
                   "null_seconds": null_s, "null_actuators": null.records}
            rows.append(row)
            found = (f"{row['measured_detectable']:.3g} ({reached[0]:g}x)" if reached
                     else f"> {sizes[effect][-1][0]:g}x")
            print(f"{cname:10s} {effect:17s} threshold {thr[effect]:9.3g} detectable "
                  f"{det[effect]:9.3g} {null.units[effect]:12s} ({param} "
                  f"{predicted[effect]:9.3g}) power "
                  f"{power:.0%} of {len(shifts)}; 90 % reached at {found}", flush=True)
        print(f"{cname}: null {null_s:.0f} s ({null.records} actuators)", flush=True)
    powers = [r["power"] for r in rows]
    summary = {"cells": len(rows), "median_power": float(np.median(powers)) if rows else None,
               "cells_at_90": int(sum(p >= 0.9 for p in powers)),
               "cells_measured": int(sum(r["measured_detectable"] is not None for r in rows)),
               "multiples": {str(m): int(sum(r["measured_multiple"] == m for r in rows))
                             for m in sorted({r["measured_multiple"] for r in rows
                                              if r["measured_multiple"] is not None})},
               "seconds": time.perf_counter() - t_start}
    print(f"{summary['cells_at_90']} of {len(rows)} cells reach 90 % power at the predicted "
          f"size; median power {summary['median_power']:.0%}; 90 % reached within "
          f"{a.escalate.split(',')[-1]}x in {summary['cells_measured']} (multiples "
          f"{summary['multiples']}); {summary['seconds']:.0f} s")
    # the result file first: its provenance checks the tree before the plot changes it
    if a.json:
        out = {"benchmark": "explain_power",
               "settings": {"alpha": a.alpha, "actuators": a.actuators, "records": a.records,
                            "escalate": a.escalate,
                            "noise_m": NOISE, "commands": commands},
               "summary": summary, "rows": rows}
        write_result(Path(a.json), out)
    if a.plot:
        plot(rows, Path(a.plot))
    return 0


if __name__ == "__main__":
    sys.exit(main())
