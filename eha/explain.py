"""The residual loop: fit the declared faults, trace the residual to a missing effect, add it.

Given a measured record (:mod:`eha.measured`), :func:`explain`

a. fits the declared fault parameters of the LF model (:func:`eha.fdi.identify`) on the fitted
   part of the record: the baseline and its residual ``r = y_measured - y_LF``;
b. traces the residual: its correlation with the *signature* of every effect of
   :data:`eha.effects.EFFECTS` (the change of the LF output xu when the effect is switched on at
   its probe value, a secant sensitivity computed by finite differences, all in one parallel
   batch) and with signals (position, sign of the jack velocity, command, tracking error, P12);
   the linearised fit ``r ~ J_faults*d_faults + a*signature`` gives the fraction of the residual
   each effect could explain, which ranks the candidates;
c. refits the faults together with each of the best-ranked candidates (its parameters free
   within their bounds) and scores it by the relative reduction of the RMSE (fitted and
   *held-out* parts weighted equally, :attr:`Evaluation.rmse_score`) minus a
   penalty per added parameter;
d. adds the best candidate when that penalised gain is significant (>= ``min_gain``), and
   repeats from (b) with the augmented model;
e. stops when no candidate is significant, when the residual is at the measurement-noise level
   (estimated from the record itself), or after ``max_steps``; it says how much of the residual
   is left unexplained (the part above the noise level).

Held-out data: the last ``holdout`` fraction of the record (the model is fitted on the first
part and simulated over the whole record), or a second record (``validate``) simulated with its
own command. RMSE in metres.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from eha.fdi import DEFAULT_METHOD
from eha.effects import (COMBINATIONS, EFFECTS, Effect, get as get_effects,
                         missing_requirements, switch_on_with_requirements)
from eha.intervals import effective_samples
from eha.residual_leads import LeadReport, residual_leads
from eha.measured import MeasuredData, noise_level
from eha.params import LFParams, ParameterError, parse_name_value, resolve
from eha.simulate import (OUTPUT_DT, command_on_grid, grid, simulate, simulate_lf_batch,
                          xj0_for_recorded)

#: Search bounds of the declared faults when none are given (wider than the thesis' chirp
#: cases, for records of unknown actuators).
DEFAULT_FAULT_BOUNDS: dict[str, tuple[float, float]] = {"BKL": (0.0, 2e-3),
                                                        "FDJ": (0.0, 8000.0)}
#: Refits of at least this many free parameters (faults + effects) run MULTISTART GA searches
#: (seeds ``seed``, ``seed + 1000``, ...) and keep the best fit.
MULTISTART_PARAMS = 5
MULTISTART = 2
#: The loop's global methods; each of their searches is finished by least squares
#: (:meth:`ResidualLoop.refit`) when LEAST_SQUARES_FINISH is on.
GLOBAL_METHODS = ("ga", "ga+ps")
LEAST_SQUARES_FINISH = True
#: A record whose first position is within this distance of its first command starts at rest
#: on the command (the LF model starts there); otherwise at the measured first position [m].
START_TOLERANCE = 5e-4
#: Candidates scoring within this margin (absolute, in relative gain) of the chosen
#: one are reported as alternatives the record cannot tell apart.
ALTERNATIVE_MARGIN = 0.05
#: Signals the residual is correlated with (name -> meaning).
SIGNALS = {
    "position": "LF position xu",
    "velocity_sign": "sign of the LF jack velocity",
    "command": "position command",
    "tracking_error": "command - LF position",
    "p12": "load pressure P12 (measured when the record has it, else LF)",
}


class ExplainError(ValueError):
    """Bad input to the residual loop (one line)."""


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


@dataclass
class ExplainResult:
    """Outcome of :func:`explain` (RMSE in metres)."""

    source: str
    fit_bounds: dict[str, tuple[float, float]]
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
    settings: dict[str, Any]
    seconds: float
    #: intervals of the final model's fitted parameters (faults and effect parameters)
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)
    level: float | None = None
    #: the residual after the best library model is still well above the noise
    unexplained: bool = False
    interval_notes: tuple[str, ...] = ()
    #: the final residual's relation to signal features (:mod:`eha.residual_leads`)
    leads: LeadReport | None = None
    #: effects chosen but not added: the rest of the model refitted explained as much
    dismissed: list[Dismissal] = field(default_factory=list)
    #: the healthy null the decisions rested on (:meth:`eha.explain_null.Null.summary`):
    #: source, alpha, and per effect its threshold and detectable size; None without one
    null: dict[str, Any] | None = None

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
            (param,) = effect.params
            lines.append(f"{name}: not detectable on this command below a change of "
                         f"{e['detectable']:.3g} {e['unit']} in {param} (healthy "
                         f"{effect.off[param]:.4g})")
        return lines

    @property
    def verdict(self) -> str:
        """One line: is the record explained by the library model, and if not, a lead.

        ``"unexplained residual 12.3 µm (8.1× noise), correlated with position_cubed (61 % of
        it)"`` when the residual after the best library model is still well above the noise
        (the effects added may then stand in for physics the library lacks: tentative), else
        ``"explained: residual 1.6 µm (1.6× noise)"``.
        """
        if self.unexplained and self.leads is not None:
            text = self.leads.describe()
            limit = (self.null or {}).get("residual_limit")
            if limit is not None:
                text += f"; healthy actuators leave up to {limit:.2g}× noise on this command"
            if self.steps:
                text += ("; the effects added are tentative (they may stand in for physics "
                         "the library lacks)")
            return text
        ratio = self.rmse_after / self.noise_rmse if self.noise_rmse > 0 else math.inf
        return f"explained: residual {1e6 * self.rmse_after:.3g} µm ({ratio:.1f}× noise)"

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
            "intervals": {k: list(v) for k, v in self.intervals.items()},
            "level": self.level, "unexplained": self.unexplained,
            "interval_notes": list(self.interval_notes),
            "verdict": self.verdict, "noise_rmse": self.noise_rmse,
            "unexplained_rmse": self.unexplained_rmse,
            "leads": self.leads.to_json() if self.leads is not None else None,
            "command_hold": self.settings.get("command_hold"),
            "p12_in_fit": bool(self.settings.get("p12_used", False)),
            "flow_gain_released": self.settings.get("flow_gain_released"),
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
        }

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
                 "params": ", ".join(f"{k}={v:.4g}" for k, v in
                                     self.final_params(s).items()) or "-",
                 "rmse_fit_before_m": s.rmse_fit_before, "rmse_fit_after_m": s.rmse_fit_after,
                 "rmse_holdout_before_m": s.rmse_hold_before,
                 "rmse_holdout_after_m": s.rmse_hold_after,
                 "rmse_before_m": s.rmse_before, "rmse_after_m": s.rmse_after,
                 "faults_before": ", ".join(f"{k}={v:.4g}" for k, v in s.faults_before.items()),
                 "faults_after": ", ".join(f"{k}={v:.4g}" for k, v in s.faults_after.items()),
                 "gain": s.gain, "score": s.score, "chosen": s.chosen,
                 "chosen_score": s.chosen_score,
                 "alternatives": ", ".join(f"{k} ({v:+.2f})" for k, v in
                                           self.alternatives_of(s).items())}
                for i, s in enumerate(self.steps)]


# --------------------------------------------------------------------------------------------
# helpers


def parse_fit(spec: str | Mapping[str, Sequence[float]] | Iterable[str] | None
              ) -> dict[str, tuple[float, float]]:
    """Fault parameters to fit: ``"BKL,FDJ"`` or ``"BKL=0:1e-3,FDJ=200:4000"`` or a mapping.

    Names without bounds take :data:`DEFAULT_FAULT_BOUNDS` or :func:`eha.fdi.default_bounds`.
    """
    from eha.fdi import DEFAULT_FIT, FDIError, check_bounds, default_bounds

    if spec is None:
        spec = DEFAULT_FIT
    if isinstance(spec, Mapping):
        items = {k: tuple(v) for k, v in spec.items()}
    else:
        parts = [p.strip() for p in (spec.split(",") if isinstance(spec, str) else spec)]
        items = {}
        for part in filter(None, parts):
            try:
                name, rng = parse_name_value(part, "--fit", "[LO:HI]")
            except ParameterError:
                raise ExplainError(f"--fit {part!r}: bounds must be NAME=LOW:HIGH, e.g. "
                                   f"BKL=0:1e-3") from None
            if name in items:
                raise ExplainError(f"--fit {name}: given twice")
            if rng is not None:
                items[name] = rng
            else:
                try:
                    items[name] = DEFAULT_FAULT_BOUNDS.get(name) or default_bounds([name])[name]
                except FDIError as exc:
                    raise ExplainError(str(exc)) from None
    if not items:
        raise ExplainError("--fit: no parameter given; e.g. --fit BKL,FDJ")
    try:
        return check_bounds(items)
    except FDIError as exc:
        raise ExplainError(str(exc)) from None


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = np.asarray(a) - np.asarray(b)
    return float(np.sqrt(np.mean(d * d))) if d.size else math.nan


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / den) if den > 0 else 0.0


class _Record:
    """A record and the means to simulate the LF model on it in batches."""

    def __init__(self, data: MeasuredData, base: LFParams):
        self.data = data
        self.recorded_start = _recorded_start(data)
        self.base = base
        self.t_end = (len(data) - 1) * OUTPUT_DT
        self.steps_per_out, self.n_out, t_steps = grid(base, self.t_end)
        self.com = command_on_grid(data.command, t_steps)

    def run(self, params: Sequence[LFParams], with_p12: bool = False):
        """Recorded xu of each parameter set, shape (n, n_out) (and P12 with ``with_p12``)."""
        rows = np.stack([p.to_array() for p in params])
        return simulate_lf_batch(rows, self.com, self.steps_per_out, self.n_out, self.base,
                                 self.recorded_start, with_p12=with_p12)

    def full(self, params: LFParams):
        if self.recorded_start is not None:
            params = params.replace(XJ0=float(xj0_for_recorded(
                self.recorded_start, params.sensor_bias, params.sensor_gain, params.XJM)))
        return simulate("lf", self.data.command, params, t_end=self.t_end)


def augmented_base(prior: Mapping[str, Any] | Sequence[Mapping[str, Any]],
                   base: LFParams | None = None) -> LFParams:
    """LF parameters with the effects of a previous run switched on.

    Parameters
    ----------
    prior : dict or list
        The ``--json`` output of an earlier ``eha explain`` (its ``steps``), or the list of
        steps itself (``{"effect": name, "params": {...}}``).
    base : LFParams, optional
        Starting set (nominal LF by default).
    """
    steps = prior.get("steps", []) if isinstance(prior, Mapping) else prior
    params = base if base is not None else LFParams()
    try:
        for step in steps:
            params = get_effects([step["effect"]])[0].switch_on(params, step.get("params", {}))
    except (KeyError, TypeError) as exc:
        raise ExplainError(f"prior: each step needs an 'effect' and 'params' ({exc})") from None
    except ParameterError as exc:
        raise ExplainError(f"prior: {exc}") from None
    return params


def _recorded_start(data: MeasuredData) -> float | None:
    """The measured first position (median of 3 samples, against noise) when the record starts
    away from its command, else None (see :func:`_initial_position`)."""
    measured = float(np.median(data.xu[:3]))
    return None if abs(measured - data.com[0]) <= START_TOLERANCE else measured


def _initial_position(data: MeasuredData, base: LFParams) -> LFParams:
    """The LF model starts at rest: on the first command when the record starts near it (the
    small difference is then left to the model to explain: friction, offset, sensor bias),
    else where its *recorded* position is the measured first position, e.g. a command that
    steps away at t = 0 or a record that starts elsewhere (every LF run of the loop then sets
    XJ0 from its own sensor bias and gain, so a sensor bias is not mistaken for a shifted
    start)."""
    start = _recorded_start(data)
    if start is None:
        start = float(data.com[0])
    return base.replace(XJ0=float(np.clip(start, -base.XJM, base.XJM)))


# --------------------------------------------------------------------------------------------
# the loop


@dataclass(frozen=True)
class LoopSettings:
    """Settings of the residual loop (one frozen record, kept in the result).

    Attributes
    ----------
    holdout : float
        Fraction of the record (at its end) held out for scoring, in [0, 0.8]. 0 scores on the
        fitted data (then only the penalty and the significance test guard against
        over-fitting).
    min_gain : float
        Smallest penalised relative reduction of the scored RMSE (fitted and held-out parts
        weighted equally) that adds an effect, in [0, 1].
    penalty : float
        Relative gain charged per added parameter.
    alpha : float
        False-positive level per record, in (0, 1): the probability that a healthy actuator
        driven by the record's command gets any effect added. An effect is added only when its
        fitted parameter leaves the band healthy actuators reach on that command
        (:mod:`eha.explain_null`, thresholds at ``alpha / m`` for ``m`` effects).
    significance : float
        Level of the F test on effective samples an added effect's gain must also pass
        (:func:`significance`): the chance that a gain on this record's correlated residual is
        chance, in (0, 1).
    null_actuators : int
        Healthy actuators of the simulated null (:func:`eha.explain_null.simulated_null`),
        >= 5.
    max_steps : int
        Most effects added.
    candidates : int
        Effects refitted per round, the best-ranked by their signature (0 = all).
    noise_factor : float
        Stop when the scored RMSE is below ``noise_factor`` times the noise level.
    joint : bool
        Refit the parameters of the effects already added in every later round (False: they
        stay at the estimates of the round that added them; the faults are always refitted).
    p12_weight : float
        Weight of the measured load pressure in every fit and score when the record carries
        P12, >= 0 (0: position only). Each P12 sample counts ``p12_weight`` times as much as
        a position sample, each measured in its own noise (:func:`p12_objective_weight`);
        the reported RMSE stay those of the position.
    flow_gain_spread : float
        The valve flow gain GQ is fitted with the declared faults, within +- this fraction
        of the base's value, in [0, 0.5] (0: held at the base's). Default 0.04: the healthy
        fleet's +-3 % (:data:`eha.detection.DISPERSION`, what the healthy null draws) and a
        third more, so that a healthy actuator's flow gain is fitted inside the spread and
        never at its edge. A healthy actuator's flow gain is its own, and where the valve
        saturates it sets the jack's velocity: held at nominal, a 3 % spread leaves a healthy
        1 cm `sine` at 25x the noise, and viscous friction, leakage and clogging stand in for
        it. Fitted, it also absorbs what reduces the flow alike (a weak torque motor, a leak):
        the spread is therefore no wider than a healthy actuator's, and a GQ at its edge
        (:func:`edge_of_spread`) is read as a flow loss beyond a healthy actuator's and GQ
        goes back to the base's value, after the declared faults' fit
        (:meth:`ResidualLoop.baseline`) or, at the end, by running the loop again
        (:func:`explain`); docs/explain.md, "The healthy flow gain". Not fitted when GQ is a
        declared fault or known (``fixed``).
    method, pop, seed
        Optimizer of every fit (:func:`eha.fdi.identify`), same seed for all fits.
    """

    holdout: float = 0.3
    min_gain: float = 0.1
    penalty: float = 0.02
    alpha: float = 0.05
    significance: float = 0.01
    null_actuators: int = 12
    max_steps: int = 6
    candidates: int = 6
    noise_factor: float = 1.25
    joint: bool = True
    p12_weight: float = 1.0
    flow_gain_spread: float = 0.04
    method: str = DEFAULT_METHOD
    pop: int = 20
    seed: int = 0

    def __post_init__(self):
        problems = []
        if not 0.0 <= self.holdout <= 0.8:
            problems.append(f"--holdout {self.holdout:g}: allowed range [0, 0.8]")
        if not 0.0 <= self.min_gain <= 1.0:
            problems.append(f"--min-gain {self.min_gain:g}: allowed range [0, 1]")
        if not 0.0 <= self.penalty <= 1.0:
            problems.append(f"penalty {self.penalty:g}: allowed range [0, 1]")
        if not 0.0 < self.alpha < 1.0:
            problems.append(f"--alpha {self.alpha:g}: allowed range (0, 1)")
        if not 0.0 < self.significance < 1.0:
            problems.append(f"significance {self.significance:g}: allowed range (0, 1)")
        if self.null_actuators < 5:
            problems.append(f"--null-actuators {self.null_actuators}: allowed range [5, ...]")
        if self.max_steps < 0:
            problems.append(f"--max-steps {self.max_steps}: allowed range [0, ...]")
        if self.candidates < 0:
            problems.append(f"--candidates {self.candidates}: allowed range [0, ...] (0 = all)")
        if not self.noise_factor >= 0.0:
            problems.append(f"noise_factor {self.noise_factor:g}: allowed range [0, ...]")
        if not 0.0 <= self.p12_weight <= 100.0:
            problems.append(f"--p12-weight {self.p12_weight:g}: allowed range [0, 100]")
        if not 0.0 <= self.flow_gain_spread <= 0.5:
            problems.append(f"--flow-gain-spread {self.flow_gain_spread:g}: allowed range "
                            f"[0, 0.5]")
        if self.pop < 2:
            problems.append(f"--pop {self.pop}: allowed range [2, ...]")
        if self.method not in ("ga", "ga+ps"):
            problems.append(f"--method {self.method}: the loop's refits search globally; "
                            f"allowed ga, ga+ps")
        if problems:
            raise ExplainError("; ".join(problems))


#: The noise assumed for a measured P12 is at least this fraction of its standard deviation:
#: a simulated record has none, and the LF's pressure is a model (on a healthy HF record of
#: ``mixed`` or ``chirp_1cm`` the LF with the structural effects is within 0.3-0.5 % of
#: P12's standard deviation, on the steps of ``test`` 5-10 %: the LF's pressure transients
#: are a model's).
P12_NOISE_FLOOR = 0.05


def p12_objective_weight(noise_xu: float, p12: np.ndarray | None, weight: float = 1.0
                         ) -> tuple[float, float]:
    """Metres of position per pascal of P12 residual in the fits, and the P12 noise [Pa].

    Each signal is measured in its own noise (``noise_xu`` [m], the P12 noise from
    :func:`eha.measured.noise_level`): ``weight * noise_xu / noise_p12``, the P12 noise
    floored at :data:`P12_NOISE_FLOOR` of its standard deviation. ``(0, nan)`` when the record has no P12, ``weight`` is 0, or either signal is
    noise-free and flat.
    """
    if p12 is None or weight <= 0:
        return 0.0, math.nan
    p12 = np.asarray(p12, dtype=np.float64)
    sigma_p = max(noise_level(p12), P12_NOISE_FLOOR * float(np.std(p12)))
    if not (sigma_p > 0 and noise_xu > 0):
        return 0.0, sigma_p
    return weight * noise_xu / sigma_p, sigma_p


#: Defaults of the loop (see :class:`LoopSettings`), for the CLI.
DEFAULTS: dict[str, Any] = {f.name: f.default for f in fields(LoopSettings)}


def significance(before: float, after: float, added: int, n_eff: float) -> float:
    """p-value of the RMSE reduction an added effect brings (an F test on effective samples).

    The residual of a model that lacks structure is correlated over many samples, so a record of
    n samples carries only ``n_eff`` independent ones (:func:`eha.intervals.effective_samples`):
    a gain that would be overwhelming on white noise is often chance on a correlated residual.
    ``F = ((before**2 - after**2) / added) / (after**2 / (n_eff - added))``.

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


