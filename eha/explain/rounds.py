"""The rounds of the residual loop (steps b-d): trace the residual, refit the best-ranked
candidates and score them, choose, confirm and accept: the :class:`Rounds` part of
:class:`eha.explain.loop.ResidualLoop`.
"""

from __future__ import annotations

import math
import time
from typing import Mapping, Sequence

from eha.explain.effects import COMBINATIONS, EFFECTS, Effect, missing_requirements
from eha.explain.decide import (Choice, choose, keeps_effect, relative_gain, significance,
                                split_combination, trades_position)
from eha.explain.results import (Candidate, Dismissal, Evaluation, Round, Step,
                                 ranking_score)
from eha.explain.settings import LOOK_AHEAD, SPECIFIC_GAIN, STRUCTURAL, SWAP_CANDIDATES
from eha.explain.tracing import trace_residual
from eha.models.params import LFParams


class Rounds:
    """One round: :meth:`candidates_of_round` traces the residual (:meth:`trace`) and refits
    the best-ranked candidates (:meth:`try_candidate`), :meth:`choose` picks what to add
    (:meth:`look_ahead` when the best were unspecific), :meth:`confirm` checks each effect
    chosen is needed and :meth:`accept` adds it. Part of
    :class:`~eha.explain.loop.ResidualLoop`."""

    def trace(self, evaluation: Evaluation, free: Mapping[str, tuple[float, float]],
              effects: Sequence[Effect]) -> Round:
        """(b) Trace the residual of ``evaluation`` to the effects' signatures."""
        return trace_residual(self.problem.record, evaluation, free, effects, self.problem.n_fit)

    def fit_phase(self) -> str:
        """What the progress messages of a fit now name: the phase (the exclusion check, a
        re-simulation), else the round (``round 2``)."""
        return self.phase or f"round {len(self.rounds)}"

    def try_candidate(self, cand: Candidate, extends: LFParams | None = None) -> Candidate:
        """(c) Refit the faults with the candidate's effects free and score the fit.

        The GA is warm-started at the model it extends (the current one, or a combination's
        fit) with the new effects at their off values (at the probe where off is outside the
        search bounds): a refit is never worse than what it extends.
        """
        s, cur = self.settings, self.cur
        members = [EFFECTS[name] for name in cand.effect.split("+")]
        t0 = time.perf_counter()
        start, free = self.fitter.candidate_start(members, self.current, self.free, extends)
        trial, trial_cost = self.fitter.fit_with_cost(
            start, free, f"round {len(self.rounds)}: refit with {cand.effect}",
            warm_start=True)
        # the healthy null's test: the same local refit the null ran on healthy records,
        # and the refit itself where it reached a deeper basin than both of its starts
        tested = [e for e in members if e.name in (self.thresholds or {})]
        local, local_cost = self.fitter.local_test(start, free, members, self.fit_phase(),
                                                   also=(trial, trial_cost)) \
            if tested else (trial, trial_cost)
        # the candidate's fit is the best of its fits: the local test's least squares can
        # reach a basin the GA's warm start missed (the supply pressure's other law)
        trial = local if local_cost < trial_cost else trial
        ev = self.fitter.evaluate([trial])[0]
        cand.refit = True
        cand.params = {p: getattr(trial, p) for e in members for p in e.params}
        cand.faults = {p: getattr(trial, p) for p in self.bounds}
        cand.rmse_fit, cand.rmse_hold, cand.rmse_all = ev.rmse_fit, ev.rmse_hold, ev.rmse_all
        cand.gain = relative_gain(cur, ev)
        cand.score = cand.gain - s.penalty * len(cand.params)
        added = sum(max(len(e.params), 1) for e in members if not e.is_on(self.current))
        cand.n_eff = ev.n_eff
        cand.p_value = significance(cur.rmse_score, ev.rmse_score, added, ev.n_eff)
        cand.shifts = {e.name: self.fitter.statistic_at(e, local) for e in tested}
        cand.shifts.update({e.shift_key: e.shift_at(local) for e in tested if e.shift_key})
        if any(e.params and (self.fitter.within_healthy_at(e, local) if e in tested else
                             self.fitter.within_healthy(e, cand.params)) for e in members):
            # the fit left an effect within the band healthy actuators reach on this command:
            # any gain is the optimizer's or a healthy spread's, not the effect's
            cand.score = -math.inf
        elif self.problem.p12_weight and trades_position(cur, ev):
            # the gain is the pressure's alone, bought with a worse position
            cand.score = -math.inf
        cand.seconds = time.perf_counter() - t0
        self.fits[id(cand)] = (cand, ev)    # kept for the step (not reported)
        return cand

    def candidates_of_round(self, remaining: list[Effect]) -> tuple[Round, list[Candidate]]:
        """(b, c) Trace the current residual and refit the best-ranked candidates; also the
        combinations of :data:`~eha.explain.effects.COMBINATIONS`, alone and with each of the
        effects that best explain the combination's residual (an effect is often only recognisable
        once the structure it interacts with is in the model: with the orifice law a load and a
        motor offset stop being equivalent). The combinations with other effects are skipped when a
        candidate made only of the structure already qualifies: the structure is then chosen first
        whatever they gain (:func:`choose`)."""
        s = self.settings
        rnd = self.trace(self.cur, self.free, remaining)
        self.rounds.append(rnd)
        ranked = sorted(rnd.candidates, key=lambda c: -c.explained)
        chosen = ranked if s.candidates <= 0 else ranked[:s.candidates]
        names_left = {e.name for e in remaining}
        room = s.max_steps - len(self.steps)    # a combination adds one step per member
        for cand in chosen:
            # an effect that needs structure the model lacks is tried with it (its signature
            # was traced so): the supply pressure with the orifice law
            needed = missing_requirements(EFFECTS[cand.effect], self.current)
            if needed and (not set(needed) <= names_left or len(needed) + 1 > room):
                continue        # the structure it needs is fixed off, not a candidate, or
                                # there is no room for both
            if needed:
                cand.effect = "+".join((*needed, cand.effect))
            self.try_candidate(cand)
        for combo in COMBINATIONS:
            if not set(combo) <= names_left or len(combo) > room:
                continue
            pair = self.try_candidate(Candidate("+".join(combo), math.nan, math.nan))
            rnd.candidates.append(pair)
            chosen.append(pair)
            rest = [e for e in remaining if e.name not in combo]
            if not rest or len(combo) + 1 > room:
                continue
            if any(set(c.effect.split("+")) <= STRUCTURAL and c.score >= s.min_gain
                   and c.p_value < s.significance for c in chosen):
                # the structure qualifies on its own: :func:`choose` takes it first whatever
                # the combinations with it gain (a structural candidate is always specific),
                # so they are not refitted (on a 3 s record: 6 refits, 36 of 94 s)
                continue
            combo_free = dict(self.free)
            for name in combo:
                combo_free.update(EFFECTS[name].bounds)
            on_top = self.trace(self.fit_of(pair), combo_free, rest)
            ranked_on_top = sorted(on_top.candidates, key=lambda c: -c.explained)
            for c in ranked_on_top if s.candidates <= 0 else ranked_on_top[:s.candidates]:
                cand = self.try_candidate(Candidate("+".join((*combo, c.effect)), math.nan,
                                                    c.explained),
                                          extends=self.fit_of(pair).params)
                rnd.candidates.append(cand)
                chosen.append(cand)
        return rnd, chosen

    def choose(self, rnd: Round, tried: list[Candidate]) -> Choice:
        """(d) :func:`choose` with this record's evaluations."""
        def split(best: Candidate) -> list[str]:
            members = [EFFECTS[name] for name in best.effect.split("+")]
            return [e.name for e in split_combination(members, self.fit_of(best),
                                                       self.fitter.evaluate, self.settings.penalty)]

        def refit_members(best: Candidate, kept: list[str]) -> Candidate | None:
            params = self.fit_of(best).params
            for name in best.effect.split("+"):
                if name not in kept:
                    params = EFFECTS[name].switch_off(params)
            cand = self.try_candidate(Candidate("+".join(kept), math.nan, math.nan),
                                      extends=params)
            rnd.candidates.append(cand)
            return cand

        return choose(list(tried), self.settings, split, refit_members,
                      beyond_healthy=self.unexplained())

    def look_ahead(self, rnd: Round, tried: list[Candidate], choice: Choice) -> Choice:
        """(d) A round whose best candidates were all set aside as unspecific (unrelated
        effects explain as much), or as not significant on a record the model leaves
        unexplained, may hold one of two effects that only stand out together:
        with a sensor bias found, a torque-motor hysteresis and a first-stage clogging each
        take a chirp's residual from 16 to 5.5 µm, a hinge moment alone nothing, hysteresis
        and hinge moment together 1.8 µm. For the :data:`LOOK_AHEAD` best set-aside
        candidates of a single effect, the residual of its fit is traced and the
        :data:`SWAP_CANDIDATES` effects that best explain it are refitted on top (as for the
        structure's combinations); the choice is made again with them. A pair is specific only
        when it gains :data:`SPECIFIC_GAIN`, and each member must pay for itself (the
        combination's split, then the confirmation). Returns the new choice, or ``choice``."""
        s = self.settings
        names_left = {e.name for e in self.remaining()}
        heads = [name for name in [*choice.unspecific, *choice.insignificant]
                 if len(set(name.split("+")) - STRUCTURAL) == 1][:LOOK_AHEAD]
        room = s.max_steps - len(self.steps)
        known = {frozenset(c.effect.split("+")) for c in [*tried, *rnd.candidates]}
        added = []
        for name in heads:
            head = next((c for c in [*tried, *rnd.candidates] if c.effect == name
                         and id(c) in self.fits), None)
            members = set(name.split("+"))
            if head is None or len(members) + 1 > room:
                continue
            free = dict(self.free)
            for member in members:
                free.update(EFFECTS[member].bounds)
            rest = [e for e in self.remaining() if e.name not in members
                    and e.name not in STRUCTURAL and e.params
                    and not missing_requirements(e, self.fit_of(head).params)]
            if not rest:
                continue
            on_top = self.trace(self.fit_of(head), free, rest)
            for c in sorted(on_top.candidates, key=lambda c: -c.explained)[:SWAP_CANDIDATES]:
                pair = f"{name}+{c.effect}"
                key = frozenset(pair.split("+"))
                if key in known or c.effect not in names_left:
                    continue
                cand = self.try_candidate(Candidate(pair, math.nan, c.explained),
                                          extends=self.fit_of(head).params)
                rnd.candidates.append(cand)
                added.append(cand)
                known.add(key)
        # only a pair that stands out is offered to the choice: against the single effects
        # a pair of stand-ins gains more than any of them (on a healthy record too)
        added = [c for c in added if c.gain >= SPECIFIC_GAIN]
        if not added:
            return choice
        again = self.choose(rnd, [*tried, *added])
        return again if again.best is not None else choice

    def confirm(self, rnd: Round, choice: Choice) -> Choice | None:
        """(d) Is each effect of the choice needed, or did the GA on the larger search merely
        find a better fit of what is already in play? (On healthy `test` records the
        structural pair's refit reaches 55 % on one record and 85 % on its sisters: a GA on
        4-6 parameters does not always find the basin, and a candidate searched with one more
        parameter may find it and take the credit.) Each effect with parameters (not the
        structure) is left out and the rest refitted from the chosen fit (pattern search); it
        stays only when it pays for itself (:func:`keeps_effect`). An effect that does not is *dismissed* for the rest of
        the run (:class:`Dismissal`). What remains is refitted as a candidate of its own and
        returned when it still qualifies; when nothing new remains, the better refit of the
        model already in place becomes the current model. None: nothing is added this round.
        """
        best = choice.best
        s, ev = self.settings, self.fit_of(best)
        kept, params = list(choice.members), ev.params
        dropped, last = [], ev
        for name in [n for n in choice.members if n not in STRUCTURAL]:
            effect = EFFECTS[name]
            if not effect.params:
                continue
            free = dict(self.free)
            for other in kept:
                if other != name:
                    free.update(EFFECTS[other].bounds)
            start = effect.switch_off(params)
            refitted = self.fitter.refit(start, free, f"round {len(self.rounds) - 1}: is {name} "
                                  f"needed in {best.effect}? (refit without it)", method="ps")
            without = min(self.fitter.evaluate([start, refitted]), key=ranking_score)
            keep, loss, p = keeps_effect(ev.rmse_score, without.rmse_score,
                                         len(effect.params), ev.n_eff, s)
            if not keep:
                kept.remove(name)
                dropped.append(Dismissal(name, len(self.rounds) - 1, loss, p))
                params, last = without.params, without
        if not dropped:
            return choice
        self.dismissed.extend(dropped)
        if not kept:       # (a choice's members are never in the model yet)
            if last.rmse_score < self.cur.rmse_score:
                self.current, self.cur = params, last
            return None
        cand = self.try_candidate(Candidate("+".join(kept), math.nan, math.nan),
                                  extends=params)
        rnd.candidates.append(cand)
        if not (cand.score >= s.min_gain and cand.p_value < s.significance):
            return None
        return Choice(cand, choice.superseded | {best.effect}, kept, "", {})

    def accept(self, choice: Choice) -> list[Step]:
        """(d) Add the chosen effect(s): polish the faults and every effect in the model
        jointly from the winning fit (a local search: an effect added earlier was estimated
        without the later ones); a combination is reported as one step per effect, in the
        order of their contribution, each step's "after" the combined fit with the later
        members off."""
        s, best = self.settings, choice.best
        members = [EFFECTS[name] for name in choice.members]
        ev = self.fit_of(best)
        joint_free = dict(self.free)
        for effect in [EFFECTS[st.effect] for st in self.steps] + members:
            joint_free.update(effect.bounds)
        polished = self.fitter.refit(ev.params, joint_free,
                              f"round {len(self.rounds)}: joint polish", method="ps")
        ev_p = self.fitter.evaluate([polished])[0]
        if ev_p.rmse_score < ev.rmse_score:
            ev = ev_p
        faults_after = {p: getattr(ev.params, p) for p in self.bounds}
        prev, faults0 = self.cur, {p: getattr(self.current, p) for p in self.bounds}
        added = []
        # the alternatives go with the member the user reads as "the effect": the first with
        # parameters (the supply pressure of orifice_law+supply_pressure, not the law)
        told = next((i for i, e in enumerate(members) if e.params), 0)
        for i, effect in enumerate(members):
            params_i = ev.params
            for later in members[i + 1:]:
                params_i = later.switch_off(params_i)
            ev_i = ev if i == len(members) - 1 else self.fitter.evaluate([params_i])[0]
            gain_i = relative_gain(prev, ev_i)
            added.append(Step(
                effect=effect.name, params={p: getattr(ev.params, p) for p in effect.params},
                rmse_before=prev.rmse_all, rmse_after=ev_i.rmse_all,
                rmse_fit_before=prev.rmse_fit, rmse_fit_after=ev_i.rmse_fit,
                rmse_hold_before=prev.rmse_hold, rmse_hold_after=ev_i.rmse_hold,
                faults_before=faults0, faults_after=faults_after, gain=gain_i,
                score=gain_i - s.penalty * len(effect.params),
                alternatives=choice.alternatives if i == told else {}, chosen=best.effect,
                chosen_score=best.score))
            prev, faults0 = ev_i, faults_after
        self.steps.extend(added)
        self.current, self.cur = ev.params, ev
        if s.joint:
            for effect in members:
                self.free.update(effect.bounds)
        return added
