"""The residual loop's settings: :class:`LoopSettings` (validated once, kept in the result,
its defaults read by the CLI) and every constant of the loop and of its healthy null.

The constants are grouped by the part of the loop that reads them: the declared faults and the
fits (:mod:`eha.explain.fitting`), the record (:mod:`eha.explain.record`), the choice of an
effect (:mod:`eha.explain.decide`), the final check (:mod:`eha.explain.final_check`), the
passes (:mod:`eha.explain.api`) and the healthy null (:mod:`eha.explain.null`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Iterable, Mapping, Sequence

from eha.explain.effects import COMBINATIONS
from eha.identification.problem import DEFAULT_METHOD, METHOD_DEFAULTS
from eha.models.faults import Bounds, search_bounds
from eha.models.params import ParameterError, parse_name_value
from eha.errors import InputError


class ExplainError(InputError):
    """Bad input to the residual loop (one line)."""


# --------------------------------------------------------------------------------------------
# the declared faults and the fits

#: Search bounds of the declared faults when none are given (wider than the thesis' chirp
#: cases, for records of unknown actuators).
DEFAULT_FAULT_BOUNDS: Bounds = search_bounds(purpose="loop", declared=True)
#: Refits of at least this many free parameters (faults + effects) run MULTISTART GA searches
#: (seeds ``seed``, ``seed + 1000``, ...) and keep the best fit.
MULTISTART_PARAMS = 5
MULTISTART = 2
#: The loop's global methods; each of their searches is finished by least squares
#: (:meth:`Fitter.refit`) when LEAST_SQUARES_FINISH is on.
GLOBAL_METHODS = ("ga", "ga+ps")
LEAST_SQUARES_FINISH = True
#: Smallest step (of each search range) of the compass polish in a ``ga+ps`` refit that least
#: squares finishes (LEAST_SQUARES_FINISH; the search alone stops at 2e-5): its halvings below
#: this cost LF runs that least squares mostly replaces. Not coarser: the LF objective is not
#: smooth at least squares' scale, whose trust region collapses short of the valley floor from
#: a rougher start (test_global_refits_are_finished_by_least_squares: 0.92 µm fitted at 1e-4
#: and at 2e-5, 1.65 µm at 1e-3). A user's ``xtol`` wins.
FINISHED_POLISH_XTOL = 1e-4


# --------------------------------------------------------------------------------------------
# the record

#: A record whose first position is within this distance of its first command starts at rest
#: on the command (the LF model starts there); otherwise at the measured first position [m].
START_TOLERANCE = 5e-4
#: The noise assumed for a measured P12 is at least this fraction of its standard deviation:
#: a simulated record has none, and the LF's pressure is a model (on a healthy HF record of
#: ``mixed`` or ``chirp_1cm`` the LF with the structural effects is within 0.3-0.5 % of
#: P12's standard deviation, on the steps of ``test`` 5-10 %: the LF's pressure transients
#: are a model's).
P12_NOISE_FLOOR = 0.05


# --------------------------------------------------------------------------------------------
# the choice of an effect

#: Candidates scoring within this margin (absolute, in relative gain) of the chosen
#: one are reported as alternatives the record cannot tell apart.
ALTERNATIVE_MARGIN = 0.05
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
#: An effect chosen in a round is added only if, left out and the rest of the model refitted
#: from the chosen fit, the model loses at least this fraction of ``min_gain`` (penalised) and
#: the loss is significant (:func:`keeps_effect`). Half: the refit without it starts from a
#: better basin than the round's candidates did, so a real effect keeps most of its gain.
CONFIRM_FRACTION = 0.5
#: A candidate whose fit makes the position's RMSE (fitted and held-out parts) worse than
#: this factor times the current model's is not added, whatever it gains on the measured P12
#: (:meth:`ResidualLoop.try_candidate`). Of 78 candidates the loop accepted on the two seed
#: blocks of several effects and the healthy block 6, the position rose with two: 1.8x (a
#: leak on a healthy `sine`) and 8.8x (a leak on a leak + viscous `test` record, repaired by
#: the next round's flapper); with every other it fell or rose at most 2 %.
POSITION_WORSENING = 1.2


# --------------------------------------------------------------------------------------------
# the final check and the passes

#: Effects tried in place of an added one by the final check's swap (:meth:`ResidualLoop.swap`):
#: those whose signature is most like the added effect's contribution.
SWAP_CANDIDATES = 3
#: Far from the noise, the rivals of a swap or merge (singles and pairs) are all refitted
#: locally from their probes, and this many of them, the best so refitted, also searched
#: globally (two GA searches each).
GLOBAL_RIVALS = 2
#: Times the rounds resume after a final check (:meth:`ResidualLoop.prune`) that changed a
#: model which still leaves the record unexplained.
REVISITS = 1
#: Run the rounds a second time, with the structure pinned, when the first pass leaves the
#: record unexplained (:func:`explain`, :func:`better_pass`).
SECOND_PASS = True
#: The flow gain fitted within its healthy spread (``--flow-gain-spread``) is at the edge of
#: that spread when it is within this fraction of the spread's width of a bound.
FLOW_GAIN_EDGE = 0.02


# --------------------------------------------------------------------------------------------
# the healthy null (:mod:`eha.explain.null`)

#: Healthy actuators of a simulated null.
DEFAULT_ACTUATORS = 12
#: Fewest healthy records a null needs (the tail threshold needs a spread).
MIN_RECORDS = 5
#: Declared faults of the simulated healthy actuators: name -> (law, a, b). A declared fault
#: is fitted on every record, but its value shapes what the effects can stand in for (a large
#: backlash hides a small offset), so the fleet spans the values a record may carry; a
#: declared fault not listed here is drawn uniformly within its fit bounds.
DECLARED_DRAW: dict[str, tuple[str, float, float]] = {
    "BKL": ("uniform", 0.0, 5e-4),
    "FDJ": ("loguniform", 100.0, 3000.0),
}
#: Power of the detectable sizes the null reports (:meth:`Null.detectable`).
DETECTION_POWER = 0.9
#: Resolution of a fitted effect parameter, as a fraction of its search range: the spread
#: of the statistic is at least this (a null whose healthy fits all sit at the bound would
#: otherwise give a zero threshold that any optimizer step crosses). It is the old
#: "switched off" margin of the loop (0.1 % of the range).
RESOLUTION = 1e-4
#: Resolution of a footprint statistic (:attr:`eha.explain.effects.Effect.footprint`) [m]:
#: a tenth of the 1 µm position noise of a typical record.
FOOTPRINT_RESOLUTION = 1e-7
#: Without a null (records made by the LF model itself) an effect is refused only when its fit
#: switched it off: within this fraction of its search range from off (0.1 %, the loop's rule
#: for effects without a tolerance before the null).
SWITCHED_OFF = 1e-3
#: What one record's residual-to-noise ratio scatters by that a dozen healthy records may
#: under-sample: the noise estimate's own scatter (on the 1 µm records of an independent
#: simulator, 0.89-1.09 µm; about 10 %).
RATIO_SPREAD = 0.1
#: Noise classes per decade: a record's noise estimate is rounded to the nearest class
#: 10**(k/5) (steps of 58 %, a round 1 µm at a class's centre: 0.79-1.26 µm), which the
#: healthy fleet is simulated with and the cache is keyed by. The estimates of one sensor's
#: noise scatter from record to record: on the foreign set's 1 µm records, 0.89-1.09 µm
#: (with 10 classes per decade two records of one command fell in two classes).
NOISE_CLASSES_PER_DECADE = 5


# --------------------------------------------------------------------------------------------
# the settings

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
        (:mod:`eha.explain.null`, thresholds at ``alpha / m`` for ``m`` effects).
    significance : float
        Level of the F test on effective samples an added effect's gain must also pass
        (:func:`significance`): the chance that a gain on this record's correlated residual is
        chance, in (0, 1).
    null_actuators : int
        Healthy actuators of the simulated null (:func:`eha.explain.null.simulated_null`),
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
        fleet's +-3 % (:data:`eha.identification.healthy.DISPERSION`, what the healthy null draws)
        and a third more, so that a healthy actuator's flow gain is fitted inside the spread and
        never at its edge. A healthy actuator's flow gain is its own, and where the valve saturates
        it sets the jack's velocity: held at nominal, a 3 % spread leaves a healthy 1 cm `sine` at
        25x the noise, and viscous friction, leakage and clogging stand in for it. Fitted, it also
        absorbs what reduces the flow alike (a weak torque motor, a leak): the spread is therefore
        no wider than a healthy actuator's, and a GQ at its edge (:func:`edge_of_spread`) is read
        as a flow loss beyond a healthy actuator's and GQ goes back to the base's value, after the
        declared faults' fit (:meth:`ResidualLoop.baseline`) or, at the end, by running the loop
        again (:func:`explain`); docs/explain.md, "The healthy flow gain". Not fitted when GQ is a
        declared fault or known (``fixed``).
    interval_replicates : int
        HF re-simulations of the final model whose refits' spread widens the intervals of a
        model the loop built, in [0, 100] (0: none; :mod:`eha.explain.replicates`).
    rival_replicates : int
        HF re-simulations of the final model, without a rival the exclusion check lists and
        with it, that may rule it out, in [0, 100] (0: none; :mod:`eha.explain.rival_check`).
    method, pop, seed
        Optimizer of every fit (:func:`eha.identification.fdi.identify`), same seed for all fits.
    options : dict of str to float
        Further options of ``method`` (``max_gen``, ``stall``, ...: the keys of
        :data:`eha.identification.problem.METHOD_DEFAULTS`), passed to every global fit.

    :meth:`override` sets settings and options by name (an unknown name is refused, naming
    it); every value is checked once, here (:meth:`problems`).
    """

    holdout: float = 0.3
    min_gain: float = 0.1
    penalty: float = 0.02
    alpha: float = 0.05
    significance: float = 0.01
    null_actuators: int = DEFAULT_ACTUATORS
    max_steps: int = 6
    candidates: int = 6
    noise_factor: float = 1.25
    joint: bool = True
    p12_weight: float = 1.0
    flow_gain_spread: float = 0.04
    interval_replicates: int = 6
    rival_replicates: int = 6
    method: str = DEFAULT_METHOD
    pop: int = 20
    seed: int = 0
    options: Mapping[str, float] = field(default_factory=dict, hash=False)

    def __post_init__(self):
        problems = self.problems()
        if problems:
            raise ExplainError(problems)

    def override(self, values: Mapping[str, Any]) -> LoopSettings:
        """These settings with ``values`` set by name: a setting (None keeps it) or an option
        of an optimizer (joined to :attr:`options`).

        Raises
        ------
        ExplainError
            A name that is neither (one line naming it and the names allowed), or a value
            outside its range (:meth:`problems`).
        """
        names = [f.name for f in fields(self) if f.name != "options"]
        known = optimizer_options()
        unknown = [k for k in values if k not in names and k not in known]
        if unknown:
            raise ExplainError(
                f"{', '.join(f'`{k}`' for k in unknown)}: not a setting of the residual loop "
                f"(settings: {', '.join(names)}; optimizer options: {', '.join(known)})")
        given = {k: v for k, v in values.items() if k in names and v is not None}
        options = {k: v for k, v in values.items() if k not in names}
        if options:
            given["options"] = {**self.options, **options}
        return replace(self, **given) if given else self

    def as_dict(self) -> dict[str, Any]:
        """Every setting by name, the options among them (a result's ``settings``)."""
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "options"},
                **self.options}

    def problems(self) -> list[str]:
        """One line per setting outside its range, naming its option (``--min-gain``) and the
        range: the one place the loop's settings are checked (the CLI builds a LoopSettings
        and prints these). Values are shown as given (``-1.0``, ``nan``)."""
        problems = []
        if not 0.0 <= self.holdout <= 0.8:
            problems.append(f"`holdout` {self.holdout}: allowed range [0, 0.8]")
        if not 0.0 <= self.min_gain <= 1.0:  # also refuses nan
            problems.append(f"`min_gain` {self.min_gain}: allowed range [0, 1]")
        if not 0.0 <= self.penalty <= 1.0:
            problems.append(f"penalty {self.penalty}: allowed range [0, 1]")
        if not 0.0 < self.alpha < 1.0:
            problems.append(f"`alpha` {self.alpha}: allowed range (0, 1)")
        if not 0.0 < self.significance < 1.0:
            problems.append(f"significance {self.significance}: allowed range (0, 1)")
        if not self.null_actuators >= MIN_RECORDS:
            problems.append(f"`null_actuators` {self.null_actuators}: allowed range "
                            f"[{MIN_RECORDS}, ...]")
        if not self.max_steps >= 0:
            problems.append(f"`max_steps` {self.max_steps}: allowed range [0, ...]")
        if not self.candidates >= 0:
            problems.append(f"`candidates` {self.candidates}: allowed range [0, ...] (0 = all)")
        if not self.noise_factor >= 0.0:
            problems.append(f"noise_factor {self.noise_factor}: allowed range [0, ...]")
        if not 0.0 <= self.p12_weight <= 100.0:
            problems.append(f"`p12_weight` {self.p12_weight}: allowed range [0, 100]")
        if not 0.0 <= self.flow_gain_spread <= 0.5:
            problems.append(f"`flow_gain_spread` {self.flow_gain_spread}: allowed range "
                            f"[0, 0.5]")
        if not 0 <= self.interval_replicates <= 100:
            problems.append(f"`interval_replicates` {self.interval_replicates}: allowed range "
                            f"[0, 100]")
        if not 0 <= self.rival_replicates <= 100:
            problems.append(f"`rival_replicates` {self.rival_replicates}: allowed range "
                            f"[0, 100]")
        if not self.pop >= 2:
            problems.append(f"`pop` {self.pop}: allowed range [2, ...]")
        if self.method not in GLOBAL_METHODS:
            problems.append(f"`method` {self.method}: the loop's refits search globally; "
                            f"allowed ga, ga+ps")
        else:
            allowed = METHOD_DEFAULTS[self.method]
            problems += [f"`{k}`: not an option of method {self.method} (allowed "
                         f"{', '.join(allowed)})" for k in self.options if k not in allowed]
        return problems


