"""Test design for the change check (``eha design --check baseline``): what a command shows of a
fault's change since the actuator's own earlier record (:mod:`eha.health.change`), predicted,
and measured on simulated pairs (``eha design verify``).

A prediction and a measurement:

- :func:`simulated_prediction`: a change calibration on simulated healthy pairs
  (:func:`eha.health.change_calibration.calibrate_change`), each fault's detectable change
  the threshold plus z(0.95) healthy stds read back through its HF gain curve: 30 pairs for
  the design and the library commands (a few seconds each), :data:`SEARCH_PAIRS` without the
  gain curves for each candidate of the search (a fraction of a second). Why simulated and
  not the estimator's analytic variance: on fast commands the HF's response to the dither
  and the nuisances is far from linear (on the 5 Hz sine the analytic figure was 7 to 30
  times optimistic, docs/health.md).
- :func:`measure` (``eha design verify --check baseline``, ``validation/baseline.py``): fresh
  held-out healthy pairs (false alarms with their binomial bound) and faulty pairs on a
  sqrt(2) grid of sizes (the detectable change at P_D >= 0.95, isolation at twice it, the
  intervals' coverage).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from eha.design.predict import Prediction
from eha.design.targets import Target
from eha.health.change import Signatures, probe
from eha.models.faults import FAULTS

#: Healthy pairs of the search's prediction (the same actuators for every candidate, so that
#: candidates are compared on common random numbers).
SEARCH_PAIRS = 8
#: z of the detection probability a detectable change needs (0.95).
Z_DETECT = 1.6449
#: Calibration pairs of a simulated prediction.
PREDICTION_PAIRS = 30
#: Sizes of a measurement, in multiples of the simulated prediction.
MEASURE_MULTIPLES = (0.25, 0.35, 0.5, 0.71, 1.0, 1.41, 2.0, 2.83, 4.0, 5.66, 8.0)


def _prediction(mds: Mapping[str, float], sigma: Mapping[str, float], sig: Signatures,
                targets: Sequence[Target]) -> Prediction:
    foot = {t.name: float(np.sqrt(np.mean((sig.S[sig.faults.index(t.name)] * probe(t.name))
                                          ** 2))) for t in targets}
    inf = {t.name: {u.name: math.inf for u in targets} for t in targets}
    # the change check needs no LF to follow the command (model_form 0): it compares two
    # records of one actuator, whose model-form error is shared
    return Prediction(dict(mds), dict(sigma), inf, foot, {t.name: probe(t.name) for t in targets},
                      0.0, inf)


def simulated_prediction(command, targets: Sequence[Target], t_end: float, noise: float = 1e-6,
                         alpha: float = 0.01, nuisances: Mapping[str, float] | None = None,
                         pairs: int = PREDICTION_PAIRS, seed: int = 0,
                         gains: bool = True) -> Prediction:
    """The change check's detectable change of each target on ``command`` from a calibration
    on ``pairs`` simulated healthy pairs: the threshold plus z(0.95) healthy stds, read back
    through the fault's HF gain curve (``gains=False``: at the signature's slope)."""
    from eha.health.change_calibration import calibrate_change, sign_of

    cal, _ = calibrate_change(command, actuators=pairs, seed=seed, t_end=t_end, noise=noise,
                              alpha=alpha, nuisances=nuisances, gains=gains)
    names = [t.name for t in targets]
    sig = Signatures(command, t_end, noise, cal.nuisances, faults=names, model="hf")
    mds, sigma = {}, {}
    for t in targets:
        f, curve = cal.faults[t.name], cal.gain(t.name)
        s = sign_of(t.name)
        need = f["threshold"] + Z_DETECT * f["std"]
        mds[t.name] = float(abs(curve.invert(s * need, s))) if curve.gains else math.inf
        sigma[t.name] = float(abs(curve.invert(s * f["std"], s))) if curve.gains else math.inf
    return _prediction(mds, sigma, sig, targets)


def measure(command, t_end: float = 1.0, faults: Sequence[str] | None = None,
            sizes: Mapping[str, Sequence[float]] | None = None, per_level: int = 9,
            held_out: int = 200, calibration: int = 30, alpha: float = 0.01,
            noise: float = 1e-6, nuisances: Mapping[str, float] | None = None, seed: int = 0,
            on_progress=None) -> dict[str, Any]:
    """The change check measured on simulated pairs of ``command`` (fresh seeds: the
    calibration's actuators from ``seed``, the held-out healthy pairs from ``seed + 300000``,
    the faulty ones from ``seed + 400000``).

    Per fault, at each of ``sizes[fault]`` (changes in the direction of degradation; default
    :data:`MEASURE_MULTIPLES` of the simulated prediction) ``per_level`` actuators: the
    detection rate, the share isolated to a group holding the fault, the group's mean size
    and the coverage of the change's interval; the detectable change (the smallest size from
    which every larger one is detected at P_D >= 0.95), and isolation at twice it (measured
    on ``per_level`` more actuators). False alarms on ``held_out`` healthy pairs with the
    one-sided 95 % binomial (Clopper-Pearson) bound.
    """
    from eha.health.change import draw_test_day
    from eha.health.change_calibration import (_faulted, _record, calibrate_change,
                                               isolate_group, judge, later_seed, sign_of)
    from eha.health.change_runs import _positions
    from eha.identification.healthy import draw_actuator, upper_bound
    from eha.identification.measured import noise_level
    from eha.models.commands import as_command

    say = on_progress or (lambda m: None)
    cmd = as_command(command)
    names = list(faults or FAULTS)
    cal, _ = calibrate_change(command, actuators=calibration, seed=seed, t_end=t_end,
                              noise=noise, alpha=alpha, nuisances=nuisances)
    first = _record(cmd, draw_actuator(seed), t_end, noise, seed)
    sig = Signatures(first.command, t_end, noise, cal.nuisances, model=cal.signatures)

    def pairs(specs):
        """``(judged, applied change)`` of each ``(actuator seed, fault, change)``: the two
        records of each pair simulated in one batch of parallel HF runs."""
        runs, applied = [], []
        for s, fault, change in specs:
            hf = draw_actuator(s)
            later, grown = draw_test_day(hf, cal.nuisances, s), 0.0
            if fault:
                later, grown = _faulted(later, fault, change)
            runs += [(hf, s), (later, later_seed(s))]
            applied.append(grown)
        xs = _positions(cmd, runs, t_end, noise)
        return [(judge(cal, sig, b - a, noise_level(a) ** 2 + noise_level(b) ** 2), grown)
                for a, b, grown in zip(xs[0::2], xs[1::2], applied)]

    alarms = sum(any(v["degraded"] for v in j.values())
                 for j, _ in pairs([(seed + 300_000 + k, None, 0.0) for k in range(held_out)]))
    say(f"{command if isinstance(command, str) else 'design'}: {alarms} of {held_out} "
        "held-out healthy pairs alarmed")
    if sizes is None:
        pred = simulated_prediction(command, [_target(n) for n in names], t_end, noise, alpha,
                                    cal.nuisances, calibration, seed)
        sizes = {n: [m * pred.mds[n] for m in MEASURE_MULTIPLES] for n in names}
    out_faults = {}
    for fi, n in enumerate(names):
        s = sign_of(n)
        # within the sizes the health check reports (its search bounds: a jammed clogging
        # filter, Kintas 1, is a failed valve, not a change to measure)
        limit = _target(n).limit

        def level(size: float, base: int) -> dict[str, Any]:
            det = iso = cov = group = 0
            applied_all = []
            for judged, applied in pairs([(base + j, n, s * size) for j in range(per_level)]):
                applied_all.append(applied)
                det += judged[n]["degraded"]
                g = isolate_group(judged)
                iso += n in g
                group += len(g)
                lo, hi = judged[n]["interval"]
                cov += lo <= applied <= hi
            return {"size": float(size), "applied": float(np.mean(np.abs(applied_all))),
                    "p_detect": det / per_level, "isolated": iso / per_level,
                    "group_size": group / max(det, 1), "coverage": cov / per_level,
                    "n": per_level}

        rows = [level(size, seed + 400_000 + 10_000 * fi + 100 * k)
                for k, size in enumerate(sizes[n]) if size <= limit]
        ok = [r["size"] for k, r in enumerate(rows)
              if all(o["p_detect"] >= 0.95 for o in rows[k:])]
        detectable = min(ok) if ok else None
        at2 = level(2 * detectable, seed + 400_000 + 10_000 * fi + 9_000) \
            if detectable and 2 * detectable <= limit else None
        out_faults[n] = {"levels": rows, "min_detectable": detectable, "at_twice": at2}
        say(f"  {n}: detectable change {detectable if detectable is None else f'{detectable:.3g}'}")
    return {"command": command if isinstance(command, str) else "design",
            "thresholds": {n: cal.faults[n]["threshold"] for n in names},
            "false_alarms": {"n": held_out, "alarms": int(alarms), "rate": alarms / held_out,
                             "upper_95": upper_bound(int(alarms), held_out)},
            "faults": out_faults, "calibration_pairs": calibration, "per_level": per_level,
            "alpha": alpha, "noise": noise, "nuisances": dict(cal.nuisances), "seed": seed}


def design_change(faults: Sequence[str] | None, limits, noise: float = 1e-6,
                  alpha: float = 0.01, seed: int = 0, population: int = 32,
                  generations: int = 30, on_progress=None):
    """``eha design --check baseline``: the command of the design family on which the change
    check sees the chosen faults' changes smallest, never worse on any of them than the best
    library command cut to the same limits (:mod:`eha.design.library`); where the search
    finds none, that library command, said so. Returns a :class:`eha.design.api.DesignResult`
    (``settings["check"] == "baseline"``)."""
    import time

    from eha.design.result import DesignResult
    from eha.design.family import command_samples, decode
    from eha.design.library import best_by_score, dominated_by, library_cut, within_limits
    from eha.design.search import best_library, search
    from eha.design.targets import resolve_targets
    from eha.models.commands import array_command

    say = on_progress or (lambda m: None)
    start = time.perf_counter()
    targets = resolve_targets(faults)
    names = {t.name for t in targets}
    cuts, beyond = within_limits(limits, say)
    say(f"library commands cut to the limits: the change check on "
        f"{', '.join(c.label for c in cuts.values())}")

    def quick(command, targets_, t_end, pairs=(), **_):
        return simulated_prediction(command, targets_, t_end, noise, alpha, pairs=SEARCH_PAIRS,
                                    seed=seed, gains=False)

    quick_library = {n: quick(c.command(), targets, limits.duration) for n, c in cuts.items()}
    x, _, history = search(targets, limits, best_library(targets, quick_library), seed=seed,
                           pop=population, generations=generations, on_progress=say,
                           detect=names, predictor=quick)
    t, com = command_samples(x, limits)
    segments = decode(x, limits)
    say("final prediction: simulated healthy pairs on the design and the library commands")
    library = {n: simulated_prediction(c.command(), targets, limits.duration, noise, alpha,
                                       seed=seed) for n, c in cuts.items()}
    prediction = simulated_prediction(array_command(t, com, "design"), targets,
                                      limits.duration, noise, alpha, seed=seed)
    reference = best_library(targets, library)
    top = best_by_score(library, targets, reference, names, cuts)
    worse = dominated_by(prediction, library[top], targets, names)
    chosen = "searched"
    if worse:
        say(f"the searched command sees {', '.join(worse)} worse than the library command "
            f"{cuts[top].label} (cut to the limits): that library command is the design")
        t, com, prediction = cuts[top].t, cuts[top].com, library[top]
        segments = [{"shape": f"library command {cuts[top].label} (cut to the limits)",
                     "start": 0.0, "length": limits.duration}]
        chosen = f"library command {top}"
    settings = {"faults": [x.name for x in targets], "effects": [], "separate": [],
                "around": {}, **limits.to_dict(), "signals": ["xu"], "sampling": 1000.0,
                "noise": {"xu": noise}, "alpha": alpha, "seed": seed, "actuators": 1,
                "population": population, "generations": generations, "p_detect": 0.95,
                "check": "baseline", "calibration_pairs": PREDICTION_PAIRS,
                "library_cut": library_cut({**cuts, **beyond}),
                "chosen": chosen}
    return DesignResult(t, com, targets, prediction, library, settings, segments, {},
                        history, time.perf_counter() - start)


def _target(name: str) -> Target:
    from eha.design.targets import fault_target

    return fault_target(name)


__all__ = ["simulated_prediction", "measure", "design_change", "SEARCH_PAIRS",
           "MEASURE_MULTIPLES"]
