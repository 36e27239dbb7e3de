"""What the residual loop reports: the evaluations, candidates, rounds, steps and dismissals of
a run, and :class:`ExplainResult` with its one serialisation, which every output is made of: the
``--json`` contract (:meth:`ExplainResult.to_json`), the steps table of the CSV and the console
(:meth:`~ExplainResult.steps_table`), the candidates' CSV, ``explain.json``
(:meth:`~ExplainResult.details`) and the database rows (:meth:`~ExplainResult.run_row`,
:meth:`~ExplainResult.step_rows`). RMSE in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from eha.explain.effects import EFFECTS
from eha.explain.facts import RunFacts
from eha.explain.leads import LeadReport
from eha.models.bounds import Bounds
from eha.models.estimate import Estimate, Interval, estimates, frame, intervals_json
from eha.models.params import LFParams
from eha.models.units import number, show


@dataclass
class Evaluation:
    """An LF parameter set scored on the record."""

    params: LFParams
    xu: np.ndarray                  # LF output on the whole record [m]
    rmse_fit: float                 # on the fitted part [m]
    rmse_hold: float                # on the held-out part or the validation record [m]
    rmse_all: float                 # whole record [m]
    #: effective independent samples of the residual (fitted + held-out parts)
    n_eff: float = math.nan
    #: RMSE of the measured P12 on the fitted / held-out part, weighted into metres of
    #: position (:func:`p12_objective_weight`); 0 when the record has no P12
    p12_fit: float = 0.0
    p12_hold: float = 0.0
    #: the same on the whole record (the validation record aside)
    p12_all: float = 0.0

    @property
    def rmse_whole(self) -> float:
        """The objective of the final estimates (:meth:`ResidualLoop.estimate`) [m]: position
        and weighted P12 on the whole record, ``hypot(rmse_all, p12_all)``."""
        return math.hypot(self.rmse_all, self.p12_all)

    @property
    def rmse_score(self) -> float:
        """What the loop scores and stops on [m]: the fitted and the held-out part weighted
        equally, ``sqrt((rmse_fit**2 + rmse_hold**2) / 2)``, with the weighted P12 RMSE of
        each part added in quadrature when the record has P12 (the fits' objective). The
        held-out part alone can be a quiet stretch (the end of a step sequence) where every
        candidate is at the noise level; the fitted part alone rewards over-fitting."""
        return math.sqrt(0.5 * (self.rmse_fit ** 2 + self.rmse_hold ** 2 + self.p12_fit ** 2
                                + self.p12_hold ** 2))


def ranking_score(ev: Evaluation) -> float:
    """An evaluation's score for choosing between fits (a diverged fit last)."""
    return ev.rmse_score if math.isfinite(ev.rmse_score) else math.inf


@dataclass
class Candidate:
    """One effect tried in one round."""

    effect: str
    signature_corr: float           # Pearson correlation of the residual with the signature
    explained: float                # fraction of the residual variance its linearised fit adds
    refit: bool = False
    params: dict[str, float] = field(default_factory=dict)
    faults: dict[str, float] = field(default_factory=dict)
    rmse_fit: float = math.nan
    rmse_hold: float = math.nan
    rmse_all: float = math.nan
    gain: float = math.nan          # relative reduction of Evaluation.rmse_score
    score: float = math.nan         # gain - penalty * added parameters
    #: significance of the gain (:func:`significance`) on ``n_eff`` effective samples
    p_value: float = math.nan
    n_eff: float = math.nan
    seconds: float = 0.0
    #: per effect tested against the healthy null: its parameter's shift from off in the
    #: local test (:meth:`ResidualLoop.local_test`)
    shifts: dict[str, float] = field(default_factory=dict)


@dataclass
class Step:
    """An effect added to the model."""

    effect: str
    params: dict[str, float]
    rmse_before: float              # whole record, before / after adding the effect [m]
    rmse_after: float
    rmse_fit_before: float
    rmse_fit_after: float
    rmse_hold_before: float
    rmse_hold_after: float
    faults_before: dict[str, float]
    faults_after: dict[str, float]
    gain: float
    score: float
    #: other candidates of the round scoring within ``ALTERNATIVE_MARGIN`` of the chosen one
    #: (name -> score): the record does not tell them apart (e.g. load, offset, sensor bias)
    alternatives: dict[str, float] = field(default_factory=dict)
    #: the candidate accepted in this step's round (a combination adds several steps) and
    #: its score, the one the alternatives compare with
    chosen: str = ""
    chosen_score: float = math.nan


@dataclass
class Dismissal:
    """An effect chosen in a round but not added (:meth:`ResidualLoop.confirm`), or added and
    removed by the final check (:meth:`ResidualLoop.prune`, ``round`` = the number of
    rounds): left out and the rest refitted, the model lost too little; it is not tried again
    in that run."""

    effect: str
    #: the round (0-based, as in ``rounds``)
    round: int
    #: relative RMSE reduction it brought over the refit without it (scored); for a swap,
    #: minus the reduction its replacement brings over it; for a two-for-one merge, the
    #: reduction the pair brought over its replacement (the same for both of the pair)
    loss: float
    #: significance of that reduction (:func:`significance`)
    p_value: float
    #: the effect that replaced it in the final check (a swap), else ""
    replaced_by: str = ""


@dataclass
class Round:
    """The trace of the residual at one stage and the candidates tried."""

    residual_rmse: float
    signals: dict[str, float]
    candidates: list[Candidate]


#: The columns of :meth:`ExplainResult.steps_table` (``steps.csv``), in order.
STEP_COLUMNS = ("step", "effect", "params", "rmse_fit_before_m", "rmse_fit_after_m",
                "rmse_holdout_before_m", "rmse_holdout_after_m", "rmse_before_m",
                "rmse_after_m", "faults_before", "faults_after", "gain", "score", "chosen",
                "chosen_score", "alternatives")


@dataclass
class ExplainResult:
    """Outcome of :func:`explain` (RMSE in metres)."""

    source: str
    fit_bounds: Bounds
    faults_before: dict[str, float]
    faults_after: dict[str, float]
    before: Evaluation
    after: Evaluation
    steps: list[Step]
    rounds: list[Round]
    noise_rmse: float
    stop_reason: str
    holdout: str
    t: np.ndarray
    measured: np.ndarray
    #: how the loop was told to run (:class:`eha.explain.settings.LoopSettings` and the fit's
    #: options)
    settings: dict[str, Any]
    seconds: float
    #: how this run went (:class:`eha.explain.facts.RunFacts`): samples fitted, candidates,
    #: P12 in the fit, passes, the flow gain fitted or released
    facts: RunFacts = field(default_factory=RunFacts)
    #: intervals of the final model's fitted parameters (faults and effect parameters)
    intervals: dict[str, Interval] = field(default_factory=dict)
    level: float | None = None
    #: the residual is above the noise level (``noise_factor`` times the noise) and above
    #: the found model's own level (:attr:`model_level`), or a rival fits as well: the
    #: model does not explain the record alone, and any effect added is tentative
    unexplained: bool = False
    #: the residual is also beyond what faults and structure leave on *healthy* actuators of
    #: this command (the null's residual limit, or the intervals' flag): the faults'
    #: intervals are widened and the loop ran its second pass
    beyond_healthy: bool = False
    interval_notes: tuple[str, ...] = ()
    #: the final residual's relation to signal features (:mod:`eha.explain.leads`)
    leads: LeadReport | None = None
    #: effects chosen but not added: the rest of the model refitted explained as much
    dismissed: list[Dismissal] = field(default_factory=list)
    #: the healthy null the decisions rested on (:meth:`eha.explain.null.Null.summary`):
    #: source, alpha, and per effect its threshold and detectable size; None without one
    null: dict[str, Any] | None = None
    #: effects outside the final model that the record cannot rule out (the loop's exclusion
    #: check, :meth:`eha.explain.final_check.FinalCheck.not_excluded`): per effect its
    #: parameter, the value its test fit reached (beyond the null's detectable size), that
    #: size and the threshold; non-empty only for a model at the noise level (or at its own
    #: level, :attr:`model_level`), then ``unexplained``
    not_excluded: list[dict[str, Any]] = field(default_factory=list)
    #: rivals the exclusion check listed that the rival check ruled out
    #: (:func:`eha.explain.rival_check.check_rival`), with its figures
    rivals_ruled_out: list[dict[str, Any]] = field(default_factory=list)
    #: what the exclusion check excluded (a model at the noise or its own level): effect ->
    #: its tested ``param``, the shift ``beyond`` which the check would have listed it with
    #: the null's power, and its ``unit``; ``"by": "first record"`` where a first record's
    #: exclusion stands for a rival this record does not show. A follow-up's ``--prior``
    #: reads it
    excluded: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: for a record above the noise within the healthy band, what the found model leaves on
    #: HF re-simulations of itself (:func:`eha.explain.replicates.model_level`), with
    #: ``explains`` (:func:`eha.explain.replicates.explains`: the record is then explained at
    #: that level when nothing outside the model fits as well); else empty
    model_level: dict[str, Any] = field(default_factory=dict)
    #: with a ``--prior`` that lists rivals: which of the first record's explanations this
    #: record leaves standing (:meth:`eha.explain.settle.Settlement.to_json`), else None
    settled: dict[str, Any] | None = None
    #: the run's name in the files and the database: :func:`eha.explain.from_file.explain_file`
    #: names it by the file's bytes and what went in; otherwise (:attr:`key`) by the record's
    #: samples and the settings
    run_id: str = ""

    @property
    def key(self) -> str:
        """:attr:`run_id`, or, when none was given, 16 hex digits of a hash of the record's
        samples, the fitted bounds and the settings (the same run, the same key)."""
        if self.run_id:
            return self.run_id
        import hashlib
        import json

        digest = hashlib.sha1(np.ascontiguousarray(self.measured, dtype=float).tobytes())
        digest.update(json.dumps([self.source, self.settings,
                                  Bounds(self.fit_bounds).to_dict()],
                                 sort_keys=True, default=str).encode())
        return digest.hexdigest()[:16]

    def as_estimates(self) -> dict[str, Estimate]:
        """The final model's :class:`~eha.models.estimate.Estimate` of each fitted parameter
        (faults and effect parameters; SI units): the value, its interval at :attr:`level`
        where one was computed."""
        names = [*self.intervals, *(k for k in self.faults_after if k not in self.intervals)]
        values = {k: self.faults_after[k] if k in self.faults_after
                  else getattr(self.after.params, k) for k in names}
        return estimates(values, self.intervals, self.level)

    def to_pandas(self, table: str = "steps"):
        """A pandas DataFrame: ``"steps"``, the steps table (:meth:`steps_table`), one row per
        added effect, RMSE columns in m; ``"estimates"``, one row per fitted parameter of the
        final model (:meth:`as_estimates`): ``parameter``, ``unit`` (SI), ``estimate``, ``lo``,
        ``hi``, ``level``."""
        import pandas as pd

        if table == "estimates":
            return frame(self.as_estimates(), key="parameter")
        if table != "steps":
            from eha.explain.settings import ExplainError

            raise ExplainError(f"`table` {table!r}: allowed steps, estimates")
        return pd.DataFrame(self.steps_table(), columns=list(STEP_COLUMNS))

    def plot(self, path=None, kind: str = "residuals"):
        """The residuals figure (measured vs LF before and after, the residuals), or with
        ``kind="trace"`` how the first residual traced to effects: a matplotlib figure, or,
        with ``path``, written as PNG (the path returned)."""
        from eha.explain.outputs import plot_explain_residuals, plot_explain_trace

        plots = {"residuals": plot_explain_residuals, "trace": plot_explain_trace}
        if kind not in plots:
            from eha.explain.settings import ExplainError

            raise ExplainError(f"`kind` {kind!r}: allowed {', '.join(plots)}")
        return plots[kind](self, path)

    def save(self, folder, json_path=None) -> dict:
        """Write the run's files under ``folder`` (:func:`eha.explain.outputs.save_result`):
        steps and candidates CSV, the two figures, ``explain.json``, and with ``json_path``
        the JSON contract; returns name -> path."""
        from eha.explain.outputs import save_result

        return save_result(self, folder, json_path)

    def store(self, results="results"):
        """Write the run's rows into ``results``' database (``explain_runs``,
        ``explain_steps``; :func:`eha.explain.outputs.store_result`); returns its path."""
        from eha.explain.outputs import store_result

        return store_result(self, results)

    def undetectable(self) -> list[str]:
        """One line per testable effect not in the model: below which size this record's
        command could not have shown it (the null's detectable size at ``alpha``), so that a
        clean verdict says what it rules out."""
        if not self.null:
            return []
        added = set(self.effects)
        lines = []
        for name, e in self.null["effects"].items():
            if name in added or not math.isfinite(e["detectable"]):
                continue
            effect = EFFECTS[name]
            param = effect.tested
            first = self.excluded.get(name, {})
            if first.get("by") == "first record":
                # beside the found model this command does not show it (the rival check)
                lines.append(f"{name}: not shown on this command beside the found model; the "
                             f"first record excludes a change beyond "
                             f"{show(first['param'], first['beyond'])} in {first['param']}")
                continue
            if effect.footprint:
                sizes = "; ".join(
                    (f"{param} {show(param, a['value'])}" if a["value"] is not None else
                     f"no {param} down to {show(param, effect.bounds[param][0])}")
                    + "".join(f" at {k} {v:g}" for k, v in a["setting"].items())
                    for a in e.get("detectable_as", []))
                shift = e.get("shift")
                also = (f" and a change of {show(shift['param'], shift['detectable'])} in "
                        f"{shift['param']}" if shift else "")
                lines.append(f"{name}: not detectable on this command below a footprint of "
                             f"{1e6 * e['detectable']:.3g} µm (the RMS change of the position "
                             f"that {'+'.join(effect.params)} as fitted make against healthy "
                             f"{param} {show(param, effect.off[param])}"
                             + (f"; made by {sizes}" if sizes else "") + ")" + also)
            else:
                lines.append(f"{name}: not detectable on this command below a change of "
                             f"{show(param, e['detectable'])} in {param} (healthy "
                             f"{number(param, effect.off[param], 4)})")
        return lines

    @property
    def verdict_facts(self):
        """The verdict's facts, kind and lines (:class:`eha.explain.verdict.Verdict`): every
        output's verdict is made from it."""
        from eha.explain.verdict import verdict_of

        return verdict_of(self)

    @property
    def verdict(self) -> str:
        """One line, ``KIND: what was found; the residual[; the rivals]``
        (:mod:`eha.explain.verdict`, docs/explain.md):

        - ``"explained: found external load 829 N [818, 839] (90 %); residual 1.03 µm, at the
          noise (1.09 µm)"``;
        - ``"explained, ambiguous: found ...; cannot be told apart on this command from a
          motor offset of -0.009 mA (...)"``: at the noise, but an effect outside the model
          fits as well with a size this command shows;
        - ``"partly explained: found leakage ... (tentative); residual 1.6 µm, 1.6× the noise
          (1 µm), within what healthy actuators leave on this command (up to 3×): an effect
          that small may be missing"``;
        - ``"unexplained residual 12.3 µm (8.1× noise), correlated with position_cubed (61 %
          of it)..."`` (the leads; the effects added are tentative).
        """
        return self.verdict_facts.text

    @property
    def rmse_before(self) -> float:
        return self.before.rmse_all

    @property
    def rmse_after(self) -> float:
        return self.after.rmse_all

    @property
    def unexplained_rmse(self) -> float:
        """RMSE left above the noise level [m]: ``sqrt(max(rmse_after^2 - noise^2, 0))``."""
        return math.sqrt(max(self.rmse_after ** 2 - self.noise_rmse ** 2, 0.0))

    @property
    def effects(self) -> list[str]:
        return [s.effect for s in self.steps]

    def final_params(self, step: Step) -> dict[str, float]:
        """The parameters of a step's effect in the final model (later steps end with a joint
        polish that refines earlier estimates; ``step.params`` holds them as first added)."""
        return {p: getattr(self.after.params, p) for p in step.params}

    def to_json(self) -> dict[str, Any]:
        """The contract of ``eha explain --json`` (issue 5): RMSE over the whole record [m],
        each step's parameters as estimated in the final model."""
        return {
            "rmse_before": self.rmse_before,
            "rmse_after": self.rmse_after,
            "faults_before": dict(self.faults_before),
            "faults_after": dict(self.faults_after),
            "intervals": intervals_json(self.as_estimates()),
            "level": self.level, "unexplained": self.unexplained,
            "beyond_healthy": self.beyond_healthy,
            "interval_notes": list(self.interval_notes),
            "verdict": self.verdict, "noise_rmse": self.noise_rmse,
            "unexplained_rmse": self.unexplained_rmse,
            "leads": self.leads.to_json() if self.leads is not None else None,
            "command_hold": self.facts.command_hold,
            "p12_in_fit": self.facts.p12_used,
            "flow_gain_released": self.facts.flow_gain_released,
            "steps": [{"effect": s.effect, "params": self.final_params(s),
                       "rmse_before": s.rmse_before, "rmse_after": s.rmse_after,
                       "tentative": self.unexplained,
                       "alternatives": self.alternatives_of(s)}
                      for s in self.steps],
            "dismissed": [{"effect": d.effect, "round": d.round, "loss": d.loss,
                           "p_value": d.p_value, "replaced_by": d.replaced_by}
                          for d in self.dismissed],
            "null": self.null,
            "undetectable": self.undetectable(),
            "not_excluded": [dict(e) for e in self.not_excluded],
            "rivals_ruled_out": [dict(e) for e in self.rivals_ruled_out],
            "excluded": {k: dict(v) for k, v in self.excluded.items()},
            "model_level": dict(self.model_level),
            "settled": self.settled,
            **self.verdict_facts.to_json(),
            "units": self.units(),
        }

    def units(self) -> dict[str, str]:
        """The unit of every number of the JSON by name: parameters in their declared (SI)
        unit (currents mA), RMSE and noise in m (``found`` also gives each value as text in
        its display unit)."""
        from eha.models.params import SPECS

        names = {*self.faults_after, *self.intervals,
                 *(p for st in self.steps for p in st.params)}
        return {"rmse": "m", "noise_rmse": "m",
                **{n: SPECS[n].unit for n in sorted(names) if n in SPECS}}

    @staticmethod
    def alternatives_of(step: Step) -> dict[str, float]:
        """Candidates of the step's round that scored within :data:`ALTERNATIVE_MARGIN` of the
        one chosen (name -> penalised score): explanations the record cannot tell from the
        step's (a motor gain for a supply pressure on a chirp). Those that contain the step's
        own effect are left out (a step put in by the final check's swap keeps its round's
        list)."""
        return {k: v for k, v in step.alternatives.items() if step.effect not in k.split("+")}

    def steps_table(self) -> list[dict[str, Any]]:
        """One row per added effect, for people (CSV / console)."""
        return [{"step": i + 1, "effect": s.effect,
                 "params": ", ".join(f"{k} {show(k, v, 4)}" for k, v in
                                     self.final_params(s).items()) or "-",
                 "rmse_fit_before_m": s.rmse_fit_before, "rmse_fit_after_m": s.rmse_fit_after,
                 "rmse_holdout_before_m": s.rmse_hold_before,
                 "rmse_holdout_after_m": s.rmse_hold_after,
                 "rmse_before_m": s.rmse_before, "rmse_after_m": s.rmse_after,
                 "faults_before": ", ".join(f"{k} {show(k, v, 4)}"
                                            for k, v in s.faults_before.items()),
                 "faults_after": ", ".join(f"{k} {show(k, v, 4)}"
                                           for k, v in s.faults_after.items()),
                 "gain": s.gain, "score": s.score, "chosen": s.chosen,
                 "chosen_score": s.chosen_score,
                 "alternatives": ", ".join(f"{k} ({v:+.2f})" for k, v in
                                           self.alternatives_of(s).items())}
                for i, s in enumerate(self.steps)]

    def candidates_table(self) -> list[dict[str, Any]]:
        """One row per candidate of every round (``candidates.csv``)."""
        return [{"round": i + 1, **{k: v for k, v in vars(c).items() if not k.startswith("_")}}
                for i, rnd in enumerate(self.rounds) for c in rnd.candidates]

    def details(self, run_id: str) -> dict[str, Any]:
        """Everything of the run (``explain.json``): the ``--json`` contract and the steps
        table, settings, signals of every round and the stop reason."""
        return {**self.to_json(), "run_id": run_id, "source": self.source,
                "noise_rmse": self.noise_rmse, "unexplained_rmse": self.unexplained_rmse,
                "stop_reason": self.stop_reason, "holdout": self.holdout,
                "steps_table": self.steps_table(), "settings": self.settings,
                "facts": self.facts.to_json(),
                "signals": [r.signals for r in self.rounds], "seconds": self.seconds}

    def run_row(self, run_id: str, source: str, created_at: Any) -> dict[str, Any]:
        """The run's row of ``explain_runs`` (:func:`eha.explain.tables.save_explain`);
        ``source`` is the record's path as given."""
        return {"run_id": run_id, "source": source, "created_at": created_at,
                "fit": Bounds(self.fit_bounds).to_dict(),
                "holdout": self.holdout, "settings": self.settings,
                "facts": self.facts.to_json(), "rmse_before": self.rmse_before, "rmse_after": self.rmse_after,
                "noise_rmse": self.noise_rmse, "unexplained_rmse": self.unexplained_rmse,
                "faults_before": self.faults_before, "faults_after": self.faults_after,
                "effects": self.effects, "stop_reason": self.stop_reason,
                "seconds": self.seconds, "unexplained": bool(self.unexplained),
                "beyond_healthy": bool(self.beyond_healthy), "verdict": self.verdict,
                **{k: v for k, v in self.verdict_facts.to_json().items() if k != "found"},
                "command_hold": self.facts.command_hold,
                "leads": self.leads.to_json() if self.leads is not None else None}

    def step_rows(self, run_id: str) -> list[dict[str, Any]]:
        """The steps' rows of ``explain_steps`` (:func:`eha.explain.tables.save_explain`)."""
        return [{"run_id": run_id, "step": i + 1, "effect": s.effect,
                 "params": self.final_params(s),
                 "rmse_before": s.rmse_before, "rmse_after": s.rmse_after,
                 "rmse_fit_before": s.rmse_fit_before, "rmse_fit_after": s.rmse_fit_after,
                 "rmse_hold_before": s.rmse_hold_before, "rmse_hold_after": s.rmse_hold_after,
                 "faults_before": s.faults_before, "faults_after": s.faults_after,
                 "gain": s.gain, "score": s.score} for i, s in enumerate(self.steps)]