#: Defaults of the loop (see :class:`LoopSettings`), for the CLI.
DEFAULTS: dict[str, Any] = {f.name: f.default for f in fields(LoopSettings)
                            if f.name != "options"}


def optimizer_options() -> list[str]:
    """The options of the loop's global optimizers (:data:`GLOBAL_METHODS`), by name."""
    return list(dict.fromkeys(k for m in GLOBAL_METHODS for k in METHOD_DEFAULTS[m]))


def parse_fit(spec: str | Mapping[str, Sequence[float]] | Iterable[str] | None
              ) -> Bounds:
    """Fault parameters to fit: ``"BKL,FDJ"`` or ``"BKL=0:1e-3,FDJ=200:4000"`` or a mapping.

    Names without bounds take :data:`DEFAULT_FAULT_BOUNDS` or
    :func:`eha.identification.problem.default_bounds`.
    """
    from eha.identification.problem import DEFAULT_FIT, FDIError, check_bounds, default_bounds

    if spec is None:
        spec = DEFAULT_FIT
    if isinstance(spec, Mapping):
        items = {k: tuple(v) for k, v in spec.items()}
    else:
        parts = [p.strip() for p in (spec.split(",") if isinstance(spec, str) else spec)]
        items = {}
        for part in filter(None, parts):
            try:
                name, rng = parse_name_value(part, "`fit`", "[LO:HI]")
            except ParameterError:
                raise ExplainError(f"`fit` {part!r}: bounds must be NAME=LOW:HIGH, e.g. "
                                   f"BKL=0:1e-3") from None
            if name in items:
                given = spec if isinstance(spec, str) else ",".join(parts)
                raise ExplainError(f"`fit` {given}: {name} given twice; name each parameter "
                                   f"once")
            if rng is not None:
                items[name] = rng
            else:
                try:
                    items[name] = DEFAULT_FAULT_BOUNDS.get(name) or default_bounds([name])[name]
                except FDIError as exc:
                    raise ExplainError(str(exc)) from None
    if not items:
        raise ExplainError("`fit`: no parameter given; e.g. `fit` BKL,FDJ")
    try:
        return check_bounds(items)
    except FDIError as exc:
        raise ExplainError(str(exc)) from None
