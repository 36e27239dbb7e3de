"""Health assessment of one record: every fault's estimate with an interval, and which fault.

The LF model carries seven fault parameters (:data:`FAULTS`). Fitting all seven at once to one
record is ill-posed — leakage, friction and clogging trade off against each other — so the
assessment runs a **bank of fault hypotheses** (the multiple-model approach of fault
isolation): ``H0`` fits the thesis' two faults (backlash BKL, jack friction FDJ) and each
``H_f`` fits them together with one more fault ``f`` (motor gain GM, clogging Kintas, leakage
Clk, offset Ofs, spool friction FSS). Each hypothesis is one identification with intervals
(:func:`eha.identification.fdi.identify`, warm-started at ``H0``'s estimate so that it is never
worse).

Hypotheses are weighed by the Bayesian information criterion computed on the *effective*
number of samples (``n / τ``, with ``τ`` the integrated autocorrelation time of the best
residual: the residual of a model-form error is correlated over tens of samples, and treating
it as white would make every small gain look decisive). A fault's interval is the central
``level`` interval of the mixture over hypotheses: normal around the estimate where the
hypothesis fits the fault, a point mass at the healthy value where it does not. Estimates are
those of the most probable hypothesis.

A fault is *degraded* when its estimate is beyond its threshold in the direction of
degradation (thresholds from :mod:`eha.health.detection`'s healthy-fleet calibration); the faults
*isolated* are the degraded ones whose hypothesis is supported by the record.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from eha.models.commands import Command
from eha.models.estimate import Estimate, Interval, estimates, frame, intervals_json
from eha.identification.fdi import identify
from eha.identification.problem import CALIBRATED_LF, DEFAULT_LEVEL, FitResult
from eha.models.faults import FAULTS as FAULT_REGISTRY, Fault, core_faults, extra_faults
from eha.models.params import LFParams, resolve
from eha.errors import InputError


#: The fault parameters the LF model carries (the registry, :mod:`eha.models.faults`: bounds,
#: healthy value and spread, direction of degradation, role in the bank).
FAULTS: dict[str, Fault] = FAULT_REGISTRY


#: Search of each one-more-fault hypothesis: warm-started at H0's estimate with the fault
#: healthy (it is never worse than H0).
HYPOTHESIS_SEARCH: dict[str, Any] = {"warm_start": True, "max_gen": 12, "stall": 4}
#: Signals an assessment can fit: the position always, the load pressure when recorded.
ASSESSED_SIGNALS = ("xu", "p12")
#: Default white noise of a recorded load pressure [Pa] (0.5 bar), where none is given.
DEFAULT_NOISE_P12 = 5e4


class HealthError(InputError):
    """Bad health-assessment input; the message is one line."""


@dataclass(frozen=True)
class Hypothesis:
    """One member of the bank: the faults it fits, its fit and its posterior weight."""

    fault: str | None
    fit: FitResult
    bic: float
    weight: float

    @property
    def label(self) -> str:
        return f"H0 ({', '.join(core_faults())})" if self.fault is None else f"H_{self.fault}"


@dataclass(frozen=True)
class Assessment:
    """Health assessment of one record.

    Attributes
    ----------
    estimates : dict
        Every fault of :data:`FAULTS` (a fault outside the most probable hypothesis is at its
        healthy value).
    intervals : dict
        ``name -> (lo, hi)`` at ``level`` (mixture over the hypotheses).
    means : dict
        Posterior mean of every fault over the hypotheses (healthy value where a hypothesis
        does not fit the fault): the detection statistic's input, continuous where the
        estimates jump between hypotheses.
    spread : dict
        The measurement uncertainty of each fault: its std in the hypothesis that fits it
        (the most probable one for BKL and FDJ).
    level : float
    hypotheses : tuple of Hypothesis
        The bank, most probable first.
    n_eff : float
        Effective number of samples of the evidence.
    noise_rmse, residual_rmse : float
        Sensor noise of the record and RMSE of the most probable hypothesis [m].
    flagged : bool
        Even the best hypothesis leaves a residual well above the noise: the record shows an
        effect outside the fault library; the intervals are wide.
    seconds : float
        Wall time [s].
    seed : int
    """

    estimates: dict[str, float]
    intervals: dict[str, Interval]
    means: dict[str, float]
    spread: dict[str, float]
    level: float
    hypotheses: tuple[Hypothesis, ...]
    n_eff: float
    noise_rmse: float
    residual_rmse: float
    flagged: bool
    seconds: float
    seed: int
    base_model: str = "calibrated"
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def best(self) -> Hypothesis:
        return self.hypotheses[0]

    def weights(self) -> dict[str, float]:
        return {("none" if h.fault is None else h.fault): h.weight for h in self.hypotheses}

    def as_estimates(self) -> dict[str, Estimate]:
        """Each fault's :class:`~eha.models.estimate.Estimate`: the estimate, its interval at
        :attr:`level`, its measurement std (:attr:`spread`), its SI unit."""
        return estimates(self.estimates, self.intervals, self.level, self.spread)

    def to_pandas(self):
        """One row per fault: its unit (SI, as ``eha params``), estimate, interval at
        ``level``, posterior mean over the hypotheses and measurement std, and ``weight``: the
        posterior probability of a hypothesis that fits it (1 for the core faults, which every
        hypothesis fits; the weight of ``H_fault`` for the others)."""
        weights = {**self.weights(), **{k: 1.0 for k in core_faults()}}
        return frame(self.as_estimates(), key="fault", columns=("unit", "estimate", "lo", "hi"),
                     extra={"mean": self.means, "std": self.spread, "weight": weights})

    def to_dict(self) -> dict[str, Any]:
        return {"estimates": dict(self.estimates),
                "intervals": intervals_json(self.as_estimates()),
                "means": dict(self.means), "spread": dict(self.spread),
                "level": self.level, "flagged": self.flagged,
                "noise_rmse": self.noise_rmse, "residual_rmse": self.residual_rmse,
                "n_eff": self.n_eff, "seconds": self.seconds, "seed": self.seed,
                "base_model": self.base_model, "notes": list(self.notes),
                "hypotheses": [{"fault": h.fault, "weight": h.weight, "bic": h.bic,
                                "rmse": h.fit.objective, "estimates": h.fit.estimates,
                                "std": h.fit.std, "hac_std": h.fit.hac_std,
                                "intervals": intervals_json(h.fit.as_estimates())}
                               for h in self.hypotheses]}


def _normal_cdf(x: np.ndarray, mean: float, std: float) -> np.ndarray:
    if not std > 0 or not math.isfinite(std):
        return (x >= mean).astype(float) if std == 0 else np.full_like(x, np.nan)
    return 0.5 * (1.0 + np.vectorize(math.erf)((x - mean) / (std * math.sqrt(2.0))))


def mixture_interval(components: Sequence[tuple[float, float, float]], level: float,
                     bounds: tuple[float, float]) -> tuple[float, float]:
    """Central ``level`` interval of a mixture of normals / point masses within ``bounds``.

    Parameters
    ----------
    components : sequence of (weight, mean, std)
        ``std = 0`` is a point mass; ``std = inf`` is uniform over ``bounds``.
    """
    lo, hi = bounds
    grid = np.linspace(lo, hi, 4001)
    means = [m for _, m, _ in components]
    grid = np.unique(np.concatenate([grid, np.clip(means, lo, hi)]))
    cdf = np.zeros_like(grid)
    total = sum(w for w, _, _ in components)
    for w, m, s in components:
        if not math.isfinite(s):
            part = (grid - lo) / (hi - lo)
        elif s == 0:
            part = (grid >= m).astype(float)
        else:
            # normal censored at the bounds: an estimate cannot leave them, so the mass
            # beyond a bound sits on it (a healthy value at a bound stays inside)
            part = _normal_cdf(grid, m, s)
            part[-1] = 1.0
        cdf += (w / total) * part
    a, b = (1.0 - level) / 2.0, (1.0 + level) / 2.0
    i_lo = int(np.searchsorted(cdf, a, side="left"))
    i_hi = int(np.searchsorted(cdf, b, side="left"))
    return float(grid[min(i_lo, grid.size - 1)]), float(grid[min(i_hi, grid.size - 1)])


def fault_components(name: str, hyps: Sequence[tuple[str | None, float, Mapping[str, float],
                                                     Mapping[str, float]]]
                     ) -> list[tuple[float, float, float]]:
    """Mixture components ``(weight, mean, std)`` of fault ``name`` over the hypotheses
    ``(fault, weight, estimates, std)``: the hypothesis' estimate and std where it fits the
    fault, else the healthy value with the healthy spread (:attr:`eha.models.faults.Fault.healthy_std`)."""
    spec = FAULTS[name]
    comps = []
    for _, weight, est, std in hyps:
        if name in est:
            comps.append((weight, est[name], std.get(name, math.inf)))
        else:
            comps.append((weight, spec.healthy, spec.healthy_std))
    return comps


def _information_bic(rmse: float, k: int, n_eff: float) -> float:
    return n_eff * math.log(max(rmse, 1e-300) ** 2) + k * math.log(n_eff)


def _lf_base(base: LFParams | Mapping[str, float] | None) -> LFParams:
    """The LF model of an assessment: given, or the calibrated LF with overrides."""
    if base is None or isinstance(base, Mapping):
        return resolve("lf", {**CALIBRATED_LF, **dict(base or {})})
    return base


def assess(reference_xu: np.ndarray, command: Command | str,
           base: LFParams | Mapping[str, float] | None = None,
           faults: Sequence[str] | None = None, level: float = DEFAULT_LEVEL,
           seed: int = 0, noise: float | None = None, t_end: float | None = None,
           recorded_start: float | None = None, pop: int = 20,
           on_progress: Callable[[str], None] | None = None,
           reference_p12: np.ndarray | None = None, p12_weight: float = 0.0) -> Assessment:
    """Assess a record: the hypothesis bank, mixture intervals, most probable faults.

    Parameters
    ----------
    reference_xu : float64 array
        Recorded position [m] at 1 kHz.
    command : Command or str
        Its position command.
    base : LFParams or mapping, optional
        The LF model (default: :data:`eha.identification.problem.CALIBRATED_LF`, the LF calibrated
        by ``eha explain``).
    faults : sequence of str
        Faults that get a hypothesis of their own (default every ``extra`` fault of the
        registry, :func:`eha.models.faults.extra_faults`).
    level : float
        Nominal coverage of the intervals.
    seed : int
        Optimizer seed (the same seed gives the same assessment).
    noise : float, optional
        Sensor noise [m] (default: estimated from the record).
    reference_p12 : float64 array, optional
        Recorded load pressure P12 [Pa] on the grid of ``reference_xu``: with ``p12_weight``
        > 0 every hypothesis fits it beside the position
        (:func:`eha.identification.fdi.identify`).
    p12_weight : float
        Metres of position per pascal of P12 residual (0: the position alone), e.g.
        ``noise_xu / noise_p12``.
    """
    extra = extra_faults()
    faults = extra if faults is None else tuple(faults)
    unknown = [f for f in faults if f not in extra]
    if unknown:
        raise HealthError(f"faults: {unknown[0]!r} has no hypothesis; allowed "
                          f"{', '.join(extra)}")
    base = _lf_base(base)
    start = time.perf_counter()
    from eha.identification.measured import noise_level

    xu = np.asarray(reference_xu, dtype=np.float64)
    noise = float(noise_level(xu) if noise is None else noise)
    say = on_progress or (lambda message: None)
    core = {n: FAULTS[n].bounds for n in core_faults()}
    common = dict(level=level, noise=noise, t_end=t_end, recorded_start=recorded_start,
                  pop=pop, seed=seed, reference_p12=reference_p12, p12_weight=p12_weight)
    say(f"H0: {', '.join(core)}")
    fits: list[tuple[str | None, FitResult]] = [(None, identify(xu, command, core, base=base,
                                                                **common))]
    h0 = fits[0][1]
    for f in faults:
        say(f"H_{f}: {', '.join(core)}, {f}")
        start_point = base.replace(**h0.estimates, **{f: FAULTS[f].healthy})
        fits.append((f, identify(xu, command, {**core, f: FAULTS[f].bounds}, base=start_point,
                                 **HYPOTHESIS_SEARCH, **common)))
    best_fit = min(fits, key=lambda p: p[1].objective)[1]
    # n / tau, tau the integrated autocorrelation time of the best residual (half the HAC
    # bandwidth its intervals used)
    n_eff = max(2.0, xu.size / max(1.0, best_fit.lag / 2.0))
    bics = [_information_bic(r.objective, len(r.names), n_eff) for _, r in fits]
    low = min(bics)
    raw = [math.exp(-0.5 * (b - low)) for b in bics]
    weights = [w / sum(raw) for w in raw]
    hyps = sorted((Hypothesis(f, r, b, w) for (f, r), b, w in zip(fits, bics, weights)),
                  key=lambda h: -h.weight)
    best = hyps[0]
    estimates, intervals, means, spread = {}, {}, {}, {}
    for name in (*core, *faults):
        spec = FAULTS[name]
        comps = fault_components(name, [(h.fault, h.weight, h.fit.estimates, h.fit.std)
                                        for h in hyps])
        intervals[name] = mixture_interval(comps, level, spec.bounds)
        estimates[name] = float(best.fit.estimates.get(name, spec.healthy))
        means[name] = float(sum(w * m for w, m, _ in comps))
        spread[name] = float(best.fit.std.get(name) if name in best.fit.std else
                             next((h.fit.std.get(name, math.inf) for h in hyps
                                   if h.fault == name), math.inf))
    rmse = best.fit.objective
    flagged = bool(best.fit.flagged)
    notes = list(best.fit.notes)
    return Assessment(estimates=estimates, intervals=intervals, means=means, spread=spread,
                      level=float(level),
                      hypotheses=tuple(hyps), n_eff=float(n_eff), noise_rmse=noise,
                      residual_rmse=float(rmse), flagged=flagged,
                      seconds=time.perf_counter() - start, seed=int(seed),
                      notes=tuple(notes))


def assess_record(data, base: LFParams | Mapping[str, float] | None = None,
                  faults: Sequence[str] | None = None, level: float = DEFAULT_LEVEL,
                  seed: int = 0, pop: int = 20,
                  on_progress: Callable[[str], None] | None = None,
                  signals: Sequence[str] = ("xu",)) -> Assessment:
    """:func:`assess` a measured record (:class:`eha.identification.measured.MeasuredData`).

    The LF model starts where the record starts, as in ``eha explain``; the noise is estimated
    on the record's raw samples (before any resampling). ``signals`` names what the fits
    use: ``("xu",)``, the position alone, or ``("xu", "p12")``, the position and the load
    pressure, each weighed by its own noise (as the residual loop weighs them,
    :func:`eha.explain.record.p12_objective_weight`).
    """
    from eha.explain.record import initial_position, p12_objective_weight, recorded_start
    from eha.identification.measured import noise_level

    unknown = [s for s in signals if s not in ASSESSED_SIGNALS]
    if unknown or "xu" not in signals:
        raise HealthError(f"signals: {','.join(signals)}; allowed xu or xu,p12")
    p12, weight = None, 0.0
    if "p12" in signals:
        if data.p12 is None:
            raise HealthError(f"signals: {data.source} has no p12 column (the load pressure "
                              "the check was asked to fit)")
        noise = data.info.get("noise_m")
        noise = float(noise_level(data.xu) if noise is None else noise)
        weight, _ = p12_objective_weight(noise, data.p12)
        p12 = data.p12
    base = initial_position(data, _lf_base(base))
    return assess(data.xu, data.command, base=base, faults=faults, level=level, seed=seed,
                  noise=data.info.get("noise_m"), t_end=data.t_end,
                  recorded_start=recorded_start(data), pop=pop, on_progress=on_progress,
                  reference_p12=p12, p12_weight=weight)
