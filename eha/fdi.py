"""Fault detection and identification (thesis chapter 6; docs/fdi.md).

Fit chosen LF parameters (by default the faults BKL and FDJ) so that the LF output matches a
reference trace: an HF run (:func:`hf_reference`) or measured data. Every decision variable is
normalised to [0, 1] within its bounds (the thesis' own suggestion), and every batch of
candidates (a GA generation, a pattern-search poll) is simulated in ONE parallel numba call
(:func:`eha.models.simulate.simulate_lf_batch`), never one Python call per individual.

Methods (``identify(method=...)``):

``"ga"``
    The thesis' method: a genetic algorithm (pymoo ``GA``, population 20 or 40) that stops
    like Matlab's ``ga`` does, when the best objective improved by less than a relative
    ``ftol`` over ``stall`` generations, or after ``max_gen`` generations.
``"ga+ps"``
    Our default: a short GA (global search; stops after fewer stall generations) followed by
    a batched compass pattern search in the unit cube (all 2k poll points in one batch, step
    halved on failure until ``xtol``). Chosen by measurement on the 12 thesis cases
    (docs/fdi.md).
``"ps"``
    The pattern search alone: a local polish from the values of ``base``.
``"lm"``
    A local least-squares polish from the values of ``base``: scipy's trust-region
    reflective ``least_squares`` (a bounded Gauss-Newton trust-region method of the
    Levenberg-Marquardt family) on the residual vector, its Jacobian by forward differences
    in one batch of k + 1 runs. Unlike the compass search it
    follows valleys that are not along a parameter axis (an offset traded against jack
    friction and a load); the residual loop's final estimate on the whole record
    (docs/explain.md). Objective ``"rmse"`` only.

Objectives: ``"rmse"`` (default) ``sqrt(mean((y_LF - y_ref)^2))`` and ``"objfcn"``, the
thesis' objfcn.m as written, ``mean(sqrt((y_LF - y_ref)^2))`` = mean absolute error. When a
measured load pressure is given (``reference_p12`` with ``p12_weight`` > 0, the residual loop
on records that carry P12) its residual joins the objective in metres of position,
``p12_weight * (P12_LF - P12_ref)``: ``sqrt(mean(e_xu^2) + mean(e_p12^2))`` (or the sum of
the mean absolute errors).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from eha.models.commands import Command, as_command
from eha.models.params import (LF, SPECS, LFParams, ParameterError, check_value, parse_name_value,
                        resolve)
from eha.models.simulate import OUTPUT_DT, Trace, command_on_grid, grid, simulate, simulate_lf_batch

#: Identification methods (see the module docstring).
METHODS = ("ga", "ga+ps", "ps", "lm")
#: The default method (chosen by measurement, docs/fdi.md).
DEFAULT_METHOD = "ga+ps"
#: Objective functions: name -> one-line meaning.
OBJECTIVES = {
    "rmse": "root-mean-square error of xu [m]",
    "objfcn": "thesis objfcn.m: mean(sqrt((y_LF - y_ref)^2)) = mean absolute error of xu [m]",
}
#: Parameters that cannot be fitted: structural switches and the integration grid.
NOT_FITTABLE = ("DT", "orifice_law")
#: Default fitted parameters (the two faults of the thesis).
DEFAULT_FIT = ("BKL", "FDJ")
#: Default search bounds of the fault parameters: the thesis' chirp cases for BKL and FDJ, and
#: for the other faults the LF model carries a range that spans healthy to severely degraded
#: (motor gain down to 30 %, clogging to 0.9, leakage to 50x nominal, offset +-1 mA, spool
#: friction to 8.5x nominal; docs/health.md).
SEARCH_BOUNDS: dict[str, tuple[float, float]] = {
    "BKL": (0.0, 1.25e-3), "FDJ": (200.0, 4000.0), "GM": (0.003, 0.012), "Kintas": (0.0, 0.9),
    "Clk": (0.0, 5e-12), "Ofs": (-1.0, 1.0), "FSS": (0.0, 60.0)}
#: Default nominal coverage of every parameter interval.
DEFAULT_LEVEL = 0.9
#: The LF model calibrated by ``eha explain`` on a healthy actuator in a 4 kN load test
#: (campaigns/thesis-fdi-augmented.toml, docs/explain.md): orifice law, leakage, flapper
#: dynamics. ``base_model="calibrated"`` selects it.
CALIBRATED_LF: dict[str, float] = {"orifice_law": 1.0, "Clk": 9.662e-14, "SNF": 3445.5,
                                   "ZF": 0.8109}
#: Named LF bases: ``plain`` is the thesis' LF model.
BASE_MODELS: dict[str, dict[str, float]] = {"plain": {}, "calibrated": CALIBRATED_LF}
#: The base of :func:`identify_source`: against an HF reference (the thesis reproduction) and
#: on a measured record (where the plain LF's structural bias would dominate the interval).
DEFAULT_BASE_MODEL = {"hf": "plain", "data": "calibrated"}


def model_form_of(base: LFParams) -> str:
    """Which measured model-form terms apply to ``base``: the named base whose structural
    settings (orifice law, flapper dynamics) it shares, else ``"none"``."""
    for name, values in BASE_MODELS.items():
        ref = resolve("lf", values)
        if base.orifice_law == ref.orifice_law and (base.SNF > 0) == (ref.SNF > 0):
            return name
    return "none"

#: Option defaults of each method. ``max_gen``: generation limit; ``stall``/``ftol``: stop when
#: the best objective improved by less than ``ftol`` (relative) over ``stall`` generations
#: (Matlab ``ga``: MaxStallGenerations 50, FunctionTolerance 1e-6, MaxGenerations 100*nvars);
#: ``xtol``/``step0``: final and initial pattern-search step in the unit cube (for ``"lm"``,
#: ``xtol`` is scipy's relative step tolerance); ``fd_step``: forward-difference step of the
#: ``"lm"`` Jacobian in the unit cube, in (0, 0.1];
#: ``max_evals``: evaluation budget of the whole identification. ``max_gen = 0`` means Matlab's
#: default of 100 generations per fitted variable.
METHOD_DEFAULTS: dict[str, dict[str, float]] = {
    "ga": {"max_gen": 0, "stall": 50, "ftol": 1e-6, "max_evals": 20000},
    "ga+ps": {"max_gen": 40, "stall": 8, "ftol": 1e-3, "step0": 0.02, "xtol": 2e-5,
              "max_evals": 20000},
    "ps": {"step0": 0.02, "xtol": 2e-5, "max_evals": 20000},
    "lm": {"fd_step": 1e-4, "xtol": 1e-10, "max_evals": 5000},
}


class FDIError(ValueError):
    """Bad identification input (bounds, method, reference); the message is one line."""


@dataclass(frozen=True)
class FitResult:
    """Outcome of one identification.

    Attributes
    ----------
    names : tuple of str
        Fitted LF parameters, in decision-vector order.
    estimates : dict
        Identified value of each fitted parameter (its unit in ``eha params``).
    objective : float
        Objective at the estimate [m].
    objective_name : str
        ``"rmse"`` or ``"objfcn"`` (:data:`OBJECTIVES`).
    evaluations : int
        LF simulations run.
    seconds : float
        Wall time of the identification [s] (reference simulation excluded).
    history : tuple of float
        Best objective after each generation / poll [m].
    method : str
        :data:`METHODS` entry.
    seed : int
        Seed of the optimizer.
    bounds : dict
        ``name -> (lower, upper)`` search bounds.
    options : dict
        Method options actually used (after defaults).
    level : float or None
        Nominal coverage of ``intervals`` (None: intervals not computed).
    intervals : dict
        ``name -> (lo, hi)``: interval of each estimate at ``level`` (eha.intervals).
    std : dict
        Standard uncertainty of each estimate (noise, residual and model-form terms).
    hac_std : dict
        Its residual (HAC) part alone, before floors and widening (diagnostics, calibration).
    lag : int or None
        The residual's HAC bandwidth [samples], twice its integrated autocorrelation time.
    flagged : bool
        The residual stays well above the record's noise: the model does not explain the
        record, the intervals are wide and the numbers are not to be trusted.
    noise_rmse : float or None
        Sensor noise estimated from the record [m].
    model_form : str
        Which measured model-form terms entered the intervals (eha.intervals.MODEL_FORM).
    notes : tuple of str
        Warnings of the interval estimate (flag, unconstrained parameters).
    """

    names: tuple[str, ...]
    estimates: dict[str, float]
    objective: float
    objective_name: str
    evaluations: int
    seconds: float
    history: tuple[float, ...]
    method: str
    seed: int
    bounds: dict[str, tuple[float, float]]
    options: dict[str, float] = field(default_factory=dict)
    level: float | None = None
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)
    std: dict[str, float] = field(default_factory=dict)
    hac_std: dict[str, float] = field(default_factory=dict)
    lag: int | None = None
    flagged: bool = False
    noise_rmse: float | None = None
    model_form: str = "none"
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (lists instead of tuples)."""
        d = asdict(self)
        d["names"] = list(self.names)
        d["history"] = list(self.history)
        d["bounds"] = {k: list(v) for k, v in self.bounds.items()}
        d["intervals"] = {k: list(v) for k, v in self.intervals.items()}
        d["notes"] = list(self.notes)
        return d


