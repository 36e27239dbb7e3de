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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from eha.identification.intervals import check_level, estimate_intervals
from eha.identification.measured import load
from eha.identification.optimizers import (BatchObjective, least_squares_polish, pattern_search,
                                           run_ga)
from eha.models.bounds import Bounds
from eha.identification.problem import (BASE_MODELS, DEFAULT_BASE_MODEL, DEFAULT_FIT,
                                        DEFAULT_LEVEL, DEFAULT_METHOD, METHOD_DEFAULTS, METHODS,
                                        OBJECTIVES, FDIError, FitResult, check_bounds,
                                        default_bounds, model_form_of)
from eha.models import O_COM, O_T, O_XU
from eha.models.commands import Command, as_command
from eha.models.params import LFParams, ParameterError, parse_name_value, resolve
from eha.models.simulate import OUTPUT_DT, Trace, command_on_grid, grid, simulate

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
        the record was resampled, :func:`eha.identification.measured.noise_level` on the raw
        samples).
    model_form : str, optional
        Key of :data:`eha.identification.intervals.MODEL_FORM` (default: recognised from ``base``).
    reference_p12 : float64 array, optional
        Measured load pressure P12 [Pa] on the grid of ``reference_xu``: with ``p12_weight``
        > 0 its residual joins the objective
        (:func:`eha.identification.optimizers.combined_objective`).
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
    opts, level = _method_options(method, objective, pop, level, options)
    bounds = check_bounds(fit if fit is not None else default_bounds(DEFAULT_FIT))
    names = tuple(bounds)
    base = base if base is not None else LFParams()
    if getattr(base, "model", None) != "lf":
        raise FDIError("base: an LF parameter set (eha.models.params.LFParams) is required")
    reference, reference_p12, (steps_per_out, n_out, t_steps) = _check_reference(
        reference_xu, reference_p12, p12_weight, t_end, base)

    start = time.perf_counter()
    com = command_on_grid(as_command(command), t_steps)     # sampled once
    obj = BatchObjective(reference, com, steps_per_out, n_out, names, bounds, base, objective,
                         recorded_start, reference_p12, p12_weight)
    history: list[float] = []
    x, f = _search(obj, method, opts, base, names, int(pop), seed, warm_start, on_generation,
                   history)
    values = obj.physical(x[None, :])[0]
    extra: dict[str, Any] = {}
    if level is not None:
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


def _method_options(method: str, objective: str, pop: int, level: float | None,
                    options: Mapping[str, float]) -> tuple[dict[str, float], float | None]:
    """The method's options (:data:`METHOD_DEFAULTS` updated by ``options``) and the checked
    interval level, after checking the method, the objective and the population;
    :class:`FDIError` otherwise."""
    if method not in METHODS:
        raise FDIError(f"method {method!r}: allowed {', '.join(METHODS)}")
    if level is not None:
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
    return opts, level


def _check_reference(reference_xu: np.ndarray, reference_p12: np.ndarray | None,
                     p12_weight: float, t_end: float | None, base: LFParams
                     ) -> tuple[np.ndarray, np.ndarray | None, tuple[int, int, int]]:
    """The reference as float arrays and the simulation grid of ``base`` over the record
    (``t_end`` by default from its samples, :func:`eha.models.simulate.grid`);
    :class:`FDIError` on a reference that is not finite or off that grid."""
    reference = np.asarray(reference_xu, dtype=np.float64)
    if reference.ndim != 1 or reference.size < 3 or not np.all(np.isfinite(reference)):
        raise FDIError("reference_xu: a finite 1-D array of at least 3 samples is required")
    if t_end is None:
        t_end = (reference.size - 1) * OUTPUT_DT
    try:
        on_grid = grid(base, t_end)
    except ParameterError as exc:
        raise FDIError(str(exc)) from None
    if on_grid[1] != reference.size:
        raise FDIError(f"reference_xu: {reference.size} samples, but t_end={t_end:g} s at 1 kHz "
                       f"needs {on_grid[1]}")
    if not (math.isfinite(p12_weight) and p12_weight >= 0):
        raise FDIError(f"p12_weight={p12_weight}: allowed range [0, ...) m/Pa")
    if reference_p12 is not None and p12_weight > 0:
        reference_p12 = np.asarray(reference_p12, dtype=np.float64)
        if reference_p12.shape != reference.shape or not np.all(np.isfinite(reference_p12)):
            raise FDIError(f"reference_p12: a finite array of {reference.size} samples (the "
                           f"grid of reference_xu) is required")
    return reference, reference_p12, on_grid


