"""How far the loop's reading moves when the actuator it found is simulated again: the
replicate term of the final intervals (:meth:`eha.explain.loop.ResidualLoop.final_intervals`).

The HAC sandwich (:mod:`eha.identification.intervals`) treats the residual as stationary
noise. The HF's dither, 10 µA every millisecond, makes the jack's stick and slip at each
reversal a random event; with a jack friction of 800 N it leaves bursts at the reversals that
the LF's mean-field dither does not reproduce, and a small effect that acts through the same
force is read off by them: a hinge moment of 8270 N/m read 7-15 % low (1 of 5 intervals
covering), a viscous friction of 5500 N·s/m 8 % low (0 of 5), an external load of 800 N 2 %
high (0 of 5), each on its separating design; beside 200 N of friction, or without the dither,
within 1-2 % and covered (``validation/design_reading.py``).

The replicate term measures that at the record's own operating point: the final model's
declared faults, the effects it started with (a prior's: :func:`started_effects`) and the
added effects' parameters, the ones the HF has, are put on the nominal HF, which is simulated
again on the record's command ``replicates`` times with fresh dither and noise (seeds
:data:`REPLICATE_SEED` + 1000 x the loop's seed + k), and the final
model is refitted to each by least squares from the final estimate. The root mean square of
each parameter's deviation -- bias and scatter together -- is added in quadrature to its
interval's floors. It is our HF's model form at this point, not a real actuator's: on an
actuator without dither it widens intervals that did not need it.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

import numpy as np

from eha.models.params import ParameterError

#: First seed of the HF re-simulations (dither and noise) of the replicate term.
REPLICATE_SEED = 770_000


def hf_overrides(params, names) -> dict[str, float]:
    """The HF parameters of the final model: ``names`` that the HF model has, at their values
    in ``params``."""
    from eha.models.params import SPECS

    return {n: float(getattr(params, n)) for n in names if n in SPECS
            and "hf" in SPECS[n].models}


def started_effects(base, fitted=()) -> dict[str, float]:
    """The HF parameters of the effects ``base`` starts with (a prior's, a settled one): every
    effect on in ``base`` but the model's known structure (the HF has its own), at its LF
    value, less the ``fitted`` parameters. Every re-simulation of a loop on ``base`` carries
    them, as the healthy fleet behind its null does (:mod:`eha.explain.healthy_fleet`): the
    question the loop asks is what such an actuator leaves, not what a healthy one does."""
    from eha.explain.effects import EFFECTS
    from eha.explain.settings import STRUCTURAL

    if base is None:
        return {}
    names = [p for e in EFFECTS.values() if e.name not in STRUCTURAL and e.is_on(base)
             for p in e.params]
    return hf_overrides(base, [n for n in names if n not in fitted])


def model_overrides(loop, params, names) -> dict[str, float]:
    """What a re-simulation of ``loop``'s model ``params`` puts on the HF: the known test
    conditions, the effects the loop started with (:func:`started_effects`) and ``names`` at
    their values in ``params`` (those the HF has)."""
    base = loop.problem.base
    return {**hf_overrides(base, loop.problem.fixed), **started_effects(base, loop.bounds),
            **hf_overrides(params, names)}


def resimulated(loop, overrides: Mapping[str, float], seed: int):
    """A :class:`~eha.explain.fitting.Fitter` of ``loop``'s fit (its bounds now, base,
    settings and known parameters) on a re-simulation of the nominal HF with ``overrides``,
    on ``loop``'s command, sampling and noise, with fresh dither and noise from ``seed``: the
    re-simulation's own :class:`~eha.explain.problem.Problem`, no null and no progress."""
    from eha.explain.fitting import Fitter
    from eha.explain.problem import Problem
    from eha.explain.simulated_record import healthy_record

    record, _ = healthy_record(loop.problem.data, {}, seed, overrides, scatter=False)
    problem = Problem.build(record, loop.settings, dict(loop.bounds), [], None,
                            loop.problem.base, loop.problem.fixed)
    return Fitter(problem, loop.settings)


