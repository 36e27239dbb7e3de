"""The final check of the residual loop (step f), after the last round: is each effect added
still needed now that the later ones are in (:meth:`FinalCheck.prune`), is it the right one
(:meth:`~FinalCheck.swap`), and can one effect take the place of two
(:meth:`~FinalCheck.merge`)? The :class:`FinalCheck` part of
:class:`eha.explain.loop.ResidualLoop`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from eha.explain.effects import EFFECTS, Effect, missing_requirements
from eha.explain.decide import keeps_effect
from eha.explain.record import corr
from eha.explain.results import Dismissal, Evaluation, Step, ranking_score
from eha.explain.rival_check import check_rival, deferred_to_first, excluded_beyond
from eha.explain.settings import GLOBAL_RIVALS, STRUCTURAL, SWAP_CANDIDATES
from eha.explain.tracing import signatures
from eha.models.params import LFParams


class FinalCheck:
    """The final check of :class:`~eha.explain.loop.ResidualLoop` (see :meth:`prune`)."""

    def not_excluded(self) -> list[dict]:
        """The exclusion check of a model at the noise level: each effect the null tests that
        is not in the final model gets the rounds' test (:meth:`local_test`, least squares
        from the effect off and from its probe, every parameter of the final model free); an
        effect whose fit runs beyond the size this command shows fits the record as well with
        a value a healthy actuator does not reach, so the record cannot rule it out. The bar
        is the null's detectable size (:meth:`eha.explain.null.Null.detectable`),
        not its threshold: a clean verdict states that nothing the command shows (the
        ``undetectable`` lines: above that size) is missing, and this check tests that
        statement; a rival between threshold and detectable size is what those lines already
        disclaim (on a nominal record, a delay of 20 µs). (A viscous friction of 4000 N·s/m
        beside a motor gain of -30 % on a chirp: the
        motor gain alone leaves the noise, and the friction's fit runs to 9300 at the same
        residual, the flow and motor gains trading against it.) The null's own test and
        threshold, but not its state: the null runs it with the structure in and no other
        effect, and an effect in the model (or the structure missing) makes others less
        identifiable, so the rate at which it lists an effect is measured, not ``alpha``
        (docs/explain.md, "The exclusion check"). An effect so listed is then re-checked on
        HF re-simulations of the final model (:func:`eha.explain.rival_check.check_rival`):
        when the record reads only what the final model's own model form makes it read, and
        a rival of the detectable size would read otherwise, it is ruled out
        (:attr:`rivals_ruled_out`, with the check's figures). On the follow-up of a first
        record (``eha explain --prior``), a rival this record does not show beside the final
        model and the first record excluded stays excluded
        (:func:`~eha.explain.rival_check.deferred_to_first`). What is excluded, and beyond
        which size, is kept in :attr:`excluded`. Returns one dict per effect not ruled out
        (empty without a null)."""
        if not self.thresholds or self.null is None:
            return []
        detectable = self.null.detectable(self.settings.alpha)
        in_model = {st.effect for st in self.steps}
        self.rivals_ruled_out, self.excluded = [], {}
        out = []
        self.phase = "exclusion check (does another effect fit as well?)"
        try:
            return self._not_excluded(detectable, in_model, out)
        finally:
            self.phase = ""

    def _not_excluded(self, detectable, in_model, out) -> list[dict]:
        for effect in self.problem.pool:
            if (effect.name in in_model or effect.name in STRUCTURAL
                    or effect.name not in self.thresholds):
                continue
            members = [*(EFFECTS[n] for n in missing_requirements(effect, self.current)),
                       effect]
            start, free = self.fitter.candidate_start(members, self.current, self.free)
            for st in self.steps:           # every parameter of the final model free
                free.update(EFFECTS[st.effect].bounds)
            local, _ = self.fitter.local_test(start, free, members, self.fit_phase())
            if not self.fitter.past(effect, local, detectable):
                self.exclude(effect, detectable)
                continue
            entry = self.rival_entry(effect, local, detectable)
            # the found model's own model form may be what pulls the rival's fit; one
            # listed by its parameter's shift is checked on that shift's bar
            by_shift = effect.footprint and entry["unit"] != effect.statistic_unit
            check = check_rival(self, effect, members, local, entry["detectable"],
                                entry["threshold"], by_shift)
            if check:
                entry["rival_check"] = check
            deferred = deferred_to_first(entry, check, self.first_excluded)
            if check.get("ruled_out"):
                self.rivals_ruled_out.append(entry)
                self.exclude(effect, detectable)
            elif deferred is not None:
                # not shown here: the first record's exclusion stands (and is carried on)
                self.rivals_ruled_out.append(deferred)
                self.excluded[effect.name] = {**deferred["first_record"],
                                              "by": "first record"}
            else:
                out.append(entry)
        return out

    def exclude(self, effect: Effect, detectable: Mapping[str, float]) -> None:
        """Note ``effect`` as excluded by this record (:attr:`excluded`): beyond which size of
        its tested parameter's shift the exclusion check would have listed it with the null's
        power (:func:`~eha.explain.rival_check.excluded_beyond`); the supply pressure's on
        its parameter's shift. Nothing for an effect without finite sizes."""
        key = effect.shift_key if effect.shift_key in detectable else effect.name
        if effect.footprint and key == effect.name:
            return          # no parameter's bar: its footprint says nothing of a size
        size = float(detectable.get(key, math.inf))
        threshold = float(self.thresholds.get(key, math.nan))
        if math.isfinite(size) and math.isfinite(threshold):
            self.excluded[effect.name] = {"param": effect.tested,
                                          "beyond": excluded_beyond(threshold, size),
                                          "unit": effect.units()[effect.tested]}

    def rival_entry(self, effect: Effect, local: LFParams,
                    detectable: Mapping[str, float]) -> dict:
        """The ``not_excluded`` entry of ``effect`` as fitted in ``local``, past its bar in
        ``detectable``: its value, and the statistic that is past (``shift``), with that
        statistic's ``threshold``, ``detectable`` size and ``unit``. An effect tested by its
        footprint that passes by its parameter's shift alone (a supply of 10.4 MPa whose
        footprint, 5 µm, is below the 20 µm this command shows) is reported by that shift, in
        the parameter's unit: its footprint is not what the record cannot rule out."""
        param = effect.tested
        statistic = float(self.fitter.statistic_at(effect, local))
        size = float(detectable.get(effect.name, math.inf))
        threshold = float(self.thresholds[effect.name])
        unit = effect.statistic_unit
        key = effect.shift_key
        if key is not None and statistic <= size and key in detectable:
            statistic, size = float(effect.shift_at(local)), float(detectable[key])
            threshold, unit = float(self.thresholds.get(key, math.nan)), effect.units()[param]
        return {"effect": effect.name, "param": param, "value": float(getattr(local, param)),
                "value_unit": effect.units()[param], "shift": statistic,
                "threshold": threshold, "detectable": size, "unit": unit}

    def prune(self) -> list[Dismissal]:
        """(f) After the last round: is each effect added still needed now that the later
        ones are in, and is it the right one? An effect added early can stand in for several
        missing ones (an offset for a load before the leak that goes with it is found), or for
        one the round did not try (a motor gain for a position delay on ``mixed``). Each added
        effect with parameters (not the structure), earliest first, is left out and the rest
        refitted (pattern search); it is removed, and listed as dismissed, when it no longer
        pays for itself (:func:`keeps_effect`). An effect that stays is then *swapped*: each
        effect not in the model — of those whose signature is most like the effect's
        contribution, :data:`SWAP_CANDIDATES` — takes its place in turn (its parameters from
        their probe values, everything refitted by pattern search); the best swap replaces it
        when it beats the model by the same rule (:func:`keeps_effect`, the swapped model against
        the current one) and leaves its own healthy band. Last, :meth:`merge` tries one
        effect in the place of each pair of added ones. When the model leaves the record
        unexplained (:meth:`unexplained`) the best rivals of the swap and the merge are also
        searched globally and the model in place is refitted from each winner's basin
        (:meth:`replacement`, :meth:`cross_seed`). Returns the dismissals (removed, swapped or
        merged effects); :meth:`run` resumes the rounds once when there are any and the model
        is still far from the noise."""
        s, removed = self.settings, []
        for step in list(self.steps):
            effect = EFFECTS[step.effect]
            if step.effect in STRUCTURAL or not effect.params:
                continue
            # (with joint=True the effects added are among self.free: not the one left out)
            free = {k: v for k, v in self.free.items() if k not in effect.bounds}
            for other in self.steps:
                if other is not step:
                    free.update(EFFECTS[other.effect].bounds)
            start = effect.switch_off(self.current)
            refitted = self.fitter.refit(start, free, f"final check: without {step.effect}",
                                  method="ps")
            without = min(self.fitter.evaluate([start, refitted]), key=ranking_score)
            keep, loss, p = keeps_effect(self.cur.rmse_score, without.rmse_score,
                                         len(effect.params), self.cur.n_eff, s)
            if not keep:
                self.steps.remove(step)
                removed.append(Dismissal(step.effect, len(self.rounds), loss, p))
                self.dismissed.append(removed[-1])     # not tried again (remaining())
                self.current, self.cur = without.params, without
                self.free = {k: v for k, v in self.free.items() if k not in effect.bounds}
                continue
            swap = self.swap(step, start, free)
            if swap is not None:
                removed.append(swap)
                self.dismissed.append(swap)
        merged = self.merge()
        self.dismissed.extend(merged)
        return removed + merged

    def replacement(self, out: Sequence[Step], without: LFParams,
                    free: Mapping[str, tuple[float, float]], label: str, pairs: bool = False
                    ) -> tuple[tuple[Effect, ...], Evaluation] | None:
        """The best single effect not in the model to take the place of the steps ``out``:
        of the :data:`SWAP_CANDIDATES` whose signature is most like what ``out`` contribute
        (``current`` against ``without``, the model with them off), each is switched on at its
        probe value and everything in ``free`` refitted with it (pattern search; when the model
        leaves the record unexplained, the :data:`GLOBAL_RIVALS` best so refitted also by the
        loop's GA warm-started at the probe and from scratch, the best fit kept); effects that
        need structure the model lacks (:attr:`Effect.requires`) are not tried. With ``pairs``
        each two of those rivals are also tried together (a one-for-two). Returns the replacing
        effects and their fit; None when every refit leaves an effect within its healthy
        band."""
        in_model = {st.effect for st in self.steps}
        others = [o for o in self.remaining()
                  if o.name not in in_model and o.name not in STRUCTURAL and o.params
                  and not missing_requirements(o, without)]
        if len(others) > SWAP_CANDIDATES:
            # a stand-in has the signature of what it stands in for
            S, _ = signatures(self.problem.record, without, others, {})
            xu = self.problem.record.run([self.current, without])
            own = xu[0] - xu[1]
            likeness = [abs(corr(own, S[i])) if np.all(np.isfinite(S[i])) else 0.0
                        for i in range(len(others))]
            order = np.argsort(likeness)[::-1][:SWAP_CANDIDATES]
            others = [others[i] for i in order]
        sets = [(o,) for o in others]
        if pairs:
            sets += list(itertools.combinations(others, 2))
        # every rival is refitted locally from its probe (pattern search); a model that leaves
        # the record unexplained is wrong somewhere, and the replacement may lie in another
        # basin than its probe's: the GLOBAL_RIVALS best rivals so refitted are also searched
        # globally, by the loop's GA warm-started at the probe and from scratch (a viscous
        # jack for a low supply pressure on `test`: 38 µm by pattern search from the probe,
        # 14 µm warm with the jack's CJ inside its healthy band, 12.6 µm from scratch with CJ
        # 15800 for 16000). Searching every rival globally cost most of a far record's time
        # (a -100 µm sensor bias on a 1 cm step: 60 GA runs in the final check) and never
        # changed a verdict on the foreign records.
        fits = []
        for group in sets:
            start, bounds = without, dict(free)
            for other in group:
                start = other.switch_on(start)
                bounds.update(other.bounds)
            name = "+".join(o.name for o in group)
            local = self.fitter.refit(start, bounds, f"final check: {name} for {label}",
                                      method="ps")
            fits.append((group, start, bounds, name, [self.fitter.evaluate([local])[0]]))
        if self.unexplained():
            ranked = sorted(fits, key=lambda f: ranking_score(f[4][0]))
            for group, start, bounds, name, trials in ranked[:GLOBAL_RIVALS]:
                found = [self.fitter.refit(start, bounds, f"final check: {name} for {label}",
                                    method=self.settings.method, warm_start=warm)
                         for warm in (True, False)]
                trials.extend(self.fitter.evaluate(found))
        best = None
        for group, _, _, _, trials in fits:
            trials = [t for t in trials
                      if not any(self.fitter.within_healthy_at(o, t.params) for o in group)]
            if not trials:
                continue
            ev = min(trials, key=ranking_score)
            if math.isfinite(ev.rmse_score) and (best is None or
                                                 ev.rmse_score < best[1].rmse_score):
                best = (group, ev)
        return best

    def replace_steps(self, out: Sequence[Step], others: Sequence[Effect],
                      ev: Evaluation) -> None:
        """Put ``others`` (fitted in ``ev``) in the place of the steps ``out`` (the first one's
        place in the report, one step each)."""
        label = " + ".join(st.effect for st in out)
        names = "+".join(o.name for o in others)
        faults = {k: getattr(ev.params, k) for k in self.bounds}
        at = self.steps.index(out[0])
        self.steps[at:at + 1] = [replace(
            out[0], effect=other.name,
            params={k: getattr(ev.params, k) for k in other.params},
            rmse_after=ev.rmse_all, rmse_fit_after=ev.rmse_fit, rmse_hold_after=ev.rmse_hold,
            faults_after=faults, chosen=f"final check: {names} for {label}")
            for other in others]
        for st in out[1:]:
            self.steps.remove(st)
        self.current, self.cur = ev.params, ev
        gone = set().union(*(EFFECTS[st.effect].bounds for st in out))
        self.free = {k: v for k, v in self.free.items() if k not in gone}
        if self.settings.joint:
            for other in others:
                self.free.update(other.bounds)

    def swap(self, step: Step, without: LFParams,
             free: Mapping[str, tuple[float, float]]) -> Dismissal | None:
        """The final check's swap of ``step`` (see :meth:`prune`); ``without`` is the model
        with the step's effect off, ``free`` what is refitted with it. The replacement must
        score better by :func:`keeps_effect` (same size: the effect in place stays unless
        beaten); when the model leaves the record unexplained, the model in place is first
        refitted from the replacement's basin (:meth:`cross_seed`), and a replacement that
        the F test cannot judge on the residual's few effective samples is taken when it
        gains ``min_gain`` after the penalty. Returns the dismissal of the replaced effect,
        or None."""
        far = self.unexplained()
        # far from the noise one effect may stand in for two (a low supply pressure for a
        # viscous jack with worn seals on `test`: 22 µm scored; the two together 2.2 µm), so
        # the rivals are also tried two at a time
        best = self.replacement([step], without, free, step.effect, pairs=far)
        if best is None:
            return None
        others, ev = best
        s = self.settings
        n_params = sum(len(o.params) for o in others)
        if far:
            self.cross_seed([step], others, ev, free)
        better, gain, p = keeps_effect(ev.rmse_score, self.cur.rmse_score, n_params,
                                       ev.n_eff, s)
        if not better and self.unexplained():
            # far from the noise the residual is structure: its few effective samples make the
            # F test blind between two models of one size (a viscous jack for a low supply
            # pressure, 25 % better at p 0.03 on 10 effective samples); the replacement is
            # then taken when it gains what an effect must gain to be added in a round
            better = gain - s.penalty * n_params >= s.min_gain
        if not better:
            return None
        self.replace_steps([step], others, ev)
        return Dismissal(step.effect, len(self.rounds), -gain, p,
                         replaced_by="+".join(o.name for o in others))

    def cross_seed(self, out: Sequence[Step], others: Sequence[Effect], ev: Evaluation,
                   free: Mapping[str, tuple[float, float]]) -> None:
        """Before ``others`` (fitted in ``ev`` by a global search) may replace the steps
        ``out``, the model in place starts from the rival's basin: the rival's fit with the
        rival off and the steps' effects back at their estimates, refitted locally (pattern
        search); taken when it lowers the score and leaves them outside their healthy
        band. A rival must win by its effect, not by the basin its search found for the
        other parameters (an offset at its bound for a sensor bias on a 1 cm step: 1.8 against
        3.1 µm, all of it from the flapper, 2750 rad/s against 8130)."""
        start, bounds = ev.params, dict(free)
        for other in others:
            start = other.switch_off(start)
        for st in out:
            effect = EFFECTS[st.effect]
            start = effect.switch_on(start, {p: getattr(self.current, p)
                                             for p in effect.params})
            bounds.update(effect.bounds)
        label = " + ".join(st.effect for st in out)
        rivals = "+".join(o.name for o in others)
        trial = self.fitter.refit(start, bounds, f"final check: {label} from {rivals}'s fit",
                           method="ps")
        mine = self.fitter.evaluate([trial])[0]
        inside = any(self.fitter.within_healthy_at(EFFECTS[st.effect], trial) for st in out)
        if mine.rmse_score < self.cur.rmse_score and not inside:
            self.current, self.cur = trial, mine

    def merge(self) -> list[Dismissal]:
        """The final check's two-for-one: can one effect not in the model take the place of
        two added ones? Two effects together can stand in for a third that neither is like
        on its own (a motor gain and a small leak for a low supply pressure under load). For
        each pair of added effects with parameters (not the structure), both are switched off
        and :meth:`replacement` tries the effects most like the pair's contribution; the pair
        stays only when it pays for its extra parameters over the best single replacement
        (:func:`keeps_effect`, the model with the pair against the one with the
        replacement) — the simpler model wins a tie. At most one merge (the best-scoring
        replacement). Returns the dismissals of the pair, or []."""
        s = self.settings
        added = [st for st in self.steps
                 if st.effect not in STRUCTURAL and EFFECTS[st.effect].params]
        best = None
        for i, a in enumerate(added):
            for b in added[i + 1:]:
                pair = (EFFECTS[a.effect], EFFECTS[b.effect])
                free = {k: v for k, v in self.free.items()
                        if not any(k in e.bounds for e in pair)}
                for other in self.steps:
                    if other is not a and other is not b:
                        free.update(EFFECTS[other.effect].bounds)
                without = pair[1].switch_off(pair[0].switch_off(self.current))
                found = self.replacement([a, b], without, free, f"{a.effect} + {b.effect}")
                if found is None:
                    continue
                others, ev = found
                if self.unexplained():
                    self.cross_seed([a, b], others, ev, free)
                extra = sum(len(e.params) for e in pair) - sum(len(o.params) for o in others)
                keep, loss, p = keeps_effect(self.cur.rmse_score, ev.rmse_score, extra,
                                             self.cur.n_eff, s)
                if not keep and (best is None or ev.rmse_score < best[3].rmse_score):
                    best = (a, b, others, ev, loss, p)
        if best is None:
            return []
        a, b, others, ev, loss, p = best
        self.replace_steps([a, b], others, ev)
        name = "+".join(o.name for o in others)
        return [Dismissal(a.effect, len(self.rounds), loss, p, replaced_by=name),
                Dismissal(b.effect, len(self.rounds), loss, p, replaced_by=name)]