NOTHING_IMPROVED = ("no candidate improved the model (every refit left its effect within its "
                    "healthy band on this command or fitted the pressure at the position's "
                    "expense)")


def choose(tried: list[Candidate], settings: LoopSettings,
           split: Callable[[Candidate], list[str]],
           refit_members: Callable[[Candidate, list[str]], Candidate | None]) -> Choice:
    """Pick the effect (or combination) to add from the refitted candidates of a round.

    The best-scoring candidate wins when its penalised gain reaches ``settings.min_gain``, its
    gain is significant (``p_value < settings.significance``) and specific (:func:`unspecific`: no
    unrelated effect explains as much). A winning combination whose members
    do not all pay for themselves (``split`` returns the names kept) is replaced by the kept
    members as a candidate of its own (``refit_members``: the candidate refitted with only
    those, or None when it switches an effect off), and the choice is made again.

    A candidate made only of the model's known structure (:data:`STRUCTURAL`) that clears
    ``min_gain`` and is significant is chosen before any other effect: the structure first.

    Pure choice logic: ``split`` and ``refit_members`` hold every model evaluation, so the
    logic is unit-tested on canned candidates.

    Returns
    -------
    Choice
        ``best`` None with ``stop`` set when nothing is added.
    """
    everything = [c for c in tried if c.refit and math.isfinite(c.gain)]
    tried = [c for c in tried if c.refit and c.score > -math.inf]
    if not tried:
        return Choice(None, stop=NOTHING_IMPROVED)
    superseded: set[str] = set()
    set_aside: list[str] = []
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
            if rivals:
                set_aside.append(best.effect)
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
                    f"by {best.gain:.1%}, {why}"), unspecific=set_aside)
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


