"""Test design (`eha design`, docs/design.md): the seven-fault design at 1 s, predicted and
verified by simulation against library commands, and the separating designs for the foreign
set's five ambiguities.

    python validation/design.py --json                 # design, verify, ambiguities
    python validation/design.py --design DIR --json    # reuse DIR/design.{json,csv}
    python validation/design.py --loop 2 --json        # + the loop on HF records

Parts:

1. **Seven-fault design** (1 s, +-1 cm, 0.1 m/s, alpha 0.01, position only; with
   ``--signals xu,p12`` also the design with the load pressure and its verification by
   checks that fit it): predicted minimum
   detectable sizes against chirp_1cm, mixed, test and sine; its wall time.
2. **Verification** (``eha design verify``): a health-detection campaign on the design and the
   ``--library`` commands with the same fleets (``--healthy`` actuators, the first
   ``--calibration`` set the thresholds, the rest measure false alarms) and each fault at 0.5,
   1, 2 and 4 times its predicted size (``--per-level`` actuators each): measured minimum
   detectable sizes (P_D >= 0.95), isolation, false-alarm rate with its 95 % bound.
3. **Ambiguities**: for each pair the foreign set's loop could not separate, a design of at
   most 2 s at the fitted values; its predicted separable sizes against chirp_1cm's; with
   ``--loop N``, the residual loop on N HF records per truth made on the design (each pair
   member as the truth, at its fitted size): how often the verdict names the truth alone.
4. **Wider limits** for the pairs the 2-s designs do not tell apart (4 s at +-1 cm, 2 s at
   +-2 cm): what would separate them (predicted separable sizes).
5. **Test loads** on the motor-gain / supply-pressure design: the load that would show the
   drop (predicted), and whether the check's LF still follows the actuator under it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper
from _results import ROOT, write_result  # noqa: E402

#: The foreign set's five ambiguities (docs/explain.md, validation/results/explain_foreign.json):
#: the effect found, its rival, and their fitted deviations from off on the record.
AMBIGUITIES = {
    "load-offset (f01, f02)": (("external_load", 800.0), ("offset", -0.009)),
    "bias-offset (f09)": (("sensor_bias", 2e-5), ("offset", -0.0039)),
    "motor gain-supply pressure (f13, f25)": (("motor_gain", -0.001),
                                              ("supply_pressure", -1.2e6)),
    "motor gain-viscous friction (f13, f25)": (("motor_gain", -0.001),
                                               ("viscous_friction", 5500.0)),
    "sensor gain-hinge moment (f21)": (("sensor_gain", -0.01), ("hinge_moment", 8270.0)),
}


def seven_faults(args) -> tuple[dict, Path]:
    from eha.design import Limits, design

    folder = Path(args.design or Path(args.out) / "seven")
    out: dict = {}
    if args.design:
        out = {"reused": str(folder),
               "design": json.loads((folder / "design.json").read_text())}
    else:
        start = time.perf_counter()
        result = design(limits=Limits(1.0, 0.01, 0.1), seed=args.seed,
                        on_progress=lambda m: print(m, flush=True))
        result.save(folder)
        out = {"seconds": time.perf_counter() - start, "design": result.to_dict()}
    if "p12" in args.signals:
        # the same limits with the load pressure recorded (and fitted by the checks)
        saved = folder / "design-p12.json"
        if args.design and saved.exists():
            out["design_p12"] = json.loads(saved.read_text())
        else:
            start = time.perf_counter()
            with_p12 = design(limits=Limits(1.0, 0.01, 0.1), seed=args.seed,
                              signals=("xu", "p12"), on_progress=lambda m: print(m, flush=True))
            with_p12.save(folder, "design-p12")
            out["design_p12"] = {**with_p12.to_dict(),
                                 "seconds": time.perf_counter() - start}
    return out, folder


def campaign_time(results: Path, campaign: str) -> dict:
    """What a verification campaign's assessments cost when they ran, read from its store:
    this run's ``seconds`` are a summary's when the campaign runner had them all already.

    Returns the runs done, their seconds in the workers (summed) and the span from the first
    start to the last finish [s] (a campaign resumed later spans the pause too)."""
    from eha.campaigns.query import query

    row = query(results, "SELECT count(*) AS n, sum(elapsed_s) AS s, min(started_at) AS a, "
                         "max(finished_at) AS b FROM runs WHERE campaign = ? AND status = 'done'",
                [campaign]).iloc[0]
    span = (row["b"] - row["a"]).total_seconds() if int(row["n"]) else 0.0
    return {"runs": int(row["n"]), "worker_seconds": float(row["s"] or 0.0),
            "span_seconds": float(span)}


def verification(args, folder: Path, name: str = "design") -> dict:
    """The verification campaign of ``folder/NAME.json`` (its design on the full healthy
    fleet, then the ``--library`` commands on the same seeds and levels)."""
    from eha.design.verify import verify

    start = time.perf_counter()
    runs = Path(args.out) / ("runs" if name == "design" else f"runs-{name}")
    # the design on the full healthy fleet (false alarms on 200 actuators never used to
    # calibrate); the library commands on the same seeds, levels and calibration, a smaller
    # held-out fleet (their false alarms are not the question)
    v = verify(folder / f"{name}.json", library=[], healthy=args.healthy,
               calibration=args.calibration, per_level=args.per_level,
               results=runs, workers=args.workers, progress=False)
    v.save(folder / f"{name}-verification.json")
    doc = v.to_dict()
    out = {"seconds": time.perf_counter() - start, **doc, "table": v.markdown(),
           "campaign_time": campaign_time(runs, doc["campaign"])}
    library = [c for c in args.library.split(",") if c]
    if library:
        lib = verify(folder / f"{name}.json", library=library, healthy=args.library_healthy,
                     calibration=args.calibration, per_level=args.library_per_level,
                     results=Path(f"{runs}-lib"), workers=args.workers,
                     progress=False, with_design=False)
        lib_doc = lib.to_dict()
        out["library"] = {**lib_doc, "table": lib.markdown(),
                          "campaign_time": campaign_time(Path(f"{runs}-lib"),
                                                         lib_doc["campaign"])}
        out["seconds"] = time.perf_counter() - start
    return out


def ambiguities(args) -> dict:
    from eha.design import Limits, design

    out = {}
    root = Path(args.out) / "ambiguities"
    # one folder per pair, named by both members (two pairs share the motor gain); with
    # --reuse-designs the pairs whose design is there run first
    order = sorted(AMBIGUITIES.items(), key=lambda it: not (
        args.reuse_designs and (root / f"{it[1][0][0]}-{it[1][1][0]}" / "design.json").exists()))
    for label, ((a, va), (b, vb)) in order:
        start = time.perf_counter()
        folder = root / f"{a}-{b}"
        if args.cached_only and not (folder / "design.json").exists():
            continue
        if args.pairs and folder.name not in args.pairs.split(","):
            continue
        if args.reuse_designs and (folder / "design.json").exists():
            saved = json.loads((folder / "design.json").read_text())
            pair, segments = saved["pairs"][0], saved["segments"]
            seconds, reused = saved.get("seconds"), True
        else:
            result = design(faults=[], separate=[(a, b)], around={a: va, b: vb},
                            limits=Limits(2.0, 0.01, 0.1), seed=args.seed,
                            generations=args.generations)
            result.save(folder)
            pair, segments = result.pairs()[0], result.segments
            seconds, reused = time.perf_counter() - start, False
        entry = {"pair": [a, b], "at": {a: va, b: vb}, "seconds": seconds,
                 "separable_size": pair, "segments": segments,
                 "command": str(folder / "design.csv"), "design_reused": reused}
        if args.loop:
            entry["loop"] = loop_verdicts(folder / "design.csv", (a, va), (b, vb), args)
        out[label] = entry
        print(label, json.dumps(_finite(entry["separable_size"])), flush=True)
    return out


#: Limits beyond the 2-s, +-1 cm of the separating tests, tried for every pair those do not
#: tell apart at the fitted sizes (the "what would show it" of docs/design.md).
WIDER = {"4 s, 1 cm": (4.0, 0.01), "2 s, 2 cm": (2.0, 0.02)}


def wider_limits(args) -> dict:
    """The separating designs under :data:`WIDER` limits of the pairs the 2-s design does not
    tell apart (predicted sizes; each design kept in OUT/wider/A-B-TAG and reused with
    ``--reuse-designs``; with ``--loop``, the loop on records made on those that do)."""
    from eha.design import Limits, design

    out = {}
    for label, ((a, va), (b, vb)) in AMBIGUITIES.items():
        if _told_apart_in_two_seconds(args, a, b):
            continue
        for tag, (duration, stroke) in WIDER.items():
            folder = Path(args.out) / "wider" / f"{a}-{b}-{tag.replace(' ', '').replace(',', '-')}"
            start = time.perf_counter()
            if args.reuse_designs and (folder / "design.json").exists():
                saved = json.loads((folder / "design.json").read_text())
                pair, seconds = saved["pairs"][0], saved.get("seconds")
            else:
                result = design(faults=[], separate=[(a, b)], around={a: va, b: vb},
                                limits=Limits(duration, stroke, 0.1), seed=args.seed,
                                generations=args.generations)
                result.save(folder)
                pair, seconds = result.pairs()[0], time.perf_counter() - start
            entry = {"limits": {"duration": duration, "max_stroke": stroke},
                     "separable_size": pair["design"],
                     "told_apart": pair["told_apart_at_these_sizes"], "seconds": seconds}
            if args.loop and entry["told_apart"]:
                # the loop on records made on a design that separates the pair on paper
                entry["loop"] = loop_verdicts(folder / "design.csv", (a, va), (b, vb), args,
                                              t_end=duration)
            out[f"{label} {tag}"] = entry
            print(label, tag, json.dumps(_finite(pair["design"])), flush=True)
    return out


#: Test loads [N] tried on the supply-pressure pair's design (the jack stalls near 16 kN).
TEST_LOADS = (0.0, 2000.0, 6000.0, 10000.0, 13000.0)


def test_loads(args) -> dict:
    """The motor-gain / supply-pressure pair on its 2-s design under :data:`TEST_LOADS`, the
    position alone and with P12 (predicted separable sizes, and whether the check's LF
    follows the loaded actuator): the LF's supply pressure bounds the load pressure, so only
    a load that brings P12 near the supply shows the drop."""
    from eha.design.predict import predict
    from eha.design.targets import SIGNALS, resolve_targets, with_probes
    from eha.models.commands import load_command_file

    (a, va), (b, vb) = AMBIGUITIES["motor gain-supply pressure (f13, f25)"]
    folder = Path(args.out) / "ambiguities" / f"{a}-{b}"
    if not (folder / "design.csv").exists():
        return {}
    command = load_command_file(str(folder / "design.csv"))
    targets = with_probes(resolve_targets([], (), [(a, b)]), {a: va, b: vb})
    out = []
    for load in TEST_LOADS:
        for signals in (("xu",), ("xu", "p12")):
            start = time.perf_counter()
            pred = predict(command, targets, 2.0, signals=signals,
                           noise={s: SIGNALS[s][1] for s in signals}, pairs=[(a, b), (b, a)],
                           setting={"FRC": load} if load else None)
            out.append({"test_load": load, "signals": list(signals),
                        "separable_size": {a: pred.separable_size(a, b),
                                           b: pred.separable_size(b, a)},
                        "followed": pred.followed, "seconds": time.perf_counter() - start})
            print(f"test load {load:g} N, {'+'.join(signals)}: {a} from "
                  f"{pred.separable_size(a, b):.3g}, {b} from {pred.separable_size(b, a):.3g}; "
                  f"followed {pred.followed}", flush=True)
    return {"design": str(folder / "design.csv"), "pair": [a, b], "rows": out}


def _told_apart_in_two_seconds(args, a: str, b: str) -> bool:
    """Whether the pair's 2-s design (OUT/ambiguities/A-B) tells both members apart at their
    fitted sizes; a pair without one is tried under the wider limits."""
    saved = Path(args.out) / "ambiguities" / f"{a}-{b}" / "design.json"
    if not saved.exists():
        return False
    return bool(json.loads(saved.read_text())["pairs"][0]["told_apart_at_these_sizes"])


def loop_verdicts(command: Path, first, second, args, t_end: float = 2.0) -> dict:
    """The residual loop on ``--loop`` HF records per truth on the designed command. Each
    record's call is kept beside it (``NAME-K.json``) and reused by a later run, so a run cut
    short loses one record; ``--cached-only`` summarises the calls kept, running none."""
    import eha
    from eha.explain.effects import EFFECTS

    out = {}
    for truth, rival in ((first, second), (second, first)):
        name, dev = truth
        param = EFFECTS[name].tested
        calls = []
        for k in range(args.loop):
            path = command.parent / "loop" / f"{name}-{k}.csv"   # the pair's own folder
            kept = path.with_suffix(".json")
            if kept.exists():
                calls.append(_judged(json.loads(kept.read_text()), name))
                continue
            if args.cached_only:
                break
            value = EFFECTS[name].off[param] + dev
            df = eha.synthetic_record(str(command), {"BKL": 1e-4, "FDJ": 800.0, param: value},
                                      t_end=t_end, noise=1e-6, seed=5000 + k)
            path.parent.mkdir(parents=True, exist_ok=True)
            df.to_csv(path, index=False)
            start = time.perf_counter()
            res = eha.explain(eha.load(path), fit="BKL,FDJ", seed=k)
            found = [e for e in res.effects if e not in ("orifice_law", "flapper_dynamics")]
            rivals = [e["effect"] for e in res.not_excluded]
            call = {"record": k, "seed": 5000 + k, "truth": {param: value},
                    "found": found, "rivals": rivals,
                    "verdict": res.verdict, "seconds": time.perf_counter() - start}
            kept.write_text(json.dumps(call, indent=1))
            call = _judged(call, name)
            print(f"  {command.parent.name} truth {name} #{k}: {res.verdict[:100]}", flush=True)
            calls.append(call)
        out[name] = {"records": calls, "n": len(calls),
                     "truth_found": sum(name in c["found"] for c in calls),
                     "explained": sum(c["explained"] for c in calls),
                     "decisive_and_right": sum(c["decisive_and_right"] for c in calls),
                     "confidently_wrong": sum(c["confidently_wrong"] for c in calls)}
    return out


def _judged(call: dict, name: str) -> dict:
    """A record's call judged against its truth ``name``. *Decisive and right*: the truth is
    the only effect found, no rival is left standing and the record is explained (the
    verdict is not "partly explained" or "unexplained": a tentative finding on a residual
    above the noise decides nothing). *Confidently wrong*: an explained record, effects found,
    the truth not among them, and no rival named (a tentative finding in an unexplained
    verdict claims nothing)."""
    found, rivals = call["found"], call["rivals"]
    explained = call["verdict"].startswith("explained")
    return {**call, "explained": explained,
            "decisive_and_right": found == [name] and not rivals and explained,
            "confidently_wrong": explained and bool(found) and name not in found
            and not rivals}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench-design"))
    ap.add_argument("--design", help="reuse a design folder (design.json, design.csv)")
    ap.add_argument("--signals", default="xu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--library", default="chirp_1cm")
    ap.add_argument("--healthy", type=int, default=230)
    ap.add_argument("--calibration", type=int, default=30)
    ap.add_argument("--per-level", type=int, default=6)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--generations", type=int, default=20, help="of each ambiguity's design")
    ap.add_argument("--loop", type=int, default=0, help="HF records per truth and pair")
    ap.add_argument("--pairs", default="",
                    help="only these ambiguities, by folder name (A-B, comma-separated)")
    ap.add_argument("--cached-only", action="store_true",
                    help="with --loop: summarise the records' calls kept in the pairs' "
                         "folders, explain no new record")
    ap.add_argument("--reuse-designs", action="store_true",
                    help="take each ambiguity's design from its folder when it has one "
                         "(OUT/ambiguities/A-B/design.json) instead of searching again")
    ap.add_argument("--skip", default="", help="parts to skip: verify, verify-p12, "
                    "ambiguities, wider, test-loads")
    ap.add_argument("--json", action="store_true", help="write the result file")
    ap.add_argument("--merge", action="store_true",
                    help="keep the result file's parts not rerun (each part has its seconds)")
    ap.add_argument("--library-healthy", type=int, default=70,
                    help="healthy actuators of the library commands' campaign")
    ap.add_argument("--library-per-level", type=int, default=5,
                    help="actuators per fault level of the library commands' campaign")
    args = ap.parse_args()
    load = os.getloadavg()
    doc, folder = seven_faults(args)
    skip = set(args.skip.split(","))
    if "verify" not in skip:
        doc["verification"] = verification(args, folder)
    if "verify-p12" not in skip and "design_p12" in doc:
        doc["verification_p12"] = verification(args, folder, "design-p12")
    if "ambiguities" not in skip:
        doc["ambiguities"] = ambiguities(args)
    if "wider" not in skip:
        doc["wider"] = wider_limits(args)
    if "test-loads" not in skip:
        doc["test_loads"] = test_loads(args)
    doc["what"] = ("the seven-fault design at 1 s predicted and verified against library "
                   "commands; separating designs for the foreign ambiguities")
    print(json.dumps({k: v for k, v in doc.items() if k != "design"}, indent=1,
                     default=lambda v: None if isinstance(v, float) and math.isinf(v) else str(v))
          [:4000])
    if args.json:
        from _results import result_path

        if args.merge and result_path("design").exists():
            old = json.loads(result_path("design").read_text())
            old.pop("provenance", None)
            # an ambiguity not rerun (--pairs, --cached-only) keeps its entry
            if "ambiguities" in doc:
                doc["ambiguities"] = {**old.get("ambiguities", {}), **doc["ambiguities"]}
            doc = {**old, **doc}
        write_result("design", _finite(doc), load_start=load)


def _finite(value):
    """``value`` with every infinite number as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


if __name__ == "__main__":
    main()
