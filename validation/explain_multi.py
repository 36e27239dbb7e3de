"""Several undeclared effects at once: does the residual loop (`eha explain`) find them all?

HF records with the declared faults BKL = 0.1 mm and FDJ = 800 N and two or three undeclared
effects of the library (:data:`eha.explain.effects.EFFECTS`; the HF parameter has the LF parameter's
name) in combinations a PHM engineer meets (:data:`COMBOS`: a loaded actuator with worn seals,
a motor offset with an aerodynamic hinge moment, ...), each on two of the commands mixed,
test (0.6 s), chirp_1cm and a random step sequence held between 1 kHz samples (``steps``:
4-8 steps within +-5 mm, explain_fp.step_sequence). 1 µm white noise on xu and 0.2 bar on P12 (``--p12-noise``; -1: no P12 column); the record is
written to CSV, read back with :func:`eha.identification.measured.load` and given to
:func:`eha.explain.explain` with its defaults (fit BKL,FDJ).

Score of a record:

``found``   every injected effect is an added step (``orifice_law`` and ``flapper_dynamics``,
            which the HF has and the LF lacks, are structural: expected, never spurious);
``params``  every injected parameter, as estimated in the final model
            (``result.after.params``), within 15 % of the truth (relative error);
``faults``  BKL and FDJ (``result.faults_after``) within 5 % of the truth;
``spurious`` effects added that were not injected (and not structural), except one the HF
            itself has at its nominal values and the loop estimated within 15 % of them: the
            HF's nominal leak (Clk 1e-13, which the LF lacks) is the HF's structure, found
            (``hf_own``);
``success`` all found, params and faults within tolerance, nothing spurious.

Prints one line per record while running (steps added, parameter errors, fault errors,
RMSE before -> after, wall time) and the fractions at the end; ``--json PATH`` writes every
record (truth, result, every refitted candidate of every round) and the summary.

Seeds: record ``i`` (index in :data:`RECORDS`) has seed ``1000*--seed + i``: noise and HF
dither of :func:`eha.identification.measured.synthetic_record` and, on ``steps``, the step sequence
(``default_rng([seed, 2])``). The loop's GA seed is ``--explain-seed`` (default 0).

    python validation/explain_multi.py                      # 24 records
    python validation/explain_multi.py --limit 3            # smoke run
    python validation/explain_multi.py --records load+leak@mixed,5
    python validation/explain_multi.py --commands test,steps --json out.json
    python validation/explain_multi.py --json   # validation/results/explain_multi.json

A record takes 0.5-3 min (one core); all 24 about 30-50 min. Run one at a time on a shared
machine (``nice -n 10``). ``PYTHONPATH=/other/copy python ...`` measures another copy of the
package; the JSON records which loop (``eha/explain/``) ran.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

from explain_fp import (STRUCTURAL, add_fit_argument, add_p12_arguments,  # noqa: E402
                              clean, fmt_effects, p12_column, provenance, result_json,
                              run_explain, step_sequence, warm_up)

#: Declared faults of every record (fitted by the loop).
FAULTS = {"BKL": 1e-4, "FDJ": 800.0}
COMMANDS = ("mixed", "test", "chirp_1cm", "steps")
T_END = {"test": 0.6}
#: Tolerances: relative error of an injected effect's parameters / of the declared faults.
PARAM_TOL = 0.15
FAULT_TOL = 0.05
#: Combinations: name -> ({effect: value of its tested parameter}, commands). Magnitudes
#: are clearly visible on the commands they run on (HF RMSE change 20-300 µm, 1 µm noise).
COMBOS: dict[str, tuple[dict[str, float], tuple[str, ...]]] = {
    # loaded actuator with worn piston seals
    "load+leak": ({"external_load": 2000.0, "leakage": 5e-12}, ("mixed", "steps")),
    # torque-motor null shift on a surface with an aerodynamic hinge moment
    "offset+hinge": ({"offset": 0.3, "hinge_moment": 1.5e5}, ("test", "chirp_1cm")),
    # position-sensor bias and seal wear
    "bias+leak": ({"sensor_bias": 1e-4, "leakage": 5e-12}, ("chirp_1cm", "mixed")),
    # loaded actuator, magnetic hysteresis of the torque motor
    "load+hysteresis": ({"external_load": 2000.0, "hysteresis": 0.2}, ("steps", "test")),
    # seal wear and a degraded (more viscous) jack (CJ was 1e4 until 2026-11-22: inside the
    # 1.2e4 tolerance the false-positive bench calibrated later, so never reportable)
    "leak+viscous": ({"leakage": 5e-12, "viscous_friction": 1.6e4}, ("test", "steps")),
    # hinge moment and a demagnetised torque motor
    "hinge+motor_gain": ({"hinge_moment": 1.5e5, "motor_gain": 0.008}, ("mixed", "chirp_1cm")),
    # first-stage filter clogging and a sensor bias (Kintas was 0.5 until 2026-11-22: on the
    # 0.5 tolerance the false-positive bench calibrated later, so never reportable)
    "clogging+bias": ({"clogging": 0.65, "sensor_bias": 1e-4}, ("test", "steps")),
    # low supply pressure under load
    "supply+load": ({"supply_pressure": 1.6e7, "external_load": 2000.0}, ("chirp_1cm", "mixed")),
    # motor offset and a delayed position measurement (sensor filter)
    "offset+delay": ({"offset": 0.3, "delay": 1e-3}, ("steps", "mixed")),
    # three at once
    "load+offset+leak": ({"external_load": 2000.0, "offset": 0.3, "leakage": 5e-12},
                         ("mixed", "test")),
    "bias+hinge+hysteresis": ({"sensor_bias": 1e-4, "hinge_moment": 1.5e5, "hysteresis": 0.2},
                              ("chirp_1cm", "steps")),
    "load+leak+motor_gain": ({"external_load": 2000.0, "leakage": 5e-12, "motor_gain": 0.008},
                             ("steps", "test")),
}
#: Every record: (name "combo@command", combo, command), in a fixed order (it fixes the seeds).
RECORDS: tuple[tuple[str, str, str], ...] = tuple(
    (f"{combo}@{command}", combo, command) for combo, (_, commands) in COMBOS.items()
    for command in commands)


def injected(combo: str) -> dict[str, dict[str, float]]:
    """effect -> {HF/LF parameter: value} of a combination (names checked in the registry).

    The sizes were chosen clear of the fixed healthy tolerances the loop once had; the null
    that replaced them is per command, so no fixed clearance is checked here."""
    from eha.explain.effects import EFFECTS

    out = {}
    for effect, value in COMBOS[combo][0].items():
        name = EFFECTS[effect].tested      # the supply pressure: PSR (its law stays nominal)
        if name is None:
            raise ValueError(f"{combo}: {effect} has no tested parameter; give one")
        out[effect] = {name: float(value)}
    return out


def make_command(command: str, seed: int):
    if command == "steps":
        return step_sequence("steps_5mm", seed, T_END.get(command, 1.0))
    return command, None


def rel(est: float, truth: float) -> float:
    return abs(est - truth) / abs(truth) if truth else abs(est)


def score(res: dict, result, inj: dict[str, dict[str, float]]) -> dict:
    """Found / parameter / fault / spurious figures of one record."""
    effects = res["effects"]
    found = {e: e in effects for e in inj}
    param_err = {p: rel(float(getattr(result.after.params, p)), v)
                 for e, ps in inj.items() for p, v in ps.items() if found[e]}
    fault_err = {k: rel(float(result.faults_after[k]), v) for k, v in FAULTS.items()}
    own = hf_own(result)
    spurious = [e for e in dict.fromkeys(effects + res["effects_on"])
                if e not in inj and e not in STRUCTURAL and e not in own]
    all_found = all(found.values())
    params_ok = all_found and all(err <= PARAM_TOL for err in param_err.values())
    faults_ok = all(err <= FAULT_TOL for err in fault_err.values())
    return {"found": found, "all_found": all_found, "param_err": param_err, "hf_own": own,
            "params_ok": params_ok, "fault_err": fault_err, "faults_ok": faults_ok,
            "spurious": spurious, "success": all_found and params_ok and faults_ok
            and not spurious}


def hf_own(result) -> dict[str, dict[str, float]]:
    """Effects of the final model that the HF has at its nominal values (its parameter
    differs from the LF's off value) and that the loop estimated within PARAM_TOL of the HF's
    value: effect -> {parameter: relative error}. Not spurious: the record has them."""
    from eha.explain.effects import EFFECTS
    from eha.models.params import HFParams

    hf, out = HFParams(), {}
    for name, effect in EFFECTS.items():
        if name in STRUCTURAL or not effect.params or not effect.is_on(result.after.params):
            continue
        truth = {p: getattr(hf, p, None) for p in effect.params}
        if any(v is None or v == effect.off[p] for p, v in truth.items()):
            continue
        err = {p: rel(float(getattr(result.after.params, p)), v) for p, v in truth.items()}
        if all(e <= PARAM_TOL for e in err.values()):
            out[name] = err
    return out


def select(args) -> list[tuple[int, str, str, str]]:
    """(index, name, combo, command) of the records to run."""
    plan = list(enumerate(RECORDS))
    if args.records:
        wanted = [w.strip() for w in args.records.split(",") if w.strip()]
        names = {name: i for i, (name, _, _) in plan}
        keep = []
        for w in wanted:
            if w.isdigit() and int(w) < len(RECORDS):
                keep.append(int(w))
            elif w in names:
                keep.append(names[w])
            elif w in COMBOS:
                keep += [i for i, (_, combo, _) in plan if combo == w]
            else:
                raise SystemExit(f"--records: unknown {w!r}; a record name (combo@command), a "
                                 f"combination or an index 0-{len(RECORDS) - 1}")
        plan = [plan[i] for i in dict.fromkeys(keep)]
    if args.commands:
        commands = set(args.commands.split(","))
        plan = [p for p in plan if p[1][2] in commands]
    if args.limit:
        plan = plan[:args.limit]
    return [(i, name, combo, command) for i, (name, combo, command) in plan]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=None,
                    help="subset: record names (combo@command), combinations or indices")
    ap.add_argument("--commands", default=None, help=f"only these, of: {', '.join(COMMANDS)}")
    ap.add_argument("--seed", type=int, default=0, help="seed block of the records")
    ap.add_argument("--explain-seed", type=int, default=0, help="GA seed of the loop")
    ap.add_argument("--pop", type=int, default=20)
    ap.add_argument("--noise", type=float, default=1e-6, help="noise std on xu [m]")
    ap.add_argument("--limit", type=int, default=0, help="only the first N records (smoke run)")
    ap.add_argument("--list", action="store_true", help="list the records and stop")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_multi")),
                    default=None, metavar="PATH",
                    help="write every record + summary (default: the result file)")
    add_p12_arguments(ap)
    add_fit_argument(ap)
    args = ap.parse_args()
    plan = select(args)
    if args.list:
        for i, name, combo, _ in plan:
            print(f"{i:3d}  {name:34} {COMBOS[combo][0]}")
        return

    from eha.identification.measured import synthetic_record

    print(f"{len(plan)} HF records with BKL={FAULTS['BKL']:g} m, FDJ={FAULTS['FDJ']:g} N and "
          f"2-3 undeclared effects, noise {1e6 * args.noise:g} µm, pop {args.pop}, GA seed "
          f"{args.explain_seed}; tolerances: params {PARAM_TOL:.0%}, faults {FAULT_TOL:.0%}",
          flush=True)
    warm_up()
    print(f"{'record':34} {'seed':>5} {'before -> after µm':>19} {'s':>5}  ok  effects added | "
          f"param errors | BKL, FDJ errors | spurious", flush=True)
    rows = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for n, (i, name, combo, command) in enumerate(plan):
            seed = 1000 * args.seed + i
            inj = injected(combo)
            overrides = {**FAULTS, **{p: v for ps in inj.values() for p, v in ps.items()}}
            cmd, steps = make_command(command, seed)
            t_end = T_END.get(command, 1.0)
            df = synthetic_record(cmd, overrides, t_end=t_end, noise=args.noise, seed=seed,
                                  command_hold="auto")
            df = p12_column(df, args.p12_noise, seed)
            data, result, seconds = run_explain(df, Path(tmp) / f"{n:03d}_{i}.csv", args.pop,
                                                args.explain_seed, args.p12_weight, args.fit,
                                                args.flow_gain_spread)
            res = result_json(data, result, seconds)
            sc = score(res, result, inj)
            rows.append({"i": i, "name": name, "combo": combo, "command": command,
                         "seed": seed, "t_end": t_end, "noise": args.noise,
                         "injected": inj, "faults": FAULTS, "overrides": overrides,
                         "command_steps": steps, **sc, **res})
            errs = ", ".join(f"{p} {100 * e:.0f}%" for p, e in sc["param_err"].items()) or "-"
            missing = [e for e, ok in sc["found"].items() if not ok]
            print(f"{name:34} {seed:5d} {1e6 * res['rmse_before']:8.3g} -> "
                  f"{1e6 * res['rmse_after']:6.3g} {seconds:5.1f}  "
                  f"{'OK' if sc['success'] else '--'}  {fmt_effects(res['effects'])}"
                  f"{' (missing: ' + ', '.join(missing) + ')' if missing else ''} | {errs} | "
                  f"{100 * sc['fault_err']['BKL']:.1f}%, {100 * sc['fault_err']['FDJ']:.1f}% | "
                  f"{', '.join(sc['spurious']) or '-'}", flush=True)
    summary = summarise(rows)
    summary["wall_s"] = time.perf_counter() - started
    print_summary(summary)
    if args.json:
        out = {"benchmark": "explain_multi", "settings": {
                   "records": [r["name"] for r in rows], "seed": args.seed,
                   "explain_seed": args.explain_seed, "pop": args.pop, "noise": args.noise,
                   "p12_noise": args.p12_noise, "p12_weight": args.p12_weight, "fit": args.fit,
                   "flow_gain_spread": args.flow_gain_spread,
                   "limit": args.limit, "faults": FAULTS, "param_tol": PARAM_TOL,
                   "fault_tol": FAULT_TOL, "structural": list(STRUCTURAL),
                   "combos": {k: {"effects": v[0], "commands": list(v[1])}
                              for k, v in COMBOS.items()},
                   "t_end": {c: T_END.get(c, 1.0) for c in COMMANDS}},
               "provenance": provenance(sys.argv), "summary": summary, "records": rows}
        write_result(Path(args.json), clean(out))


def summarise(rows: list[dict]) -> dict:
    def fractions(rs: list[dict]) -> dict:
        n = len(rs)
        return {"records": n,
                **{k: (sum(r[k] for r in rs) / n if n else math.nan)
                   for k in ("all_found", "params_ok", "faults_ok", "success")},
                "no_spurious": sum(not r["spurious"] for r in rs) / n if n else math.nan}

    effect_found: dict[str, list[bool]] = {}
    for r in rows:
        for e, ok in r["found"].items():
            effect_found.setdefault(e, []).append(ok)
    spurious: dict[str, int] = {}
    for r in rows:
        for e in r["spurious"]:
            spurious[e] = spurious.get(e, 0) + 1
    return {**fractions(rows),
            "two_effects": fractions([r for r in rows if len(r["injected"]) == 2]),
            "three_effects": fractions([r for r in rows if len(r["injected"]) == 3]),
            "per_command": {c: fractions([r for r in rows if r["command"] == c])
                            for c in COMMANDS if any(r["command"] == c for r in rows)},
            "effect_found_rate": {e: sum(v) / len(v) for e, v in effect_found.items()},
            "spurious_counts": spurious,
            "seconds_median": statistics.median(r["seconds"] for r in rows) if rows else None,
            "seconds_max": max((r["seconds"] for r in rows), default=None)}


def print_summary(s: dict) -> None:
    def line(label: str, f: dict) -> str:
        if not f["records"]:
            return f"{label:14} {0:7d}"
        return (f"{label:14} {f['records']:7d} {100 * f['all_found']:6.0f}% "
                f"{100 * f['params_ok']:9.0f}% {100 * f['faults_ok']:9.0f}% "
                f"{100 * f['no_spurious']:11.0f}% {100 * f['success']:7.0f}%")

    print(f"\n{'':14} {'records':>7} {'found':>7} {'params15%':>10} {'faults5%':>10} "
          f"{'no spurious':>12} {'success':>8}   ({s['wall_s']:.0f} s)")
    print(line("all", s))
    print(line("two effects", s["two_effects"]))
    print(line("three effects", s["three_effects"]))
    for c, f in s["per_command"].items():
        print(line(c, f))
    print("found per effect: " + ", ".join(f"{e} {100 * v:.0f}%" for e, v in
                                           s["effect_found_rate"].items()))
    print("spurious: " + (", ".join(f"{e} x{n}" for e, n in s["spurious_counts"].items())
                          or "none"), flush=True)


if __name__ == "__main__":
    main()