#: An effect chosen in a round is added only if, left out and the rest of the model refitted
#: from the chosen fit, the model loses at least this fraction of ``min_gain`` (penalised) and
#: the loss is significant (:func:`keeps_effect`). Half: the refit without it starts from a
#: better basin than the round's candidates did, so a real effect keeps most of its gain.
CONFIRM_FRACTION = 0.5


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


#: Effects tried in place of an added one by the final check's swap (:meth:`ResidualLoop.swap`):
#: those whose signature is most like the added effect's contribution.
SWAP_CANDIDATES = 3

#: Effects that are the LF model's known structure (members of COMBINATIONS): always specific.
STRUCTURAL = frozenset(name for combo in COMBINATIONS for name in combo)
#: A gain below this is checked for specificity (:func:`unspecific`): a real effect of a
#: visible size at least halves the RMSE it explains; the stand-ins on healthy records gain
#: 10-40 % (docs/explain.md, "No invented effects").
SPECIFIC_GAIN = 0.5
#: Rivals within this gain of the best make it unspecific.
RIVAL_MARGIN = 0.05
#: Candidates set aside as unspecific that the round's look-ahead extends by one effect
#: (:meth:`ResidualLoop.look_ahead`).
LOOK_AHEAD = 2
#: Times the rounds resume after a final check (:meth:`ResidualLoop.prune`) that changed a
#: model which still leaves the record unexplained.
REVISITS = 1


