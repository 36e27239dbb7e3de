"""What the residual loop fits, built once per record: :class:`Problem`.

One :func:`eha.explain.explain` call builds one problem from its record and inputs (the
declared faults, the candidate effects, the validation record, the base, the known
parameters) and its settings; the healthy null's probe, the loop's passes, settle and the flow
gain's second run all take it (:class:`eha.explain.fitting.Fitter` fits it). A re-simulated
or healthy record is another record, and gets a problem of its own
(:func:`Problem.build` with the same inputs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Iterable

from eha.explain.effects import EFFECTS, Effect, get as get_effects
from eha.explain.record import Record, initial_position, p12_objective_weight
from eha.explain.settings import ExplainError, LoopSettings, parse_fit
from eha.identification.measured import MeasuredData, noise_level
from eha.models.bounds import Bounds
from eha.models.params import LFParams, ParameterError, resolve


@dataclass(frozen=True, eq=False)
class Problem:
    """A record and what the loop fits on it (built by :meth:`build`; read-only, compared by
    identity).

    Attributes
    ----------
    data : MeasuredData
        The record.
    validate : MeasuredData or None
        A second record scored as held-out data.
    faults : Bounds
        The declared faults and their search bounds (:func:`parse_fit`).
    flow_gain : (float, float) or None
        The flow gain GQ's bounds when it is fitted with the faults within its healthy
        spread (``flow_gain_spread``), else None.
    pool : list of Effect
        The candidate effects: none already in the base, overlapping the declared faults
        or touching a known parameter.
    base : LFParams
        The starting LF parameters, XJ0 from the record (:func:`initial_position`).
    given_base : LFParams or None
        The base as given (None: nominal), for the healthy null's fleet.
    fixed : frozenset of str
        Known LF parameters held at the base's values.
    n_fit : int
        Samples fitted (the rest, up to ``len(data)``, held out).
    holdout_text : str
        What is held out, in words.
    record, check : Record, Record or None
        The record (and the validation record) ready to simulate the LF model on.
    noise : float
        The record's position noise [m] (``noise_m`` of its info, else estimated).
    noise_ref : float
        The noise the residual is compared with
        (:func:`eha.identification.intervals.noise_reference`) [m].
    p12_weight, p12_noise : float
        Metres of position per pascal of P12 residual in the fits (0: position only) and the
        P12 noise [Pa] (:func:`p12_objective_weight`).
    score_noise : float
        The score of a model that leaves only noise [m].
    """

    data: MeasuredData
    validate: MeasuredData | None
    faults: Bounds
    flow_gain: tuple[float, float] | None
    pool: list[Effect]
    base: LFParams
    given_base: LFParams | None
    fixed: frozenset[str]
    n_fit: int
    holdout_text: str
    record: Record
    check: Record | None
    noise: float
    noise_ref: float
    p12_weight: float
    p12_noise: float
    score_noise: float

    @property
    def bounds(self) -> Bounds:
        """Everything fitted with the declared faults: the faults and, when fitted, GQ (new
        each time: the loop's own copy may drop GQ)."""
        return Bounds({**self.faults, **({"GQ": self.flow_gain} if self.flow_gain else {})})

    def without_flow_gain(self) -> Problem:
        """The same problem with GQ held at the base's value (the loop's second run when the
        fitted GQ ends at the edge of its spread)."""
        return replace(self, flow_gain=None)

    @classmethod
    def build(cls, data: MeasuredData, settings: LoopSettings = LoopSettings(),
              fit=None, effects: Iterable[str] | str | None = None,
              validate: MeasuredData | None = None, base: LFParams | None = None,
              fixed: Iterable[str] = ()) -> Problem:
        """The problem of ``data`` (see :func:`eha.explain.explain` for the inputs); reads
        ``holdout``, ``p12_weight`` and ``flow_gain_spread`` of ``settings``.

        Raises
        ------
        ExplainError
            Bad bounds, a known parameter also fitted or XJ0, a base the LF refuses, or too
            few samples left to fit after the hold-out.
        """
        from eha.identification.intervals import noise_reference

        given_base = base
        faults = parse_fit(fit)
        pool = get_effects(effects) if effects is not None else list(EFFECTS.values())
        try:
            base = initial_position(data, resolve("lf", {}, base=base) if base else LFParams())
        except ParameterError as exc:
            raise ExplainError(str(exc)) from None
        fixed = frozenset(fixed)
        for name in sorted(fixed):
            if name in faults:
                raise ExplainError(f"`fixed` {name}: also a fitted fault (`fit`); give it one "
                                   "role")
            if name == "XJ0":
                raise ExplainError("`fixed` XJ0: the initial position is taken from the record")
        flow_gain = None
        if settings.flow_gain_spread > 0 and "GQ" not in faults and "GQ" not in fixed:
            # the healthy flow gain is the actuator's own: fitted with the faults throughout
            # (bounds to 6 significant digits, as typed: 0.2 +- 10 % is GQ=0.18:0.22)
            spread = settings.flow_gain_spread
            flow_gain = (float(f"{base.GQ * (1.0 - spread):.6g}"),
                         float(f"{base.GQ * (1.0 + spread):.6g}"))
        fitted = {*faults, *(("GQ",) if flow_gain else ())}
        # effects already in the base (a prior), overlapping the declared faults or touching
        # a known (fixed) parameter are not tried
        pool = [e for e in pool if not set(e.params) & fitted
                and not e.is_on(base) and not set(e.off) & fixed]
        n = len(data)
        if validate is not None:
            n_fit = n
            holdout_text = f"validation record {validate.source} ({len(validate)} samples)"
        else:
            n_fit = n - int(round(settings.holdout * n))
            holdout_text = (f"last {settings.holdout:.0%} of the record ({n - n_fit} samples)"
                            if n_fit < n else "none (scored on the fitted data)")
        if n_fit < 20:
            raise ExplainError(f"record: {n_fit} samples left to fit after the hold-out; "
                               f"at least 20 are required (lower `holdout`)")
        noise = float(data.info.get("noise_m", noise_level(data.xu)))
        # the measured load pressure joins every fit and score when the record has it
        p12_weight, p12_noise = p12_objective_weight(noise, data.p12, settings.p12_weight)
        # the score of a model that leaves only noise (the P12 noise in metres of position)
        score_noise = math.hypot(noise, p12_weight * p12_noise) if p12_weight else noise
        return cls(data=data, validate=validate, faults=faults, flow_gain=flow_gain, pool=pool,
                   base=base, given_base=given_base, fixed=fixed, n_fit=n_fit,
                   holdout_text=holdout_text,
                   record=Record(data, base),
                   check=(Record(validate, initial_position(validate, base))
                          if validate is not None else None),
                   noise=noise, noise_ref=noise_reference(noise, data.xu),
                   p12_weight=p12_weight, p12_noise=p12_noise, score_noise=score_noise)
