"""Wall time of the residual loop (eha explain) on synthetic records; prints a table.

Usage: python benchmarks/bench_explain.py [--pop 20] [--candidates 6] [--t-end 1.0]

Records: HF with BKL = 0.1 mm, FDJ = 800 N, 1 µm noise; "nominal" on the mixed command (the
loop finds the structural HF-LF differences), "load" (FRC = 2000 N) on the test command with the
HF structure as prior.
"""

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import write_result  # noqa: E402
from eha.explain import augmented_base, explain  # noqa: E402
from eha.identification.measured import from_arrays, synthetic_record  # noqa: E402

PRIOR = [{"effect": "orifice_law", "params": {}},
         {"effect": "flapper_dynamics", "params": {"SNF": 2513.0, "ZF": 0.6}}]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pop", type=int, default=20)
    ap.add_argument("--candidates", type=int, default=6)
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--json", action="store_true",
                    help="write the figures to benchmarks/results/bench_explain.json "
                         "(replacing it)")
    args = ap.parse_args()
    rows = []
    cases = [("nominal", "mixed", {}, None), ("load", "test", {"FRC": 2000.0}, PRIOR)]
    print(f"pop {args.pop}, candidates {args.candidates}, record {args.t_end:g} s at 1 kHz")
    print(f"{'record':8} {'seconds':>8} {'fits':>5} {'s/fit':>6} {'rounds':>6}  "
          f"{'RMSE before -> after [µm]':>26}  effects")
    for name, command, overrides, prior in cases:
        df = synthetic_record(command, {"BKL": 1e-4, "FDJ": 800.0, **overrides},
                              t_end=args.t_end, noise=1e-6, seed=1)
        data = from_arrays(df.t, df.com, df.xu, source=name)
        fits = []
        start = time.perf_counter()
        res = explain(data, base=augmented_base(prior) if prior else None, pop=args.pop,
                      candidates=args.candidates, seed=0, on_progress=fits.append)
        seconds = time.perf_counter() - start
        print(f"{name:8} {seconds:8.1f} {len(fits):5d} {seconds / len(fits):6.2f} "
              f"{len(res.rounds):6d}  {1e6 * res.rmse_before:11.3g} -> "
              f"{1e6 * res.rmse_after:<11.3g}  {', '.join(res.effects) or '-'}")
        rows.append({"record": name, "command": command, "seconds": seconds, "fits": len(fits),
                     "rounds": len(res.rounds), "rmse_before": res.rmse_before,
                     "rmse_after": res.rmse_after, "effects": res.effects})
    if args.json:
        write_result("bench_explain", {"settings": {"pop": args.pop, "candidates":
                                                    args.candidates, "t_end": args.t_end},
                                       "records": rows})


if __name__ == "__main__":
    main()