def unspecific(best: Candidate, candidates: Sequence[Candidate]) -> list[str]:
    """Candidates of *unrelated* effects that reduce the RMSE as much as ``best``.

    A residual that a delay, a motor-gain change and viscous friction all explain alike is not
    evidence for any of them: it is what the LF model's known structure and a healthy
    actuator's spread leave. ``best`` is unspecific when its gain is below
    :data:`SPECIFIC_GAIN` and a candidate sharing none of its non-structural effects gains
    within :data:`RIVAL_MARGIN` of it — counting refits rejected because their effect stayed
    within its healthy band (they show a healthy-size change does as well). Structural
    candidates (only :data:`STRUCTURAL` members) are always specific.

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


#: A candidate whose fit makes the position's RMSE (fitted and held-out parts) worse than
#: this factor times the current model's is not added, whatever it gains on the measured P12
#: (:meth:`ResidualLoop.try_candidate`). Of 78 candidates the loop accepted on the two seed
#: blocks of several effects and the healthy block 6, the position rose with two: 1.8x (a
#: leak on a healthy `sine`) and 8.8x (a leak on a leak + viscous `test` record, repaired by
#: the next round's flapper); with every other it fell or rose at most 2 %.
POSITION_WORSENING = 1.2


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


class ResidualLoop:
    """The residual loop on one record; each step of the loop is a method.

    :meth:`baseline` fits the declared faults (a); :meth:`trace` correlates the residual with
    the effects' signatures (b); :meth:`try_candidate` refits with a candidate switched on and
    scores it (c); :meth:`choose` picks what to add (d, the pure :func:`choose`);
    :meth:`confirm` checks that each effect chosen is needed (the rest refitted without it);
    :meth:`accept` adds it; :meth:`run` repeats until a stop rule holds (e), checks each added
    effect once more with all the others in (:meth:`prune`, f) and returns the
    :class:`ExplainResult`. See :func:`explain` for the parameters.
    """

    def __init__(self, data: MeasuredData, fit: Any = None,
                 effects: Iterable[str] | str | None = None,
                 validate: MeasuredData | None = None, base: LFParams | None = None,
                 settings: LoopSettings = LoopSettings(), fixed: Iterable[str] = (),
                 on_progress: Callable[[str], None] | None = None,
                 pin_structure: bool = False, null: Any = None, **fdi_options: float):
        self.started = time.perf_counter()
        self.settings = settings
        #: the healthy null (:class:`eha.explain_null.Null`) and its thresholds at ``alpha``
        #: (effect -> largest healthy shift); empty without a null
        self.null = null
        self.thresholds: dict[str, float] | None = \
            null.thresholds(settings.alpha) if null is not None else {}
        self.data, self.validate = data, validate
        self.bounds = parse_fit(fit)
        pool = get_effects(effects) if effects is not None else list(EFFECTS.values())
        try:
            base = _initial_position(data, resolve("lf", {}, base=base) if base else LFParams())
        except ParameterError as exc:
            raise ExplainError(str(exc)) from None
        fixed = set(fixed)
        for name in sorted(fixed):
            if name in self.bounds:
                raise ExplainError(f"--set {name}: also a fitted fault (--fit); give it one role")
            if name == "XJ0":
                raise ExplainError("--set XJ0: the initial position is taken from the record")
        self.flow_gain_fitted = (settings.flow_gain_spread > 0 and "GQ" not in self.bounds
                                 and "GQ" not in fixed)
        if self.flow_gain_fitted:
            # the healthy flow gain is the actuator's own: fitted with the faults throughout
            # (bounds to 6 significant digits, as typed: 0.2 +- 10 % is GQ=0.18:0.22)
            spread = settings.flow_gain_spread
            self.bounds["GQ"] = (float(f"{base.GQ * (1.0 - spread):.6g}"),
                                 float(f"{base.GQ * (1.0 + spread):.6g}"))
        #: why the flow gain stopped being fitted (:meth:`baseline`), or None
        self.flow_gain_released: str | None = None
        # effects already in the base (a prior), overlapping the declared faults or touching
        # a known (fixed) parameter are not tried
        self.pool = [e for e in pool if not set(e.params) & set(self.bounds)
                     and not e.is_on(base) and not set(e.off) & fixed]
        self.base = base
        #: the structure put in at its physical values before the rounds and held there until
        #: the final estimates (:meth:`baseline`, :func:`explain`'s second pass)
        self.pinned = [e for e in self.pool if e.name in STRUCTURAL] if pin_structure else []
        self.progress = on_progress or (lambda message: None)
        self.fdi_options = fdi_options
        n = len(data)
        if validate is not None:
            self.n_fit = n
            self.holdout_text = (f"validation record {validate.source} ({len(validate)} "
                                 f"samples)")
        else:
            self.n_fit = n - int(round(settings.holdout * n))
            self.holdout_text = (f"last {settings.holdout:.0%} of the record "
                                 f"({n - self.n_fit} samples)" if self.n_fit < n
                                 else "none (scored on the fitted data)")
        if self.n_fit < 20:
            raise ExplainError(f"record: {self.n_fit} samples left to fit after the hold-out; "
                               f"at least 20 are required (lower --holdout)")
        self.record = _Record(data, base)
        self.check = (_Record(validate, _initial_position(validate, base))
                      if validate is not None else None)
        self.noise = float(data.info.get("noise_m", noise_level(data.xu)))
        # the measured load pressure joins every fit and score when the record has it
        self.p12_weight, self.p12_noise = p12_objective_weight(
            self.noise, data.p12, settings.p12_weight)
        # the score of a model that leaves only noise (the P12 noise in metres of position)
        self.score_noise = math.hypot(self.noise, self.p12_weight * self.p12_noise) \
            if self.p12_weight else self.noise
        self.steps: list[Step] = []
        self.dismissed: list[Dismissal] = []
        self.rounds: list[Round] = []
        self.current: LFParams = base
        self.cur: Evaluation | None = None
        # refitted every round: the faults (and, with joint=True, the effects already added)
        self.free = dict(self.bounds)

    # -- the healthy band ------------------------------------------------------------------
    def within_healthy(self, effect: Effect, values: Mapping[str, float]) -> bool:
        """Is the effect's fitted parameter (``values``) within what healthy actuators reach
        on this record's command (the null's threshold at ``alpha``)? An effect the null does
        not cover (the structure, or no null) is within it when switched off: within
        :data:`eha.explain_null.SWITCHED_OFF` of its search range from off."""
        from eha.explain_null import SWITCHED_OFF

        threshold = (self.thresholds or {}).get(effect.name)
        if threshold is not None:
            return effect.shift(values) <= threshold
        off = effect.off
        return all(abs(values[n] - off[n]) <= SWITCHED_OFF * (hi - lo)
                   for n, (lo, hi) in effect.bounds.items())

    def within_healthy_at(self, effect: Effect, params: LFParams) -> bool:
        """:meth:`within_healthy` of the effect's parameters in ``params`` (False for a
        switch: a fit cannot put it back)."""
        return bool(effect.params) and self.within_healthy(
            effect, {n: getattr(params, n) for n in effect.params})

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
            r_fit = _rmse(xu[j, :n_fit], data.xu[:n_fit])
            p_fit = w * _rmse(p12[j, :n_fit], data.p12[:n_fit]) if w else 0.0
            if check is not None:
                r_hold = _rmse(hold[j], self.validate.xu)
                # a validation record without P12: its position alone is held out
                p_hold = w * _rmse(hold_p12[j], self.validate.p12) if check_p12 else 0.0
                resid = np.concatenate([data.xu - xu[j], self.validate.xu - hold[j]])
            else:
                held = n_fit < len(data)
                r_hold = _rmse(xu[j, n_fit:], data.xu[n_fit:]) if held else r_fit
                p_hold = (w * _rmse(p12[j, n_fit:], data.p12[n_fit:]) if held else p_fit) \
                    if w else 0.0
                resid = data.xu - xu[j]
            out.append(Evaluation(p, xu[j], r_fit, r_hold, _rmse(xu[j], data.xu),
                                  n_eff=effective_samples(resid)
                                  if np.all(np.isfinite(resid)) else 2.0,
                                  p12_fit=p_fit, p12_hold=p_hold,
                                  p12_all=w * _rmse(p12[j], data.p12) if w else 0.0))
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
        from eha.fdi import METHOD_DEFAULTS, FDIError, identify

        s = self.settings
        method = method or s.method
        self.progress(label)
        # the local methods take only their own options (the user's GA options are not theirs;
        # "lm" keeps its defaults: its xtol is not the pattern search's)
        options = (self.fdi_options if method not in ("ps", "lm") else
                   {k: v for k, v in self.fdi_options.items()
                    if k in METHOD_DEFAULTS[method] and method == "ps"})
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

    # -- the steps -------------------------------------------------------------------------
    def baseline(self) -> Evaluation:
        """(a) Fit the declared faults; the model every later step extends.

        A flow gain fitted within its healthy spread that runs to the spread's edge
        (:func:`edge_of_spread`) is a flow loss (or surplus) beyond a healthy actuator's: GQ
        goes back to the base's value, is no longer fitted, and the faults are fitted again.
        (Left free, it would share the loss with the effect that causes it: on an LF record
        with a torque motor at 80 % of its gain, GQ 0.188 and GM 0.0085, their product
        right, each wrong.)"""
        self.current = self.refit(self.base, self.bounds, "fit the declared faults")
        edge = edge_of_spread(self.current.GQ, self.bounds["GQ"]) \
            if self.flow_gain_fitted else None
        if edge is not None:
            self.flow_gain_fitted, self.flow_gain_released = False, edge
            del self.bounds["GQ"]
            self.free.pop("GQ", None)
            self.current = self.refit(self.base, self.bounds,
                                      f"{edge}: fit the declared faults with GQ at nominal")
        self.cur = self.evaluate([self.current])[0]
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
        fitted = self.refit(start, self.bounds, f"fit the declared faults with {names} pinned")
        ev = self.evaluate([fitted])[0]
        gain = 1.0 - ev.rmse_score / prev.rmse_score if prev.rmse_score > 0 else 0.0
        faults = {p: getattr(fitted, p) for p in self.bounds}
        for i, effect in enumerate(self.pinned):
            last = i == len(self.pinned) - 1
            self.steps.append(Step(
                effect.name, {p: getattr(fitted, p) for p in effect.params},
                prev.rmse_all, ev.rmse_all if last else prev.rmse_all, prev.rmse_fit,
                ev.rmse_fit if last else prev.rmse_fit, prev.rmse_hold,
                ev.rmse_hold if last else prev.rmse_hold, faults0, faults,
                gain if last else 0.0, gain if last else 0.0, {},
                f"{names} pinned at physical values", gain))
        self.current, self.cur = fitted, ev

    def trace(self, evaluation: Evaluation, free: Mapping[str, tuple[float, float]],
              effects: Sequence[Effect]) -> Round:
        """(b) Trace the residual of ``evaluation`` to the effects' signatures."""
        return trace_residual(self.record, evaluation, free, effects, self.n_fit)

    def try_candidate(self, cand: Candidate, extends: LFParams | None = None) -> Candidate:
        """(c) Refit the faults with the candidate's effects free and score the fit.

        The GA is warm-started at the model it extends (the current one, or a combination's
        fit) with the new effects at their off values (at the probe where off is outside the
        search bounds): a refit is never worse than what it extends.
        """
        s, cur = self.settings, self.cur
        members = [EFFECTS[name] for name in cand.effect.split("+")]
        t0 = time.perf_counter()
        start, free = self.candidate_start(members, extends)
        trial = self.refit(start, free, f"round {len(self.rounds)}: refit with {cand.effect}",
                           warm_start=True)
        # the healthy null's test: the same local refit the null ran on healthy records
        tested = [e for e in members if e.name in (self.thresholds or {})]
        local = self.local_test(start, free, members) if tested else trial
        ev = self.evaluate([trial])[0]
        cand.refit = True
        cand.params = {p: getattr(trial, p) for e in members for p in e.params}
        cand.faults = {p: getattr(trial, p) for p in self.bounds}
        cand.rmse_fit, cand.rmse_hold, cand.rmse_all = ev.rmse_fit, ev.rmse_hold, ev.rmse_all
        cand.gain = 1.0 - ev.rmse_score / cur.rmse_score if cur.rmse_score > 0 else 0.0
        cand.score = cand.gain - s.penalty * len(cand.params)
        added = sum(max(len(e.params), 1) for e in members if not e.is_on(self.current))
        cand.n_eff = ev.n_eff
        cand.p_value = significance(cur.rmse_score, ev.rmse_score, added, ev.n_eff)
        cand.shifts = {e.name: e.shift_at(local) for e in tested}
        if any(e.params and (self.within_healthy_at(e, local) if e in tested else
                             self.within_healthy(e, cand.params)) for e in members):
            # the fit left an effect within the band healthy actuators reach on this command:
            # any gain is the optimizer's or a healthy spread's, not the effect's
            cand.score = -math.inf
        elif self.p12_weight and trades_position(cur, ev):
            # the gain is the pressure's alone, bought with a worse position
            cand.score = -math.inf
        cand.seconds = time.perf_counter() - t0
        cand._evaluation = ev          # kept for the step, not reported
        return cand

    def candidate_start(self, members: Sequence[Effect], extends: LFParams | None = None
                        ) -> tuple[LFParams, dict[str, tuple[float, float]]]:
        """Where a candidate's refits start and what they fit: the model it extends (the
        current one, or a combination's fit) with the new effects at their off values (at the
        probe where off is outside the search bounds), and everything the rounds refit plus
        the effects' parameters."""
        start = extends if extends is not None else self.current
        free = dict(self.free)
        for effect in members:
            if not effect.is_on(start):
                start = effect.switch_on(start, {
                    p: effect.off[p] for p, (lo, hi) in effect.bounds.items()
                    if lo <= effect.off[p] <= hi})
            free.update(effect.bounds)
        return start, free

    def local_test(self, start: LFParams, free: Mapping[str, tuple[float, float]],
                   members: Sequence[Effect]) -> LFParams:
        """The statistic of the healthy null (:mod:`eha.explain_null`): the candidate refitted
        by least squares from two starts, ``start`` (:meth:`candidate_start`: the effects off)
        and the same with the effects at their probes, keeping the better fit. The null runs
        it alike on each healthy record; how far it moves an effect's parameter from off is
        tested against the healthy band.

        Why two starts: from off alone least squares stalls where the cost is flat at off
        (a viscous friction of 3000 N·s/m on held steps: the GA refit found 623 with a 17 %
        gain, the local fit stayed at 50), so the test was blind; from the probe alone it
        stalls at the probe on healthy records and the null's band becomes the probe. The
        better of the two follows the data from either side, on records and null alike.
        """
        label = f"round {len(self.rounds)}: local test of " \
                f"{'+'.join(e.name for e in members)}"
        best, cost = self.fit_with_cost(start, free, label, method="lm")
        probe = start
        for effect in members:
            values = {p: v for p, v in effect.probe.items()
                      if p in effect.bounds and effect.bounds[p][0] <= v <= effect.bounds[p][1]}
            if values:
                probe = probe.replace(**values)
        if probe != start:
            fit, fit_cost = self.fit_with_cost(probe, free, label + " (from the probe)",
                                               method="lm")
            if fit_cost < cost:
                best = fit
        return best

    def candidates_of_round(self, remaining: list[Effect]) -> tuple[Round, list[Candidate]]:
        """(b, c) Trace the current residual and refit the best-ranked candidates; also the
        combinations of :data:`~eha.effects.COMBINATIONS`, alone and with each of the effects
        that best explain the combination's residual (an effect is often only recognisable
        once the structure it interacts with is in the model: with the orifice law a load and
        a motor offset stop being equivalent). The combinations with other effects are
        skipped when a candidate made only of the structure already qualifies: the structure
        is then chosen first whatever they gain (:func:`choose`)."""
        s = self.settings
        rnd = self.trace(self.cur, self.free, remaining)
        self.rounds.append(rnd)
        ranked = sorted(rnd.candidates, key=lambda c: -c.explained)
        chosen = ranked if s.candidates <= 0 else ranked[:s.candidates]
        names_left = {e.name for e in remaining}
        for cand in chosen:
            # an effect that needs structure the model lacks is tried with it (its signature
            # was traced so): the supply pressure with the orifice law
            needed = missing_requirements(EFFECTS[cand.effect], self.current)
            if needed and not set(needed) <= names_left:
                continue        # the structure it needs is fixed off or not a candidate
            if needed:
                cand.effect = "+".join((*needed, cand.effect))
            self.try_candidate(cand)
        room = s.max_steps - len(self.steps)    # a combination adds one step per member
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
            on_top = self.trace(pair._evaluation, combo_free, rest)
            ranked_on_top = sorted(on_top.candidates, key=lambda c: -c.explained)
            for c in ranked_on_top if s.candidates <= 0 else ranked_on_top[:s.candidates]:
                cand = self.try_candidate(Candidate("+".join((*combo, c.effect)), math.nan,
                                                    c.explained),
                                          extends=pair._evaluation.params)
                rnd.candidates.append(cand)
                chosen.append(cand)
        return rnd, chosen

    def choose(self, rnd: Round, tried: list[Candidate]) -> Choice:
        """(d) :func:`choose` with this record's evaluations."""
        def split(best: Candidate) -> list[str]:
            members = [EFFECTS[name] for name in best.effect.split("+")]
            return [e.name for e in _split_combination(members, best._evaluation,
                                                       self.evaluate, self.settings.penalty)]

        def refit_members(best: Candidate, kept: list[str]) -> Candidate | None:
            params = best._evaluation.params
            for name in best.effect.split("+"):
                if name not in kept:
                    params = EFFECTS[name].switch_off(params)
            cand = self.try_candidate(Candidate("+".join(kept), math.nan, math.nan),
                                      extends=params)
            rnd.candidates.append(cand)
            return cand

        return choose(list(tried), self.settings, split, refit_members)

    def look_ahead(self, rnd: Round, tried: list[Candidate], choice: Choice) -> Choice:
        """(d) A round whose best candidates were all set aside as unspecific (unrelated
        effects explain as much) may hold one of two effects that only stand out together:
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
        heads = [name for name in choice.unspecific
                 if len(set(name.split("+")) - STRUCTURAL) == 1][:LOOK_AHEAD]
        room = s.max_steps - len(self.steps)
        known = {frozenset(c.effect.split("+")) for c in [*tried, *rnd.candidates]}
        added = []
        for name in heads:
            head = next((c for c in [*tried, *rnd.candidates] if c.effect == name
                         and getattr(c, "_evaluation", None) is not None), None)
            members = set(name.split("+"))
            if head is None or len(members) + 1 > room:
                continue
            free = dict(self.free)
            for member in members:
                free.update(EFFECTS[member].bounds)
            rest = [e for e in self.remaining() if e.name not in members
                    and e.name not in STRUCTURAL and e.params
                    and not missing_requirements(e, head._evaluation.params)]
            if not rest:
                continue
            on_top = self.trace(head._evaluation, free, rest)
            for c in sorted(on_top.candidates, key=lambda c: -c.explained)[:SWAP_CANDIDATES]:
                pair = f"{name}+{c.effect}"
                key = frozenset(pair.split("+"))
                if key in known or c.effect not in names_left:
                    continue
                cand = self.try_candidate(Candidate(pair, math.nan, c.explained),
                                          extends=head._evaluation.params)
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
        s, ev = self.settings, best._evaluation
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
            refitted = self.refit(start, free, f"round {len(self.rounds) - 1}: "
                                  f"{best.effect} without {name}", method="ps")
            without = min(self.evaluate([start, refitted]), key=lambda e: e.rmse_score
                          if math.isfinite(e.rmse_score) else math.inf)
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
        unexplained (:meth:`unexplained`) the rivals of the swap and the merge are searched
        globally and the model in place is refitted from each winner's basin
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
            refitted = self.refit(start, free, f"final check: without {step.effect}",
                                  method="ps")
            without = min(self.evaluate([start, refitted]), key=lambda e: e.rmse_score
                          if math.isfinite(e.rmse_score) else math.inf)
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
        leaves the record unexplained, the loop's GA warm-started at the probe and from
        scratch, the better kept); effects that need structure the model lacks
        (:attr:`Effect.requires`) are not tried. With ``pairs`` each two of those rivals are
        also tried together (a one-for-two). Returns the replacing effects and their fit;
        None when every refit leaves an effect within its healthy band."""
        in_model = {st.effect for st in self.steps}
        others = [o for o in self.remaining()
                  if o.name not in in_model and o.name not in STRUCTURAL and o.params
                  and not missing_requirements(o, without)]
        if len(others) > SWAP_CANDIDATES:
            # a stand-in has the signature of what it stands in for
            S, _ = signatures(self.record, without, others, {})
            xu = self.record.run([self.current, without])
            own = xu[0] - xu[1]
            likeness = [abs(_corr(own, S[i])) if np.all(np.isfinite(S[i])) else 0.0
                        for i in range(len(others))]
            order = np.argsort(likeness)[::-1][:SWAP_CANDIDATES]
            others = [others[i] for i in order]
        # a model that leaves the record unexplained is wrong somewhere, and the replacement
        # may lie in another basin than its probe's: it is searched globally, by the loop's
        # GA warm-started at the probe and from scratch (a viscous jack for a low supply
        # pressure on `test`: 38 µm by pattern search from the probe, 14 µm warm with the
        # jack's CJ inside its healthy band, 12.6 µm from scratch with CJ 15800 for 16000)
        searches = ((self.settings.method, True), (self.settings.method, False)) \
            if self.unexplained() else (("ps", False),)
        sets = [(o,) for o in others]
        if pairs:
            sets += list(itertools.combinations(others, 2))
        best = None
        for group in sets:
            start, bounds = without, dict(free)
            for other in group:
                start = other.switch_on(start)
                bounds.update(other.bounds)
            name = "+".join(o.name for o in group)
            trials = [self.refit(start, bounds, f"final check: {name} for {label}",
                                 method=method, warm_start=warm) for method, warm in searches]
            trials = [t for t in trials if not any(self.within_healthy_at(o, t) for o in group)]
            if not trials:
                continue
            ev = min(self.evaluate(trials), key=lambda e: e.rmse_score
                     if math.isfinite(e.rmse_score) else math.inf)
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
        trial = self.refit(start, bounds, f"final check: {label} from {rivals}'s fit",
                           method="ps")
        mine = self.evaluate([trial])[0]
        inside = any(self.within_healthy_at(EFFECTS[st.effect], trial) for st in out)
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

    def estimate(self) -> None:
        """(g) The final estimates: the model chosen, every fitted parameter (faults and the
        effects added) is refitted on the *whole* record by least squares (``"lm"``,
        :func:`eha.fdi.identify`) from the loop's fit. The hold-out serves the choice of
        effects; once they are chosen the estimates use all the data. The loop's refits are on
        the fitted part alone, and a GA or compass search there can stop in a valley's side
        basin that the held-out part would have ruled out (an offset of 0.21 for 0.3 traded
        against jack friction and a load on ``mixed``); the least-squares step follows the
        valley. The polish runs from the loop's model and from it with the structure's
        parameters at their physical values (the flapper's probe); the better is kept, only
        when it lowers the whole record's objective and leaves every added effect outside its
        healthy band. A model without added effects keeps its fit (a
        record to which nothing was added: ``after`` is ``before``). After it the "held-out"
        RMSE of the final model is in-sample (reported as such in docs/explain.md)."""
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
            trial = self.refit(start, free, "final estimates on the whole record",
                               method="lm", whole=True)
            # an added effect polished back inside its healthy band would be reported
            # without being one: such a polish is not taken
            if any(self.within_healthy_at(EFFECTS[st.effect], trial) for st in self.steps):
                continue
            ev_t = self.evaluate([trial])[0]
            if ev_t.rmse_whole < ev.rmse_whole:
                polished, ev = trial, ev_t
        if ev is not self.cur:
            self.current, self.cur = polished, ev
            if self.steps:      # the last step's "after" is the final model
                self.steps[-1] = replace(
                    self.steps[-1], rmse_after=ev.rmse_all, rmse_fit_after=ev.rmse_fit,
                    rmse_hold_after=ev.rmse_hold,
                    faults_after={k: getattr(polished, k) for k in self.bounds})

    def accept(self, choice: Choice) -> list[Step]:
        """(d) Add the chosen effect(s): polish the faults and every effect in the model
        jointly from the winning fit (a local search: an effect added earlier was estimated
        without the later ones); a combination is reported as one step per effect, in the
        order of their contribution, each step's "after" the combined fit with the later
        members off."""
        s, best = self.settings, choice.best
        members = [EFFECTS[name] for name in choice.members]
        ev = best._evaluation
        joint_free = dict(self.free)
        for effect in [EFFECTS[st.effect] for st in self.steps] + members:
            joint_free.update(effect.bounds)
        polished = self.refit(ev.params, joint_free,
                              f"round {len(self.rounds)}: joint polish", method="ps")
        ev_p = self.evaluate([polished])[0]
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
            ev_i = ev if i == len(members) - 1 else self.evaluate([params_i])[0]
            gain_i = 1.0 - ev_i.rmse_score / prev.rmse_score if prev.rmse_score > 0 else 0.0
            added.append(Step(effect.name, {p: getattr(ev.params, p) for p in effect.params},
                              prev.rmse_all, ev_i.rmse_all, prev.rmse_fit, ev_i.rmse_fit,
                              prev.rmse_hold, ev_i.rmse_hold, faults0, faults_after,
                              gain_i, gain_i - s.penalty * len(effect.params),
                              choice.alternatives if i == told else {}, best.effect,
                              best.score))
            prev, faults0 = ev_i, faults_after
        self.steps.extend(added)
        self.current, self.cur = ev.params, ev
        if s.joint:
            for effect in members:
                self.free.update(effect.bounds)
        return added

    def rounds_until_stop(self) -> str:
        """Trace / try / choose / confirm / accept until a stop rule holds; returns why it
        stopped."""
        while True:
            stop = self.stop_rule()
            if stop:
                return stop
            rnd, tried = self.candidates_of_round(self.remaining())
            choice = self.choose(rnd, tried)
            if choice.best is None and choice.unspecific:
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
        if cur.rmse_score <= s.noise_factor * self.score_noise:
            what = " with P12" if self.p12_weight else ""
            return (f"RMSE {cur.rmse_score:.3g} m (fitted and held-out parts{what}) is at the "
                    f"noise level ({self.score_noise:.3g} m estimated from the record)")
        if not self.remaining():
            return "every candidate effect is already in the model"
        return ""

    def leads(self) -> LeadReport:
        """The current residual's relation to signal features of the current model (whole
        record; P12 measured when the record has it, else the model's)."""
        data = self.data
        full = self.record.full(self.current)
        p12 = data.p12 if data.p12 is not None else full["p12"]
        return residual_leads(data.xu - self.cur.xu, data.t, data.com, self.cur.xu,
                              full["dxj"], p12, self.noise)

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
        fitted = self.refit(wo, free, "faults without the tentative effects", method="lm",
                            whole=True)
        return {k: float(getattr(fitted, k)) for k in self.bounds}

    def unexplained(self) -> bool:
        """Does the current model leave the record unexplained: its position residual above
        what faults and structure leave on healthy actuators of this command
        (:meth:`eha.explain_null.Null.residual_limit`, at most
        :data:`eha.intervals.FLAG_RATIO` times the noise; without a null, that ratio)?"""
        from eha.intervals import noise_reference

        return self.cur.rmse_all > self.residual_limit * noise_reference(self.noise,
                                                                          self.data.xu)

    @property
    def residual_limit(self) -> float:
        """Residual-to-noise ratio above which the record is unexplained."""
        from eha.intervals import FLAG_RATIO

        if self.null is None:
            return FLAG_RATIO
        return self.null.residual_limit(self.settings.alpha)

    def remaining(self) -> list[Effect]:
        added = {st.effect for st in self.steps} | {d.effect for d in self.dismissed}
        return [e for e in self.pool if e.name not in added]

    def run(self) -> ExplainResult:
        """Baseline, then trace / try / choose / accept until a stop rule holds, the final
        check (resumed rounds when it changed a model still far from the noise, at most
        :data:`REVISITS` times), the final estimates and their intervals."""
        from eha.fdi import DEFAULT_LEVEL, intervals_at, model_form_of
        from eha.intervals import MODEL_FORM, loop_terms

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
        for rnd in self.rounds:
            for c in rnd.candidates:
                c.__dict__.pop("_evaluation", None)
        # intervals of the final model's fitted parameters on the whole record (no refit)
        final_bounds = dict(self.bounds)
        for step in self.steps:
            final_bounds.update(EFFECTS[step.effect].bounds)
        data = self.data
        # a model the loop built carries its model-form floor (the LF with the right effects
        # is still not the actuator); a model to which nothing was added keeps its base's
        form = model_form_of(self.current)
        terms = loop_terms(MODEL_FORM.get(form, {}), list(final_bounds)) if self.steps else None
        iv = intervals_at(data.xu, data.command, self.current, final_bounds,
                          level=DEFAULT_LEVEL, noise=self.noise,
                          recorded_start=self.record.recorded_start, t_end=data.t_end,
                          model_form=form, terms=terms)
        bounds, notes = dict(iv.bounds), iv.notes
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
        s = self.settings
        settings = {**{f.name: getattr(s, f.name) for f in fields(s)}, "n_fit": self.n_fit,
                    "effects": [e.name for e in self.pool],
                    "command_hold": data.info.get("command_hold", "linear"),
                    "p12_used": bool(self.p12_weight), "p12_noise_pa": self.p12_noise,
                    "p12_m_per_pa": self.p12_weight,
                    "structure_pinned": [e.name for e in self.pinned], "passes": 1,
                    "flow_gain_fitted": self.flow_gain_fitted,
                    "flow_gain_released": self.flow_gain_released,
                    **self.fdi_options}
        return ExplainResult(
            source=data.source, fit_bounds=self.bounds, faults_before=faults_before,
            faults_after={k: getattr(self.current, k) for k in self.bounds}, before=before,
            after=self.cur, steps=self.steps, rounds=self.rounds, noise_rmse=self.noise,
            stop_reason=stop, holdout=self.holdout_text, t=data.t.copy(),
            measured=data.xu.copy(), settings=settings,
            seconds=time.perf_counter() - self.started, intervals=bounds, level=iv.level,
            unexplained=flagged, interval_notes=notes, leads=self.leads(),
            dismissed=self.dismissed,
            null=self.null.summary(s.alpha) if self.null is not None else None)


