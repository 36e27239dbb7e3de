"""The residual loop on one record, :class:`ResidualLoop`: the baseline, the rounds until a
stop rule holds, the final check, the final estimates and their intervals, read top-down in
:meth:`ResidualLoop.run`. The rounds (:mod:`eha.explain.rounds`), the final check
(:mod:`eha.explain.final_check`) and the fits (:mod:`eha.explain.fitting`) are its parts.
"""

from __future__ import annotations

import math
import time
from dataclasses import fields, replace
from typing import Any, Callable, Iterable, Mapping

from eha.explain.effects import EFFECTS, Effect, missing_requirements
from eha.explain.facts import RunFacts
from eha.explain.decide import edge_of_spread, relative_gain
from eha.explain.final_check import FinalCheck
from eha.explain.fitting import Fitter
from eha.explain.leads import LeadReport, residual_leads
from eha.explain.problem import Problem
from eha.explain.replicates import at_a_bound, explains
from eha.explain.results import Candidate, Dismissal, Evaluation, ExplainResult, Round, Step
from eha.explain.rounds import Rounds
from eha.explain.settings import REVISITS, STRUCTURAL, LoopSettings
from eha.identification.measured import MeasuredData
from eha.models.bounds import Bounds
from eha.models.estimate import Interval
from eha.models.params import LFParams


