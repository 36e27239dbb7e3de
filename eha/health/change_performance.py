"""Detection and isolation figures of a change campaign (``[health] baseline = true``,
:mod:`eha.health.change_campaign`): thresholds from the campaign's own healthy pairs, in the
structure of :func:`eha.health.detection.performance` (what ``eha report health`` writes).

Per command, the healthy pairs' linear estimates give each fault's mean and std, split into
the white-noise part (scaled at each pair by its own records' noise) and the rest (nuisances,
dither), and the tolerance bound at ``alpha / m`` (with its tail factor) of
:func:`eha.health.change_calibration.judge_estimates`; a pair alarms on a fault when its
statistic is beyond the bound at its noise. The ROC is drawn on the statistic in units of its
scale (``z``), which is what the bound thresholds. Isolation: the alarming fault with the
largest likelihood ratio, with the faults its signature is not told from
(:func:`eha.health.change_calibration.isolate_group`); the confusion matrix counts the first.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from eha.health.change import probe
from eha.health.change_calibration import (ChangeCalibration, isolate_group, judge_estimates,
                                           sign_of, tail_factor, tolerance_factor)
from eha.health.detection import DEFAULT_ALPHA, roc_curve
from eha.models.faults import FAULTS

#: Fewest healthy pairs a command's thresholds are set from.
MIN_PAIRS = 5


def calibration_of(healthy: Sequence[Mapping[str, Any]], alpha: float,
                   level: float = 0.9) -> ChangeCalibration:
    """A change calibration from a campaign's healthy pairs (unit gains: the changes are the
    linear estimates, in fault units at the signature's slope)."""
    from eha.models.simulate import MODEL_VERSION

    names = list(healthy[0]["estimates"])
    noise2 = np.array([float(r["noise2"]) for r in healthy])
    faults = {}
    for name in names:
        d = sign_of(name) * np.array([float(r["estimates"][name]) for r in healthy])
        var = float(d.var(ddof=1))
        nf = float(healthy[0]["noise_factor"][name])
        noise_var = nf * float(noise2.mean())
        two = FAULTS[name].direction == 0
        p = alpha / len(names) / (2.0 if two else 1.0)
        # the tail factor as eha.health.change_calibration sets it (the heavier tail if two)
        tail = max(tail_factor(d, p), tail_factor(-d, p)) if two else tail_factor(d, p)
        faults[name] = {"mean": float(d.mean()), "std": math.sqrt(var), "noise_var": noise_var,
                        "other_var": max(var - noise_var, 0.0), "noise_factor": nf,
                        "threshold": 0.0, "tail": tail, "two_sided": two,
                        "n": int(d.size)}
    gains = {n: {"sizes": [probe(n)], "gains": [1.0], "spread": [0.0]} for n in names}
    info = {n: float(healthy[0]["info"][n]) for n in names}
    s2 = 2.0 * max(float(healthy[0]["noise"]), 1e-9) ** 2     # the weights' noise variance
    excess = [faults[n]["std"] ** 2 * info[n] / s2 for n in names if info[n] > 0]
    first = healthy[0]
    return ChangeCalibration(
        command=str(first["command"]), command_sig="", t_end=float(first["t_end"]),
        model_version=MODEL_VERSION, alpha=float(alpha), level=float(level),
        noise=float(first["noise"]), nuisances=dict(first["nuisances"]), pairs=len(healthy),
        seed=int(first["seed"]), faults=faults, gains=gains, screen={},
        excess=max(float(np.median(excess)) if excess else 1.0, 1.0))


