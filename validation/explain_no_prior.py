"""`eha explain` with default settings (no prior) on HF records with one undeclared effect.

Prints, per command and injected effect: the steps added (parameters as estimated in the final
model), RMSE before -> after and the wall time. The table "Without a prior" in docs/explain.md
comes from this script (population 20, seed 0, 1 µm noise).

    python validation/explain_no_prior.py [--commands mixed,test] [--cases load,bias]
"""

import argparse
import tempfile
import time
from pathlib import Path

from eha.explain import explain
from eha.identification.measured import load, synthetic_record

FAULTS = {"BKL": 1e-4, "FDJ": 800.0}
CASES = {
    "nominal": {},
    "load": {"FRC": 2000.0},
    "offset": {"Ofs": 0.3},
    "hinge": {"Kaer": 1.5e5},
    "leak": {"Clk": 5e-12},
    "bias": {"sensor_bias": 1e-4},
}
T_END = {"test": 0.6}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default="mixed,test")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--pop", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for command in args.commands.split(","):
            for name in args.cases.split(","):
                path = Path(tmp) / f"{command}_{name}.csv"
                synthetic_record(command, {**FAULTS, **CASES[name]},
                                 t_end=T_END.get(command, 1.0), noise=1e-6,
                                 seed=1).to_csv(path, index=False)
                t0 = time.perf_counter()
                doc = explain(load(path), pop=args.pop, seed=args.seed).to_json()
                steps = ", ".join(
                    s["effect"] + ("" if not s["params"] else " (" + ", ".join(
                        f"{k}={v:.4g}" for k, v in s["params"].items()) + ")")
                    for s in doc["steps"]) or "(nothing)"
                print(f"{command:6s} {name:8s} {1e6 * doc['rmse_before']:7.3g} -> "
                      f"{1e6 * doc['rmse_after']:6.3g} um  {time.perf_counter() - t0:5.1f} s  "
                      f"{steps}", flush=True)


if __name__ == "__main__":
    main()
