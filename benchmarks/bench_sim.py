"""Milliseconds per simulated second of the HF and LF kernels on every preset command.

One core (NUMBA_NUM_THREADS=1), after JIT warm-up, median of several runs. Two figures per
model and command:

* ``kernel``: the numba integration alone, the command already sampled on the step grid (what
  a fault identification pays per evaluation: it samples the command once);
* ``end_to_end``: the whole ``simulate()`` call (parameter checks, command sampling, dither,
  kernel, sensor stage, Trace).

Usage: ``python benchmarks/bench_sim.py [--json] [--repeat N] [--t-end S]``.
``--json`` prints ``{"hf": {"mixed": ms, ...}, "lf": {...}, "end_to_end": {...}}`` (kernel
figures at the top level).
"""

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import write_result  # noqa: E402

import numpy as np  # noqa: E402

from eha.models.commands import PRESETS  # noqa: E402
from eha.models import OUTPUTS  # noqa: E402
from eha.models.hf import dither_samples, run_hf  # noqa: E402
from eha.models.lf import run_lf  # noqa: E402
from eha.models.params import resolve  # noqa: E402
from eha.models.simulate import command_on_grid, grid, simulate  # noqa: E402


def _median_ms(fn, repeat):
    fn()  # warm-up (JIT or cache load)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def measure(repeat=15, t_end=1.0):
    kernel = {"hf": {}, "lf": {}}
    end_to_end = {"hf": {}, "lf": {}}
    for model in ("hf", "lf"):
        p = resolve(model)
        spo, n_out, ts = grid(p, t_end)
        vec = p.to_array()
        out = np.empty((n_out, len(OUTPUTS)))
        dith = dither_samples(p.dither_ma if model == "hf" else 0.0, n_out - 1, 0)
        for name in PRESETS:
            com = command_on_grid(name, ts)
            if model == "hf":
                def run():
                    run_hf(vec, com, dith, spo, out)
            else:
                def run():
                    run_lf(vec, com, spo, out)
            kernel[model][name] = _median_ms(run, repeat) / t_end
            end_to_end[model][name] = _median_ms(
                lambda: simulate(model, name, t_end=t_end), repeat) / t_end
    return kernel, end_to_end


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true",
                    help="print JSON only and write it to the result file, "
                         "benchmarks/results/bench_sim.json (replacing it)")
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--t-end", type=float, default=1.0)
    args = ap.parse_args()
    kernel, e2e = measure(args.repeat, args.t_end)
    if args.json:
        figures = {**kernel, "end_to_end": e2e}
        print(json.dumps(figures, indent=1))
        write_result("bench_sim", {"settings": {"repeat": args.repeat, "t_end": args.t_end},
                                   "ms_per_simulated_second": figures})
        return
    print(f"ms per simulated second (median of {args.repeat}, one core, t_end={args.t_end} s)")
    print(f"{'command':<10} {'HF kernel':>10} {'LF kernel':>10} {'HF simulate':>12} "
          f"{'LF simulate':>12}")
    for name in PRESETS:
        print(f"{name:<10} {kernel['hf'][name]:>10.2f} {kernel['lf'][name]:>10.2f} "
              f"{e2e['hf'][name]:>12.2f} {e2e['lf'][name]:>12.2f}")
    print(f"targets on mixed: HF <= 3 ms (measured {kernel['hf']['mixed']:.2f}), "
          f"LF <= 1.5 ms (measured {kernel['lf']['mixed']:.2f})")


if __name__ == "__main__":
    main()