# --------------------------------------------------------------------------------------------
# validation


def check_bounds(fit: Mapping[str, Sequence[float]]) -> dict[str, tuple[float, float]]:
    """Validate search bounds: LF parameter names, ``lo < hi``, both inside the allowed range.

    Raises
    ------
    FDIError
        One line naming the parameter and its allowed range.
    """
    if not fit:
        raise FDIError("fit: no parameter to identify; give at least one NAME with bounds")
    out: dict[str, tuple[float, float]] = {}
    for name, pair in fit.items():
        if name in NOT_FITTABLE:
            raise FDIError(f"fit {name}: cannot be identified (structural switch or grid); "
                           f"pick fault parameters such as {', '.join(DEFAULT_FIT)}")
        try:
            lo, hi = (float(v) for v in pair)
        except (TypeError, ValueError):
            raise FDIError(f"fit {name}: bounds must be two numbers (lower, upper), got "
                           f"{pair!r}") from None
        spec = SPECS.get(name)
        try:
            check_value(name, lo, "lf")
            check_value(name, hi, "lf")
        except ParameterError as exc:
            raise FDIError(f"fit bounds: {exc}") from None
        if not lo < hi:
            raise FDIError(f"fit {name}: lower bound {lo:g} must be below upper bound {hi:g} "
                           f"(allowed range {spec.range_text()})")
        out[name] = (lo, hi)
    return out


