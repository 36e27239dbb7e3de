"""What the right model reads on the separating designs: bias and interval coverage.

The residual loop's verdicts on records made on the separating designs
(``validation/design.py --loop``) judge its search: which effect it names. This study
judges the reading that follows, apart from the search: on the same records (each pair's
2-s design in ``OUT/ambiguities/A-B``, each member as the truth at its fitted size, BKL 1e-4,
1 µm noise, seeds 5000+k as there), the *right* model -- the HF's structure (orifice law,
flapper dynamics) and the true effect -- is fitted to the whole record by least squares
from the truth (``eha.identification.fdi.identify(method="lm")`` through the loop's
``refit``), and the 90 % interval the loop would report at that estimate (HAC, widening, the
loop's model-form floor :data:`eha.identification.intervals.LOOP_MODEL_FORM`), without and
with the loop's replicate term (:mod:`eha.explain.replicates`: the spread of refits to HF
re-simulations of the estimate), is checked against the truth. The jack friction is declared at 800 N (the loop records') and at 200 N
(the thesis' healthy bound): a small effect read beside a large friction is where the
reading is hardest.

    python validation/design_reading.py --out results/bench-design --records 5 --json

One record takes 10-30 s with its replicates (one core); 10 truths x 2 frictions x 5 records
about 30-50 min.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper
from _results import ROOT, write_result  # noqa: E402

from design import AMBIGUITIES  # noqa: E402
from explain_coverage import LEVEL, covered, model_of, spreads  # noqa: E402

#: The declared jack frictions of the records [N].
FRICTIONS = (800.0, 200.0)
STRUCTURE = ("orifice_law", "flapper_dynamics")


def read_one(command: Path, name: str, dev: float, friction: float, seed: int,
             tmp: Path) -> dict:
    """The right model's reading of effect ``name`` (deviation ``dev`` from off) on one HF
    record made on ``command``."""
    import eha
    from eha.explain import LoopSettings, ResidualLoop
    from eha.explain.effects import EFFECTS
    from eha.explain.replicates import replicate_spread
    from eha.identification.intervals import LOOP_MODEL_FORM

    effect = EFFECTS[name]
    param = effect.tested
    value = effect.off[param] + dev
    truth = {"BKL": 1e-4, "FDJ": friction, param: value}
    df = eha.synthetic_record(str(command), truth, t_end=2.0, noise=1e-6, seed=seed)
    path = tmp / "record.csv"
    df.to_csv(path, index=False)
    loop = ResidualLoop.on(eha.load(path), settings=LoopSettings())
    values = {k: getattr(loop.problem.base, k) for k in loop.bounds}
    values.update(truth)
    start, bounds = model_of(loop, {**{s: {} for s in STRUCTURE}, name: {}}, values)
    fitted = loop.fitter.refit(start, bounds, "right model", method="lm", whole=True)
    row = spreads(loop, fitted, bounds)[param]
    # the loop's replicate term (eha.explain.replicates), as the loop adds it
    spread, _ = replicate_spread(loop, fitted, bounds, [*loop.bounds, *effect.params],
                                 LoopSettings().interval_replicates)
    widened = {**row, "base": {**row["base"], "abs": float(np.hypot(row["base"]["abs"],
                                                                    spread.get(param, 0.0)))}}
    return {"seed": seed, "friction": friction, "param": param, "truth": value,
            "read": row["value"], "error": row["value"] - value,
            "rel_error": (row["value"] - value) / value if value else None,
            "error_of_deviation": (row["value"] - value) / dev,
            "hac_std": row["hac"], "residual_um": 1e6 * row["residual"],
            "covered_without_replicates": bool(covered(row, value, LOOP_MODEL_FORM.rel)),
            "replicate_rms": spread.get(param),
            "covered": bool(covered(widened, value, LOOP_MODEL_FORM.rel))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench-design"),
                    help="the folder of validation/design.py (its ambiguities/A-B designs)")
    ap.add_argument("--records", type=int, default=5, help="records per truth and friction")
    ap.add_argument("--json", action="store_true", help="write the result file")
    args = ap.parse_args()
    load = os.getloadavg()
    t0 = time.perf_counter()
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, members in AMBIGUITIES.items():
            a, b = members[0][0], members[1][0]
            command = Path(args.out) / "ambiguities" / f"{a}-{b}" / "design.csv"
            if not command.exists():
                print(f"{label}: no design in {command.parent}, skipped", flush=True)
                continue
            for name, dev in members:
                for friction in FRICTIONS:
                    rows = [read_one(command, name, dev, friction, 5000 + k, Path(tmp))
                            for k in range(args.records)]
                    rel = [r["rel_error"] for r in rows if r["rel_error"] is not None]
                    of_dev = [r["error_of_deviation"] for r in rows]
                    entry = {"design": f"{a}-{b}", "truth": name, "friction": friction,
                             "records": rows, "covered": sum(r["covered"] for r in rows),
                             "covered_without_replicates": sum(
                                 r["covered_without_replicates"] for r in rows),
                             "n": len(rows),
                             "rel_error_mean": float(np.mean(rel)) if rel else None,
                             "rel_error_range": [float(min(rel)), float(max(rel))]
                             if rel else None,
                             "error_of_deviation_range": [float(min(of_dev)),
                                                          float(max(of_dev))]}
                    out[f"{a}-{b}: {name} @ FDJ {friction:g} N"] = entry
                    print(f"{a}-{b}: {name} @ FDJ {friction:g} N: covered "
                          f"{entry['covered_without_replicates']}/{len(rows)} without the "
                          f"replicates, {entry['covered']}/{len(rows)} with them, error {100 * entry['rel_error_mean']:+.1f} % "
                          f"[{100 * min(rel):+.1f}, {100 * max(rel):+.1f}]; of the deviation "
                          f"[{100 * min(of_dev):+.0f}, {100 * max(of_dev):+.0f}] %", flush=True)
    doc = {"what": "the right model's reading of each ambiguity's truth on its 2-s design: "
                   f"error and {LEVEL:.0%} interval coverage",
           "level": LEVEL, "records_per_case": args.records, "cases": out,
           "seconds": time.perf_counter() - t0}
    if args.json:
        write_result("design_reading", doc, load_start=load)


if __name__ == "__main__":
    main()