def replicate_spread(loop, params, bounds: Mapping[str, tuple[float, float]],
                     hf_names, replicates: int, seed: int = 0
                     ) -> tuple[dict[str, float], list[int]]:
    """RMS deviation of each parameter of ``bounds`` over ``replicates`` least-squares refits
    of ``params`` to HF re-simulations of it (see the module docstring).

    Parameters
    ----------
    loop : ResidualLoop
        The loop whose final model is ``params`` (its record, base, settings, known
        parameters and fit options).
    params : LFParams
        The final model.
    bounds : mapping
        Every fitted parameter and its bounds.
    hf_names : iterable of str
        Parameters put on the HF (the declared faults and the added effects'); those the HF
        does not have are left at the HF's own.
    replicates : int
        Re-simulations (0: none).
    seed : int
        The loop's seed.

    Returns
    -------
    spread : dict of str to float
        Per parameter, the RMS deviation [its unit]; empty with fewer than two refits that
        ended finite.
    seeds : list of int
        The seeds of the re-simulations.
    """
    seeds = [REPLICATE_SEED + 1000 * seed + k for k in range(replicates)]
    deviations: dict[str, list[float]] = {n: [] for n in bounds}
    for refit, _ in _refits(loop, params, bounds, hf_names, seeds):
        values = {n: float(getattr(refit, n)) - float(getattr(params, n)) for n in bounds}
        if all(math.isfinite(v) for v in values.values()):
            for n, v in values.items():
                deviations[n].append(v)
    if min((len(v) for v in deviations.values()), default=0) < 2:
        return {}, seeds
    return {n: float(np.sqrt(np.mean(np.square(v)))) for n, v in deviations.items()}, seeds


def _refits(loop, params, bounds: Mapping[str, tuple[float, float]], hf_names,
            seeds: list[int]) -> list[tuple]:
    """``(refit, residual-to-noise ratio)`` of ``params`` refitted by least squares on the whole
    of each HF re-simulation of it (one per seed; none where the HF refuses the model). Kept on
    ``loop`` (its ``replicate_refits``): the intervals' replicate term and :func:`model_level`
    share them."""
    key = (tuple(sorted(bounds)), tuple(sorted(hf_names)), tuple(seeds),
           tuple(float(getattr(params, n)) for n in sorted({*bounds, *hf_names})))
    cache = loop.replicate_refits
    if key in cache:
        return cache[key]
    overrides = model_overrides(loop, params, hf_names)
    out = []
    for s in seeds:
        try:
            again = resimulated(loop, overrides, s)
        except (ParameterError, FloatingPointError, ValueError):
            continue        # a model the HF refuses (a value beyond its range): no replicate
        refit = again.refit(params, dict(bounds), "interval replicate", method="lm",
                            whole=True)
        ev = again.evaluate([refit])[0]
        out.append((refit, ev.rmse_all / again.problem.noise_ref))
    cache[key] = out
    return out


def model_level(loop, bounds: Mapping[str, tuple[float, float]], hf_names,
                record_ratio: float, restarts: bool = True) -> dict:
    """What the final model leaves on the HF simulated again with it: its residual-to-noise
    ratio over ``interval_replicates`` least-squares refits (the replicate term's
    re-simulations), their mean, standard deviation and one-sided prediction bound at the
    loop's ``alpha`` (Student t, ``mean + t s sqrt(1 + 1/n)``), beside the record's own
    level. A record above the noise but within that bound leaves what an actuator with
    exactly the found model leaves: the LF's model form at this point, not a missing effect
    (our HF's model form, not a real actuator's). Empty with fewer than two refits.

    Each re-simulation is refitted from the values that made it; the record was fitted by the
    loop's search, which can stop in a nearby minimum of the same model (a clogging and a
    sensor bias on the 0.6-s test: 1.87x where the right model reaches 1.75x from the truth,
    above a bound of 1.84x). So that both are read alike, with ``restarts`` the record is
    refitted (least squares, the whole record) from one more start per re-simulation: the
    final estimate moved by that re-simulation's refit error, mirrored (``2 x final - refit``,
    within the bounds), where the best fit may lie if the record's estimate is off by as much;
    the record's level (``record``) is the lowest of its own ``record_ratio`` (``record_loop``)
    and those (``restarts``). Those fits are not taken as the final model: its intervals were
    computed at the loop's estimate."""
    from scipy.stats import t as student

    n = loop.settings.interval_replicates
    seeds = [REPLICATE_SEED + 1000 * loop.settings.seed + k for k in range(n)]
    loop.progress(f"residual: {n} HF re-simulations of the final model")
    refits = _refits(loop, loop.current, bounds, hf_names, seeds)
    ratios = [r for _, r in refits if math.isfinite(r)]
    again = _restarted(loop, bounds, [p for p, _ in refits]) if restarts else []
    if len(ratios) < 2:
        return {}
    mean, std = float(np.mean(ratios)), float(np.std(ratios, ddof=1))
    k = len(ratios)
    bound = mean + float(student.ppf(1.0 - loop.settings.alpha, k - 1)) * std * math.sqrt(
        1.0 + 1.0 / k)
    record = min([float(record_ratio), *again])
    return {"record": record, "record_loop": float(record_ratio), "restarts": again,
            "ratios": ratios, "mean": mean, "std": std, "bound": bound,
            "within": bool(record <= bound), "seeds": [seeds[0], seeds[-1]]}


