"""False-positive rate of the residual loop (`eha explain`) on HEALTHY HF records.

Every record is the HF model of a healthy actuator -- nominal HF parameters with a healthy
manufacturing spread drawn per record (:func:`healthy_params`: GP, GQ, CJ, MJ, FSS within
+-3 %, GM +-1 %, FDJ ~ N(200, 20) N, Clk log-uniform 0.7e-13..1.4e-13, BKL uniform 0..30 µm) --
plus white Gaussian noise on xu (1 µm) and on P12 (0.2 bar, ``--p12-noise``; -1 drops the
P12 column), written to CSV, read back with
:func:`eha.identification.measured.load` and given to :func:`eha.explain.explain` with its defaults
(fit BKL,FDJ; population ``--pop``, GA seed ``--explain-seed``). The HF really has the orifice law
and the flapper dynamics that the LF lacks: ``orifice_law`` and ``flapper_dynamics`` are
*structural* and expected. A **false positive** is a record where the loop adds any other effect.

Commands (1 s, ``test`` 0.6 s as in explain_no_prior.py): the presets sine, chirp_1mm,
chirp_1cm, mixed, test, ramp, and two kinds of random step sequences held between 1 kHz
samples (a digital controller; :func:`step_sequence`):

``steps_5mm``  4-8 steps to random levels within +-5 mm (the spool saturates on large ones);
``steps_1mm``  6-10 steps to random levels within +-1 mm (small moves: friction, backlash).

Prints per record: command, record seed, effects added (structural ones in brackets), RMSE
before -> after and the noise estimate of the record (µm), the best rejected candidate of the
last round (effect, gain, score = gain - penalty*params; "runner-up" when that round added
an effect and the loop then stopped at the noise level) and the wall time; then the FP rate
overall and per command, and how many records the loop stopped at the noise level.

``--json`` writes the current result file, ``validation/results/explain_fp.json``
(replacing it; ``--json PATH`` a part that ``merge_results.py fp`` merges into it), with every record (truth, result, steps, and every refitted candidate of
every round with gain, score, RMSE on the fitted / held-out part and its parameters: what a
stopping rule can be calibrated on offline) and the summary.

Seeds: record ``k`` of command ``c`` (index in :data:`COMMANDS`) has seed
``1000*--seed + 50*c + k``; that one seed draws its healthy parameters and its step sequence
(``numpy.random.default_rng([seed, 1])`` and ``[seed, 2]``) and is the noise/dither seed of
the HF simulation (:func:`eha.identification.measured.synthetic_record`). The loop's GA seed is
``--explain-seed`` (default 0, like ``eha explain``).

    python validation/explain_fp.py                         # 8 commands x 4 records
    python validation/explain_fp.py --limit 3               # smoke run
    python validation/explain_fp.py --commands mixed,steps_5mm --per-command 2
    python validation/explain_fp.py --json                  # validation/results/explain_fp.json
    python validation/explain_fp.py --seed 6 --json part6.json   # a part, for merge_results.py

One record takes 5-60 s (one core); 32 records about 15 min. Run one at a time on a shared
machine (``nice -n 10``). To measure another copy of the package (e.g. the loop as committed
while ``eha/explain/`` is being rewritten) put it first on the path:
``PYTHONPATH=/tmp/eha_before python validation/explain_fp.py ...``; the JSON records
which loop ran (the package's path, the sha256 of its ``eha/explain/*.py``, whether they are
the committed ones).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import provenance as common_provenance, result_path, write_result  # noqa: E402

#: Commands in their fixed order (the order fixes the record seeds; a subset keeps them).
COMMANDS = ("sine", "chirp_1mm", "chirp_1cm", "mixed", "test", "ramp", "steps_5mm",
            "steps_1mm")
#: Record lengths that differ from 1 s.
T_END = {"test": 0.6}
#: Random step sequences: name -> (fewest steps, most steps, largest |level| [m]).
STEP_KINDS = {"steps_5mm": (4, 8, 5e-3), "steps_1mm": (6, 10, 1e-3)}
#: The effects the HF has and the LF lacks by construction: never a false positive.
STRUCTURAL = ("orifice_law", "flapper_dynamics")
#: Healthy spread: parameter -> relative half-width of a uniform draw around the HF nominal.
SPREAD = {"GP": 0.03, "GQ": 0.03, "CJ": 0.03, "MJ": 0.03, "FSS": 0.03, "GM": 0.01}


def record_seed(seed: int, command: str, k: int) -> int:
    """Seed of record ``k`` of ``command`` (stable when the command list is a subset)."""
    return 1000 * seed + 50 * COMMANDS.index(command) + k if command in COMMANDS else \
        1000 * seed + 50 * len(COMMANDS) + k


def healthy_params(seed: int) -> dict[str, float]:
    """HF overrides of a healthy actuator drawn with ``default_rng([seed, 1])``."""
    from eha.models.params import HFParams

    nominal = HFParams()
    rng = np.random.default_rng([seed, 1])
    out = {name: float(getattr(nominal, name) * (1.0 + rng.uniform(-rel, rel)))
           for name, rel in SPREAD.items()}
    out["FDJ"] = float(max(rng.normal(200.0, 20.0), 0.0))
    out["Clk"] = float(math.exp(rng.uniform(math.log(0.7e-13), math.log(1.4e-13))))
    out["BKL"] = float(rng.uniform(0.0, 3e-5))
    return out


def step_sequence(kind: str, seed: int, t_end: float = 1.0):
    """A random step sequence held between 1 kHz samples (``default_rng([seed, 2])``).

    ``n`` steps (uniform in the kind's range) at distinct random sample instants in
    [20 ms, t_end - 50 ms], at least 40 ms apart, each to a level uniform within +-max; the
    command starts at 0. Returns the :class:`~eha.models.commands.Command` and its step list.
    """
    from eha.models.commands import array_command

    lo, hi, amp = STEP_KINDS[kind]
    rng = np.random.default_rng([seed, 2])
    n = int(rng.integers(lo, hi + 1))
    n_samples = int(round(t_end / 1e-3)) + 1
    first, last, gap = 20, n_samples - 50, 40
    while True:                      # rejection: instants at least `gap` samples apart
        idx = np.sort(rng.choice(np.arange(first, last), size=n, replace=False))
        if np.all(np.diff(idx) >= gap):
            break
    levels = rng.uniform(-amp, amp, size=n)
    t = np.arange(n_samples) * 1e-3
    values = np.zeros(n_samples)
    for i, level in zip(idx, levels):
        values[i:] = level
    steps = [{"t": round(float(t[i]), 6), "level": float(v)} for i, v in zip(idx, levels)]
    return array_command(t, values, name=kind, hold="zoh"), steps


def make_command(command: str, seed: int):
    """The command of a record (a preset name, or a step sequence drawn from ``seed``)."""
    if command in STEP_KINDS:
        return step_sequence(command, seed, T_END.get(command, 1.0))
    return command, None


def clean(x):
    """JSON-safe copy: numpy scalars to float, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    return x


def step_groups(result) -> list[list]:
    """Steps grouped by the round that added them (a combination adds several steps with the
    same ``chosen``)."""
    groups: list[list] = []
    for s in result.steps:
        chosen = getattr(s, "chosen", "")
        if groups and chosen and getattr(groups[-1][0], "chosen", "") == chosen:
            groups[-1].append(s)
        else:
            groups.append([s])
    return groups


def rounds_json(result) -> list[dict]:
    """Every round: the reference RMSE the gains are relative to, the accepted candidate (None
    for a round that added nothing) and every refitted candidate."""
    groups = step_groups(result)
    out = []
    for i, rnd in enumerate(result.rounds):
        if i == 0:
            ref_fit, ref_hold = result.before.rmse_fit, result.before.rmse_hold
        elif i - 1 < len(groups):
            ref_fit, ref_hold = groups[i - 1][-1].rmse_fit_after, groups[i - 1][-1].rmse_hold_after
        else:                                                # pragma: no cover
            ref_fit = ref_hold = math.nan
        accepted = None
        if i < len(groups):
            accepted = getattr(groups[i][0], "chosen", "") or "+".join(s.effect for s in groups[i])
        cands = []
        for c in rnd.candidates:
            if not getattr(c, "refit", False):
                continue
            score = getattr(c, "score", math.nan)
            cands.append({"effect": c.effect, "gain": c.gain, "score": score,
                          "switched_off": bool(score == -math.inf),
                          "rmse_fit": c.rmse_fit, "rmse_hold": c.rmse_hold,
                          "rmse_all": getattr(c, "rmse_all", math.nan),
                          "params": dict(c.params), "faults": dict(getattr(c, "faults", {})),
                          "explained": getattr(c, "explained", math.nan),
                          "signature_corr": getattr(c, "signature_corr", math.nan),
                          "seconds": getattr(c, "seconds", math.nan),
                          "accepted": c.effect == accepted})
        out.append({"round": i, "residual_rmse": getattr(rnd, "residual_rmse", math.nan),
                    "ref_rmse_fit": ref_fit, "ref_rmse_hold": ref_hold,
                    "ref_rmse_score": math.sqrt(0.5 * (ref_fit ** 2 + ref_hold ** 2)),
                    "signals": dict(getattr(rnd, "signals", {})),
                    "accepted": accepted, "candidates": cands})
    return out


def best_rejected(rounds: list[dict]) -> dict | None:
    """The best-scoring refitted candidate of the last round that was not accepted.

    ``runner_up`` is True when the last round accepted a candidate (the loop then stopped at
    the noise level or at max_steps without tracing again): the candidate lost to a better
    one, not to the threshold."""
    if not rounds:
        return None
    cands = [c for c in rounds[-1]["candidates"] if not c["accepted"]]
    finite = [c for c in cands if c["score"] is not None and math.isfinite(c["score"])]
    best = max(finite, key=lambda c: c["score"]) if finite else (cands[0] if cands else None)
    return None if best is None else {**best, "runner_up": rounds[-1]["accepted"] is not None}


def noise_stop(result) -> bool:
    """The loop stopped because the scored RMSE reached the noise level."""
    reason = getattr(result, "stop_reason", "") or ""
    if reason:
        return "noise level" in reason
    settings = getattr(result, "settings", {}) or {}
    factor = settings.get("noise_factor", 1.25)
    after = result.after
    score = math.sqrt(0.5 * (after.rmse_fit ** 2 + after.rmse_hold ** 2))
    return score <= factor * result.noise_rmse


#: Default noise of the recorded load pressure P12 [Pa] (0.2 bar, 0.1 % of a 210 bar
#: transducer's range); the simulator's P12 is noise-free.
P12_NOISE = 2e4


def p12_column(df, noise: float, seed: int):
    """The record with its P12 column noisy (std ``noise`` [Pa], ``default_rng([seed, 3])``),
    or without P12 when ``noise`` < 0 (a record with position only)."""
    import numpy as np

    df = df.copy()
    if noise < 0:
        return df.drop(columns=["p12"])
    if noise > 0:
        df["p12"] = df["p12"] + np.random.default_rng([seed, 3]).normal(0.0, noise, len(df))
    return df


def add_fit_argument(ap) -> None:
    ap.add_argument("--fit", default=None,
                    help="parameters fitted throughout, as eha explain --fit (default BKL,FDJ); "
                         "e.g. BKL,FDJ,GQ=0.18:0.22 adds the healthy flow-gain spread")
    ap.add_argument("--flow-gain-spread", type=float, default=None,
                    help="as eha explain --flow-gain-spread (default: the loop's); unlike GQ in "
                         "--fit, a flow gain at the spread's edge goes back to nominal")


def add_p12_arguments(ap) -> None:
    ap.add_argument("--p12-noise", type=float, default=P12_NOISE,
                    help="noise std on the recorded P12 [Pa]; -1: records without P12")
    ap.add_argument("--p12-weight", type=float, default=None,
                    help="weight of the measured P12 in the loop's fits (default: the loop's)")


def run_explain(df, path: Path, pop: int, seed: int, p12_weight: float | None = None,
                fit: str | None = None, flow_gain_spread: float | None = None):
    """Write the record, read it back and run the loop with its defaults (``fit``: the
    parameters fitted throughout, ``eha explain --fit``; None: its default, BKL and FDJ)."""
    from eha.explain import explain
    from eha.identification.measured import load

    df.to_csv(path, index=False)
    data = load(path)
    t0 = time.perf_counter()
    result = explain(data, fit=fit, pop=pop, seed=seed, p12_weight=p12_weight,
                     flow_gain_spread=flow_gain_spread)
    return data, result, time.perf_counter() - t0


def effects_on(result) -> list[str]:
    """Effects on in the final model and not in the starting one (the loop's doing)."""
    from eha.explain.effects import EFFECTS

    return [name for name, e in EFFECTS.items()
            if e.is_on(result.after.params) and not e.is_on(result.before.params)]


def result_json(data, result, seconds: float) -> dict:
    """The figures of one loop run (the public contract plus the trace)."""
    rounds = rounds_json(result)
    return {
        "effects": list(result.effects),
        # every effect switched on in the final model (a guard: must equal the steps)
        "effects_on": effects_on(result),
        "steps": [{"effect": s.effect, "params": dict(s.params), "gain": s.gain,
                   "score": s.score, "chosen": getattr(s, "chosen", ""),
                   "rmse_before": s.rmse_before, "rmse_after": s.rmse_after,
                   "alternatives": dict(getattr(s, "alternatives", {}))}
                  for s in result.steps],
        "final_params": {p: getattr(result.after.params, p) for s in result.steps
                         for p in s.params},
        "faults_before": dict(result.faults_before), "faults_after": dict(result.faults_after),
        # every parameter of the final model (the flow-gain spread GQ fitted with the faults
        # too): explain_coverage recomputes its intervals from them
        "params_after": result.after.params.as_dict(),
        "rmse_before": result.rmse_before, "rmse_after": result.rmse_after,
        "rmse_fit_after": result.after.rmse_fit, "rmse_hold_after": result.after.rmse_hold,
        "noise_rmse": result.noise_rmse, "noise_stop": noise_stop(result),
        "stop_reason": getattr(result, "stop_reason", ""),
        "unexplained": getattr(result, "unexplained", None),
        "command_hold": data.info.get("command_hold"), "samples": len(data),
        "rounds": rounds, "best_rejected": best_rejected(rounds),
        "seconds": seconds, "result_seconds": result.seconds,
        "to_json": result.to_json(),
    }


def provenance(argv: list[str]) -> dict:
    """Where the figures come from: git commit, whether the tree was dirty, hash of the loop."""
    root = Path(__file__).resolve().parents[1]

    def git(*args: str) -> str:
        try:
            return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                                  timeout=30).stdout.strip()
        except (OSError, subprocess.SubprocessError):       # pragma: no cover
            return ""

    import eha.explain

    # the loop that actually ran (PYTHONPATH may point at another copy of the package): the
    # sha256 of its modules (name and text of each eha/explain/*.py, in name order)
    loop_dir = Path(eha.explain.__file__).resolve().parent
    names = sorted(p.name for p in loop_dir.glob("*.py"))

    def loop_sha256(text_of) -> str:
        digest = hashlib.sha256()
        for name in names:
            digest.update(name.encode() + b"\0" + text_of(name) + b"\0")
        return digest.hexdigest()

    ran = loop_sha256(lambda name: (loop_dir / name).read_bytes())
    head = loop_sha256(lambda name: subprocess.run(
        ["git", "show", f"HEAD:eha/explain/{name}"], cwd=root, capture_output=True).stdout)
    return {**common_provenance(argv),
            "dirty": sorted(line[3:] for line in git("status", "--porcelain").splitlines()
                            if line[3:].startswith("eha/")),
            "eha_package": str(loop_dir.parent),
            # (the keys keep their names from the single module eha/explain.py)
            "explain_py_sha256": ran, "explain_py_is_head": ran == head,
            }


