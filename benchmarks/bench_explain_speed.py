"""Wall time of `eha explain` on long and fast-sampled records (issue: residual loop on
real-world records, item 5: each <= 60 s on 2 cores).

Two records, each an HF run (BKL 0.1 mm, FDJ 800 N, a 1500 N undeclared load, 1 µm noise):

``steps_3s``   3 s of 12 random held steps within +-5 mm (a digital controller at 1 kHz);
``mixed_2khz`` the 1 s ``mixed`` command logged at 2 kHz (the HF's 1 kHz output interpolated
               to 2 kHz before the noise is added; the command sampled at 2 kHz).

Each is written to CSV and explained with the defaults through
:func:`eha.identification.measured.load`, as ``eha explain`` does. Prints the wall time, the
effects added, the load estimate, the number of fits and the machine's load average; ``--json
PATH`` writes them.

    python benchmarks/bench_explain_speed.py [--json]   # benchmarks/results/bench_explain_speed.json
"""

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402
from eha.models.commands import array_command, as_command  # noqa: E402
from eha.explain import explain  # noqa: E402
from eha.identification.measured import load, synthetic_record  # noqa: E402

TRUTH = {"BKL": 1e-4, "FDJ": 800.0, "FRC": 1500.0}


def steps_3s(seed: int = 0) -> pd.DataFrame:
    grid = np.arange(3001) * 1e-3
    rng = np.random.default_rng(seed)
    values = np.zeros(grid.size)
    for k in np.sort(rng.choice(np.arange(50, 2950), 12, replace=False)):
        values[k:] = rng.uniform(-5e-3, 5e-3)
    return synthetic_record(array_command(grid, values, "steps_3s", hold="zoh"), TRUTH,
                            t_end=3.0, noise=1e-6, seed=1)


def mixed_2khz(seed: int = 1) -> pd.DataFrame:
    base = synthetic_record("mixed", TRUTH, t_end=1.0, noise=0.0, seed=seed)
    t = np.arange(2001) * 5e-4
    rng = np.random.default_rng(seed)
    return pd.DataFrame({"t": t, "com": as_command("mixed").sample(t),
                         "xu": np.interp(t, base.t, base.xu) + rng.normal(0.0, 1e-6, t.size)})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", nargs="?", const=str(result_path("bench_explain_speed")),
                    default=None, metavar="PATH", help="write the figures (default: the result file)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, make in (("steps_3s", steps_3s), ("mixed_2khz", mixed_2khz)):
            path = Path(tmp) / f"{name}.csv"
            make().to_csv(path, index=False)
            fits = []
            load_before = os.getloadavg()[0]
            t0 = time.perf_counter()
            res = explain(load(path), on_progress=fits.append)
            wall = time.perf_counter() - t0
            frc = res.after.params.FRC if "external_load" in res.effects else None
            row = {"record": name, "seconds": wall, "fits": len(fits), "effects": res.effects,
                   "FRC": frc, "faults_after": res.faults_after,
                   "rmse_before": res.rmse_before, "rmse_after": res.rmse_after,
                   "verdict": res.verdict, "load_before": load_before,
                   "load_after": os.getloadavg()[0]}
            rows.append(row)
            print(f"{name:11s} {wall:6.1f} s  {len(fits):3d} fits  {', '.join(res.effects)}  "
                  f"FRC={frc if frc is None else round(frc)} N  "
                  f"{1e6 * res.rmse_before:.1f} -> {1e6 * res.rmse_after:.2f} µm  "
                  f"(load {load_before:.1f})", flush=True)
    if args.json:
        write_result(Path(args.json), {"benchmark": "bench_explain_speed", "truth": TRUTH,
                                       "records": rows})


if __name__ == "__main__":
    main()