def explains(level: Mapping[str, Any], residual_limit: float) -> bool:
    """Does a record's :func:`model_level` explain its rest: the record within the found
    model's own prediction bound, that bound below ``residual_limit`` (the ratio healthy
    actuators reach on the command), and no added effect at a bound of its range
    (``at_bound``, :func:`at_a_bound`)? A bound at or beyond the healthy band's limit decides
    nothing: re-simulations that scatter as widely as healthy actuators do would call any
    record within the band explained."""
    return (bool(level) and bool(level.get("within")) and not level.get("at_bound")
            and float(level["bound"]) < residual_limit)


def at_a_bound(params, effects: Iterable[str]) -> list[str]:
    """The parameters of the added ``effects`` whose value in ``params`` sits at a bound of
    the effect's range other than its off value: within
    :data:`~eha.explain.settings.FLOW_GAIN_EDGE` of the range's width, the margin at which the
    flow gain is at the edge of its spread. The bootstrap of an estimate on the boundary of its
    parameter space is not consistent (D. W. K. Andrews, "Inconsistency of the bootstrap when
    a parameter is on the boundary of the parameter space", Econometrica 68, 2000): the
    re-simulations are refitted within the same range and cannot show what the record's fit
    would do beyond it, so a model pinned at a bound is not tested by its own level (a motor
    offset at 2.0 mA of ±2 beside a sensor gain and the bias of f10, a held-step record)."""
    from eha.explain.effects import EFFECTS
    from eha.explain.settings import FLOW_GAIN_EDGE

    out = []
    for name in effects:
        effect = EFFECTS[name]
        for param, (lo, hi) in effect.bounds.items():
            value, margin = float(getattr(params, param)), FLOW_GAIN_EDGE * (hi - lo)
            off = effect.off.get(param)
            if any(abs(value - b) <= margin and (off is None or abs(off - b) > margin)
                   for b in (lo, hi)):
                out.append(param)
    return out


def _restarted(loop, bounds: Mapping[str, tuple[float, float]], refits) -> list[float]:
    """The record's residual-to-noise ratio refitted (least squares, whole record) from the
    final estimate moved by each re-simulation's refit error, mirrored and kept within
    ``bounds`` (see :func:`model_level`); none for a start whose fit fails (the list stays
    plain JSON)."""
    from eha.explain.settings import ExplainError

    reference = loop.problem.noise_ref
    out = []
    for refit in refits:
        start = loop.current.replace(**{
            name: min(max(2.0 * getattr(loop.current, name) - getattr(refit, name), lo), hi)
            for name, (lo, hi) in bounds.items()})
        try:
            fitted = loop.fitter.refit(start, dict(bounds),
                                       "residual: the record from another start",
                                       method="lm", whole=True)
            ratio = float(loop.fitter.evaluate([fitted])[0].rmse_all / reference)
        except (ExplainError, ParameterError, FloatingPointError, ValueError):
            continue
        if math.isfinite(ratio):
            out.append(ratio)
    return out


def with_replicates(loop, terms: Mapping, bounds: Mapping[str, tuple[float, float]],
                    added) -> tuple[dict, str | None]:
    """``terms`` (the final model's :class:`~eha.identification.intervals.ModelForm` per
    parameter) with the replicate spread (:func:`replicate_spread`) added in quadrature to
    each ``abs`` floor, and the note that says so; ``terms`` unchanged and no note when the
    loop's ``interval_replicates`` is 0 or the refits failed. ``added``: the effects the loop
    added (their parameters are put on the HF with the declared faults)."""
    from eha.explain.effects import EFFECTS
    from eha.identification.intervals import ModelForm

    n = loop.settings.interval_replicates
    if not n:
        return dict(terms), None
    names = [*loop.bounds, *(p for e in added for p in EFFECTS[e].params)]
    loop.progress(f"intervals: {n} HF re-simulations of the final model")
    spread, seeds = replicate_spread(loop, loop.current, bounds, names, n, loop.settings.seed)
    if not spread:
        return dict(terms), (f"the {n} HF re-simulations of the final model did not refit: "
                             "intervals without their spread")
    out = {k: ModelForm(scale=t.scale, rel=t.rel, abs=math.hypot(t.abs, spread.get(k, 0.0)))
           for k, t in terms.items()}
    return out, (f"intervals include the spread of {n} refits to HF re-simulations of the "
                 f"final model (dither and noise; seeds {seeds[0]}-{seeds[-1]})")