def warm_up() -> None:
    """Load the compiled kernels (numba cache) outside the timings."""
    from eha.explain import explain
    from eha.identification.measured import from_arrays, synthetic_record

    df = synthetic_record("mixed", {}, t_end=0.1, noise=1e-6, seed=0)
    explain(from_arrays(df.t.to_numpy(), df.com.to_numpy(), df.xu.to_numpy()), pop=4,
            max_steps=0)


def fmt_cand(c: dict | None) -> str:
    if c is None:
        return "-"
    score = "off" if c["switched_off"] else ("nan" if c["score"] is None else
                                            f"{c['score']:+.3f}")
    gain = "nan" if c["gain"] is None else f"{c['gain']:+.3f}"
    return f"{c['effect']} {gain}/{score}" + (" (runner-up)" if c.get("runner_up") else "")


def fmt_effects(effects: list[str]) -> str:
    return ", ".join(f"[{e}]" if e in STRUCTURAL else e for e in effects) or "(nothing)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(COMMANDS),
                    help=f"comma-separated, of: {', '.join(COMMANDS)}")
    ap.add_argument("--per-command", type=int, default=4, help="records per command")
    ap.add_argument("--seed", type=int, default=0, help="seed block of the records")
    ap.add_argument("--explain-seed", type=int, default=0, help="GA seed of the loop")
    ap.add_argument("--pop", type=int, default=20)
    ap.add_argument("--noise", type=float, default=1e-6, help="noise std on xu [m]")
    ap.add_argument("--limit", type=int, default=0, help="only the first N records (smoke run)")
    ap.add_argument("--seeds", default=None,
                    help="only the records of these seeds, comma-separated (a rerun of those a "
                         "change can touch; validation/merge_results.py puts them in place)")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_fp")), default=None,
                    metavar="PATH", help="write every record + summary (default: the result file)")
    add_p12_arguments(ap)
    add_fit_argument(ap)
    args = ap.parse_args()
    commands = [c for c in args.commands.split(",") if c]
    unknown = [c for c in commands if c not in COMMANDS]
    if unknown:
        ap.error(f"--commands: unknown {unknown[0]!r}; allowed: {', '.join(COMMANDS)}")
    plan = [(c, record_seed(args.seed, c, k)) for c in commands for k in range(args.per_command)]
    if args.seeds:
        wanted = {int(w) for w in args.seeds.split(",") if w.strip()}
        unknown = wanted - {seed for _, seed in plan}
        if unknown:
            ap.error(f"--seeds: {sorted(unknown)} not among the records of --commands "
                     f"and --seed")
        plan = [(c, seed) for c, seed in plan if seed in wanted]
    if args.limit:
        plan = plan[:args.limit]

    from eha.identification.measured import synthetic_record

    print(f"{len(plan)} healthy HF records, noise {1e6 * args.noise:g} µm, pop {args.pop}, "
          f"GA seed {args.explain_seed}; [structural] effects are expected", flush=True)
    warm_up()
    print(f"{'command':10} {'seed':>5} {'RMSE before -> after':>21} {'noise':>6} {'s':>5}  "
          f"{'FP':2}  effects added | best rejected of the last round (gain/score)",
          flush=True)
    rows = []
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for i, (command, seed) in enumerate(plan):
            truth = healthy_params(seed)
            cmd, steps = make_command(command, seed)
            t_end = T_END.get(command, 1.0)
            df = synthetic_record(cmd, truth, t_end=t_end, noise=args.noise, seed=seed,
                                  command_hold="auto")
            df = p12_column(df, args.p12_noise, seed)
            data, result, seconds = run_explain(df, Path(tmp) / f"{i:03d}_{command}.csv",
                                                args.pop, args.explain_seed, args.p12_weight,
                                                args.fit, args.flow_gain_spread)
            res = result_json(data, result, seconds)
            spurious = [e for e in dict.fromkeys(res["effects"] + res["effects_on"])
                        if e not in STRUCTURAL]
            row = {"i": i, "command": command, "seed": seed, "t_end": t_end,
                   "noise": args.noise, "truth": truth, "command_steps": steps,
                   "false_positive": bool(spurious), "spurious": spurious, **res}
            rows.append(row)
            print(f"{command:10} {seed:5d} {1e6 * res['rmse_before']:8.3g} -> "
                  f"{1e6 * res['rmse_after']:6.3g} um {1e6 * res['noise_rmse']:6.3g} "
                  f"{seconds:5.1f}  {'FP' if spurious else '  '}  "
                  f"{fmt_effects(res['effects'])}"
                  f"{' (noise stop)' if res['noise_stop'] else ''} | "
                  f"{fmt_cand(res['best_rejected'])}", flush=True)
    wall = time.perf_counter() - started
    summary = summarise(rows, commands)
    summary["wall_s"] = wall
    print_summary(summary)
    if args.json:
        out = {"benchmark": "explain_fp", "settings": {
                   "commands": commands, "per_command": args.per_command, "seed": args.seed,
                   "explain_seed": args.explain_seed, "pop": args.pop, "noise": args.noise,
                   "p12_noise": args.p12_noise, "p12_weight": args.p12_weight,
                   "limit": args.limit, "seeds": args.seeds, "fit": args.fit,
                   "flow_gain_spread": args.flow_gain_spread,
                   "structural": list(STRUCTURAL),
                   "spread": {**SPREAD, "FDJ": "N(200, 20)", "Clk": "log-uniform 0.7e-13..1.4e-13",
                              "BKL": "uniform 0..3e-5"},
                   "step_kinds": {k: {"steps": [lo, hi], "max_level_m": a}
                                  for k, (lo, hi, a) in STEP_KINDS.items()},
                   "t_end": {c: T_END.get(c, 1.0) for c in commands}},
               "provenance": provenance(sys.argv), "summary": summary, "records": rows}
        write_result(Path(args.json), clean(out))


