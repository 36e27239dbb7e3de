"""The residual loop's entry points: :func:`explain` (a record in, an :class:`ExplainResult`
out: the healthy null, the loop's first pass and, when it leaves a residual beyond what healthy
actuators leave on the command, its second pass from the structure pinned; the loop again with the flow gain at nominal when the
final model has it at the edge of its healthy spread) and :func:`healthy_null`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, Iterable, Mapping

from eha.explain.decide import better_pass, flow_gain_at_edge
from eha.explain.loop import ResidualLoop
from eha.explain.null import Null, NullError, records_null, simulated_null
from eha.explain.results import ExplainResult
from eha.explain.settings import SECOND_PASS, STRUCTURAL, ExplainError, LoopSettings
from eha.identification.problem import DEFAULT_METHOD
from eha.identification.measured import MeasuredData
from eha.models.params import LFParams


def explain(data: MeasuredData, *, fit: Any = None,
            effects: Iterable[str] | str | None = None, holdout: float | None = None,
            validate: MeasuredData | None = None, base: LFParams | None = None,
            fixed: Iterable[str] = (), null: Any = "simulate", method: str | None = None,
            pop: int = 20, seed: int = 0, min_gain: float | None = None,
            penalty: float | None = None, alpha: float | None = None,
            max_steps: int | None = None, candidates: int | None = None,
            noise_factor: float | None = None, joint: bool | None = None,
            p12_weight: float | None = None, flow_gain_spread: float | None = None,
            null_actuators: int | None = None, interval_replicates: int | None = None,
            rival_replicates: int | None = None, first_excluded: Mapping | None = None,
            on_progress: Callable[[str], None] | None = None,
            **fdi_options: float) -> ExplainResult:
    """Find and add the effects the LF model lacks to explain a measured record.

    Parameters
    ----------
    data : MeasuredData
        The record (:func:`eha.identification.measured.load`).
    fit : str or mapping, optional
        Declared fault parameters and bounds (:func:`parse_fit`); default BKL, FDJ.
    effects : names, optional
        Candidate effects (names of docs/model.md's effect table); default all of
        :data:`eha.explain.effects.EFFECTS`.
    holdout : float, optional
        Fraction of the record (at its end) held out for scoring, in [0, 0.8]; default 0.3.
    validate : MeasuredData, optional
        A second record used as held-out data instead (the first is then fitted whole).
    base : LFParams, optional
        Starting LF parameters (nominal by default; XJ0 is set from the record's command).
    method, pop, seed, **fdi_options
        Passed to :func:`eha.identification.fdi.identify` for every fit (same seed for all fits).
    min_gain, penalty, alpha, max_steps, candidates, noise_factor, joint
        The stop and choice rules (:class:`LoopSettings`, where their defaults are).
    p12_weight : float, optional
        Weight of a measured P12 in the fits (:class:`LoopSettings`; 0 = position only).
    flow_gain_spread : float, optional
        The healthy flow gain's range, fitted with the faults (:class:`LoopSettings`;
        0 = GQ held at the base's value). A GQ at the edge of that range goes back to the
        base's value: after the declared faults' fit (:meth:`ResidualLoop.baseline`), or, at
        the end (:func:`flow_gain_at_edge`), by running the loop again and reporting that
        run; ``facts.flow_gain_released`` says why.
    fixed : names, optional
        LF parameters held at their values in ``base`` (known test conditions, ``eha explain
        --set``): not fitted, and no effect touching them is a candidate.
    alpha : float, optional
        False-positive level per record (:class:`LoopSettings`, default 0.05).
    null : "simulate", str or Path, Null or None
        What healthy looks like on this record's command (:mod:`eha.explain.null`):
        ``"simulate"`` (default) a simulated healthy fleet driven by the record's command,
        cached; a folder of the user's healthy records; a ready
        :class:`~eha.explain.null.Null`; None for no null (an effect is then refused only
        when its fit switches it off: for records made by the LF model itself, which have no
        healthy scatter).
    null_actuators : int, optional
        Healthy actuators of a simulated null (:class:`LoopSettings`, default 12).
    interval_replicates : int, optional
        HF re-simulations of the final model whose refits widen the intervals of a model the
        loop built (:class:`LoopSettings`, default 6; 0: none).
    rival_replicates : int, optional
        HF re-simulations without and with a rival the exclusion check lists, which may rule
        it out (:class:`LoopSettings`, default 6; 0: none).
    first_excluded : mapping, optional
        A first record's ``excluded``: :func:`eha.explain.rival_check.deferred_to_first`.
    on_progress : callable(str), optional
        Called with a short message before each fit.

    Every setting is a keyword, checked in one place (:meth:`LoopSettings.problems`): a value
    outside its range raises :class:`ExplainError` naming the keyword (`` `holdout` ``).

    Returns
    -------
    ExplainResult
    """
    given = {"holdout": holdout, "min_gain": min_gain, "penalty": penalty, "alpha": alpha,
             "max_steps": max_steps, "candidates": candidates, "noise_factor": noise_factor,
             "joint": joint, "p12_weight": p12_weight, "flow_gain_spread": flow_gain_spread,
             "null_actuators": null_actuators, "interval_replicates": interval_replicates,
             "rival_replicates": rival_replicates}
    settings = loop_settings(given, method, pop, seed)
    null = healthy_null(data, fit, effects, base, settings, fixed, null, on_progress,
                        fdi_options)
    result = _passes(data, fit, effects, validate, base, settings, fixed, on_progress,
                     fdi_options, null, first_excluded)
    edge = flow_gain_at_edge(result)
    if edge is None:
        return result
    # the flow gain left the healthy actuator's spread: a loss (or surplus) of flow beyond
    # it is the library's to explain (a weak torque motor, a low supply, a clogged filter),
    # not the actuator's own; fitted, GQ would stand in for it. The loop runs again with GQ
    # at the base's value and that run is reported
    if on_progress:
        on_progress(f"{edge}: the loop again with GQ at its nominal value")
    again = _passes(data, fit, effects, validate, base,
                    replace(settings, flow_gain_spread=0.0), fixed, on_progress, fdi_options,
                    null, first_excluded)
    again.settings["flow_gain_spread"] = settings.flow_gain_spread
    again.facts.flow_gain_released = edge
    again.seconds += result.seconds
    return again


def loop_settings(given: Mapping[str, Any], method: str | None = None, pop: int = 20,
                  seed: int = 0) -> LoopSettings:
    """:class:`LoopSettings` from :func:`explain`'s keywords (None: the default)."""
    given = {k: v for k, v in given.items() if v is not None}
    return LoopSettings(**given, method=method or DEFAULT_METHOD, pop=pop, seed=seed)


def settle_prior(data: MeasuredData, prior: Mapping[str, Any], *, fit: Any = None,
                 effects: Iterable[str] | str | None = None, base: LFParams | None = None,
                 fixed: Iterable[str] = (), null: Any = "simulate", method: str | None = None,
                 pop: int = 20, seed: int = 0,
                 on_progress: Callable[[str], None] | None = None, **keywords: Any):
    """:func:`eha.explain.settle.settle` on ``data``: the first record's explanations
    (``prior``, its ``--json``) against this record, with the healthy null of this command
    for the nominal ``base`` (known test conditions only). ``keywords``: :func:`explain`'s
    settings and fit options. Returns the :class:`~eha.explain.settle.Settlement`, or None
    when the prior lists no rival."""
    from eha.explain.settle import settle

    names = set(LoopSettings.__dataclass_fields__)
    settings = loop_settings({k: v for k, v in keywords.items() if k in names}, method, pop,
                             seed)
    fdi_options = {k: v for k, v in keywords.items() if k not in names and k != "validate"}
    found = healthy_null(data, fit, effects, base, settings, fixed, null, on_progress,
                         fdi_options)
    loop = ResidualLoop(data, fit, effects, None, base, settings, fixed, on_progress,
                        pin_structure=True, null=found, **fdi_options)
    return settle(loop, prior)


def healthy_null(data: MeasuredData, fit: Any, effects: Iterable[str] | str | None,
                 base: LFParams | None, settings: LoopSettings, fixed: Iterable[str],
                 null: Any, on_progress: Callable[[str], None] | None = None,
                 fdi_options: Mapping[str, float] | None = None):
    """The :class:`~eha.explain.null.Null` of :func:`explain`'s ``null`` argument for this
    record: simulated on its command (cached), read from a folder of healthy records, given,
    or None."""
    if null is None or isinstance(null, Null):
        return null
    probe = ResidualLoop(data, fit, effects, None, base, settings, fixed)
    names = [e.name for e in probe.pool]
    try:
        if isinstance(null, str) and null == "simulate":
            return simulated_null(
                data, probe.bounds, names, settings, actuators=settings.null_actuators,
                base=probe.base if base is not None else None, fixed=list(fixed),
                on_progress=on_progress, fdi_options=fdi_options)
        return records_null(null, probe.bounds, names, settings,
                            command_hold=data.info.get("command_hold", "auto"), base=base,
                            fixed=list(fixed), on_progress=on_progress, fdi_options=fdi_options,
                            record=data)
    except NullError as exc:
        raise ExplainError(str(exc)) from None


def _passes(data: MeasuredData, fit: Any, effects: Iterable[str] | str | None,
            validate: MeasuredData | None, base: LFParams | None, settings: LoopSettings,
            fixed: Iterable[str], on_progress: Callable[[str], None] | None,
            fdi_options: Mapping[str, float], null: Any = None,
            first_excluded: Mapping[str, Mapping[str, Any]] | None = None) -> ExplainResult:
    """The loop's first pass and, when it leaves a residual beyond the healthy band
    (``beyond_healthy``), its second pass from
    the structure pinned (:func:`better_pass` picks the result)."""
    first = ResidualLoop(data, fit, effects, validate, base, settings, fixed, on_progress,
                         null=null, first_excluded=first_excluded, **fdi_options)
    result = first.run()
    structure = [e for e in first.pool if e.name in STRUCTURAL]
    if not (result.beyond_healthy and SECOND_PASS and structure
            and len(structure) <= settings.max_steps):
        return result
    # a model still far from the noise may have been led astray in its first rounds: an
    # effect fitted while the structure was missing (or in a side basin, a flapper at 760
    # rad/s and 0.18 damping standing in for a clogged filter) set the path. The rounds run
    # once more from the model's known structure at its physical values
    if on_progress:
        on_progress("second pass: the structure pinned at its physical values")
    second = ResidualLoop(data, fit, effects, validate, base, settings, fixed, on_progress,
                          pin_structure=True, null=null, first_excluded=first_excluded,
                          **fdi_options).run()
    chosen = better_pass(result, second, settings)
    chosen.seconds = result.seconds + second.seconds
    chosen.facts.passes = 2
    return chosen
