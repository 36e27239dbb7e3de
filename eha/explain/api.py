"""The residual loop's entry points: :func:`explain` (a record in, an :class:`ExplainResult`
out: the healthy null, the loop's first pass and, when it leaves a residual beyond what healthy
actuators leave on the command, its second pass from the structure pinned; the loop again with the flow gain at nominal when the
final model has it at the edge of its healthy spread) and :func:`healthy_null`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, Mapping

from eha.explain.decide import better_pass, flow_gain_at_edge
from eha.explain.loop import ResidualLoop
from eha.explain.null import Null, NullError, records_null, simulated_null
from eha.explain.problem import Problem
from eha.explain.results import ExplainResult
from eha.explain.settings import SECOND_PASS, STRUCTURAL, ExplainError, LoopSettings
from eha.identification.measured import MeasuredData


#: :func:`explain`'s keywords that are not settings (:class:`LoopSettings`): what the record
#: is explained with, and their defaults.
INPUTS: dict[str, Any] = {"fit": None, "effects": None, "validate": None, "base": None,
                          "fixed": (), "null": "simulate", "first_excluded": None,
                          "on_progress": None}


def arguments(settings: LoopSettings | None, keywords: Mapping[str, Any]
              ) -> tuple[dict[str, Any], LoopSettings]:
    """:func:`explain`'s keywords split into its inputs (:data:`INPUTS`, defaults filled in)
    and ``settings`` overridden by the rest (:meth:`LoopSettings.override`: an unknown name
    is refused, naming it)."""
    inputs = {**INPUTS, **{k: v for k, v in keywords.items() if k in INPUTS}}
    settings = (settings if settings is not None else LoopSettings()).override(
        {k: v for k, v in keywords.items() if k not in INPUTS})
    return inputs, settings


def problem_of(data: MeasuredData, settings: LoopSettings, inputs: Mapping[str, Any],
               validate: bool = True) -> Problem:
    """The :class:`Problem` of ``data`` and :func:`explain`'s ``inputs`` (without the
    validation record unless ``validate``)."""
    return Problem.build(data, settings, inputs["fit"], inputs["effects"],
                         inputs["validate"] if validate else None, inputs["base"],
                         inputs["fixed"])


def explain(data: MeasuredData, settings: LoopSettings | None = None,
            **overrides: Any) -> ExplainResult:
    """Find and add the effects the LF model lacks to explain a measured record.

    Parameters
    ----------
    data : MeasuredData
        The record (:func:`eha.identification.measured.load`).
    settings : LoopSettings, optional
        The loop's settings (default ``LoopSettings()``); ``overrides`` name the ones that
        differ (``holdout=0.2``, ``significance=0.05``, ``pop=12``) and the fitting
        optimizer's options (``max_gen=20``), and give the inputs below. A name that is
        none of these is refused (:class:`ExplainError` naming it).
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
    method, pop, seed, and the optimizer's options (``max_gen``, ``stall``, ...)
        Passed to :func:`eha.identification.fdi.identify` for every fit (same seed for all fits).
    min_gain, penalty, alpha, significance, max_steps, candidates, noise_factor, joint
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

    Every setting is declared once, with its default and its check, in :class:`LoopSettings`
    (:meth:`LoopSettings.problems`): a value outside its range raises :class:`ExplainError`
    naming the keyword (`` `holdout` ``). One :class:`Problem` of the record serves the
    healthy null, every pass and the flow gain's second run.

    Returns
    -------
    ExplainResult
    """
    inputs, settings = arguments(settings, overrides)
    problem = problem_of(data, settings, inputs)
    progress = inputs["on_progress"]
    null = healthy_null(problem, settings, inputs["null"], progress)
    result = _passes(problem, settings, null, progress, inputs["first_excluded"])
    edge = flow_gain_at_edge(result)
    if edge is None:
        return result
    # the flow gain left the healthy actuator's spread: a loss (or surplus) of flow beyond
    # it is the library's to explain (a weak torque motor, a low supply, a clogged filter),
    # not the actuator's own; fitted, GQ would stand in for it. The loop runs again with GQ
    # at the base's value and that run is reported
    if progress:
        progress(f"{edge}: the loop again with GQ at its nominal value")
    again = _passes(problem.without_flow_gain(), replace(settings, flow_gain_spread=0.0), null,
                    progress, inputs["first_excluded"])
    again.settings["flow_gain_spread"] = settings.flow_gain_spread
    again.facts.flow_gain_released = edge
    again.seconds += result.seconds
    return again


def settle_prior(data: MeasuredData, prior: Mapping[str, Any],
                 settings: LoopSettings | None = None, **overrides: Any):
    """:func:`eha.explain.settle.settle` on ``data``: the first record's explanations
    (``prior``, its ``--json``) against this record, with the healthy null of this command
    for the nominal ``base`` (known test conditions only). ``settings`` and ``overrides``:
    :func:`explain`'s (its ``validate`` is not used). Returns the
    :class:`~eha.explain.settle.Settlement`, or None when the prior lists no rival."""
    from eha.explain.settle import settle

    inputs, settings = arguments(settings, overrides)
    problem = problem_of(data, settings, inputs, validate=False)
    found = healthy_null(problem, settings, inputs["null"], inputs["on_progress"])
    loop = ResidualLoop(problem, settings, found, inputs["on_progress"], pin_structure=True)
    return settle(loop, prior)


def healthy_null(problem: Problem, settings: LoopSettings, null: Any = "simulate",
                 on_progress: Callable[[str], None] | None = None):
    """The :class:`~eha.explain.null.Null` of :func:`explain`'s ``null`` argument for the
    record of ``problem``: simulated on its command (cached), read from a folder of healthy
    records, given, or None."""
    if null is None or isinstance(null, Null):
        return null
    data, base = problem.data, problem.given_base
    names = [e.name for e in problem.pool]
    options = dict(settings.options)
    try:
        if isinstance(null, str) and null == "simulate":
            return simulated_null(
                data, problem.bounds, names, settings, actuators=settings.null_actuators,
                base=problem.base if base is not None else None, fixed=list(problem.fixed),
                on_progress=on_progress, fdi_options=options)
        return records_null(null, problem.bounds, names, settings,
                            command_hold=data.info.get("command_hold", "auto"), base=base,
                            fixed=list(problem.fixed), on_progress=on_progress,
                            fdi_options=options, record=data)
    except NullError as exc:
        raise ExplainError(str(exc)) from None


def _passes(problem: Problem, settings: LoopSettings, null: Any = None,
            on_progress: Callable[[str], None] | None = None,
            first_excluded: Mapping[str, Mapping[str, Any]] | None = None) -> ExplainResult:
    """The loop's first pass and, when it leaves a residual beyond the healthy band
    (``beyond_healthy``), its second pass from
    the structure pinned (:func:`better_pass` picks the result)."""
    first = ResidualLoop(problem, settings, null, on_progress, first_excluded=first_excluded)
    result = first.run()
    structure = [e for e in problem.pool if e.name in STRUCTURAL]
    if not (result.beyond_healthy and SECOND_PASS and structure
            and len(structure) <= settings.max_steps):
        return result
    # a model still far from the noise may have been led astray in its first rounds: an
    # effect fitted while the structure was missing (or in a side basin, a flapper at 760
    # rad/s and 0.18 damping standing in for a clogged filter) set the path. The rounds run
    # once more from the model's known structure at its physical values
    if on_progress:
        on_progress("second pass: the structure pinned at its physical values")
    second = ResidualLoop(problem, settings, null, on_progress, pin_structure=True,
                          first_excluded=first_excluded).run()
    chosen = better_pass(result, second, settings)
    chosen.seconds = result.seconds + second.seconds
    chosen.facts.passes = 2
    return chosen
