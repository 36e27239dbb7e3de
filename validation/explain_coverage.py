"""Coverage of the residual loop's 90 % intervals, and the model-form floor that restores it.

The loop's final model (`eha explain`) reports an interval for every fitted parameter (the
declared faults and each added effect's): the HAC sandwich at the final estimate, widened
when the residual is far above the noise (:mod:`eha.identification.intervals`). On the
several-effects bench those intervals under-cover: the misses are 1-3 half-widths at a few tenths
of a percent to a few percent of bias, the bias of a model (the LF with the effects) that is not
the HF. This bench measures that bias where the truth is known and calibrates one relative floor,
added in quadrature to every parameter of a model the loop built
(:data:`eha.identification.intervals.LOOP_MODEL_FORM`).

``--calibrate``: on the records of :mod:`explain_multi` drawn with *other* seed blocks
(``--seeds``, default 1,2; the bench's own records are block 0), the right model -- the HF's
structure (orifice law, flapper dynamics) and the injected effects -- is fitted to the whole
record by least squares (``eha.identification.fdi.identify(method="lm")``) from the truth (the
flapper at its physical values). At that best fit of the right model the HAC standard deviations
are taken (:func:`eha.identification.fdi.intervals_at`, no floor), and the smallest relative floor
``rel`` is found for which the 90 % intervals cover the truth on at least 90 % of the (record,
parameter) pairs. What it measures is the model-form bias, not the loop's search (which the final
least-squares estimates make small on explained records).

``--evaluate PATH``: re-scores a :mod:`explain_multi` JSON (the loop's own runs): the
coverage of the injected truth by the intervals every record's final model reports (floor
included), all records and explained ones alone; where the JSON keeps every fitted value
(``params_after``) also recomputed at those estimates without and with the floor now in
:data:`eha.identification.intervals.LOOP_MODEL_FORM`.

    python validation/explain_coverage.py --calibrate --seeds 1,2 --json cal.json
    python validation/explain_coverage.py --evaluate validation/results/explain_multi.json --json

One calibration record takes 1-5 s (one core): 24 records about 1-2 min.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

from explain_fp import P12_NOISE, clean, p12_column, provenance  # noqa: E402
from explain_multi import (FAULTS, RECORDS, STRUCTURAL, T_END, injected,  # noqa: E402
                                 make_command)

LEVEL = 0.9
#: Floors tried (relative, fraction of the estimate).
FLOOR_GRID = np.round(np.arange(0.0, 0.2001, 0.0025), 4)


def build(i: int, block: int, tmp: Path):
    """Record ``i`` of explain_multi drawn with seed block ``block``: (data, truth)."""
    from eha.identification.measured import load, synthetic_record

    name, combo, command = RECORDS[i]
    seed = 1000 * block + i
    inj = injected(combo)
    truth = {**FAULTS, **{p: v for ps in inj.values() for p, v in ps.items()}}
    cmd, _ = make_command(command, seed)
    df = synthetic_record(cmd, truth, t_end=T_END.get(command, 1.0), noise=1e-6, seed=seed,
                          command_hold="auto")
    df = p12_column(df, P12_NOISE, seed)
    path = tmp / f"{block}_{i}.csv"
    df.to_csv(path, index=False)
    return load(path), inj, truth


def model_of(loop, effects: dict[str, dict[str, float]], values: dict[str, float]):
    """The loop's base with ``effects`` on at ``values`` (the structure at its probe) and the
    faults at ``values``: (params, bounds of every fitted parameter)."""
    from eha.explain.effects import EFFECTS

    params, bounds = loop.problem.base, dict(loop.bounds)
    for name in effects:
        effect = EFFECTS[name]
        params = effect.switch_on(params, {p: values.get(p, effect.probe.get(p))
                                           for p in effect.params})
        bounds.update(effect.bounds)
    return params.replace(**{k: values[k] for k in loop.bounds}), bounds


def spreads(loop, params, bounds) -> dict[str, dict[str, float]]:
    """HAC std, widening and the base model-form term of every fitted parameter at ``params``
    (no floor of the loop)."""
    from eha.identification.fdi import intervals_at
    from eha.identification.problem import model_form_of
    from eha.identification.intervals import MODEL_FORM, ModelForm, inflation, noise_reference

    data = loop.problem.data
    iv = intervals_at(data.xu, data.command, params, bounds, level=LEVEL, noise=loop.problem.noise,
                      recorded_start=loop.problem.record.recorded_start, t_end=data.t_end)
    widen = inflation(iv.residual_rmse / noise_reference(loop.problem.noise, data.xu))
    base = MODEL_FORM.get(model_form_of(params), {})
    return {n: {"value": float(getattr(params, n)), "hac": iv.hac_std[n], "widen": widen,
                "base": base.get(n, ModelForm()).__dict__, "residual": iv.residual_rmse}
            for n in bounds}


def covered(row: dict, truth: float, rel: float) -> bool:
    from eha.identification.intervals import ModelForm, loop_terms, normal_quantile, total_std

    term = loop_terms({"p": ModelForm(**row["base"])}, ["p"], ModelForm(rel=rel))["p"]
    s = total_std(row["hac"], row["value"], term, row["widen"])
    return abs(row["value"] - truth) <= normal_quantile(LEVEL) * s


def calibrate(args) -> dict:
    from eha.explain import LoopSettings, ResidualLoop

    blocks = [int(b) for b in args.seeds.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for block in blocks:
            for i, (name, _, _) in enumerate(RECORDS):
                t0 = time.perf_counter()
                data, inj, truth = build(i, block, Path(tmp))
                loop = ResidualLoop.on(data, settings=LoopSettings())
                effects = {**{s: {} for s in STRUCTURAL}, **inj}
                start, bounds = model_of(loop, effects, truth)
                fitted = loop.fitter.refit(start, bounds, "right model", method="lm", whole=True)
                sp = spreads(loop, fitted, bounds)
                for p, t in truth.items():
                    rows.append({"record": name, "block": block, "param": p, "truth": t,
                                 **sp[p], "rel_err": (sp[p]["value"] - t) / t})
                worst = max(abs(r["rel_err"]) for r in rows[-len(truth):])
                print(f"{name:34} block {block}  residual {1e6 * sp['BKL']['residual']:5.2f} µm"
                      f"  worst error {100 * worst:5.1f} %  {time.perf_counter() - t0:4.1f} s",
                      flush=True)
    table = []
    for rel in FLOOR_GRID:
        cov = float(np.mean([covered(r, r["truth"], rel) for r in rows]))
        table.append({"rel": float(rel), "coverage": cov})
    chosen = next((t for t in table if t["coverage"] >= LEVEL), table[-1])
    print(f"\n{len(rows)} (record, parameter) pairs from blocks {blocks}")
    for t in table:
        if t["rel"] in (0.0, chosen["rel"]) or t is table[-1]:
            print(f"  floor {100 * t['rel']:5.2f} %: coverage {100 * t['coverage']:5.1f} %")
    print(f"smallest floor with coverage >= {LEVEL:.0%}: {100 * chosen['rel']:.2f} %")
    return {"mode": "calibrate", "blocks": blocks, "level": LEVEL, "pairs": rows,
            "table": table, "chosen": chosen}


def evaluate(args) -> dict:
    """Coverage of the intervals each record's final model *reports* (``explain.json``'s
    ``intervals``, floor included: what a user reads), and, where the record keeps every
    fitted value (``params_after``: the flow-gain spread GQ too), of the intervals recomputed
    at those estimates without and with the floor."""
    from eha.explain import LoopSettings, ResidualLoop
    from eha.identification.intervals import LOOP_MODEL_FORM

    doc = json.loads(Path(args.evaluate).read_text())
    rel = LOOP_MODEL_FORM.rel
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in doc["records"]:
            block = r["seed"] // 1000
            data, inj, truth = build(r["i"], block, Path(tmp))
            reported = (r.get("to_json") or {}).get("intervals") or {}
            estimates = {**r["final_params"], **r["faults_after"]}
            sp = {}
            if r.get("params_after"):
                loop = ResidualLoop.on(data, settings=LoopSettings())
                params, bounds = model_of(loop, {e: {} for e in r["effects"]},
                                          r["params_after"])
                sp = spreads(loop, params, bounds)
            for p, t in truth.items():
                if p not in reported:
                    continue            # an effect the loop did not find: no interval
                lo, hi = reported[p]
                rows.append({"record": r["name"], "param": p, "truth": t,
                             "unexplained": r["unexplained"], "reported": lo <= t <= hi,
                             "without": covered(sp[p], t, 0.0) if p in sp else None,
                             "with": covered(sp[p], t, rel) if p in sp else None,
                             "rel_err": (estimates.get(p, 0.5 * (lo + hi)) - t) / t})
    out = {}
    for label, sel in (("all", rows), ("explained", [x for x in rows if not x["unexplained"]])):
        out[label] = {"pairs": len(sel), "reported": sum(x["reported"] for x in sel)}
        text = f"{label:10} {len(sel):3d} pairs: reported intervals cover {out[label]['reported']}"
        if sel and all(x["without"] is not None for x in sel):
            out[label].update(without_floor=sum(x["without"] for x in sel),
                              with_floor=sum(x["with"] for x in sel))
            text += (f"; recomputed: {out[label]['without_floor']} without the floor, "
                     f"{out[label]['with_floor']} with it ({100 * rel:.2f} %)")
        print(text)
    for x in rows:
        if not x["reported"]:
            print(f"  miss: {x['record']:34} {x['param']:12} error {100 * x['rel_err']:+.2f} %")
    return {"mode": "evaluate", "source": args.evaluate, "floor_rel": rel, "level": LEVEL,
            "summary": out, "pairs": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibrate", action="store_true", help="measure the floor")
    ap.add_argument("--seeds", default="1,2", help="seed blocks of the calibration records")
    ap.add_argument("--evaluate", default=None, metavar="PATH",
                    help="re-score a explain_multi JSON with and without the floor")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_coverage")),
                    default=None, metavar="PATH",
                    help="write the figures (default: the result file; a part not run now is "
                         "kept from it)")
    args = ap.parse_args()
    if not args.calibrate and not args.evaluate:
        ap.error("give --calibrate and/or --evaluate PATH")
    out = {"benchmark": "explain_coverage", "provenance": provenance(sys.argv)}
    if args.calibrate:
        out["calibration"] = calibrate(args)
    if args.evaluate:
        out["evaluation"] = evaluate(args)
    if args.json:
        old = Path(args.json)
        if old.is_file() and old.resolve() == result_path("explain_coverage").resolve():
            kept = json.loads(old.read_text())
            for part in ("calibration", "evaluation"):
                if part not in out and part in kept:
                    out[part] = kept[part]
                    out.setdefault("kept_from_previous", []).append(part)
        write_result(old, clean(out))


if __name__ == "__main__":
    main()
