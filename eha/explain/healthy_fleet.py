"""The healthy fleet behind the residual loop's null (:mod:`eha.explain.null`): one simulated
healthy record like the user's (:func:`~eha.explain.simulated_record.healthy_record`) and the
loop's candidate test of each effect on it (:func:`healthy_statistics`), the statistic whose
distribution the null is.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from eha.explain.settings import STRUCTURAL
from eha.explain.simulated_record import healthy_record


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
    (:meth:`eha.explain.loop.ResidualLoop.try_candidate`, with no gate), on the record's
    :class:`~eha.explain.problem.Problem` and a :class:`~eha.explain.fitting.Fitter`.

    Returns
    -------
    shifts, gains : dict of str to float
        Per effect, its parameter's distance from off and the relative RMSE gain.
    ratio : float
        The residual of faults and structure over the record's noise (what the verdict
        compares with the flag ratio).
    """
    from dataclasses import replace

    from eha.explain.decide import relative_gain
    from eha.explain.effects import COMBINATIONS, EFFECTS, missing_requirements
    from eha.explain.fitting import Fitter
    from eha.explain.problem import Problem

    STRUCTURAL_ORDER = [name for combo in COMBINATIONS for name in combo]

    # the structure is always in the pool: the null's baseline carries it
    pool = list(dict.fromkeys([*STRUCTURAL_ORDER, *effects]))
    settings = replace(settings, options=dict(fdi_options or {}))
    problem = Problem.build(data, settings, dict(fit), pool, None, base, fixed)
    fitter = Fitter(problem, settings)          # the statistic itself: no gate
    start, free = problem.base, problem.bounds
    for effect in [e for e in problem.pool if e.name in STRUCTURAL]:
        start = effect.switch_on(start)
        free.update(effect.bounds)
    # the state of the loop once it has added the structure: its parameters are refitted
    # with the faults in every later round (joint refits)
    # (one GA start: the null's baseline needs to be good, not the best of several)
    current = fitter.refit(start, free, "healthy record: the declared faults", starts=1)
    cur = fitter.evaluate([current])[0]
    ratio = cur.rmse_all / problem.noise_ref
    shifts, gains = {}, {}
    for effect in problem.pool:
        if effect.name in STRUCTURAL or effect.name not in effects or not effect.params:
            continue
        members = [EFFECTS[n] for n in missing_requirements(effect, current)] + [effect]
        start, free_e = fitter.candidate_start(members, current, free)
        local, _ = fitter.local_test(start, free_e, members, "round 0")
        shifts[effect.name] = fitter.statistic_at(effect, local)
        if effect.shift_key:
            shifts[effect.shift_key] = effect.shift_at(local)
        ev = fitter.evaluate([local])[0]
        gains[effect.name] = relative_gain(cur, ev)
    return shifts, gains, float(ratio)


def fleet_actuator(data, fit: Mapping[str, tuple[float, float]], seed: int, base=None,
                   fixed: Sequence[str] = ()):
    """The healthy fleet's actuator ``seed`` on ``data``'s command: its record and HF
    parameters (:func:`~eha.explain.simulated_record.healthy_record`). A known test condition
    (``fixed``: a test load) is every actuator's; so are the effects ``base`` starts with (a
    prior's, a settled one: :func:`~eha.explain.replicates.started_effects`), each scattered as
    the part it changes is. The null is then what an actuator *with* those effects leaves, the
    question the loop asks when it starts from them: without them on the HF a settled motor
    gain left a healthy actuator's own leakage of 1e-13 m^3/(s*Pa) to be found beside it."""
    from eha.explain.replicates import hf_overrides, started_effects

    known = hf_overrides(base, fixed) if base is not None and fixed else {}
    return healthy_record(data, fit, seed, known, started=started_effects(base, fit))


def _fleet_member(args):
    data, fit, effects, settings, seed, base, fixed, fdi_options = args
    record, _ = fleet_actuator(data, fit, seed, base, fixed)
    return healthy_statistics(record, fit, effects, settings, base, fixed, fdi_options)