def judge_row(cal: ChangeCalibration, row: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """One pair judged against ``cal``: :func:`judge_estimates` with each fault's generalized
    likelihood ratio and look-alikes (for :func:`isolate_group`)."""
    names = list(cal.faults)
    est = np.array([float(row["estimates"][n]) for n in names])
    noise2 = float(row["noise2"])
    out = judge_estimates(cal, names, est, noise2, blind=row.get("blind") or ())
    for name, v in out.items():
        v["alike"] = list((row.get("alike") or {}).get(name, ()))
        # info was stored times the weights' noise variance: at the pair's own noise
        v["glr"] = float(v["statistic"] ** 2 * float(row["info"][name])
                         / max(noise2, 1e-30) / cal.excess)
    return out


def _loo(healthy: Sequence[Mapping[str, Any]], alpha: float) -> dict[str, Any]:
    """Each healthy pair judged against the thresholds of the others."""
    alarms = 0
    for j, r in enumerate(healthy):
        cal = calibration_of([o for i, o in enumerate(healthy) if i != j], alpha)
        alarms += int(any(v["degraded"] for v in judge_row(cal, r).values()))
    return {"any": alarms / len(healthy), "n": len(healthy)}


def _declared(judged: Mapping[str, Mapping[str, Any]]) -> str:
    group = isolate_group(judged)
    return group[0] if group else "none"


def performance_change(rows: Sequence[Mapping[str, Any]], alpha: float = DEFAULT_ALPHA,
                       p_detect: float = 0.95) -> dict[str, Any]:
    """Per command: thresholds from the healthy pairs, false alarms (in sample and leave one
    out), per fault and injected change the detection rate and ROC, the smallest detectable
    change (the smallest injected change from which every larger one is detected at
    ``p_detect``; None when none is), and the confusion matrix (rows: injected fault,
    columns: declared fault). ``check``: ``"change"``."""
    out: dict[str, Any] = {}
    for command in sorted({r["command"] for r in rows}):
        mine = [r for r in rows if r["command"] == command]
        healthy = [r for r in mine if r["grp"] == "healthy"]
        if len(healthy) < MIN_PAIRS:
            continue
        cal = calibration_of(healthy, alpha, float(healthy[0].get("level") or 0.9))
        judged_h = [judge_row(cal, r) for r in healthy]
        per = {n: float(np.mean([j[n]["degraded"] for j in judged_h])) for n in cal.faults}
        fa = {"per_fault": per, "n": len(healthy),
              "any": float(np.mean([any(v["degraded"] for v in j.values()) for j in judged_h]))}
        confusion: dict[str, dict[str, int]] = {"none": {}}
        for j in judged_h:
            d = _declared(j)
            confusion["none"][d] = confusion["none"].get(d, 0) + 1
        faults: dict[str, Any] = {}
        for label in sorted({r["grp"] for r in mine} - {"healthy"}):
            rs = [r for r in mine if r["grp"] == label]
            name = rs[0]["fault"]
            judged = [judge_row(cal, r) for r in rs]
            z_h = np.array([j[name]["z"] for j in judged_h])
            z_f = np.array([j[name]["z"] for j in judged])
            pfa, pdet = roc_curve(z_h, z_f)
            change = float(np.mean([r["truth_change"] for r in rs]))
            dev = abs(change) if FAULTS[name].direction == 0 else sign_of(name) * change
            entry = faults.setdefault(name, {"levels": []})
            entry["levels"].append({
                "value": change, "deviation": dev, "n": len(rs),
                "p_detect": float(np.mean([j[name]["degraded"] for j in judged])),
                "estimate": float(np.mean([j[name]["change"] for j in judged])),
                "roc": {"pfa": pfa.tolist(), "pd": pdet.tolist()}})
            row = confusion.setdefault(name, {})
            for j in judged:
                d = _declared(j)
                row[d] = row.get(d, 0) + 1
        for name, entry in faults.items():
            entry["levels"].sort(key=lambda e: e["deviation"])
            entry["min_detectable_deviation"] = _detectable(entry["levels"], p_detect)
            entry["threshold"] = _margin(cal, name)
        out[command] = {"check": "change", "thresholds": {n: _margin(cal, n) for n in cal.faults},
                        "healthy": {n: {"mean": f["mean"], "std": f["std"], "n": f["n"]}
                                    for n, f in cal.faults.items()},
                        "false_alarms": fa, "false_alarms_loo": _loo(healthy, alpha),
                        "faults": faults, "confusion": confusion}
    return out


def _margin(cal: ChangeCalibration, name: str) -> float:
    """The threshold of fault ``name``'s change at the healthy pairs' mean noise (fault
    unit, over the healthy mean): the tolerance bound of
    :func:`eha.health.change_calibration.judge_estimates`."""
    f = cal.faults[name]
    p = cal.alpha / len(cal.faults) / (2.0 if f["two_sided"] else 1.0)
    return tolerance_factor(f["n"], p) * f["std"] * f.get("tail", 1.0)


def _detectable(levels: Sequence[Mapping[str, Any]], p_detect: float) -> float | None:
    """The smallest deviation from which every larger injected one is detected."""
    best = None
    for e in reversed(levels):
        if e["p_detect"] < p_detect:
            break
        best = e["deviation"]
    return best


__all__ = ["performance_change", "calibration_of", "judge_row", "MIN_PAIRS"]