def explain(data: MeasuredData, fit: Any = None, effects: Iterable[str] | str | None = None,
            holdout: float | None = None, validate: MeasuredData | None = None,
            base: LFParams | None = None, method: str | None = None, pop: int = 20,
            seed: int = 0, min_gain: float | None = None, penalty: float | None = None,
            max_steps: int | None = None, candidates: int | None = None,
            noise_factor: float | None = None, joint: bool | None = None,
            alpha: float | None = None, p12_weight: float | None = None,
            flow_gain_spread: float | None = None, null: Any = "simulate",
            null_actuators: int | None = None,
            on_progress: Callable[[str], None] | None = None, fixed: Iterable[str] = (),
            **fdi_options: float) -> ExplainResult:
    """Find and add the effects the LF model lacks to explain a measured record.

    Parameters
    ----------
    data : MeasuredData
        The record (:func:`eha.measured.load`).
    fit : str or mapping, optional
        Declared fault parameters and bounds (:func:`parse_fit`); default BKL, FDJ.
    effects : names, optional
        Candidate effects (names of docs/model.md's effect table); default all of
        :data:`eha.effects.EFFECTS`.
    holdout : float, optional
        Fraction of the record (at its end) held out for scoring, in [0, 0.8]; default 0.3.
    validate : MeasuredData, optional
        A second record used as held-out data instead (the first is then fitted whole).
    base : LFParams, optional
        Starting LF parameters (nominal by default; XJ0 is set from the record's command).
    method, pop, seed, **fdi_options
        Passed to :func:`eha.fdi.identify` for every fit (same seed for all fits).
    min_gain, penalty, alpha, max_steps, candidates, noise_factor, joint
        The stop and choice rules (:class:`LoopSettings`, where their defaults are).
    p12_weight : float, optional
        Weight of a measured P12 in the fits (:class:`LoopSettings`; 0 = position only).
    flow_gain_spread : float, optional
        The healthy flow gain's range, fitted with the faults (:class:`LoopSettings`;
        0 = GQ held at the base's value). A GQ at the edge of that range goes back to the
        base's value: after the declared faults' fit (:meth:`ResidualLoop.baseline`), or, at
        the end (:func:`flow_gain_at_edge`), by running the loop again and reporting that
        run; ``settings["flow_gain_released"]`` says why.
    fixed : names, optional
        LF parameters held at their values in ``base`` (known test conditions, ``eha explain
        --set``): not fitted, and no effect touching them is a candidate.
    alpha : float, optional
        False-positive level per record (:class:`LoopSettings`, default 0.05).
    null : "simulate", str or Path, Null or None
        What healthy looks like on this record's command (:mod:`eha.explain_null`):
        ``"simulate"`` (default) a simulated healthy fleet driven by the record's command,
        cached; a folder of the user's healthy records; a ready
        :class:`~eha.explain_null.Null`; None for no null (an effect is then refused only
        when its fit switches it off: for records made by the LF model itself, which have no
        healthy scatter).
    null_actuators : int, optional
        Healthy actuators of a simulated null (default 20).
    on_progress : callable(str), optional
        Called with a short message before each fit.

    Returns
    -------
    ExplainResult
    """
    given = {"holdout": holdout, "min_gain": min_gain, "penalty": penalty, "alpha": alpha,
             "max_steps": max_steps, "candidates": candidates, "noise_factor": noise_factor,
             "joint": joint, "p12_weight": p12_weight, "flow_gain_spread": flow_gain_spread,
             "null_actuators": null_actuators}
    settings = LoopSettings(**{k: v for k, v in given.items() if v is not None},
                            method=method or DEFAULT_METHOD, pop=pop, seed=seed)
    null = healthy_null(data, fit, effects, base, settings, fixed, null, on_progress,
                        fdi_options)
    result = _passes(data, fit, effects, validate, base, settings, fixed, on_progress,
                     fdi_options, null)
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
                    null)
    again.settings["flow_gain_spread"] = settings.flow_gain_spread
    again.settings["flow_gain_released"] = edge
    again.seconds += result.seconds
    return again


