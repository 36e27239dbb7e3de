"""How the residual loop scores and fits parameter sets on its record, and the healthy band an
effect's fit must leave: the :class:`Fitting` part of :class:`eha.explain.loop.ResidualLoop`.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from eha.explain.effects import Effect
from eha.explain.record import rmse
from eha.explain.results import Evaluation
from eha.explain.settings import (FINISHED_POLISH_XTOL, GLOBAL_METHODS, LEAST_SQUARES_FINISH,
                                  MULTISTART, MULTISTART_PARAMS, SWITCHED_OFF, ExplainError)
from eha.identification.intervals import effective_samples
from eha.models.params import LFParams


class Fitting:
    """Scoring (:meth:`evaluate`), fitting (:meth:`refit`, :meth:`fit_with_cost`) and the
    healthy band (:meth:`within_healthy`) of :class:`~eha.explain.loop.ResidualLoop`, on its
    record, settings, null thresholds and P12 weight (set by its ``__init__``)."""

    # -- the healthy band ------------------------------------------------------------------
    def within_healthy(self, effect: Effect, values: Mapping[str, float]) -> bool:
        """Is the effect's fitted parameter (``values``) within what healthy actuators reach
        on this record's command (the null's threshold at ``alpha``)? An effect the null does
        not cover (the structure, or no null) is within it when switched off: within
        :data:`eha.explain.settings.SWITCHED_OFF` of its search range from off."""
        threshold = (self.thresholds or {}).get(effect.name)
        if threshold is not None:
            return effect.shift(values) <= threshold
        off = effect.off
        return all(abs(values[n] - off[n]) <= SWITCHED_OFF * (hi - lo)
                   for n, (lo, hi) in effect.bounds.items())

    def within_healthy_at(self, effect: Effect, params: LFParams) -> bool:
        """:meth:`within_healthy` of the effect as fitted in ``params`` (False for a
        switch: a fit cannot put it back); an effect tested by its footprint
        (:attr:`~eha.explain.effects.Effect.footprint`) is within unless :meth:`past` its
        thresholds."""
        if not effect.params:
            return False
        if effect.footprint and effect.name in (self.thresholds or {}):
            return not self.past(effect, params, self.thresholds)
        return self.within_healthy(effect, {n: getattr(params, n) for n in effect.params})

    def past(self, effect: Effect, params: LFParams, bars: dict[str, float]) -> bool:
        """Whether the effect as fitted in ``params`` is past its bar in ``bars`` (the null's
        thresholds or its detectable sizes, keyed as :meth:`eha.explain.null.Null.summary`):
        :func:`~eha.explain.decide.past_any` of its statistic (:meth:`statistic_at`) and, for
        an effect tested by its footprint, its parameter's shift
        (:attr:`~eha.explain.effects.Effect.shift_key`)."""
        from eha.explain.decide import past_any

        statistics = {effect.name: self.statistic_at(effect, params)}
        if effect.shift_key is not None:
            statistics[effect.shift_key] = effect.shift_at(params)
        return past_any(statistics, bars)

    def statistic_at(self, effect: Effect, params: LFParams) -> float:
        """The statistic the healthy null tests for ``effect`` as fitted in ``params``: its
        footprint on the record (m) or its tested parameter's shift from off
        (:meth:`~eha.explain.effects.Effect.shift_at`)."""
        if effect.footprint:
            return self.record.footprint(effect, params)
        return effect.shift_at(params)

    # -- evaluation and fitting ------------------------------------------------------------
    def evaluate(self, params: list[LFParams]) -> list[Evaluation]:
        """Simulate parameter sets on the record (one batch) and score them."""
        data, n_fit, check, w = self.data, self.n_fit, self.check, self.p12_weight
        xu, p12 = self.record.run(params, with_p12=True)
        check_p12 = w and check is not None and self.validate.p12 is not None
        if check is not None:
            hold, hold_p12 = check.run([p.replace(XJ0=check.base.XJ0) for p in params],
                                       with_p12=True)
        out = []
        for j, p in enumerate(params):
            r_fit = rmse(xu[j, :n_fit], data.xu[:n_fit])
            p_fit = w * rmse(p12[j, :n_fit], data.p12[:n_fit]) if w else 0.0
            if check is not None:
                r_hold = rmse(hold[j], self.validate.xu)
                # a validation record without P12: its position alone is held out
                p_hold = w * rmse(hold_p12[j], self.validate.p12) if check_p12 else 0.0
                resid = np.concatenate([data.xu - xu[j], self.validate.xu - hold[j]])
            else:
                held = n_fit < len(data)
                r_hold = rmse(xu[j, n_fit:], data.xu[n_fit:]) if held else r_fit
                p_hold = (w * rmse(p12[j, n_fit:], data.p12[n_fit:]) if held else p_fit) \
                    if w else 0.0
                resid = data.xu - xu[j]
            out.append(Evaluation(p, xu[j], r_fit, r_hold, rmse(xu[j], data.xu),
                                  n_eff=effective_samples(resid)
                                  if np.all(np.isfinite(resid)) else 2.0,
                                  p12_fit=p_fit, p12_hold=p_hold,
                                  p12_all=w * rmse(p12[j], data.p12) if w else 0.0))
        return out

    def refit(self, start: LFParams, free: Mapping[str, tuple[float, float]], label: str,
              method: str | None = None, warm_start: bool = False,
              whole: bool = False, starts: int | None = None) -> LFParams:
        """The parameters ``free`` fitted from ``start`` on the fitted part of the record
        (``whole``: on all of it)."""
        return self.fit_with_cost(start, free, label, method, warm_start, whole, starts)[0]

    def fit_with_cost(self, start: LFParams, free: Mapping[str, tuple[float, float]],
                      label: str, method: str | None = None, warm_start: bool = False,
                      whole: bool = False, starts: int | None = None
                      ) -> tuple[LFParams, float]:
        """:meth:`refit`, and the objective it reached (the fit's cost, to compare fits)."""
        from eha.identification.fdi import identify
        from eha.identification.problem import METHOD_DEFAULTS, FDIError

        s = self.settings
        method = method or s.method
        self.progress(label)
        # the local methods take only their own options (the user's GA options are not theirs;
        # "lm" keeps its defaults: its xtol is not the pattern search's)
        options = (self.fdi_options if method not in ("ps", "lm") else
                   {k: v for k, v in self.fdi_options.items()
                    if k in METHOD_DEFAULTS[method] and method == "ps"})
        if method == "ga+ps" and LEAST_SQUARES_FINISH:
            options = {"xtol": FINISHED_POLISH_XTOL, **options}
        # searches of many parameters get more GA starts (other seeds); the best fit is kept
        if starts is None:
            starts = 1 if method in ("ps", "lm") or len(free) < MULTISTART_PARAMS \
                else MULTISTART
        n = len(self.data) if whole else self.n_fit
        # what every search of this refit fits: the record's part, its start and its P12
        record = dict(reference_xu=self.data.xu[:n], command=self.data.command,
                      fit=dict(free), recorded_start=self.record.recorded_start, level=None,
                      p12_weight=self.p12_weight,
                      reference_p12=self.data.p12[:n] if self.p12_weight else None)
        best = None
        try:
            for i in range(starts):
                res = identify(base=start, method=method, pop=s.pop, seed=s.seed + 1000 * i,
                               warm_start=warm_start, **record, **options)
                if best is None or res.objective < best.objective:
                    best = res
            if method in GLOBAL_METHODS and LEAST_SQUARES_FINISH:
                # a global search is finished by least squares from its best point: the GA
                # (and its compass polish) stops on the side of a narrow valley of many
                # parameters, where the fitted part is matched by a wrong trade-off that the
                # held-out part rejects (a flapper refit on a 7-parameter steps record:
                # 2.3 µm fitted, 17.8 µm held out after the GA; 1.0 and 2.1 µm after lm)
                polished = identify(base=start.replace(**best.estimates), method="lm",
                                    **record)
                if polished.objective < best.objective:
                    best = polished
        except FDIError as exc:
            raise ExplainError(str(exc)) from None
        return start.replace(**best.estimates), float(best.objective)
