"""Is a rival the exclusion check cannot rule out only the final model's own model form?

The exclusion check (:meth:`eha.explain.final_check.FinalCheck.not_excluded`) lists an effect
whose fit beside the final model runs beyond the size the command shows on healthy actuators.
Beside a found effect that bar is the wrong one: the found effect's own model form (how the LF
applies it against how the actuator does) pulls the rival's fit too. An external load of
800 N on its separating design pulls an offset to -0.007 mA beside it, beyond the 0.0027 mA a
healthy actuator reaches and below the 0.014 mA at which the design tells the two apart: 4 of
5 such records named the offset as a rival.

The check here is a parametric bootstrap on the HF, relative to the found model. The final
model (its declared faults, the effects it started with and those it added, the parameters
the HF has) is simulated ``rival_replicates`` times with fresh dither and noise, *without* the
rival, and as many times *with* it at the size the exclusion check's bar stands for (the
healthy null's detectable size, on the side the record points to); on each re-simulation the
rival is refitted beside the final model exactly as on the record. The readings without it
are what the found model's model form makes the rival read; the healthy null's threshold is
how far a healthy actuator's own scatter moves that reading. The rival is ruled out when all
three hold:

1. the record's reading is within the threshold of the mean reading without it;
2. those readings scatter within the threshold themselves (a Student-t band at the loop's
   ``alpha``): the found model pins the rival's reading down;
3. a rival of the detectable size shows beside the found model: the mean reading with it
   moves towards it by at least half that size (:data:`MIN_SHOWN`), not absorbed by the
   found effect.

Where the pair trades (the rival can stand in for the found effect) the readings without it
scatter widely or the injected rival is absorbed, and the rival stays: the check never turns an
undecidable pair into a confident answer. An effect tested by its footprint (the supply
pressure) is re-checked only when it is listed by its parameter's shift alone (its footprint
within its bar): on that parameter, with the shift's threshold and detectable size; a footprint
past its bar is not re-checked.

Measured on the external load's separating design (an 800 N load, the offset as the rival):
the record reads -0.0060 mA, the load alone -0.0070 ± 0.0002 mA on the HF, an offset of
0.0024 mA beside it -0.0046 ± 0.0006 mA; the healthy threshold is 0.0018 mA.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from eha.explain.replicates import hf_overrides, model_overrides, resimulated
from eha.models.params import ParameterError

#: First seed of the re-simulations of the rival check (dither and noise).
RIVAL_SEED = 880_000
#: Fraction of an injected rival's size its reading must move by beside the found model.
MIN_SHOWN = 0.5


def reading(effect, params, by_shift: bool = False) -> float:
    """What the check compares: the rival's tested parameter (signed); nan for an effect
    tested by its footprint, unless it is checked ``by_shift`` (its parameter's)."""
    if effect.footprint and not by_shift:
        return math.nan
    return float(getattr(params, effect.tested))


def _side(effect, preferred: float, size: float) -> float | None:
    """The side of off on which a rival of ``size`` lies within its search bounds: the
    record's side when it can (a viscous friction cannot go below its off value), else the
    other; None when neither can."""
    lo, hi = effect.bounds[effect.tested]
    off = effect.off[effect.tested]
    for side in (preferred, -preferred):
        if lo <= off + side * size <= hi:
            return side
    return None


def _readings(loop, effect, members, overrides, seeds, by_shift: bool = False) -> list[float]:
    """The rival's reading on re-simulations of ``overrides`` (one per seed), refitted beside
    the final model as :meth:`~eha.explain.final_check.FinalCheck.not_excluded` does."""
    from eha.explain.effects import EFFECTS

    out = []
    for s in seeds:
        again = resimulated(loop, overrides, s)
        start, free = again.candidate_start(members, loop.current, loop.free)
        for st in loop.steps:
            free.update(EFFECTS[st.effect].bounds)
        local, _ = again.local_test(start, free, members, "rival check")
        out.append(reading(effect, local, by_shift))
    return out


def check_rival(loop, effect, members: Sequence, local, detectable: float,
                threshold: float, by_shift: bool = False) -> dict:
    """The rival check of ``effect`` (fitted beside the final model in ``local``, with the
    ``members`` it needs; ``detectable`` and ``threshold``: the healthy null's detectable size
    and threshold of its statistic, its parameter's unit; ``by_shift``: an effect tested by
    its footprint, listed by its parameter's shift and checked on it); see the module
    docstring.

    Returns
    -------
    dict
        ``record`` (the record's reading), ``without`` and ``with`` ([mean, std] of the
        readings, the parameter's unit), ``size`` (the rival put on the HF), ``threshold``,
        ``spread`` (the Student-t half-width of the readings without it), ``shown`` (the
        injected rival moved the reading towards it by at least :data:`MIN_SHOWN` of its
        size, :func:`shows`), ``ruled_out`` and ``seeds`` (first and last); empty when
        ``rival_replicates`` is 0, the effect is tested by its footprint (and not
        ``by_shift``) or the sizes are not finite.
    """
    from scipy.stats import t as student

    from eha.explain.effects import EFFECTS

    n = loop.settings.rival_replicates
    if not n or (effect.footprint and not by_shift) or not (math.isfinite(detectable)
                                         and math.isfinite(threshold)):
        return {}
    added = [p for st in loop.steps for p in EFFECTS[st.effect].params]
    names = [*loop.bounds, *added]
    without = model_overrides(loop, loop.current, names)
    first = RIVAL_SEED + 1000 * loop.settings.seed
    seeds = [first + k for k in range(n)], [first + 500 + k for k in range(n)]
    loop.progress(f"rival check: {effect.name}, {2 * n} HF re-simulations")
    try:
        r0 = _readings(loop, effect, members, without, seeds[0], by_shift)
        record = reading(effect, local, by_shift)
        m0, s0 = float(np.mean(r0)), float(np.std(r0, ddof=1))
        side = _side(effect, 1.0 if record >= m0 else -1.0, detectable)
        if side is None:
            return {}
        rival = {**hf_overrides(local, [p for m in members for p in m.params]),
                 effect.tested: effect.off[effect.tested] + side * detectable}
        r1 = _readings(loop, effect, members, {**without, **hf_overrides(
            local.replace(**rival), list(rival))}, seeds[1], by_shift)
    except (ParameterError, FloatingPointError, ValueError):
        return {}       # a re-simulation the HF refuses decides nothing: the rival stays
    m1, s1 = float(np.mean(r1)), float(np.std(r1, ddof=1))
    spread = float(student.ppf(1.0 - loop.settings.alpha / 2.0, n - 1)) * s0
    finite = all(math.isfinite(v) for v in (*r0, *r1, record))
    shown = finite and shows(m0, m1, side, detectable)
    ruled_out = finite and abs(record - m0) <= threshold and spread <= threshold and shown
    return {"record": record, "without": [m0, s0], "with": [m1, s1],
            "size": side * detectable, "threshold": threshold, "spread": spread,
            "shown": bool(shown), "ruled_out": bool(ruled_out),
            "seeds": [seeds[0][0], seeds[1][-1]]}


def shows(without: float, with_rival: float, side: float, size: float) -> bool:
    """Rule 3: does a rival of ``size`` put on the ``side`` (+1 or -1) of off show beside the
    found model? Its mean reading must move towards it by at least :data:`MIN_SHOWN` of the
    size; a reading that moves the other way does not follow it (a supply lowered by 7.6 MPa
    beside a sensor bias read 5.1 MPa higher on the bias / offset design)."""
    return (with_rival - without) * side >= MIN_SHOWN * size


def excluded_beyond(threshold: float, detectable: float) -> float:
    """The size beyond which the exclusion check would have listed an effect with the null's
    power, had the record held it: the check lists a fit past the ``detectable`` size (the
    threshold plus ``z(power)`` healthy scales), so a true shift of ``detectable`` plus one
    more such margin is listed with that power: ``2 detectable - threshold`` [its unit]."""
    return 2.0 * detectable - threshold


def deferred_to_first(entry: dict, check: dict, first_excluded: dict) -> dict | None:
    """A rival this record cannot show, left where a first record of the same actuator put it.

    The follow-up of ``eha explain --prior`` was designed to tell the first record's pair
    apart, not to show everything: beside the found model an effect it does not show (the
    rival check's injected rival does not move the reading towards it by :data:`MIN_SHOWN`
    of its size, ``check["shown"]`` false) reads whatever the fit wanders to, and that reading says
    nothing of the actuator. When the first record's exclusion check excluded the effect
    (``first_excluded``: its ``--json``'s ``excluded``), that exclusion stands: the entry,
    with the first record's figures under ``first_record``; else None (the rival stays: this
    record and the first leave it open alike)."""
    first = first_excluded.get(entry["effect"])
    if not check or check.get("shown", True) or check.get("ruled_out") or not first:
        return None
    return {**entry, "first_record": dict(first)}