def healthy_null(data: MeasuredData, fit: Any, effects: Iterable[str] | str | None,
                 base: LFParams | None, settings: LoopSettings, fixed: Iterable[str],
                 null: Any, on_progress: Callable[[str], None] | None = None,
                 fdi_options: Mapping[str, float] | None = None):
    """The :class:`~eha.explain_null.Null` of :func:`explain`'s ``null`` argument for this
    record: simulated on its command (cached), read from a folder of healthy records, given,
    or None."""
    from eha import explain_null
    from eha.explain_null import Null, NullError

    if null is None or isinstance(null, Null):
        return null
    probe = ResidualLoop(data, fit, effects, None, base, settings, fixed)
    names = [e.name for e in probe.pool]
    try:
        if isinstance(null, str) and null == "simulate":
            return explain_null.simulated_null(
                data, probe.bounds, names, settings, actuators=settings.null_actuators,
                base=probe.base if base is not None else None, fixed=list(fixed),
                on_progress=on_progress, fdi_options=fdi_options)
        return explain_null.records_null(null, probe.bounds, names, settings,
                                         command_hold=data.info.get("command_hold", "auto"),
                                         base=base, fixed=list(fixed), on_progress=on_progress,
                                         fdi_options=fdi_options)
    except NullError as exc:
        raise ExplainError(str(exc)) from None


