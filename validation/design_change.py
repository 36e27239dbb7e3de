"""Test design under a check of the change from the actuator's own earlier record: can a 1-s
command within +-1 cm reach half the best library command's minimum detectable size for four
of the seven faults, when the fleet's scatter and the LF's model-form error are out of the
null (docs/design.md, "Floors that no command moves")?

    python validation/design_change.py --json

The check studied here is the plainest one that keeps its false-alarm rate: the new record
minus the same actuator's earlier record on the same command (its acceptance test; same
actuator, other sensor noise and HF dither), projected on each fault's LF signature (the
LF model's change of the position per unit of the fault, at nominal parameters), is a linear
estimate of the fault's change, Gaussian under no change (noise and dither only). Thresholds
(:func:`thresholds`): per fault a normal prediction bound at alpha/7 with Student's t from
``--calibration`` healthy pairs, two-sided for the offset; the false-alarm rate on
``--held-out`` other healthy pairs; a detected record is isolated to the alarming
fault whose unit signature the difference projects on most (the generalized likelihood ratio
of one fault under white noise).

Parts:

1. The library commands (chirp_1cm, mixed, test, sine), 1 s each, and a pymoo search over
   eha's design family (:mod:`eha.design.family`, ``--max-rate`` up to the family's largest)
   for the command with the most faults at <= 0.5x the best library command's predicted
   size (prediction: threshold and spread of the estimate over the healthy pairs, over its
   gain at a probe).
2. Measured on fresh seeds for the found command and every library command: each fault at
   the same levels on every command (sqrt(2) steps from 0.25 to 8 times the found command's
   prediction, ``--per-level`` actuators each): minimum detectable size (P_D >= 0.95), isolation, false alarms.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from _results import write_result  # noqa: E402

from eha.design.family import Limits, command_samples, decode, genes, n_genes  # noqa: E402
from eha.health.detection import statistic  # noqa: E402
from eha.identification.healthy import draw_actuator  # noqa: E402
from eha.identification.synthetic import synthetic_record  # noqa: E402
from eha.models import OUTPUTS  # noqa: E402
from eha.models.commands import array_command, as_command  # noqa: E402
from eha.models.faults import FAULTS  # noqa: E402
from eha.models.simulate import simulate_lf_rows  # noqa: E402

LIBRARY = ("chirp_1cm", "mixed", "test", "sine")
#: LF signature steps (changes from healthy, in the direction of degradation).
PROBE = {"BKL": 5e-6, "FDJ": 50.0, "GM": -5e-4, "Kintas": 0.1, "Clk": 5e-13, "Ofs": 0.01,
         "FSS": 5.0}
NAMES = tuple(PROBE)
Z95 = 1.6449
#: Seed ranges: search pairs, calibration pairs, held-out pairs, faulty actuators.
SEARCH0, CAL0, HELD0, FAULT0 = 100_000, 200_000, 300_000, 400_000
#: The earlier record of an actuator is recorded with noise and dither seed + SHIFT.
SHIFT = 1_000_000


def faulted(hf: dict, fault: str | None, change: float) -> dict:
    """Actuator ``hf`` with ``fault`` changed by ``change`` from its own value (within the
    fault's bounds)."""
    if not fault:
        return dict(hf)
    f = FAULTS[fault]
    return {**hf, fault: min(max(hf.get(fault, f.healthy) + change, f.bounds[0]), f.bounds[1])}


class Check:
    """The change check on one command: signatures, estimates of a pair, thresholds."""

    def __init__(self, command, t_end: float, noise: float):
        self.command, self.t_end, self.noise = as_command(command), t_end, noise
        params = [{}] + [{n: FAULTS[n].healthy + PROBE[n]} for n in NAMES]
        y = simulate_lf_rows(params, self.command, t_end)[:, 1:, OUTPUTS.index("xu")]
        self.S = np.stack([(y[i + 1] - y[0]) / PROBE[n] for i, n in enumerate(NAMES)])
        self.norm2 = (self.S ** 2).sum(axis=1)
        self.unit = self.S / np.sqrt(self.norm2)[:, None]
        self._healthy: dict[int, np.ndarray] = {}      # new records of healthy actuators

    def record(self, hf: dict, seed: int) -> np.ndarray:
        return synthetic_record(self.command, hf, t_end=self.t_end, noise=self.noise,
                                seed=seed)["xu"].to_numpy()[1:]

    def pair(self, seed: int, fault: str | None = None, change: float = 0.0) -> np.ndarray:
        """The difference new - earlier of actuator ``seed`` (a fault ``change`` from its own
        value in the new record)."""
        hf = draw_actuator(seed)
        return self.record(faulted(hf, fault, change), seed) - self.record(hf, seed + SHIFT)

    def estimate(self, r: np.ndarray) -> np.ndarray:
        return (self.S @ r) / self.norm2

    def stats(self, r: np.ndarray) -> np.ndarray:
        a = self.estimate(r)
        return np.array([statistic(n, FAULTS[n].healthy + a[i]) for i, n in enumerate(NAMES)])

    def calibrate(self, seeds, alpha: float) -> dict:
        return thresholds(np.array([self.estimate(self.pair(s)) for s in seeds]), alpha)

    def gain(self, fault: str, change: float, seeds) -> float:
        """The estimate's change per unit of a fault's change ``change`` (signed), noise-free:
        the new record with the fault minus the one without (same seed: noise and dither
        cancel), mean over the actuators of ``seeds``."""
        i, out = NAMES.index(fault), []
        for s in seeds:
            hf = draw_actuator(s)
            if s not in self._healthy:
                self._healthy[s] = self.record(hf, s)
            r = self.record(faulted(hf, fault, change), s) - self._healthy[s]
            out.append(self.estimate(r)[i] / change)
        return float(np.mean(out))

    def predicted(self, cal: dict, seeds) -> dict[str, float]:
        """Per fault, the change detected at P_D 0.95: the threshold's margin over the healthy
        pairs' mean plus z(0.95) of their stds, over the estimate's gain (:meth:`gain`), read
        at the probe and again at the size so predicted (faults whose response is not linear
        in their size: the motor gain on a fast command)."""
        out = {}
        for n in NAMES:
            need = cal["thresholds"][n] - cal["mean"][n] + Z95 * cal["std"][n]
            g = self.gain(n, PROBE[n], seeds)
            if g > 0:
                g = self.gain(n, math.copysign(need / g, PROBE[n]), seeds)
            out[n] = float(need / g) if g > 0 else math.inf
        return out

    def declared(self, r: np.ndarray, thr: dict) -> str:
        st = self.stats(r)
        alarmed = [i for i, n in enumerate(NAMES) if st[i] > thr[n]]
        if not alarmed:
            return "none"
        proj = np.abs(self.unit @ r)
        return NAMES[max(alarmed, key=lambda i: proj[i])]


def thresholds(est: np.ndarray, alpha: float) -> dict:
    """Per fault, the threshold of the statistic from the healthy pairs' estimates ``est``
    (one row per pair): the normal prediction bound of probability ``alpha / 7`` for one more
    pair with Student's t (the std is estimated from the pairs), two-sided for the offset
    (whose statistic is the absolute change: the fleet rule's ``mean + z std`` of the absolute
    value under-covers a folded normal, measured here at 14 of 200 held-out pairs)."""
    from scipy.stats import t as student

    n = est.shape[0]
    thr, std, means = {}, {}, {}
    for i, name in enumerate(NAMES):
        d = est[:, i] * (1.0 if FAULTS[name].direction == 0 else FAULTS[name].direction)
        mean, sd = float(d.mean()), float(d.std(ddof=1))
        two = FAULTS[name].direction == 0
        q = float(student.ppf(1.0 - alpha / len(NAMES) / (2.0 if two else 1.0), n - 1))
        half = q * sd * math.sqrt(1.0 + 1.0 / n)
        thr[name] = max(abs(mean - half), abs(mean + half)) if two else mean + half
        std[name], means[name] = sd, mean
    return {"thresholds": thr, "std": std, "mean": means}


def prediction(command, args, n_pairs: int) -> dict[str, float]:
    chk = Check(command, 1.0, args.noise)
    seeds = list(range(SEARCH0, SEARCH0 + n_pairs))
    cal = chk.calibrate(seeds, args.alpha)
    return chk.predicted(cal, seeds[:2])


def search(args, library: dict[str, dict[str, float]]) -> dict:
    """A GA over the design family: most faults at <= 0.5x the best library prediction, then
    the mean log2 ratio."""
    from pymoo.algorithms.soo.nonconvex.ga import GA
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize

    limits = Limits(1.0, 0.01, args.max_rate, 20.0)
    # the library predicted as the candidates are (the same healthy pairs)
    library = {c: prediction(c, args, args.search_pairs) for c in library}
    best_lib = {n: min(p[n] for p in library.values()) for n in NAMES}
    seen: list = []

    def objective(x: np.ndarray) -> float:
        t, com = command_samples(x, limits)
        pred = prediction(array_command(t, com, name="candidate"), args, args.search_pairs)
        ratio = np.array([pred[n] / best_lib[n] for n in NAMES])
        ratio = np.where(np.isfinite(ratio) & (ratio > 0), ratio, 1e3)
        value = -float(np.sum(ratio <= 0.5)) + 0.1 * float(np.mean(np.log2(ratio)))
        seen.append((value, x.copy(), pred))
        return value

    class Family(Problem):
        def __init__(self):
            super().__init__(n_var=n_genes(), n_obj=1, xl=0.0, xu=1.0)

        def _evaluate(self, X, out, *a, **k):
            out["F"] = np.array([[objective(x)] for x in X])
            print(f"  {len(seen)} candidates, best {min(s[0] for s in seen):.3f}", flush=True)

    # the population starts with +-1 cm sines and triangles (the library's strongest shape
    # under this check) and random members of the family
    rng = np.random.default_rng(args.seed)
    start = rng.random((args.pop, n_genes()))
    starts = [genes([{"shape": shape, "share": 1.0, "amplitude": 1.0, "frequency": f}], limits)
              for shape in ("sine", "triangle") for f in (3.0, 5.0, 8.0)]
    start[:min(len(starts), args.pop)] = starts[:args.pop]
    minimize(Family(), GA(pop_size=args.pop, sampling=start), ("n_gen", args.generations), seed=args.seed,
             verbose=False)
    value, x, pred = min(seen, key=lambda s: s[0])
    return {"value": value, "genes": x.tolist(), "segments": decode(x, limits),
            "predicted": pred, "limits": limits.to_dict(), "candidates": len(seen)}


def measure(command, levels: dict[str, list[float]], args) -> dict:
    from scipy.stats import kurtosis

    chk = Check(command, 1.0, args.noise)
    cal = chk.calibrate(list(range(CAL0, CAL0 + args.calibration)), args.alpha)
    thr = cal["thresholds"]
    held = [chk.pair(s) for s in range(HELD0, HELD0 + args.held_out)]
    alarms = sum(chk.declared(r, thr) != "none" for r in held)
    # how normal the healthy estimates are (the thresholds assume it)
    excess = kurtosis(np.array([chk.estimate(r) for r in held]), axis=0)
    faults = {}
    for n in NAMES:
        sign = -1.0 if FAULTS[n].direction < 0 else 1.0
        rows = []
        for k, size in enumerate(levels[n]):
            det = iso = 0
            for j in range(args.per_level):
                seed = FAULT0 + 10_000 * NAMES.index(n) + 100 * k + j
                r = chk.pair(seed, n, sign * size)
                det += int(chk.stats(r)[NAMES.index(n)] > thr[n])
                iso += int(chk.declared(r, thr) == n)
            lo, hi = FAULTS[n].bounds
            rows.append({"size": size, "p_detect": det / args.per_level,
                         "isolated": iso / args.per_level, "n": args.per_level,
                         "clipped": not lo <= FAULTS[n].healthy + sign * size <= hi})
        # the smallest level from which every larger one is detected in >= 95 % of its records
        # (with 9 a level: all of them)
        ok = [e["size"] for k, e in enumerate(rows)
              if all(o["p_detect"] >= 0.95 for o in rows[k:])]
        faults[n] = {"levels": rows, "min_detectable": min(ok) if ok else None}
    from eha.design.verify import upper_bound

    return {"thresholds": thr, "healthy_excess_kurtosis": dict(zip(NAMES, excess.tolist())),
            "false_alarms": {"n": len(held), "alarms": int(alarms),
                                                "rate": alarms / len(held),
                                                "upper_95": upper_bound(alarms, len(held))},
            "faults": faults}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--alpha", type=float, default=0.01)
    ap.add_argument("--noise", type=float, default=1e-6)
    ap.add_argument("--max-rate", type=float, default=1.0)
    ap.add_argument("--search-pairs", type=int, default=16)
    ap.add_argument("--library-pairs", type=int, default=60)
    ap.add_argument("--pop", type=int, default=30)
    ap.add_argument("--generations", type=int, default=20)
    ap.add_argument("--calibration", type=int, default=30)
    ap.add_argument("--held-out", type=int, default=200)
    ap.add_argument("--per-level", type=int, default=9)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reuse", action="store_true",
                    help="measure the command found by the last run (its result file)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if not 1 <= args.per_level <= 100:
        ap.error("--per-level: allowed range [1, 100] (the faulty actuators' seeds)")
    start = time.perf_counter()
    library = {c: prediction(c, args, args.library_pairs) for c in LIBRARY}
    for c, p in library.items():
        print(c, {n: f"{v:.3g}" for n, v in p.items()}, flush=True)
    if args.reuse:
        from _results import result_path

        found = json.loads(result_path("design_change").read_text())["found"]
    else:
        found = search(args, library)
    t, com = command_samples(np.array(found["genes"]), Limits(**found["limits"]))
    design = array_command(t, com, name="found")
    found["predicted"] = prediction(design, args, args.library_pairs)
    best_lib = {n: min(p[n] for p in library.values()) for n in NAMES}
    print("found", {n: f"{found['predicted'][n] / best_lib[n]:.2f}" for n in NAMES}, flush=True)
    levels = {n: [found["predicted"][n] * m for m in (0.25, 0.35, 0.5, 0.71, 1, 1.41, 2, 2.83, 4, 5.66, 8)] for n in NAMES}
    measured = {"found": measure(design, levels, args)}
    for c in LIBRARY:
        measured[c] = measure(c, levels, args)
        print(c, "measured", flush=True)
    out = {"settings": vars(args), "library_predicted": library, "found": found,
           "levels": levels, "measured": measured, "seconds": time.perf_counter() - start}
    for c, m in measured.items():
        print(c, m["false_alarms"], {n: (f["min_detectable"] and f"{f['min_detectable']:.3g}")
                                     for n, f in m["faults"].items()})
    if args.json:
        write_result("design_change", out)


if __name__ == "__main__":
    main()