def summarise(rows: list[dict], commands: list[str]) -> dict:
    per = {}
    for c in commands:
        rs = [r for r in rows if r["command"] == c]
        if not rs:
            continue
        per[c] = {"records": len(rs), "false_positives": sum(r["false_positive"] for r in rs),
                  "fp_rate": sum(r["false_positive"] for r in rs) / len(rs),
                  "noise_stops": sum(r["noise_stop"] for r in rs),
                  "spurious": sorted({e for r in rs for e in r["spurious"]}),
                  "seconds_median": statistics.median(r["seconds"] for r in rs)}
    spurious_counts: dict[str, int] = {}
    for r in rows:
        for e in r["spurious"]:
            spurious_counts[e] = spurious_counts.get(e, 0) + 1
    # the steps that were false positives, with their gain/score (what a rule must reject)
    fp_steps = [{"command": r["command"], "seed": r["seed"], "effect": s["effect"],
                 "gain": s["gain"], "score": s["score"], "chosen": s["chosen"],
                 "params": r["final_params"] and {p: r["final_params"].get(p) for p in s["params"]},
                 "noise_rmse": r["noise_rmse"]}
                for r in rows for s in r["steps"] if s["effect"] not in STRUCTURAL]
    structural_found = sum(all(e in r["effects"] for e in STRUCTURAL) for r in rows)
    n = len(rows)
    return {"records": n, "false_positives": sum(r["false_positive"] for r in rows),
            "fp_rate": sum(r["false_positive"] for r in rows) / n if n else math.nan,
            "noise_stops": sum(r["noise_stop"] for r in rows),
            "structural_both_found": structural_found,
            "spurious_counts": spurious_counts, "fp_steps": fp_steps, "per_command": per,
            "seconds_median": statistics.median(r["seconds"] for r in rows) if rows else None,
            "seconds_max": max((r["seconds"] for r in rows), default=None)}


def print_summary(s: dict) -> None:
    print(f"\nfalse positives: {s['false_positives']}/{s['records']} records "
          f"({100 * s['fp_rate']:.0f} %); stopped at the noise level: {s['noise_stops']}/"
          f"{s['records']}; both structural effects found: {s['structural_both_found']}/"
          f"{s['records']}; {s['wall_s']:.0f} s", flush=True)
    print(f"{'command':10} {'records':>7} {'FP':>3} {'rate':>5} {'noise stop':>10} "
          f"{'median s':>8}  spurious effects")
    for c, p in s["per_command"].items():
        print(f"{c:10} {p['records']:7d} {p['false_positives']:3d} "
              f"{100 * p['fp_rate']:4.0f}% {p['noise_stops']:10d} {p['seconds_median']:8.1f}  "
              f"{', '.join(p['spurious']) or '-'}")
    if s["fp_steps"]:
        print("spurious steps (gain / score):")
        for f in s["fp_steps"]:
            params = ", ".join(f"{k}={v:.4g}" for k, v in (f["params"] or {}).items())
            print(f"  {f['command']:10} seed {f['seed']:5d}  {f['effect']:16} "
                  f"{f['gain']:+.3f} / {f['score']:+.3f}  ({params})")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
