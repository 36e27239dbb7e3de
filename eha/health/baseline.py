"""The baseline-referenced health check: a record judged against the same actuator's own
earlier record on the same command (its acceptance test), not against the fleet.

Why: a fleet check cannot see a fault smaller than the healthy fleet's manufacturing scatter
in the estimate (measured, docs/design.md: the jack friction's 20 N spread, the motor gain's
confusion with the +-3 % flow gain, the LF's model-form floor on the backlash), whatever the
command. Two records of one actuator on one command share its scatter and the LF model's
model-form error on that command; what differs between them is the sensor noise, the HF
dither and the fault. The check's statistic of a fault is then the change of the bank's
posterior mean from the baseline record to the new one, in the direction of degradation, and
its thresholds come from pairs of records of healthy actuators
(:func:`eha.health.detection.calibrate_thresholds` on :func:`referenced` rows).

A referenced row is an assessment row whose means are ``healthy + (new - baseline)``: every
function that reads a fleet check's rows (thresholds, false alarms, detection, isolation)
reads a baseline check's unchanged.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from eha.identification.healthy import DetectionError
from eha.models.faults import FAULTS

#: Group label of the baseline records in a health campaign.
BASELINE_GROUP = "baseline"
#: The baseline record of actuator ``s`` is recorded with noise and dither seed
#: ``(s + BASELINE_SEED_SHIFT) % 2**31`` (another record of the same actuator).
BASELINE_SEED_SHIFT = 2**30


def baseline_record_seed(seed: int) -> int:
    """Noise and dither seed of the baseline record of the actuator of ``seed``."""
    return (int(seed) + BASELINE_SEED_SHIFT) % 2**31


def referenced_means(new: Mapping[str, float], baseline: Mapping[str, float]
                     ) -> dict[str, float]:
    """Per fault, ``healthy + (new - baseline)``: the new record's estimate as a change from
    the actuator's own baseline (faults missing from either mapping are left out)."""
    return {n: FAULTS[n].healthy + (float(new[n]) - float(baseline[n]))
            for n in new if n in baseline and n in FAULTS}


def without_model_form(row: Mapping[str, Any]) -> dict[str, float]:
    """Per fault, the measurement std of one check (its ``spread``) without the check's
    model-form floor (:data:`eha.identification.intervals.MODEL_FORM` of its base model), which
    two records of one actuator on one command share: ``sqrt(spread^2 - floor^2)``, the
    noise part (at least; the widening of a poor fit stays in it)."""
    from eha.identification.intervals import MODEL_FORM

    terms = MODEL_FORM.get(row.get("base_model", "calibrated"), {})
    values = row.get("estimates") or row.get("means") or {}
    out = {}
    for name, sd in (row.get("spread") or {}).items():
        term = terms.get(name)
        floor2 = 0.0 if term is None else \
            (term.rel * float(values.get(name, 0.0))) ** 2 + term.abs ** 2
        out[name] = math.sqrt(max(float(sd) ** 2 - floor2, 0.0)) if math.isfinite(sd) else sd
    return out


def referenced(row: Mapping[str, Any], baseline: Mapping[str, Any]) -> dict[str, Any]:
    """An assessment row (``health_assessments``) referenced to its actuator's baseline row:
    means and estimates as changes from the baseline's; the spread, the noise parts of both
    checks in quadrature (:func:`without_model_form`); weights and the rest are the new
    record's."""
    out = dict(row)
    out["means"] = referenced_means(row["means"], baseline["means"])
    if "estimates" in row and "estimates" in baseline:
        out["estimates"] = referenced_means(row["estimates"], baseline["estimates"])
    sp, sb = without_model_form(row), without_model_form(baseline)
    out["spread"] = {n: math.hypot(float(sp[n]), float(sb[n])) for n in sp if n in sb}
    out["baseline_seed"] = baseline.get("seed")
    return out


def pair_threshold(values: Sequence[float], alpha: float, two_sided: bool = False
                   ) -> tuple[float, dict[str, float]]:
    """The baseline check's threshold of a statistic from its values on healthy pairs: the
    one-sided normal prediction bound of probability ``alpha`` for one more pair,
    ``mean + t(1 - alpha; n - 1) * std * sqrt(1 + 1/n)`` (Student's t: the std is estimated
    from ``n`` pairs). ``two_sided``: ``values`` are signed changes of a fault that degrades
    either way (its statistic is their absolute value), and the threshold is the larger
    ``|mean +- t(1 - alpha/2; n - 1) * std * sqrt(1 + 1/n)|``.

    Why not the fleet check's floor (:func:`eha.identification.healthy.tail_threshold` with the
    median measurement std of one check): that std is the HAC std of one fit, whose residual
    carries the LF's model-form error, common to both records of a pair (docs/decisions.md:
    8 to 100 times the pairs' own std on a small fleet)."""
    from scipy.stats import t as student

    d = np.asarray(values, dtype=np.float64)
    d = d[np.isfinite(d)]
    if d.size < 3:
        raise DetectionError(f"{d.size} healthy pairs; a baseline threshold needs at least 3")
    mean, std, n = float(d.mean()), float(d.std(ddof=1)), int(d.size)
    scale = std * math.sqrt(1.0 + 1.0 / n)
    q = float(student.ppf(1.0 - (alpha / 2.0 if two_sided else alpha), n - 1))
    summary = {"mean": mean, "std": std, "spread": 0.0, "scale": scale, "n": n,
               "max": float(np.max(np.abs(d)) if two_sided else d.max())}
    if two_sided:
        return max(abs(mean + q * scale), abs(mean - q * scale)), summary
    return mean + q * scale, summary


def is_referenced(rows: Sequence[Mapping[str, Any]]) -> bool:
    """Are these rows a baseline check's (:func:`referenced`)?"""
    return bool(rows) and all("baseline_seed" in r for r in rows)


def pair_with_baselines(rows: Sequence[Mapping[str, Any]], strict: bool = True
                        ) -> list[dict[str, Any]]:
    """The rows of a campaign with baseline records, each referenced to the baseline of its
    actuator (same command, same actuator seed); the baseline rows themselves are dropped.
    Rows of a campaign without baselines come back unchanged. Without ``strict`` a record
    whose baseline is not (yet) there is left out (a report of a running campaign).

    Raises
    ------
    DetectionError
        With ``strict``, a record whose actuator has no baseline record.
    """
    base = {(r["command"], int(r["seed"])): r for r in rows if r["grp"] == BASELINE_GROUP}
    if not base:
        return [dict(r) for r in rows]
    out = []
    for r in rows:
        if r["grp"] == BASELINE_GROUP:
            continue
        key = (r["command"], int(r["seed"]))
        if key not in base and not strict:
            continue
        if key not in base:
            raise DetectionError(f"baseline: no baseline record of actuator {key[1]} on "
                                 f"{key[0]} (the campaign is not finished?)")
        out.append(referenced(r, base[key]))
    return out


__all__ = ["BASELINE_GROUP", "baseline_record_seed", "referenced", "referenced_means",
           "pair_with_baselines", "without_model_form", "pair_threshold", "is_referenced"]
