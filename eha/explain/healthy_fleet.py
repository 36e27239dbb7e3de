"""The healthy fleet behind the residual loop's null (:mod:`eha.explain.null`): one simulated
healthy record like the user's (:func:`healthy_record`) and the loop's candidate test of each
effect on it (:func:`healthy_statistics`), the statistic whose distribution the null is.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from eha.explain.settings import DECLARED_DRAW, NOISE_CLASSES_PER_DECADE, STRUCTURAL
from eha.identification.healthy import draw_actuator


def noise_class(noise: float) -> float:
    """The noise level [the unit of ``noise``] a null is simulated with for a record whose
    noise is estimated at ``noise``: the nearest class 10**(k/5) (0 stays 0)."""
    if not noise > 0:
        return 0.0
    k = round(math.log10(noise) * NOISE_CLASSES_PER_DECADE)
    return float(10.0 ** (k / NOISE_CLASSES_PER_DECADE))


# ------------------------------------------------------------------------------------------
# the statistic on one healthy record

def healthy_statistics(data, fit: Mapping[str, tuple[float, float]], effects: Sequence[str],
                       settings, base=None, fixed: Sequence[str] = (),
                       fdi_options: Mapping[str, float] | None = None
                       ) -> tuple[dict[str, float], dict[str, float], float]:
    """The loop's candidate test of each effect on one healthy record.

    The declared faults are fitted with the model's known structure at its physical values
    (the structure the loop adds first on a simulated record), then each effect of
    ``effects`` is refitted on top as a round of the loop refits it
    (:meth:`eha.explain.loop.ResidualLoop.try_candidate`, with no gate).

    Returns
    -------
    shifts, gains : dict of str to float
        Per effect, its parameter's distance from off and the relative RMSE gain.
    ratio : float
        The residual of faults and structure over the record's noise (what the verdict
        compares with the flag ratio).
    """
    from eha.explain.effects import COMBINATIONS, EFFECTS, missing_requirements
    from eha.explain.loop import ResidualLoop

    STRUCTURAL_ORDER = [name for combo in COMBINATIONS for name in combo]

    # the structure is always in the pool: the null's baseline carries it
    pool = list(dict.fromkeys([*STRUCTURAL_ORDER, *effects]))
    loop = ResidualLoop(data, dict(fit), pool, None, base, settings, fixed,
                        pin_structure=True, **dict(fdi_options or {}))
    loop.thresholds = None          # the statistic itself: no gate
    start, free = loop.current, dict(loop.bounds)
    for effect in loop.pinned:
        start = effect.switch_on(start)
        free.update(effect.bounds)
    # the state of the loop once it has added the structure: its parameters are refitted
    # with the faults in every later round (joint refits)
    # (one GA start: the null's baseline needs to be good, not the best of several)
    loop.current = loop.refit(start, free, "healthy record: the declared faults", starts=1)
    loop.cur = loop.evaluate([loop.current])[0]
    loop.free = free
    from eha.identification.intervals import noise_reference
    ratio = loop.cur.rmse_all / noise_reference(loop.noise, data.xu)
    shifts, gains = {}, {}
    for effect in loop.pool:
        if effect.name in STRUCTURAL or effect.name not in effects or not effect.params:
            continue
        members = [EFFECTS[n] for n in missing_requirements(effect, loop.current)] + [effect]
        start, free_e = loop.candidate_start(members)
        local, _ = loop.local_test(start, free_e, members)
        shifts[effect.name] = loop.statistic_at(effect, local)
        if effect.shift_key:
            shifts[effect.shift_key] = effect.shift_at(local)
        ev = loop.evaluate([local])[0]
        gains[effect.name] = (1.0 - ev.rmse_score / loop.cur.rmse_score
                              if loop.cur.rmse_score > 0 else 0.0)
    return shifts, gains, float(ratio)


# ------------------------------------------------------------------------------------------
# simulated healthy fleet

def _declared_values(rng: np.random.Generator, fit: Mapping[str, tuple[float, float]]
                     ) -> dict[str, float]:
    out = {}
    for name, (lo, hi) in fit.items():
        law, a, b = DECLARED_DRAW.get(name, ("uniform", lo, hi))
        a, b = max(a, lo), min(b, hi)
        if law == "loguniform" and a > 0:
            out[name] = float(math.exp(rng.uniform(math.log(a), math.log(b))))
        else:
            out[name] = float(rng.uniform(a, b))
    return out


def healthy_record(data, fit: Mapping[str, tuple[float, float]], seed: int,
                   known: Mapping[str, float] | None = None):
    """One simulated healthy record like ``data``: same command (its original samples and
    hold), sampling, length and noise (position; P12 when ``data`` has it).

    The actuator is :func:`eha.identification.healthy.draw_actuator` ``(seed)`` with the declared
    faults drawn by :data:`DECLARED_DRAW` (``default_rng([seed, 3])``); ``seed`` is also the HF's
    dither seed and, with ``[seed, 4]``, the noise's. ``known`` HF parameters (test conditions) are
    set on every actuator.
    """
    from eha.identification.measured import from_arrays, noise_level
    from eha.models.simulate import simulate

    overrides = draw_actuator(seed)
    overrides.update(_declared_values(np.random.default_rng([seed, 3]), fit))
    overrides.update(known or {})
    t_cmd, com = data.command.samples
    trace = simulate("hf", data.command, overrides, t_end=float(t_cmd[-1] - t_cmd[0]),
                     seed=seed)
    rng = np.random.default_rng([seed, 4])
    t = np.asarray(t_cmd, dtype=np.float64) - float(t_cmd[0])
    noise = noise_class(float(data.info.get("noise_m", noise_level(data.xu))))
    xu = np.interp(t, trace.t, trace.xu) + rng.normal(0.0, noise, t.size)
    p12 = None
    if data.p12 is not None:
        sigma_p = noise_class(noise_level(data.p12))
        p12 = np.interp(t, trace.t, trace["p12"]) + rng.normal(0.0, sigma_p, t.size)
    record = from_arrays(t, np.asarray(com, dtype=np.float64), xu, p12,
                         source=f"healthy actuator {seed}",
                         command_hold=data.info.get("command_hold", "auto"))
    return record, overrides


def _fleet_member(args):
    data, fit, effects, settings, seed, base, fixed, fdi_options = args
    known = {}
    if base is not None and fixed:
        from eha.models.params import SPECS
        # a known test condition (a test load) is the healthy fleet's too
        known = {n: getattr(base, n) for n in fixed if "hf" in SPECS[n].models}
    record, _ = healthy_record(data, fit, seed, known)
    return healthy_statistics(record, fit, effects, settings, base, fixed, fdi_options)