class ResidualLoop(Rounds, FinalCheck):
    """The residual loop on one record; each step of the loop is a method.

    :meth:`run` reads top-down: :meth:`baseline` fits the declared faults (a); the rounds
    (:meth:`rounds_until_stop`, :class:`~eha.explain.rounds.Rounds`) trace the residual to the
    effects' signatures (b, :meth:`trace`), refit with each candidate switched on and score it
    (c, :meth:`try_candidate`), pick what to add (d, :meth:`choose`, the pure
    :func:`~eha.explain.decide.choose`), check that each effect chosen is needed (the rest
    refitted without it, :meth:`confirm`) and add it (:meth:`accept`), until a stop rule holds
    (e, :meth:`stop_rule`); the final check (f, :class:`~eha.explain.final_check.FinalCheck`)
    checks each added effect once more with all the others in (:meth:`prune`); the final
    estimates (g, :meth:`estimate`) and :meth:`result` end it. The fits are those of a
    :class:`~eha.explain.fitting.Fitter` (:attr:`fitter`) on the loop's
    :class:`~eha.explain.problem.Problem`, which the loop reads and never changes (its own
    state: :attr:`bounds`, :attr:`current`, :attr:`free`, :attr:`steps`, ...). Build one with
    :meth:`on` from a record and :func:`eha.explain.explain`'s inputs.
    """

    def __init__(self, problem: Problem, settings: LoopSettings = LoopSettings(),
                 null: Any = None, on_progress: Callable[[str], None] | None = None,
                 pin_structure: bool = False,
                 first_excluded: Mapping[str, Mapping[str, Any]] | None = None,
                 fitter: type[Fitter] = Fitter):
        self.started = time.perf_counter()
        self.problem, self.settings = problem, settings
        #: the healthy null (:class:`eha.explain.null.Null`) and its thresholds at ``alpha``
        #: (effect -> largest healthy shift); empty without a null
        self.null = null
        self.progress = on_progress or (lambda message: None)
        #: the fits and the scores on the problem (a :class:`~eha.explain.fitting.Fitter`, or
        #: the ``fitter`` class given: a test's scripted one)
        self.fitter = fitter(problem, settings,
                             null.thresholds(settings.alpha) if null is not None else {},
                             self.progress)
        #: the faults (and GQ while it is fitted): :meth:`baseline` may release GQ
        self.bounds = problem.bounds
        #: rivals of the exclusion check ruled out by the rival check (FinalCheck.not_excluded)
        self.rivals_ruled_out: list[dict] = []
        #: what the exclusion check excluded: effect -> {param, beyond, unit} (FinalCheck)
        self.excluded: dict[str, dict] = {}
        #: what a first record of this actuator excluded (its --json's ``excluded``): a
        #: rival this record does not show stays excluded (rival_check.deferred_to_first)
        self.first_excluded = {k: dict(v) for k, v in (first_excluded or {}).items()}
        self.flow_gain_fitted = problem.flow_gain is not None
        #: why the flow gain stopped being fitted (:meth:`baseline`), or None
        self.flow_gain_released: str | None = None
        #: the structure put in at its physical values before the rounds and held there until
        #: the final estimates (:meth:`baseline`, :func:`explain`'s second pass)
        self.pinned = [e for e in problem.pool if e.name in STRUCTURAL] if pin_structure else []
        #: the phase the progress labels name ("" : the rounds, "round N")
        self.phase = ""
        self.steps: list[Step] = []
        self.dismissed: list[Dismissal] = []
        self.rounds: list[Round] = []
        #: each candidate tried (by ``id``) and its fit (:meth:`fit_of`)
        self.fits: dict[int, tuple[Candidate, Evaluation]] = {}
        #: the HF re-simulations' refits of the final model, shared by the intervals'
        #: replicate term and the model's own level (:mod:`eha.explain.replicates`)
        self.replicate_refits: dict[tuple, list] = {}
        self.current: LFParams = problem.base
        self.cur: Evaluation | None = None
        # refitted every round: the faults (and, with joint=True, the effects already added)
        self.free = dict(self.bounds)

    @classmethod
    def on(cls, data: MeasuredData, fit: Any = None,
           effects: Iterable[str] | str | None = None,
           validate: MeasuredData | None = None, base: LFParams | None = None,
           settings: LoopSettings = LoopSettings(), fixed: Iterable[str] = (),
           on_progress: Callable[[str], None] | None = None,
           pin_structure: bool = False, null: Any = None,
           first_excluded: Mapping[str, Mapping[str, Any]] | None = None,
           fitter: type[Fitter] = Fitter, **options: float) -> ResidualLoop:
        """The loop on ``data``: its :class:`~eha.explain.problem.Problem` built from the
        inputs (see :func:`eha.explain.explain`); ``options`` join ``settings.options``."""
        if options:
            settings = replace(settings, options={**settings.options, **options})
        problem = Problem.build(data, settings, fit, effects, validate, base, fixed)
        return cls(problem, settings, null, on_progress, pin_structure, first_excluded, fitter)

    @property
    def thresholds(self) -> dict[str, float]:
        """The healthy null's thresholds at ``alpha`` (the fitter's), empty without a null."""
        return self.fitter.thresholds

    def fit_of(self, cand: Candidate) -> Evaluation:
        """The fit of a candidate :meth:`try_candidate` tried."""
        return self.fits[id(cand)][1]

    # -- the run ---------------------------------------------------------------------------
    def run(self) -> ExplainResult:
        """Baseline, then trace / try / choose / accept until a stop rule holds, the final
        check (resumed rounds when it changed a model still far from the noise, at most
        :data:`REVISITS` times), the final estimates and their intervals."""
        before = self.baseline()
        faults_before = {k: getattr(before.params, k) for k in self.bounds}
        for _ in range(REVISITS + 1):
            stop = self.rounds_until_stop()
            changed = self.prune()
            # a final check that changed a model still far from the noise opened a path the
            # rounds had not seen (with the viscous jack in place of the low supply pressure
            # the flapper dynamics pays): the rounds resume from it
            if not changed or not self.unexplained():
                break
        self.estimate()
        self.rivals = self.not_excluded() if self.at_noise_level() else []
        return self.result(before, faults_before, stop)

    # -- the steps -------------------------------------------------------------------------
    def baseline(self) -> Evaluation:
        """(a) Fit the declared faults; the model every later step extends.

        A flow gain fitted within its healthy spread that runs to the spread's edge
        (:func:`edge_of_spread`) is a flow loss (or surplus) beyond a healthy actuator's: GQ
        goes back to the base's value, is no longer fitted, and the faults are fitted again.
        (Left free, it would share the loss with the effect that causes it: on an LF record
        with a torque motor at 80 % of its gain, GQ 0.188 and GM 0.0085, their product
        right, each wrong.)"""
        self.current = self.fitter.refit(self.problem.base, self.bounds, "fit the declared faults")
        edge = edge_of_spread(self.current.GQ, self.bounds["GQ"]) \
            if self.flow_gain_fitted else None
        if edge is not None:
            self.flow_gain_fitted, self.flow_gain_released = False, edge
            del self.bounds["GQ"]
            self.free.pop("GQ", None)
            self.current = self.fitter.refit(self.problem.base, self.bounds,
                                      f"{edge}: fit the declared faults with GQ at nominal")
        self.cur = self.fitter.evaluate([self.current])[0]
        before = self.cur
        if self.pinned:
            self.pin_structure()
        return before

    def pin_structure(self) -> None:
        """Put the model's known structure (:attr:`pinned`) in at its physical values (the
        probes: the thesis' flapper, 2513 rad/s at 0.6 damping) and refit the declared faults
        with it. It is reported as the first step(s) and held at those values through the
        rounds (its parameters are not in :attr:`free`; the joint polish of an accepted
        effect may move them locally); the final estimates fit it with everything else."""
        prev, faults0 = self.cur, {p: getattr(self.current, p) for p in self.bounds}
        start = self.current
        for effect in self.pinned:
            start = effect.switch_on(start)         # at its probe: the physical values
        names = "+".join(e.name for e in self.pinned)
        fitted = self.fitter.refit(start, self.bounds,
                                   f"fit the declared faults with {names} pinned")
        ev = self.fitter.evaluate([fitted])[0]
        gain = relative_gain(prev, ev)
        faults = {p: getattr(fitted, p) for p in self.bounds}
        for i, effect in enumerate(self.pinned):
            last = i == len(self.pinned) - 1
            after = ev if last else prev     # the fit with all of them is the last's
            self.steps.append(Step(
                effect=effect.name, params={p: getattr(fitted, p) for p in effect.params},
                rmse_before=prev.rmse_all, rmse_after=after.rmse_all,
                rmse_fit_before=prev.rmse_fit, rmse_fit_after=after.rmse_fit,
                rmse_hold_before=prev.rmse_hold, rmse_hold_after=after.rmse_hold,
                faults_before=faults0, faults_after=faults, gain=gain if last else 0.0,
                score=gain if last else 0.0, alternatives={},
                chosen=f"{names} pinned at physical values", chosen_score=gain))
        self.current, self.cur = fitted, ev

    def rounds_until_stop(self) -> str:
        """Trace / try / choose / confirm / accept until a stop rule holds; returns why it
        stopped."""
        while True:
            stop = self.stop_rule()
            if stop:
                return stop
            rnd, tried = self.candidates_of_round(self.remaining())
            choice = self.choose(rnd, tried)
            if choice.best is None and (choice.unspecific or (choice.insignificant
                                                             and self.unexplained())):
                # two effects may only stand out together: on a record the model leaves
                # unexplained also when each alone was chance on the few effective samples
                # (a 16 MPa supply and a 2000 N load on `mixed`: 12-13 % each, p 0.02 on 21)
                choice = self.look_ahead(rnd, tried, choice)
            if choice.best is None:
                return choice.stop
            confirmed = self.confirm(rnd, choice)
            if confirmed is not None:
                self.accept(confirmed)

    def stop_rule(self) -> str:
        """(e) Why the loop stops before tracing again, or ``""`` to go on."""
        s, cur = self.settings, self.cur
        if len(self.steps) >= s.max_steps:
            return f"reached max_steps={s.max_steps:g}"
        if cur.rmse_score <= s.noise_factor * self.problem.score_noise:
            what = " with P12" if self.problem.p12_weight else ""
            return (f"RMSE {1e6 * cur.rmse_score:.3g} µm (fitted and held-out parts{what}) is "
                    f"at the noise level ({1e6 * self.problem.score_noise:.3g} µm estimated from "
                    f"the record)")
        if not self.remaining():
            return "every candidate effect is already in the model"
        return ""

    def remaining(self) -> list[Effect]:
        added = {st.effect for st in self.steps} | {d.effect for d in self.dismissed}
        return [e for e in self.problem.pool if e.name not in added]

    def unexplained(self) -> bool:
        """Does the current model leave the record unexplained: its position residual above
        what faults and structure leave on healthy actuators of this command
        (:meth:`eha.explain.null.Null.residual_limit`, at most
        :data:`eha.identification.intervals.FLAG_RATIO` times the noise; without a null, that
        ratio)?"""
        return self.cur.rmse_all > self.residual_limit * self.problem.noise_ref

    def at_noise_level(self) -> bool:
        """Is the current model's position residual at the record's noise level (at most
        ``noise_factor`` times it, the stop rule's factor)? Above it the record is explained
        only at the found model's own level (:func:`eha.explain.replicates.explains`), not by
        what healthy actuators leave on the command: a residual of 1.6× the noise over a
        thousand samples is not noise (ExplainResult.verdict)."""
        return self.cur.rmse_all <= self.settings.noise_factor * self.problem.noise_ref

    @property
    def residual_limit(self) -> float:
        """Residual-to-noise ratio above which the record is unexplained."""
        from eha.identification.intervals import FLAG_RATIO

        if self.null is None:
            return FLAG_RATIO
        return self.null.residual_limit(self.settings.alpha)

    def estimate(self) -> None:
        """(g) The final estimates: the model chosen, every fitted parameter (faults and the
        effects added) is refitted on the *whole* record by least squares (``"lm"``,
        :func:`eha.identification.fdi.identify`) from the loop's fit. The hold-out serves the
        choice of effects; once they are chosen the estimates use all the data. The loop's refits
        are on the fitted part alone, and a GA or compass search there can stop in a valley's side
        basin that the held-out part would have ruled out (an offset of 0.21 for 0.3 traded against
        jack friction and a load on ``mixed``); the least-squares step follows the valley. The
        polish runs from the loop's model and from it with the structure's parameters at their
        physical values (the flapper's probe); the better is kept, only when it lowers the whole
        record's objective and leaves every added effect outside its healthy band. A model without
        added effects keeps its fit (a record to which nothing was added: ``after`` is ``before``).
        After it the "held-out" RMSE of the final model is in-sample (reported as such in
        docs/explain.md)."""
        if not self.steps:
            return
        free = dict(self.bounds)
        for step in self.steps:
            free.update(EFFECTS[step.effect].bounds)
        if not free:
            return
        starts = [self.current]
        # the structure's parameters are also restarted from their physical values (the
        # probe: the thesis' flapper, 2513 rad/s at 0.6 damping): a round's GA may have left
        # them in a side basin where the other estimates compensate (flapper at 1750 rad/s and
        # 0.32 with FDJ 12 % off on a viscous `test` record; from the probe 2310 rad/s, 5 %)
        physical = {p: v for st in self.steps if st.effect in STRUCTURAL
                    for p, v in EFFECTS[st.effect].probe.items()}
        if physical and any(getattr(self.current, p) != v for p, v in physical.items()):
            starts.append(self.current.replace(**physical))
        polished, ev = self.current, self.cur
        for start in starts:
            trial = self.fitter.refit(start, free, "final estimates on the whole record",
                               method="lm", whole=True)
            # an added effect polished back inside its healthy band would be reported
            # without being one: such a polish is not taken
            if any(self.fitter.within_healthy_at(EFFECTS[st.effect], trial) for st in self.steps):
                continue
            ev_t = self.fitter.evaluate([trial])[0]
            if ev_t.rmse_whole < ev.rmse_whole:
                polished, ev = trial, ev_t
        if ev is not self.cur:
            self.current, self.cur = polished, ev
            if self.steps:      # the last step's "after" is the final model
                self.steps[-1] = replace(
                    self.steps[-1], rmse_after=ev.rmse_all, rmse_fit_after=ev.rmse_fit,
                    rmse_hold_after=ev.rmse_hold,
                    faults_after={k: getattr(polished, k) for k in self.bounds})

    # -- the result ------------------------------------------------------------------------
    def result(self, before: Evaluation, faults_before: dict[str, float], stop: str
               ) -> ExplainResult:
        """The run's :class:`ExplainResult`: the final model, its intervals
        (:meth:`final_intervals`), the settings, the rounds and the residual's leads."""
        bounds, notes, level, flagged = self.final_intervals()
        data, s = self.problem.data, self.settings
        model_level = {}
        if not flagged and not self.at_noise_level() and s.interval_replicates:
            # above the noise, within the healthy band: what does the found model itself
            # leave on the HF? (eha.explain.replicates.model_level)
            model_level = self.model_level()
            if model_level:
                pinned = at_a_bound(self.current, self.final_model()[1])
                if pinned:
                    model_level["at_bound"] = pinned
                model_level["explains"] = explains(model_level, self.residual_limit)
            if model_level.get("explains"):
                # the rest is the found model's own: explained, as a record at the noise
                # is, when nothing outside the model fits as well (the exclusion check)
                self.rivals = self.not_excluded()
        settings = s.as_dict()
        facts = RunFacts(
            n_fit=self.problem.n_fit, candidates=[e.name for e in self.problem.pool],
            command_hold=data.info.get("command_hold", "linear"),
            p12_used=bool(self.problem.p12_weight), p12_noise_pa=self.problem.p12_noise,
            p12_m_per_pa=self.problem.p12_weight, structure_pinned=[e.name for e in self.pinned],
            flow_gain_fitted=self.flow_gain_fitted, flow_gain_released=self.flow_gain_released)
        return ExplainResult(
            source=data.source, fit_bounds=self.bounds, faults_before=faults_before,
            faults_after={k: getattr(self.current, k) for k in self.bounds}, before=before,
            after=self.cur, steps=self.steps, rounds=self.rounds, noise_rmse=self.problem.noise,
            stop_reason=stop, holdout=self.problem.holdout_text, t=data.t.copy(),
            measured=data.xu.copy(), settings=settings, facts=facts,
            seconds=time.perf_counter() - self.started, intervals=bounds, level=level,
            unexplained=flagged or not (self.at_noise_level() or model_level.get("explains"))
            or bool(self.rivals),
            beyond_healthy=flagged, not_excluded=self.rivals,
            rivals_ruled_out=self.rivals_ruled_out, excluded=self.excluded,
            model_level=model_level,
            interval_notes=notes, leads=self.leads(),
            dismissed=self.dismissed,
            null=self.null_summary())

    def model_level(self) -> dict:
        """:func:`eha.explain.replicates.model_level` of the final model, on the re-simulations
        of its intervals' replicate term (the same fitted parameters and HF values)."""
        from eha.explain.replicates import model_level
        final_bounds, added = self.final_model()
        names = [*self.bounds, *(p for e in added for p in EFFECTS[e].params)]
        ratio = self.cur.rmse_all / self.problem.noise_ref
        return model_level(self, final_bounds, names, ratio)

    def final_model(self) -> tuple[Bounds, list[str]]:
        """The final model's fitted parameters with their bounds (the faults and every step's
        effect) and the effects the loop added that are not the structure."""
        final_bounds = Bounds(self.bounds)
        for step in self.steps:
            final_bounds.update(EFFECTS[step.effect].bounds)
        added = [st.effect for st in self.steps
                 if st.effect not in STRUCTURAL and EFFECTS[st.effect].params]
        return final_bounds, added

    def null_summary(self) -> dict | None:
        """The null's summary at ``alpha`` (:meth:`eha.explain.null.Null.summary`), with, for
        an effect tested by its footprint, the parameter values that make the detectable
        footprint on this record from the final model (``detectable_as``: a user reads a
        supply pressure, not micrometres)."""
        if self.null is None:
            return None
        summary = self.null.summary(self.settings.alpha)
        for name, entry in summary["effects"].items():
            effect = EFFECTS.get(name)
            if effect is None or not effect.footprint or not math.isfinite(entry["detectable"]):
                continue
            base = self.current
            for needed in missing_requirements(effect, base):
                base = EFFECTS[needed].switch_on(base)
            entry["detectable_as"] = [
                {"setting": setting, "param": effect.tested, "value": value}
                for setting, value in self.problem.record.footprint_size(
                    effect, entry["detectable"], effect.switch_off(base))]
        return summary

    def final_intervals(self) -> tuple[dict[str, Interval], tuple[str, ...], float,
                                       bool]:
        """Intervals of the final model's fitted parameters on the whole record (no refit),
        their notes and level, and whether the record is left unexplained (flagged by the
        intervals, or :meth:`unexplained`); then the faults' intervals also span their
        estimates without the tentative effects (:meth:`faults_without_tentative`)."""
        from eha.identification.fdi import intervals_at
        from eha.identification.problem import DEFAULT_LEVEL, model_form_of
        from eha.identification.intervals import MODEL_FORM, loop_terms
        from eha.explain.replicates import with_replicates

        final_bounds, added = self.final_model()
        data = self.problem.data
        # a model the loop built carries its model-form floor (the LF with the right effects
        # is still not the actuator); a model to which nothing was added keeps its base's
        form = model_form_of(self.current)
        terms = loop_terms(MODEL_FORM.get(form, {}), list(final_bounds)) if self.steps else None
        replicated = None
        if terms is not None and added:
            # how far the reading moves on the HF simulated again (eha.explain.replicates)
            terms, replicated = with_replicates(self, terms, final_bounds, added)
        iv = intervals_at(data.xu, data.command, self.current, final_bounds,
                          level=DEFAULT_LEVEL, noise=self.problem.noise,
                          recorded_start=self.problem.record.recorded_start, t_end=data.t_end,
                          model_form=form, terms=terms)
        bounds, notes = dict(iv.bounds), (*iv.notes, *([replicated] if replicated else []))
        flagged = iv.flagged or self.unexplained()
        if flagged:
            without = self.faults_without_tentative()
            if without:
                # the faults may lie anywhere between what the model says with the effects
                # that may be stand-ins and without them
                for k, v in without.items():
                    lo, hi = bounds[k]
                    bounds[k] = (min(lo, v), max(hi, v))
                notes = (*notes, "the faults' intervals span their estimates without the "
                         "tentative effects (" + ", ".join(f"{k}={v:.4g}" for k, v in
                                                           without.items()) + ")")
        return bounds, notes, iv.level, flagged

    def faults_without_tentative(self) -> dict[str, float]:
        """The declared faults refitted on the whole record (least squares, from the final
        model) with every added effect that is not the structure switched off: what the faults
        would be if those effects — tentative in an unexplained record, possibly stand-ins
        for physics the library lacks — were not there. Empty when no such effect was
        added. (A 50 µm spool overlap on `mixed`: with the leak the loop added as its
        stand-in BKL 63 µm, without it 280 µm, the truth 100 µm.)"""
        wo, free = self.current, dict(self.bounds)
        for st in self.steps:
            effect = EFFECTS[st.effect]
            if st.effect in STRUCTURAL or not effect.params:
                free.update(effect.bounds)
            else:
                wo = effect.switch_off(wo)
        if wo == self.current:
            return {}
        fitted = self.fitter.refit(wo, free, "faults without the tentative effects", method="lm",
                            whole=True)
        return {k: float(getattr(fitted, k)) for k in self.bounds}

    def leads(self) -> LeadReport:
        """The current residual's relation to signal features of the current model (whole
        record; P12 measured when the record has it, else the model's)."""
        data = self.problem.data
        full = self.problem.record.full(self.current)
        p12 = data.p12 if data.p12 is not None else full["p12"]
        return residual_leads(data.xu - self.cur.xu, data.t, data.com, self.cur.xu,
                              full["dxj"], p12, self.problem.noise)