def _search(obj: BatchObjective, method: str, opts: Mapping[str, float], base: LFParams,
            names: Sequence[str], pop: int, seed: int, warm_start: bool,
            on_generation: Callable[[int, float], None] | None, history: list[float]
            ) -> tuple[np.ndarray, float]:
    """Run ``method`` on ``obj``; the best unit-cube point and its objective (``history``
    gets the best objective after each generation or poll)."""
    max_evals = int(opts["max_evals"])
    max_gen = int(opts.get("max_gen", 0)) or 100 * len(names)
    x_base = np.clip((np.array([getattr(base, n) for n in names]) - obj.lo) / obj.span,
                     0.0, 1.0)
    if method in ("ps", "lm"):
        x, f = x_base, float(obj(x_base[None, :])[0])
        history.append(f)
    else:
        x, f = run_ga(obj, len(names), pop, seed, max_gen, int(opts["stall"]), opts["ftol"],
                      max_evals, history, on_generation, x0=x_base if warm_start else None)
    if method in ("ga+ps", "ps"):
        x, f = pattern_search(obj, x, f, opts["step0"], opts["xtol"], max_evals, history)
    elif method == "lm":
        x, f = least_squares_polish(obj, x, f, opts["fd_step"], opts["xtol"], max_evals,
                                    history)
    return x, f


def intervals_at(reference_xu: np.ndarray, command: Command | str, params: LFParams,
                 bounds: Mapping[str, Sequence[float]], level: float = DEFAULT_LEVEL,
                 noise: float | None = None, recorded_start: float | None = None,
                 t_end: float | None = None, model_form: str | None = None,
                 terms: Mapping[str, Any] | None = None):
    """Intervals of the parameters ``bounds`` names at the values in ``params`` (an estimate
    found elsewhere, e.g. the final model of the residual loop), without refitting: one batch
    of ``2k + 1`` LF runs (:func:`eha.identification.intervals.estimate_intervals`; ``terms``: its
    model-form terms, default those of ``model_form``)."""
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


def parse_bounds(items: Iterable[str]) -> Bounds:
    """Parse ``NAME=LO:HI`` strings (``BKL=0:1.25e-3``) into bounds (validated later).

    Raises
    ------
    FDIError
        A malformed item, in :func:`eha.models.params.parse_name_value`'s words.
    """
    out = Bounds()
    for item in items:
        try:
            name, rng = parse_name_value(item, "`bounds`", "LO:HI")
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

    def to_pandas(self):
        """One row per fitted parameter: its unit (SI, as ``eha params``), estimate, interval
        (NaN when none was computed), the truth and the error in % of it (HF references)."""
        from eha.models.estimate import frame

        return frame(self.result.as_estimates(), key="parameter",
                     columns=("unit", "estimate", "lo", "hi"),
                     extra={"truth": self.truth or {}, "error_pct": self.errors_pct or {}})

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
    ``seed``) or a measured record (``data``: CSV/Parquet with t, com, xu;
    eha.identification.measured).

    ``bounds`` overrides :func:`default_bounds` per name; ``base`` holds LF parameters fixed
    on top of ``base_model`` (:data:`BASE_MODELS`; default :data:`DEFAULT_BASE_MODEL`: the
    thesis' plain LF against an HF reference, the calibrated LF on a measured record, where the
    plain LF biases FDJ by 4-25 %); ``level`` is the intervals' nominal coverage;
    ``command_hold`` how a measured record's command is rebuilt between its samples
    (:data:`eha.identification.measured.COMMAND_HOLDS`); ``on_generation`` is :func:`identify`'s
    progress hook.
    """
    if (command is None) == (data is None):
        raise FDIError("give either `command` (HF reference) or `data` (a measured record file)")
    names = tuple(dict.fromkeys(fit))
    if not names:
        raise FDIError("`fit`: name at least one LF parameter, e.g. BKL,FDJ")
    extra = set(bounds or {}) - set(names)
    if extra:
        raise FDIError(f"`bounds` {sorted(extra)[0]}: not among the fitted parameters "
                       f"({', '.join(names)})")
    chosen = {**default_bounds(names), **{k: tuple(v) for k, v in (bounds or {}).items()}}
    if base_model is None:
        base_model = DEFAULT_BASE_MODEL["data" if data is not None else "hf"]
    if base_model not in BASE_MODELS:
        raise FDIError(f"`base_model` {base_model!r}: allowed {', '.join(BASE_MODELS)}")
    try:
        lf_base = resolve("lf", {**BASE_MODELS[base_model], **dict(base or {})})
    except ParameterError as exc:
        raise FDIError(f"`base` {exc}") from None
    noise = None
    truth = None
    hold = None
    if data is not None:
        rec = load(data, command_hold=command_hold)
        hold = rec.info["command_hold"]
        cmd: Command = rec.command
        ref_data = np.full((len(rec), 9), np.nan)
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
