"""The change check's two-fault reading: the other faults judged beside the first isolated one.

With two faults grown together (a backlash and a jack friction growing through an actuator's
life), the single-fault estimates give the whole difference to the one that explains most of
it. Each other fault's change is estimated jointly with a free change of the first
(:meth:`eha.health.change.Signatures.conditional`), less what the first one's own nonlinear
response leaves there at its size (measured by the calibration on HF runs of the first fault
alone, ``leak``), and judged against the healthy pairs' tolerance bound widened by the leak's
spread over actuators.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from eha.health.change import Signatures
from eha.health.change_calibration import (ChangeCalibration, change_interval, isolate_group,
                                           judge, sign_of, tolerance_factor)


def judge_second(cal: ChangeCalibration, sig: Signatures, r: np.ndarray, noise2: float,
                 judged: Mapping[str, Mapping[str, Any]], isolated: Sequence[str],
                 level: float | None = None) -> dict[str, dict[str, Any]]:
    """The other faults judged beside the first isolated one: each one's change estimated
    jointly with a free change of it (:meth:`Signatures.conditional`), less what the first
    one's own nonlinear response leaves there at its estimated size (the calibration's
    ``leak``, measured on HF runs of the first fault alone), against the tolerance bound of
    the healthy pairs widened by the leak's spread over actuators. A fault the records do not
    tell from the first one, or a first change beyond the sizes the leak was measured at, is
    not judged; a calibration without leaks (``gains=False``) judges none.

    Returns per judged fault: ``statistic``, ``threshold``, ``degraded``, ``change`` (read
    through its gain curve), its ``interval`` at ``level`` (default the calibration's: the
    joint estimate's spread over the healthy pairs with the leak's spread added, read back as
    :func:`change_interval` reads the single-fault one, widened by the calibration's
    ``interaction``: how far the reading strayed with both faults grown, relative to the
    change, at the first fault's size), ``open_ended`` and ``beside`` (the first fault)."""
    if not isolated or not cal.second:
        return {}
    level = cal.level if level is None else float(level)
    first = isolated[0]
    figures = cal.second.get(first) or {}
    cond = sig.conditional(sig.faults.index(first))
    info = sig.conditional_info(sig.faults.index(first))
    size = abs(float(judged[first]["change"]))
    skip = set(isolated) | set(judged[first].get("alike", ()))
    m = len(cal.faults)
    out = {}
    for j, g in enumerate(sig.faults):
        f = figures.get(g)
        if f is None or g in skip or not (f.get("leak") or {}).get("sizes"):
            continue
        leak = f["leak"]
        xs = np.abs(np.array(leak["sizes"], dtype=float))
        if size > xs[-1]:
            continue                     # beyond what the calibration measured: not judged
        mean = float(np.interp(size, np.r_[0.0, xs], np.r_[0.0, leak["mean"]]))
        spread = float(np.interp(size, np.r_[0.0, xs], np.r_[0.0, leak["std"]]))
        s = sign_of(g)
        d = s * float(cond[j] @ r) - f["mean"] - mean
        two, n = bool(f["two_sided"]), int(f["n"])
        stat = abs(d) if two else d
        sd = math.sqrt(max(f["other_var"] + f["noise_factor"] * noise2 + spread ** 2, 1e-300))
        thr = tolerance_factor(n, cal.alpha / m / (2.0 if two else 1.0)) * sd * \
            f.get("tail", 1.0)
        inter = f.get("interaction") or {}
        relative = float(np.interp(size, np.r_[0.0, inter["sizes"]], np.r_[0.0, inter["rel"]])) \
            if inter.get("sizes") else 0.0
        change, lo, hi, open_end = change_interval(cal.gain(g), s, d,
                                                   sd * math.sqrt(1.0 + 1.0 / n), n, level,
                                                   relative)
        out[g] = {"statistic": stat, "threshold": thr, "degraded": bool(stat > thr),
                  # the two-fault fit's gain in likelihood over the first fault alone (the
                  # model's variance at the record's noise): which one is beside it
                  "glr": float(d * d * info[j] * sig.noise2 / max(noise2, 1e-30)),
                  "change": change, "interval": [lo, hi], "open_ended": open_end,
                  "beside": first}
    return out


#: Most faults the check names as changed beside the first isolated one: its reading is a
#: two-fault model (with two faults grown, a third one's leak is not calibrated: on
#: ``chirp_1cm`` a backlash and a friction grown together put the spool friction or the
#: clogging over their thresholds in 4 of 10 pairs).
MAX_BESIDE = 1


def also_changed(second: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The fault(s) :func:`judge_second` finds changed beside the first: of those beyond
    their thresholds, the one whose two-fault fit explains the most (the largest likelihood
    ratio; at most :data:`MAX_BESIDE`)."""
    return [g for _, g in sorted(((v.get("glr", 0.0), g) for g, v in second.items()
                                  if v["degraded"]), reverse=True)][:MAX_BESIDE]


def judge_change(cal: ChangeCalibration, sig: Signatures, r: np.ndarray, noise2: float,
                 level: float | None = None) -> tuple[dict, list[str], dict, list[str]]:
    """A record difference judged whole: each fault's change (:func:`judge`), the faults it is
    isolated to (:func:`isolate_group`), the others judged beside the first
    (:func:`judge_second`) and those changed beside it (:func:`also_changed`)."""
    judged = judge(cal, sig, r, noise2, level)
    isolated = isolate_group(judged)
    second = judge_second(cal, sig, r, noise2, judged, isolated, level)
    return judged, isolated, second, also_changed(second)


__all__ = ["MAX_BESIDE", "judge_second", "also_changed", "judge_change"]
