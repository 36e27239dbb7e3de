"""The identification problem: methods, objectives, fitted parameters and their bounds, the
named LF bases, the method options and the result of one fit (:class:`FitResult`).

What :func:`eha.identification.fdi.identify` is asked to do and what it answers; the search
itself is :mod:`eha.identification.optimizers`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Mapping, Sequence

from eha.errors import InputError
from eha.models.bounds import Bounds
from eha.models.estimate import Estimate, Interval, estimates, intervals_json
from eha.models.faults import Derived, search_bounds
from eha.models.params import SPECS, LFParams, ParameterError, check_value, resolve

#: Identification methods (see :mod:`eha.identification.fdi`).
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
#: Default search bounds of the fault parameters (the thesis reproduction's): declared with each
#: fault (:attr:`eha.models.faults.Fault.fdi_bounds`, docs/health.md), read live from the registry.
SEARCH_BOUNDS: Mapping[str, tuple[float, float]] = Derived(search_bounds, "SEARCH_BOUNDS")
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


class FDIError(InputError):
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
        ``name -> (lo, hi)``: interval of each estimate at ``level`` (eha.identification.intervals).
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
        Which measured model-form terms entered the intervals
        (eha.identification.intervals.MODEL_FORM).
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
    bounds: Bounds
    options: dict[str, float] = field(default_factory=dict)
    level: float | None = None
    intervals: dict[str, Interval] = field(default_factory=dict)
    std: dict[str, float] = field(default_factory=dict)
    hac_std: dict[str, float] = field(default_factory=dict)
    lag: int | None = None
    flagged: bool = False
    noise_rmse: float | None = None
    model_form: str = "none"
    notes: tuple[str, ...] = ()

    def as_estimates(self) -> dict[str, Estimate]:
        """Each fitted parameter's :class:`~eha.models.estimate.Estimate`: value, interval at
        :attr:`level` (NaN where none was computed), std, SI unit."""
        return estimates(self.estimates, self.intervals, self.level, self.std)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (lists instead of tuples)."""
        d = asdict(self)
        d["names"] = list(self.names)
        d["history"] = list(self.history)
        d["bounds"] = Bounds(self.bounds).to_dict()
        d["intervals"] = intervals_json(self.as_estimates())
        d["notes"] = list(self.notes)
        return d


# --------------------------------------------------------------------------------------------
# validation


def check_bounds(fit: Mapping[str, Sequence[float]]) -> Bounds:
    """Validate search bounds: LF parameter names, ``lo < hi``, both inside the allowed range.

    Raises
    ------
    FDIError
        One line naming the parameter and its allowed range.
    """
    if not fit:
        raise FDIError("fit: no parameter to identify; give at least one NAME with bounds")
    out = Bounds()
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


def default_bounds(names: Iterable[str]) -> Bounds:
    """:data:`SEARCH_BOUNDS` for the faults, else the parameter's allowed range
    (:func:`eha.models.faults.search_bounds`)."""
    try:
        return search_bounds(list(names), "fdi")
    except ParameterError as exc:
        raise FDIError(str(exc)) from None