#: The flow gain fitted within its healthy spread (``--flow-gain-spread``) is at the edge of
#: that spread when it is within this fraction of the spread's width of a bound.
FLOW_GAIN_EDGE = 0.02


def flow_gain_at_edge(result: ExplainResult) -> str | None:
    """``"GQ 0.18 at the lower bound of its healthy spread 0.18-0.22"`` when the loop fitted
    the flow gain within its healthy spread to the end (``flow_gain_spread``, GQ not a
    declared fault) and the final model has it at the spread's edge (:func:`edge_of_spread`);
    else None."""
    if not result.settings.get("flow_gain_fitted") or "GQ" not in result.fit_bounds:
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


def _passes(data: MeasuredData, fit: Any, effects: Iterable[str] | str | None,
            validate: MeasuredData | None, base: LFParams | None, settings: LoopSettings,
            fixed: Iterable[str], on_progress: Callable[[str], None] | None,
            fdi_options: Mapping[str, float], null: Any = None) -> ExplainResult:
    """The loop's first pass and, when it leaves the record unexplained, its second pass from
    the structure pinned (:func:`better_pass` picks the result)."""
    first = ResidualLoop(data, fit, effects, validate, base, settings, fixed, on_progress,
                         null=null, **fdi_options)
    result = first.run()
    structure = [e for e in first.pool if e.name in STRUCTURAL]
    if not (result.unexplained and SECOND_PASS and structure
            and len(structure) <= settings.max_steps):
        return result
    # a model still far from the noise may have been led astray in its first rounds: an
    # effect fitted while the structure was missing (or in a side basin, a flapper at 760
    # rad/s and 0.18 damping standing in for a clogged filter) set the path. The rounds run
    # once more from the model's known structure at its physical values
    if on_progress:
        on_progress("second pass: the structure pinned at its physical values")
    second = ResidualLoop(data, fit, effects, validate, base, settings, fixed, on_progress,
                          pin_structure=True, null=null, **fdi_options).run()
    chosen = better_pass(result, second, settings)
    chosen.seconds = result.seconds + second.seconds
    chosen.settings["passes"] = 2
    return chosen


