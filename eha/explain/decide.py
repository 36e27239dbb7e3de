"""The residual loop's decision rule: pure functions on numbers (scored RMSE, gains, p-values,
effective samples) and on candidates already scored, unit-tested without simulation.

:func:`significance` (the F test on effective samples), :func:`choose` (what a round adds),
:func:`unspecific` (a gain unrelated effects match), :func:`keeps_effect` (does an effect pay
for itself next to the others), :func:`trades_position` (a gain on P12 bought with the
position), :func:`split_combination` (the members of a combination that pay), and the
passes' rules: :func:`edge_of_spread` / :func:`flow_gain_at_edge` (a flow gain at the edge of
its healthy spread) and :func:`better_pass`; :func:`past_any` (an effect's statistics against
the null's bars). Where a rule needs a model evaluation it is
handed in as a callable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from eha.explain.effects import EFFECTS, Effect
from eha.explain.results import Candidate, Evaluation, ExplainResult
from eha.explain.settings import (ALTERNATIVE_MARGIN, CONFIRM_FRACTION, FLOW_GAIN_EDGE,
                                  POSITION_WORSENING, RIVAL_MARGIN, SPECIFIC_GAIN, STRUCTURAL,
                                  LoopSettings)
from eha.models.params import LFParams


def relative_gain(before: Evaluation, after: Evaluation) -> float:
    """The relative reduction of the scored RMSE (:attr:`Evaluation.rmse_score`) from
    ``before`` to ``after``; 0 when ``before`` scores 0 (nothing left to reduce)."""
    if before.rmse_score > 0:
        return 1.0 - after.rmse_score / before.rmse_score
    return 0.0


def significance(before: float, after: float, added: int, n_eff: float) -> float:
    """p-value of the RMSE reduction an added effect brings (an F test on effective samples).

    The residual of a model that lacks structure is correlated over many samples, so a record of
    n samples carries only ``n_eff`` independent ones
    (:func:`eha.identification.intervals.effective_samples`): a gain that would be overwhelming on
    white noise is often chance on a correlated residual. ``F = ((before**2 - after**2) / added) /
    (after**2 / (n_eff - added))``.

    Parameters
    ----------
    before, after : float
        Scored RMSE before and after adding the effect [m].
    added : int
        Parameters the effect adds (a pure switch counts as 1).
    n_eff : float
        Effective independent samples of the residual.
    """
    from scipy.stats import f as f_dist

    added = max(int(added), 1)
    dof = n_eff - added
    if not (math.isfinite(before) and math.isfinite(after)) or dof <= 1 or after <= 0:
        return 0.0 if after <= 0 < before else 1.0
    if after >= before:
        return 1.0
    stat = ((before ** 2 - after ** 2) / added) / (after ** 2 / dof)
    return float(f_dist.sf(stat, added, dof))


@dataclass
class Choice:
    """What :func:`choose` decided in one round."""

    best: Candidate | None
    #: the candidate names the choice set aside (combinations replaced by their kept members)
    superseded: set[str] = field(default_factory=set)
    #: effect objects of the chosen candidate, in report order
    members: list[str] = field(default_factory=list)
    stop: str = ""
    alternatives: dict[str, float] = field(default_factory=dict)
    #: candidates set aside because unrelated effects explain as much (:func:`unspecific`),
    #: best first
    unspecific: list[str] = field(default_factory=list)
    #: candidates set aside because their gain was not significant on the record's effective
    #: samples, best first
    insignificant: list[str] = field(default_factory=list)


NOTHING_IMPROVED = ("no candidate improved the model (every refit left its effect within its "
                    "healthy band on this command or fitted the pressure at the position's "
                    "expense)")


def past_any(statistics: Mapping[str, float | None], bars: Mapping[str, float]) -> bool:
    """Whether any of an effect's statistics is past its bar (the null's thresholds or its
    detectable sizes, by the null's statistic keys): with the union bound each statistic is
    one of the ``m``, so one past its own bar is enough (the supply pressure's footprint or
    its PSR shift). A statistic without a bar, or None, is never past it; one that is not a
    number (a diverged fit) is."""
    return any(v is not None and not v <= bars.get(k, math.inf) for k, v in statistics.items())


def choose(tried: list[Candidate], settings: LoopSettings,
           split: Callable[[Candidate], list[str]],
           refit_members: Callable[[Candidate, list[str]], Candidate | None],
           beyond_healthy: bool = False) -> Choice:
    """Pick the effect (or combination) to add from the refitted candidates of a round.

    The best-scoring candidate wins when its penalised gain reaches ``settings.min_gain``, its
    gain is significant (``p_value < settings.significance``) and specific (:func:`unspecific`: no
    unrelated effect explains as much). A winning combination whose members
    do not all pay for themselves (``split`` returns the names kept) is replaced by the kept
    members as a candidate of its own (``refit_members``: the candidate refitted with only
    those, or None when it switches an effect off), and the choice is made again.

    A candidate made only of the model's known structure (:data:`STRUCTURAL`) that clears
    ``min_gain`` and is significant is chosen before any other effect: the structure first.

    ``beyond_healthy``: the model the round extends leaves more than faults and structure
    leave on healthy actuators of this command (:meth:`ResidualLoop.unexplained`). A rival
    refused by its gate then no longer counts against ``best``'s specificity
    (:func:`unspecific`).

    Pure choice logic: ``split`` and ``refit_members`` hold every model evaluation, so the
    logic is unit-tested on canned candidates.

    Returns
    -------
    Choice
        ``best`` None with ``stop`` set when nothing is added.
    """
    everything = [c for c in tried if c.refit and math.isfinite(c.gain)
                  and not (beyond_healthy and c.score == -math.inf)]
    tried = [c for c in tried if c.refit and c.score > -math.inf]
    if not tried:
        return Choice(None, stop=NOTHING_IMPROVED)
    superseded: set[str] = set()
    set_aside: list[str] = []
    chance: list[str] = []
    known = {c.effect: c for c in tried}
    while True:
        pool = [c for c in tried if c.effect not in superseded]
        best = max(pool, key=lambda c: c.score, default=None)
        if best is None:
            return Choice(None, superseded, stop=NOTHING_IMPROVED)
        structure = [c for c in pool if set(c.effect.split("+")) <= STRUCTURAL
                     and c.score >= settings.min_gain and c.p_value < settings.significance]
        if structure and not set(best.effect.split("+")) <= STRUCTURAL:
            # the model's known structure first: the LF model is known to lack it, and an
            # effect chosen before it may be its stand-in (a leak standing in for the flapper
            # dynamics on a healthy `test` record); a real effect still explains its part in
            # the next round, with the structure in the model
            best = max(structure, key=lambda c: c.score)
        names = best.effect.split("+")
        if best.score < settings.min_gain:
            return Choice(None, superseded, stop=(
                f"no significant effect left: best candidate {best.effect} reduces the RMSE "
                f"by {best.gain:.1%} (penalised {best.score:.1%} < {settings.min_gain:.0%})"))
        rivals = [] if best.p_value >= settings.significance else unspecific(best, everything)
        if best.p_value >= settings.significance or rivals:
            # a chance gain on this record's correlated residual, or a stand-in that other
            # effects match: set it aside and try the next one; the reason of the last one
            # set aside is the stop reason when nothing else can win
            superseded.add(best.effect)
            (set_aside if rivals else chance).append(best.effect)
            if all(c.effect in superseded or c.score < settings.min_gain
                   or c.p_value >= settings.significance for c in tried):
                why = (f"not significant on this record (p = {best.p_value:.2g} >= alpha "
                       f"{settings.significance:g}, {best.n_eff:.0f} effective samples)"
                       if not rivals else
                       f"but {', '.join(rivals)} reduce it as much (a residual that "
                       f"unrelated effects explain alike is the model's structure or the "
                       f"actuator's spread, not an effect)")
                kind = "significant" if not rivals else "specific"
                return Choice(None, superseded, stop=(
                    f"no {kind} effect left: best candidate {best.effect} reduces the RMSE "
                    f"by {best.gain:.1%}, {why}"), unspecific=set_aside,
                    insignificant=chance)
            continue
        if len(names) == 1:
            break
        kept = split(best)
        if len(kept) == len(names):
            names = kept
            break
        superseded.add(best.effect)
        name = "+".join(kept)
        cand = known.get(name)
        if cand is None:
            cand = refit_members(best, kept)
            if cand is not None:
                known[name] = cand
        if cand is not None and cand.refit and cand.score > -math.inf and cand not in tried:
            tried.append(cand)
    alternatives = {c.effect: c.score for c in tried if c is not best
                    and c.effect not in superseded and c.score >= settings.min_gain
                    and c.p_value < settings.significance
                    and best.score - c.score <= ALTERNATIVE_MARGIN}
    return Choice(best, superseded, names, "", alternatives)


def keeps_effect(with_rmse: float, without_rmse: float, n_params: int, n_eff: float,
                 settings: LoopSettings) -> tuple[bool, float, float]:
    """Does an effect pay for itself next to the others (:meth:`ResidualLoop.confirm`)?

    Parameters
    ----------
    with_rmse, without_rmse : float
        Scored RMSE of the model with the effect and refitted without it [m].
    n_params : int
        The effect's parameters (a pure switch counts as 1).
    n_eff : float
        Effective independent samples of the residual with the effect.
    settings : LoopSettings
        ``min_gain``, ``penalty`` and ``alpha`` of the loop.

    Returns
    -------
    keep, loss, p_value
        ``loss`` is the relative RMSE reduction the effect brings (``1 - with/without``);
        it is kept when ``loss - penalty * n_params >= CONFIRM_FRACTION * min_gain`` and
        ``p_value < alpha``.
    """
    if not math.isfinite(without_rmse):
        return True, math.inf, 0.0
    loss = 1.0 - with_rmse / without_rmse if without_rmse > 0 else 0.0
    p = significance(without_rmse, with_rmse, n_params, n_eff)
    n = max(int(n_params), 1)
    keep = loss - settings.penalty * n >= CONFIRM_FRACTION * settings.min_gain \
        and p < settings.significance
    return keep, loss, p


def unspecific(best: Candidate, candidates: Sequence[Candidate]) -> list[str]:
    """Candidates of *unrelated* effects that reduce the RMSE as much as ``best``.

    A residual that a delay, a motor-gain change and viscous friction all explain alike is not
    evidence for any of them: it is what the LF model's known structure and a healthy
    actuator's spread leave. ``best`` is unspecific when its gain is below
    :data:`SPECIFIC_GAIN` and a candidate sharing none of its non-structural effects gains
    within :data:`RIVAL_MARGIN` of it. :func:`choose` passes refits rejected because their
    effect stayed within its healthy band too (they show that a healthy-size change does as
    well) while the model is within what healthy actuators leave; beyond it that argument
    fails (healthy actuators, fitted, do not leave such a residual) and only admissible
    rivals count. Structural candidates (only :data:`STRUCTURAL` members) are always
    specific.

    Returns
    -------
    list of str
        The rival candidates' names (empty: specific).
    """
    own = set(best.effect.split("+")) - STRUCTURAL
    if not own or not best.gain < SPECIFIC_GAIN:
        return []
    rivals = []
    for c in candidates:
        other = set(c.effect.split("+")) - STRUCTURAL
        if other and not other & own and math.isfinite(c.gain) \
                and c.gain >= best.gain - RIVAL_MARGIN:
            rivals.append(c.effect)
    return rivals


def trades_position(current: Evaluation, candidate: Evaluation,
                    factor: float = POSITION_WORSENING) -> bool:
    """Does ``candidate`` make the position's RMSE (fitted and held-out parts,
    ``hypot(rmse_fit, rmse_hold)``) worse than ``factor`` times ``current``'s?

    On a record with P12 such a candidate can still score better (its gain is the pressure's):
    the LF's P12 is a model (:data:`P12_NOISE_FLOOR`), and an effect that trades the position
    for it stands in for the pressure model's form (a leak on a healthy HF `sine`: position
    2.3 -> 4.4 µm, the score up 48 % on P12). The loop does not add it.
    """
    return (math.hypot(candidate.rmse_fit, candidate.rmse_hold)
            > factor * math.hypot(current.rmse_fit, current.rmse_hold))


def split_combination(members: Sequence[Effect], combined: Evaluation,
                       evaluate_many: Callable[[list[LFParams]], list[Evaluation]],
                       penalty: float) -> list[Effect]:
    """The members of a winning combination that pay for themselves, ordered for the report.

    A member is kept when switching it off in the combined fit (the others at their values)
    raises the scored RMSE by at least ``penalty`` per parameter (a pure switch: ``penalty``),
    relative, or makes the run unstable; the most useful member is always kept. The kept
    members are ordered: switches without parameters first (the orifice law: the others'
    parameters were estimated with it on), then, greedily, the one whose switching on (at its
    combined-fit value) lowers the scored RMSE most, so that the steps' RMSE falls from one to
    the next.
    """
    def with_only(kept: Sequence[Effect]) -> LFParams:
        params = combined.params
        for effect in members:
            if effect not in kept:
                params = effect.switch_off(params)
        return params

    def score(ev: Evaluation) -> float:
        return ev.rmse_score if math.isfinite(ev.rmse_score) else math.inf

    full = combined.rmse_score
    without = evaluate_many([with_only([m for m in members if m is not e]) for e in members])
    worth = [1.0 - full / score(ev) if score(ev) > 0 else 0.0 for ev in without]
    kept = [e for e, w in zip(members, worth) if w >= penalty * max(len(e.params), 1)]
    if not kept:
        kept = [members[int(np.argmax(worth))]]
    # an effect kept keeps the structure it requires (the supply pressure its orifice law)
    needed = {r for e in kept for r in e.requires}
    kept = [e for e in members if e in kept or e.name in needed]
    order: list[Effect] = []
    left = list(kept)
    while left:
        pool = [e for e in left if not e.params] or left
        trials = evaluate_many([with_only([*order, e]) for e in pool])
        effect = pool[int(np.argmin([score(ev) for ev in trials]))]
        left.remove(effect)
        order.append(effect)
    return order


def flow_gain_at_edge(result: ExplainResult) -> str | None:
    """``"GQ 0.18 at the lower bound of its healthy spread 0.18-0.22"`` when the loop fitted
    the flow gain within its healthy spread to the end (``flow_gain_spread``, GQ not a
    declared fault) and the final model has it at the spread's edge (:func:`edge_of_spread`);
    else None."""
    if not result.facts.flow_gain_fitted or "GQ" not in result.fit_bounds:
        return None
    return edge_of_spread(float(result.faults_after["GQ"]), result.fit_bounds["GQ"])


def edge_of_spread(value: float, bounds: tuple[float, float]) -> str | None:
    """The flow gain ``value`` is at the edge of its healthy spread ``bounds`` when it is
    within :data:`FLOW_GAIN_EDGE` of the spread's width from a bound: the text saying so, or
    None."""
    lo, hi = bounds
    margin = FLOW_GAIN_EDGE * (hi - lo)
    if lo + margin < value < hi - margin:
        return None
    side = "lower" if value - lo <= hi - value else "upper"
    return f"GQ {value:.4g} at the {side} bound of its healthy spread {lo:.4g}-{hi:.4g}"


def better_pass(first: ExplainResult, second: ExplainResult,
                settings: LoopSettings) -> ExplainResult:
    """The result to report of two passes of the loop on one record: the second replaces the
    first only when it is better by the loop's own rule for adding an effect: its scored RMSE
    lower by ``min_gain`` once ``penalty`` is charged for each parameter it has more."""
    def n_params(result: ExplainResult) -> int:
        return sum(len(EFFECTS[st.effect].params) for st in result.steps)

    a, b = first.after.rmse_score, second.after.rmse_score
    if not math.isfinite(b) or not a > 0:
        return first
    gain = 1.0 - b / a if math.isfinite(a) else 1.0
    extra = max(n_params(second) - n_params(first), 0)
    return second if gain - settings.penalty * extra >= settings.min_gain else first