def default_bounds(names: Iterable[str]) -> dict[str, tuple[float, float]]:
    """:data:`SEARCH_BOUNDS` for the faults, else the parameter's allowed range."""
    out = {}
    for name in names:
        spec = SPECS.get(name)
        if spec is None:
            raise FDIError(f"fit {name}: unknown parameter (see `eha params --model lf`)")
        out[name] = SEARCH_BOUNDS.get(name, (spec.lo, spec.hi))
    return out


# --------------------------------------------------------------------------------------------
# objective


def objective_values(xu: np.ndarray, reference: np.ndarray, objective: str = "rmse"
                     ) -> np.ndarray:
    """Objective of each row of ``xu`` (shape ``(n, n_out)``) against ``reference`` [m]."""
    diff = xu - reference
    if objective == "rmse":
        return np.sqrt(np.mean(diff * diff, axis=-1))
    if objective == "objfcn":
        return np.mean(np.abs(diff), axis=-1)
    raise FDIError(f"objective {objective!r}: allowed {', '.join(OBJECTIVES)}")


def combined_objective(xu: np.ndarray, reference: np.ndarray, p12: np.ndarray,
                       reference_p12: np.ndarray, p12_weight: float, objective: str = "rmse"
                       ) -> np.ndarray:
    """Objective of position and load pressure together, in metres of position.

    ``p12_weight`` [m/Pa] converts the P12 residual into position: with ``sigma_xu /
    sigma_p12`` (the two sensors' noise) each sample of either signal counts by its noise, the
    least-squares form of the two measurements' joint likelihood.
    """
    a = objective_values(xu, reference, objective)
    b = objective_values(p12_weight * p12, p12_weight * reference_p12, objective)
    return np.sqrt(a * a + b * b) if objective == "rmse" else a + b


class BatchObjective:
    """Objective of unit-cube points: maps rows of ``U`` in [0, 1]^k to LF runs, one batch.

    Parameters
    ----------
    reference : float64 array
        Recorded xu [m] at 1 kHz.
    com : float64 array
        Command on the integration-step grid (sampled once per identification).
    names, bounds :
        Fitted parameters and their ``(lo, hi)``.
    base : LFParams
        Fixed parameters (effects switched on, ...).
    """

    def __init__(self, reference: np.ndarray, com: np.ndarray, steps_per_out: int, n_out: int,
                 names: Sequence[str], bounds: Mapping[str, tuple[float, float]],
                 base: LFParams, objective: str, recorded_start: float | None = None,
                 reference_p12: np.ndarray | None = None, p12_weight: float = 0.0):
        self.reference = np.ascontiguousarray(reference, dtype=np.float64)
        # measured P12 joins the objective only when it is given and weighted
        self.reference_p12 = (np.ascontiguousarray(reference_p12, dtype=np.float64)
                              if reference_p12 is not None and p12_weight > 0 else None)
        self.p12_weight = float(p12_weight)
        self.com = com
        self.steps_per_out = steps_per_out
        self.n_out = n_out
        self.base = base
        self.base_row = base.to_array()
        self.index = np.array([int(LF[n]) for n in names])
        self.lo = np.array([bounds[n][0] for n in names])
        self.span = np.array([bounds[n][1] - bounds[n][0] for n in names])
        self.objective = objective
        self.recorded_start = recorded_start
        self.evaluations = 0

    def physical(self, U: np.ndarray) -> np.ndarray:
        """Unit-cube points -> parameter values (clipped to the bounds)."""
        return self.lo + np.clip(U, 0.0, 1.0) * self.span

    def simulate(self, U: np.ndarray, with_p12: bool = False):
        """Recorded LF xu of each unit-cube point, shape ``(n, n_out)`` (with ``with_p12``
        the pair ``(xu, p12)``)."""
        U = np.atleast_2d(U)
        rows = np.tile(self.base_row, (U.shape[0], 1))
        rows[:, self.index] = self.physical(U)
        self.evaluations += U.shape[0]
        return simulate_lf_batch(rows, self.com, self.steps_per_out, self.n_out, self.base,
                                 self.recorded_start, with_p12=with_p12)

    def __call__(self, U: np.ndarray) -> np.ndarray:
        if self.reference_p12 is None:
            values = objective_values(self.simulate(U), self.reference, self.objective)
        else:
            xu, p12 = self.simulate(U, with_p12=True)
            values = combined_objective(xu, self.reference, p12, self.reference_p12,
                                        self.p12_weight, self.objective)
        # an unstable parameter set (NaN/inf trace) is simply the worst candidate
        return np.where(np.isfinite(values), values, np.inf)