#: Run the rounds a second time, with the structure pinned, when the first pass leaves the
#: record unexplained (:func:`explain`, :func:`better_pass`).
SECOND_PASS = True


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


def _split_combination(members: Sequence[Effect], combined: Evaluation,
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


def signatures(record: _Record, current: LFParams, effects: Sequence[Effect],
               free: Mapping[str, tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Effect signatures and free-parameter sensitivities of xu, one batch of LF runs.

    Returns
    -------
    S : array (n_effects, n_out)
        ``xu(effect on at its probe value) - xu(current)`` [m], with the effects it requires
        switched on too (the candidate the loop tries, :attr:`Effect.requires`).
    J : array (n_free, n_out)
        Finite-difference sensitivity of xu to each free parameter, scaled to 2 % of its
        search range [m].
    """
    rows = [current] + [switch_on_with_requirements(e, current) for e in effects]
    for name, (lo, hi) in free.items():
        value = getattr(current, name)
        h = 0.02 * (hi - lo)
        step = value + h if value + h <= hi else value - h
        rows.append(current.replace(**{name: step}))
    xu = record.run(rows)
    ref = xu[0]
    m = len(effects)
    return xu[1:1 + m] - ref, xu[1 + m:] - ref


def trace_residual(record: _Record, cur: Evaluation, free: Mapping[str, tuple[float, float]],
                   effects: Sequence[Effect], n_fit: int) -> Round:
    """Correlate the residual with every effect's signature and with signals (step b).

    ``explained`` of a candidate is the fraction of the residual's energy (on the fitted part)
    that the linearised fit over the free parameters *and* the effect explains, minus what the
    free parameters alone explain.
    """
    r = (record.data.xu - cur.xu)[:n_fit]
    S, J = signatures(record, cur.params, effects, free)
    S, J = S[:, :n_fit], J[:, :n_fit]

    def explained(columns: np.ndarray) -> float:
        # unit-norm columns (sensitivities differ by orders of magnitude); unusable ones dropped
        norms = np.linalg.norm(columns, axis=1) if columns.size else np.zeros(0)
        keep = np.isfinite(norms) & (norms > 0)
        rr = float(r @ r)
        if not keep.any() or rr <= 0.0:
            return 0.0
        A = (columns[keep] / norms[keep, None]).T
        coef, *_ = np.linalg.lstsq(A, r, rcond=1e-10)
        return float(np.clip(1.0 - float(np.sum((r - A @ coef) ** 2)) / rr, 0.0, 1.0))

    base_explained = explained(J)
    cands = [Candidate(e.name, _corr(r, S[i]) if np.all(np.isfinite(S[i])) else 0.0,
                       max(explained(np.vstack([J, S[i:i + 1]])) - base_explained, 0.0))
             for i, e in enumerate(effects)]
    full = record.full(cur.params)
    dxj = full["dxj"][:n_fit]
    p12 = record.data.p12[:n_fit] if record.data.p12 is not None else full["p12"][:n_fit]
    signals = {"position": _corr(r, cur.xu[:n_fit]),
               "velocity_sign": _corr(r, np.sign(np.where(np.abs(dxj) > 1e-6, dxj, 0.0))),
               "command": _corr(r, record.data.com[:n_fit]),
               "tracking_error": _corr(r, (record.data.com - cur.xu)[:n_fit]),
               "p12": _corr(r, p12)}
    return Round(_rmse(r, 0.0), signals, cands)


__all__ = ["explain", "ResidualLoop", "LoopSettings", "choose", "Choice", "significance",
           "augmented_base", "ExplainResult", "ExplainError", "Step", "Candidate", "Round",
           "parse_fit", "noise_level", "trace_residual", "signatures", "DEFAULTS",
           "DEFAULT_FAULT_BOUNDS", "SIGNALS"]
