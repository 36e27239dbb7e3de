"""Test design for the change check (``eha design --check baseline``): what a command shows of a
fault's change since the actuator's own earlier record (:mod:`eha.health.change`), predicted,
and measured on simulated pairs (``eha design verify``).

Two predictions, one measurement:

- :func:`analytic_prediction` (the search's, ~0.1 s a command): the change check's estimator
  on the command, each fault's detectable change ``(t(1 - alpha/m) + z(0.95)) * sigma`` with
  ``sigma^2 = EXCESS / (S_f^T Sigma^-1 S_f)``: the model's variance (noise and the test-day
  nuisances) times the healthy pairs' measured excess over it (the dither).
- :func:`simulated_prediction` (the design's and the library's, ~4 s a command): a change
  calibration on simulated healthy pairs (:func:`eha.health.change_calibration.calibrate_change`),
  the detectable change read back through each fault's HF gain curve.
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
from eha.health.change import Signatures, check_nuisances, probe
from eha.models.faults import FAULTS

#: The healthy pairs' variance over the change check's model (noise and nuisances), measured
#: on chirp_1cm (the calibration's ``excess``, 1.6): the dither and what the linear model
#: leaves out. The search multiplies the model's variance by it; the final prediction is
#: simulated and needs none.
EXCESS = 1.6
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


def analytic_prediction(command, targets: Sequence[Target], t_end: float, noise: float = 1e-6,
                        alpha: float = 0.01, nuisances: Mapping[str, float] | None = None,
                        pairs: int = PREDICTION_PAIRS, **_) -> Prediction:
    """The search's prediction of the change check on ``command`` (see the module doc)."""
    from scipy.stats import t as student

    names = [t.name for t in targets]
    sig = Signatures(command, t_end, noise, check_nuisances(nuisances), faults=names,
                     model="hf")
    m = len(FAULTS)
    mds, sigma = {}, {}
    for i, t in enumerate(targets):
        two = FAULTS[t.name].direction == 0
        q = float(student.ppf(1 - alpha / m / (2 if two else 1), pairs - 1))
        info = sig.info[i]
        sd = math.sqrt(EXCESS / info) if info > 0 else math.inf
        sigma[t.name] = sd
        mds[t.name] = (q * math.sqrt(1 + 1 / pairs) + Z_DETECT) * sd
    return _prediction(mds, sigma, sig, targets)


def simulated_prediction(command, targets: Sequence[Target], t_end: float, noise: float = 1e-6,
                         alpha: float = 0.01, nuisances: Mapping[str, float] | None = None,
                         pairs: int = PREDICTION_PAIRS, seed: int = 0) -> Prediction:
    """The change check's detectable change of each target on ``command`` from a calibration
    on ``pairs`` simulated healthy pairs: the threshold plus z(0.95) healthy stds, read back
    through the fault's HF gain curve."""
    from eha.health.change_calibration import calibrate_change, sign_of

    cal, _ = calibrate_change(command, actuators=pairs, seed=seed, t_end=t_end, noise=noise,
                              alpha=alpha, nuisances=nuisances)
    names = [t.name for t in targets]
    sig = Signatures(command, t_end, noise, cal.nuisances, faults=names, model="hf")
    mds, sigma = {}, {}
    for t in targets:
        f, curve = cal.faults[t.name], cal.gain(t.name)
        s = sign_of(t.name)
        need = f["threshold"] + Z_DETECT * f["std"]
        mds[t.name] = abs(curve.invert(s * need, s)) if curve.gains else math.inf
        sigma[t.name] = abs(curve.invert(s * f["std"], s)) if curve.gains else math.inf
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
    from eha.design.verify import upper_bound
    from eha.health.change import draw_test_day
    from eha.health.change_calibration import (_faulted, _record, calibrate_change,
                                               isolate_group, judge, later_seed, sign_of)
    from eha.identification.healthy import draw_actuator
    from eha.identification.measured import noise_level
    from eha.models.commands import as_command

    say = on_progress or (lambda m: None)
    cmd = as_command(command)
    names = list(faults or FAULTS)
    cal, _ = calibrate_change(command, actuators=calibration, seed=seed, t_end=t_end,
                              noise=noise, alpha=alpha, nuisances=nuisances)
    first = _record(cmd, draw_actuator(seed), t_end, noise, seed)
    sig = Signatures(first.command, t_end, noise, cal.nuisances, model=cal.signatures)

    def pair(s: int, fault: str | None = None, change: float = 0.0):
        hf = draw_actuator(s)
        a = _record(cmd, hf, t_end, noise, s)
        later = draw_test_day(hf, cal.nuisances, s)
        applied = 0.0
        if fault:
            later, applied = _faulted(later, fault, change)
        b = _record(cmd, later, t_end, noise, later_seed(s))
        j = judge(cal, sig, b.xu - a.xu, noise_level(a.xu) ** 2 + noise_level(b.xu) ** 2)
        return j, applied

    alarms = 0
    for k in range(held_out):
        j, _ = pair(seed + 300_000 + k)
        alarms += any(v["degraded"] for v in j.values())
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
            for j in range(per_level):
                judged, applied = pair(base + j, n, s * size)
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


def _target(name: str) -> Target:
    from eha.design.targets import fault_target

    return fault_target(name)


__all__ = ["analytic_prediction", "simulated_prediction", "measure", "EXCESS"]