# --------------------------------------------------------------------------------------------
# optimizers (all work in the unit cube and evaluate whole batches)


def _stalled(history: list[float], stall: int, ftol: float) -> bool:
    """Matlab-``ga``-like stop: relative improvement of the best over ``stall`` generations."""
    if len(history) <= stall:
        return False
    old, new = history[-1 - stall], history[-1]
    return old - new <= ftol * max(abs(old), 1e-300)


def _run_ga(obj: BatchObjective, k: int, pop: int, seed: int, max_gen: int, stall: int,
            ftol: float, max_evals: int, history: list[float],
            on_generation: Callable[[int, float], None] | None = None,
            x0: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    from pymoo.algorithms.soo.nonconvex.ga import GA
    from pymoo.core.problem import Problem
    from pymoo.termination.max_gen import MaximumGenerationTermination

    class _UnitCube(Problem):
        def __init__(self):
            super().__init__(n_var=k, n_obj=1, xl=np.zeros(k), xu=np.ones(k))

        def _evaluate(self, X, out, *args, **kwargs):
            out["F"] = obj(X)[:, None]   # the whole generation: one parallel numba call

    if x0 is None:
        algorithm = GA(pop_size=pop, eliminate_duplicates=True)
    else:   # first population: x0 and pop - 1 uniform points (seeded)
        first = np.random.default_rng(seed).random((pop, k))
        first[0] = x0
        algorithm = GA(pop_size=pop, sampling=first, eliminate_duplicates=True)
    algorithm.setup(_UnitCube(), termination=MaximumGenerationTermination(max_gen),
                    seed=int(seed), verbose=False)
    while algorithm.has_next():
        algorithm.next()
        history.append(float(algorithm.opt[0].F[0]))
        if on_generation is not None:
            on_generation(len(history), history[-1])
        if _stalled(history, stall, ftol) or obj.evaluations >= max_evals:
            break
    best = algorithm.opt[0]
    return np.array(best.X, dtype=np.float64), float(best.F[0])


def _pattern_search(obj: BatchObjective, x: np.ndarray, f: float, step0: float, xtol: float,
                    max_evals: int, history: list[float]) -> tuple[np.ndarray, float]:
    """Compass search: poll ``x ± step·e_i`` (one batch), move to the best improving point,
    else halve the step; stop below ``xtol`` or at the evaluation budget."""
    k = x.size
    step = step0
    eye = np.eye(k)
    while step >= xtol and obj.evaluations < max_evals:
        polls = np.clip(np.vstack([x + step * eye, x - step * eye]), 0.0, 1.0)
        polls = polls[np.any(polls != x, axis=1)]          # drop points clipped onto x
        if polls.shape[0] == 0:
            step *= 0.5
            continue
        values = obj(polls)
        i = int(np.argmin(values))
        if values[i] < f:
            x, f = polls[i], float(values[i])
        else:
            step *= 0.5
        history.append(f)
    return x, f


def _least_squares(obj: BatchObjective, x: np.ndarray, f: float, fd_step: float, xtol: float,
                   max_evals: int, history: list[float]) -> tuple[np.ndarray, float]:
    """Bounded least squares from ``x`` (scipy ``least_squares``, trust-region reflective).

    The residual vector of a unit-cube point is ``(e_xu, p12_weight * e_p12) / sqrt(n)``
    (its norm is the ``"rmse"`` objective), divided by the starting objective so that the
    solver's tolerances are scale-free. The Jacobian is one batch of k + 1 runs (the point and
    k forward differences, a backward one at the upper bound). A point whose run fails (not
    finite, or 1e3 times the start's residual) gets a large residual, so the solver rejects
    the step; a solver error returns ``x``; the result is never worse than ``x``. At most
    ``max_evals`` runs in all (``max_evals // (k + 2)`` iterations).
    """
    from scipy.optimize import least_squares

    k = x.size
    n = obj.reference.size
    scale = f if math.isfinite(f) and f > 0 else 1.0
    size = n if obj.reference_p12 is None else 2 * n

    worst = 1e3 / math.sqrt(size)          # residual of a failed run: norm 1e3 x the start

    def residuals(U: np.ndarray) -> np.ndarray:
        if obj.reference_p12 is None:
            r = obj.simulate(U) - obj.reference
        else:
            xu, p12 = obj.simulate(U, with_p12=True)
            r = np.concatenate([xu - obj.reference,
                                obj.p12_weight * (p12 - obj.reference_p12)], axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            r = r / (math.sqrt(n) * scale)
            # a diverged run (finite but huge) counts as failed like a NaN one: its
            # differences would overflow the Jacobian
            ok = np.isfinite(r).all(axis=1) & (np.abs(r).max(axis=1) < 1e3)
        return np.where(ok[:, None], r, worst)

    def fun(u: np.ndarray) -> np.ndarray:
        return residuals(u[None, :])[0]

    def jac(u: np.ndarray) -> np.ndarray:
        steps = np.where(u + fd_step <= 1.0, fd_step, -fd_step)
        R = residuals(np.vstack([u, u + np.diag(steps)]))
        return np.nan_to_num(((R[1:] - R[0]) / steps[:, None]).T)

    # each iteration is one residual and one Jacobian batch: k + 2 runs
    budget = max(int((max_evals - obj.evaluations) // (k + 2)), 1)
    try:
        sol = least_squares(fun, np.clip(x, 0.0, 1.0), jac=jac, bounds=(0.0, 1.0),
                            method="trf", x_scale="jac", xtol=xtol, ftol=1e-12, gtol=1e-12,
                            max_nfev=budget)
    except (ValueError, np.linalg.LinAlgError):
        # a solver failure (e.g. a degenerate Jacobian) leaves the start as the answer
        history.append(f)
        return x, f
    f_new = float(obj(sol.x[None, :])[0])
    history.append(min(f, f_new))
    return (sol.x, f_new) if f_new < f else (x, f)


# --------------------------------------------------------------------------------------------
# public API


def identify(reference_xu: np.ndarray, command: Command | str,
             fit: Mapping[str, Sequence[float]] | None = None,
             base: LFParams | None = None, method: str = DEFAULT_METHOD, pop: int = 20,
             seed: int = 0, objective: str = "rmse", t_end: float | None = None,
             on_generation: Callable[[int, float], None] | None = None,
             warm_start: bool = False, recorded_start: float | None = None,
             level: float | None = DEFAULT_LEVEL, noise: float | None = None,
             model_form: str | None = None, reference_p12: np.ndarray | None = None,
             p12_weight: float = 0.0, **options: float) -> FitResult:
    """Identify LF parameters from a recorded position trace.

    Parameters
    ----------
    reference_xu : float64 array
        Recorded control-surface position xu [m] at 1 kHz from t = 0 (same grid as the LF
        output: ``round(t_end/1e-3) + 1`` samples).
    command : Command or str
        The position command of the record (a preset name or e.g. an array command).
    fit : mapping name -> (lower, upper), optional
        LF parameters to identify and their search bounds (units of ``eha params``).
        Default: BKL in [0, 1.25e-3] m and FDJ in [200, 4000] N (the thesis' chirp cases).
    base : LFParams, optional
        Parameters held fixed (nominal LF by default; effects switched on, ...).
    method : {"ga", "ga+ps", "ps", "lm"}
        ``"ga"`` is the thesis' genetic algorithm; ``"ga+ps"`` adds a pattern-search polish;
        ``"ps"`` is the pattern search alone and ``"lm"`` a least-squares polish, both local,
        starting from the values of ``base`` (clipped into the bounds): ``pop`` and ``seed``
        are then unused.
    pop : int
        GA population size (thesis: 20, or 40 for case 12).
    seed : int
        Optimizer seed; the same seed gives the same result.
    objective : {"rmse", "objfcn"}
    t_end : float, optional
        Record length [s]; default ``(len(reference_xu) - 1)*1e-3``.
    on_generation : callable(generation, best_objective), optional
        Progress hook called after each GA generation.
    warm_start : bool
        Put the values of ``base`` (clipped into the bounds) in the GA's first population, so
        the result is never worse than that starting point (``"ps"`` always starts there).
    recorded_start : float, optional
        The LF model starts at rest where its recorded position (with the candidate's sensor
        bias and gain) is this value [m], instead of at ``base.XJ0``: for records that start
        away from their command.
    level : float or None
        Nominal coverage of the parameter intervals (default 0.9; None skips them: the
        residual loop's inner refits). Costs one batch of ``2k + 1`` LF runs.
    noise : float, optional
        Sensor noise of the record [m] (default: estimated from ``reference_xu``; give it when
        the record was resampled, :func:`eha.measured.noise_level` on the raw samples).
    model_form : str, optional
        Key of :data:`eha.intervals.MODEL_FORM` (default: recognised from ``base``).
    reference_p12 : float64 array, optional
        Measured load pressure P12 [Pa] on the grid of ``reference_xu``: with ``p12_weight``
        > 0 its residual joins the objective (:func:`combined_objective`).
    p12_weight : float
        Metres of position per pascal of P12 residual, >= 0 (0: P12 is not used), e.g.
        ``noise_xu / noise_p12``.
    **options
        Method options (:data:`METHOD_DEFAULTS`): max_gen, stall, ftol, step0, xtol,
        fd_step, max_evals.

    Returns
    -------
    FitResult
    """
    if method not in METHODS:
        raise FDIError(f"method {method!r}: allowed {', '.join(METHODS)}")
    if level is not None:
        from eha.intervals import check_level

        try:
            level = check_level(level)
        except ValueError as exc:
            raise FDIError(str(exc)) from None
    if objective not in OBJECTIVES:
        raise FDIError(f"objective {objective!r}: allowed {', '.join(OBJECTIVES)}")
    if method == "lm" and objective != "rmse":
        raise FDIError(f"method lm: a least-squares polish; objective {objective!r} is not a "
                       f"sum of squares (allowed: rmse)")
    if not isinstance(pop, (int, np.integer)) or not 4 <= pop <= 10000:
        raise FDIError(f"pop={pop}: allowed range [4, 10000] individuals")
    unknown = set(options) - set(METHOD_DEFAULTS[method])
    if unknown:
        raise FDIError(f"method {method}: unknown option {sorted(unknown)[0]!r}; allowed "
                       f"{', '.join(METHOD_DEFAULTS[method])}")
    opts = {**METHOD_DEFAULTS[method], **{k: float(v) for k, v in options.items()}}
    if method == "lm" and not 0.0 < opts["fd_step"] <= 0.1:
        raise FDIError(f"fd_step={opts['fd_step']:g}: allowed range (0, 0.1] of each range")
    bounds = check_bounds(fit if fit is not None else default_bounds(DEFAULT_FIT))
    names = tuple(bounds)
    base = base if base is not None else LFParams()
    if getattr(base, "model", None) != "lf":
        raise FDIError("base: an LF parameter set (eha.models.params.LFParams) is required")

    reference = np.asarray(reference_xu, dtype=np.float64)
    if reference.ndim != 1 or reference.size < 3 or not np.all(np.isfinite(reference)):
        raise FDIError("reference_xu: a finite 1-D array of at least 3 samples is required")
    if t_end is None:
        t_end = (reference.size - 1) * OUTPUT_DT
    try:
        steps_per_out, n_out, t_steps = grid(base, t_end)
    except ParameterError as exc:
        raise FDIError(str(exc)) from None
    if n_out != reference.size:
        raise FDIError(f"reference_xu: {reference.size} samples, but t_end={t_end:g} s at 1 kHz "
                       f"needs {n_out}")

    if not (math.isfinite(p12_weight) and p12_weight >= 0):
        raise FDIError(f"p12_weight={p12_weight}: allowed range [0, ...) m/Pa")
    if reference_p12 is not None and p12_weight > 0:
        reference_p12 = np.asarray(reference_p12, dtype=np.float64)
        if reference_p12.shape != reference.shape or not np.all(np.isfinite(reference_p12)):
            raise FDIError(f"reference_p12: a finite array of {reference.size} samples (the "
                           f"grid of reference_xu) is required")

    start = time.perf_counter()
    com = command_on_grid(as_command(command), t_steps)     # sampled once
    obj = BatchObjective(reference, com, steps_per_out, n_out, names, bounds, base, objective,
                         recorded_start, reference_p12, p12_weight)
    history: list[float] = []
    max_evals = int(opts["max_evals"])
    max_gen = int(opts.get("max_gen", 0)) or 100 * len(names)
    x_base = np.clip((np.array([getattr(base, n) for n in names]) - obj.lo) / obj.span,
                     0.0, 1.0)
    if method in ("ps", "lm"):
        x, f = x_base, float(obj(x_base[None, :])[0])
        history.append(f)
    else:
        x, f = _run_ga(obj, len(names), int(pop), seed, max_gen, int(opts["stall"]),
                       opts["ftol"], max_evals, history, on_generation,
                       x0=x_base if warm_start else None)
    if method in ("ga+ps", "ps"):
        x, f = _pattern_search(obj, x, f, opts["step0"], opts["xtol"], max_evals, history)
    elif method == "lm":
        x, f = _least_squares(obj, x, f, opts["fd_step"], opts["xtol"], max_evals, history)
    values = obj.physical(x[None, :])[0]
    extra: dict[str, Any] = {}
    if level is not None:
        from eha.intervals import estimate_intervals

        form = model_form if model_form is not None else model_form_of(base)
        iv = estimate_intervals(reference, obj.simulate, x, names, obj.lo, obj.span,
                                level=level, noise=noise, model_form=form)
        extra = {"level": iv.level, "intervals": iv.bounds, "std": iv.std,
                 "hac_std": iv.hac_std, "lag": iv.lag,
                 "flagged": iv.flagged, "noise_rmse": iv.noise_rmse, "model_form": form,
                 "notes": iv.notes}
    seconds = time.perf_counter() - start
    return FitResult(names=names, estimates={n: float(v) for n, v in zip(names, values)},
                     objective=float(f), objective_name=objective,
                     evaluations=int(obj.evaluations), seconds=float(seconds),
                     history=tuple(history), method=method, seed=int(seed), bounds=bounds,
                     options=opts, **extra)


def intervals_at(reference_xu: np.ndarray, command: Command | str, params: LFParams,
                 bounds: Mapping[str, Sequence[float]], level: float = DEFAULT_LEVEL,
                 noise: float | None = None, recorded_start: float | None = None,
                 t_end: float | None = None, model_form: str | None = None,
                 terms: Mapping[str, Any] | None = None):
    """Intervals of the parameters ``bounds`` names at the values in ``params`` (an estimate
    found elsewhere, e.g. the final model of the residual loop), without refitting: one batch
    of ``2k + 1`` LF runs (:func:`eha.intervals.estimate_intervals`; ``terms``: its model-form
    terms, default those of ``model_form``)."""
    from eha.intervals import estimate_intervals

    bounds = check_bounds(bounds)
    names = tuple(bounds)
    reference = np.asarray(reference_xu, dtype=np.float64)
    if t_end is None:
        t_end = (reference.size - 1) * OUTPUT_DT
    steps_per_out, n_out, t_steps = grid(params, t_end)
    obj = BatchObjective(reference, command_on_grid(as_command(command), t_steps),
                         steps_per_out, n_out, names, bounds, params, "rmse", recorded_start)
    x = np.clip((np.array([getattr(params, n) for n in names]) - obj.lo) / obj.span, 0.0, 1.0)
    return estimate_intervals(reference, obj.simulate, x, names, obj.lo, obj.span, level=level,
                              noise=noise, model_form=model_form if model_form is not None
                              else model_form_of(params), terms=terms)


def hf_reference(command: Command | str, faults: Mapping[str, float] | None = None,
                 seed: int = 0, t_end: float = 1.0) -> Trace:
    """The HF run with injected ``faults`` (``{"BKL": 1e-4, "FDJ": 800}``) used as reference.

    ``seed`` drives the HF dither (its only random input).
    """
    return simulate("hf", command, dict(faults or {}), t_end=t_end, seed=seed)


def percent_errors(truth: Mapping[str, float], estimates: Mapping[str, float]
                   ) -> dict[str, float]:
    """Thesis percent error ``(input - output)/input*100`` per fitted parameter (0 when the
    input is 0, as in the thesis' Figure 6.17)."""
    out = {}
    for name, est in estimates.items():
        true = float(truth.get(name, LFParams().as_dict()[name]))
        out[name] = 0.0 if true == 0.0 else 100.0 * (true - est) / true
    return out


def mean_error_pct(errors: Mapping[str, float]) -> float:
    """Thesis mean error: the mean of the absolute percent errors (``(|BKL| + |FDJ|)/2``)."""
    return float(np.mean([abs(v) for v in errors.values()])) if errors else math.nan


# --------------------------------------------------------------------------------------------
# one identification from the command line (eha fdi)


def parse_bounds(items: Iterable[str]) -> dict[str, tuple[float, float]]:
    """Parse ``NAME=LO:HI`` strings (``BKL=0:1.25e-3``) into bounds (validated later).

    Raises
    ------
    FDIError
        A malformed item, in :func:`eha.models.params.parse_name_value`'s words.
    """
    out: dict[str, tuple[float, float]] = {}
    for item in items:
        try:
            name, rng = parse_name_value(item, "--bounds", "LO:HI")
        except ParameterError as exc:
            raise FDIError(str(exc)) from None
        out[name] = rng
    return out


@dataclass(frozen=True)
class Identification:
    """One identification against a reference: the fit, the reference and the fitted trace.

    ``truth``/``errors_pct``/``mean_err_pct`` are set only for HF references (known faults).
    """

    result: FitResult
    reference: Trace
    fitted: Trace
    source: str
    truth: dict[str, float] | None = None
    errors_pct: dict[str, float] | None = None
    mean_err_pct: float | None = None

    base_model: str = "plain"
    #: how a measured record's command was rebuilt between samples (None for HF references)
    command_hold: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, **self.result.to_dict(), "truth": self.truth,
                "errors_pct": self.errors_pct, "mean_err_pct": self.mean_err_pct,
                "base_model": self.base_model, "command_hold": self.command_hold}


def identify_source(command: str | None = None, faults: Mapping[str, float] | None = None,
                    data: str | Path | None = None, fit: Sequence[str] = DEFAULT_FIT,
                    bounds: Mapping[str, Sequence[float]] | None = None,
                    base: Mapping[str, float] | None = None, method: str = DEFAULT_METHOD,
                    pop: int = 20, seed: int = 0, objective: str = "rmse",
                    t_end: float = 1.0,
                    on_generation: Callable[[int, float], None] | None = None,
                    level: float | None = DEFAULT_LEVEL, base_model: str | None = None,
                    command_hold: str = "auto", **options: float) -> Identification:
    """Identify ``fit`` against an HF reference (``command`` + injected ``faults``, dither seed
    ``seed``) or a measured record (``data``: CSV/Parquet with t, com, xu; eha.measured).

    ``bounds`` overrides :func:`default_bounds` per name; ``base`` holds LF parameters fixed
    on top of ``base_model`` (:data:`BASE_MODELS`; default :data:`DEFAULT_BASE_MODEL`: the
    thesis' plain LF against an HF reference, the calibrated LF on a measured record, where the
    plain LF biases FDJ by 4-25 %); ``level`` is the intervals' nominal coverage;
    ``command_hold`` how a measured record's command is rebuilt between its samples
    (:data:`eha.measured.COMMAND_HOLDS`); ``on_generation`` is :func:`identify`'s progress hook.
    """
    if (command is None) == (data is None):
        raise FDIError("give either --command (HF reference) or --data FILE (measured record)")
    names = tuple(dict.fromkeys(fit))
    if not names:
        raise FDIError("--fit: name at least one LF parameter, e.g. BKL,FDJ")
    extra = set(bounds or {}) - set(names)
    if extra:
        raise FDIError(f"--bounds {sorted(extra)[0]}: not among the fitted parameters "
                       f"({', '.join(names)})")
    chosen = {**default_bounds(names), **{k: tuple(v) for k, v in (bounds or {}).items()}}
    if base_model is None:
        base_model = DEFAULT_BASE_MODEL["data" if data is not None else "hf"]
    if base_model not in BASE_MODELS:
        raise FDIError(f"--base-model {base_model!r}: allowed {', '.join(BASE_MODELS)}")
    try:
        lf_base = resolve("lf", {**BASE_MODELS[base_model], **dict(base or {})})
    except ParameterError as exc:
        raise FDIError(f"--base {exc}") from None
    noise = None
    truth = None
    hold = None
    if data is not None:
        from eha.measured import load

        rec = load(data, command_hold=command_hold)
        hold = rec.info["command_hold"]
        cmd: Command = rec.command
        ref_data = np.full((len(rec), 9), np.nan)
        from eha.models import O_COM, O_T, O_XU

        ref_data[:, O_T], ref_data[:, O_COM], ref_data[:, O_XU] = rec.t, rec.com, rec.xu
        reference = Trace(ref_data, {"model": "measured", "source": str(data),
                                     "command": cmd.describe(), "params": {}})
        t_end, source = rec.t_end, str(data)
        noise = rec.info.get("noise_m")    # on the raw samples, before resampling
    else:
        cmd = as_command(command)
        reference = hf_reference(cmd, faults, seed=seed, t_end=t_end)
        hf = reference.meta["params"]
        truth = {n: float(hf.get(n, resolve("hf").as_dict().get(n, math.nan))) for n in names}
        source = f"HF {command} " + (", ".join(f"{k}={v:g}" for k, v in (faults or {}).items())
                                     or "nominal") + f", seed {seed}"
    res = identify(reference.xu, cmd, chosen, base=lf_base, method=method, pop=pop, seed=seed,
                   objective=objective, t_end=t_end, on_generation=on_generation, level=level,
                   noise=noise, **options)
    fitted = simulate("lf", cmd, lf_base.replace(**res.estimates), t_end=t_end)
    errors = mean = None
    if truth is not None:
        errors = percent_errors(truth, res.estimates)
        mean = mean_error_pct(errors)
    return Identification(res, reference, fitted, source, truth, errors, mean, base_model, hold)
