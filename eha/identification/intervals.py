"""Intervals on identified parameters: how far the truth may be from an estimate.

An identification (:func:`eha.identification.fdi.identify`) minimises the RMSE between the LF model
and a record. Its estimate is wrong for three reasons, and the interval accounts for each:

1. **Sensor noise** (white, estimated from the record's fourth differences,
   :func:`eha.identification.measured.noise_level`).
2. **What the LF model cannot reproduce** — the HF dither, unmodelled effects, faults that were
   not fitted, model-form error. It shows up as a residual that is larger than the noise and
   strongly autocorrelated (tens of ms). We treat the residual as one realisation of a
   stationary discrepancy process: the part of that process that lies along the model's
   sensitivities has been absorbed by the estimate, and its variance is what a
   heteroscedasticity-and-autocorrelation-consistent (HAC, Newey–West) sandwich estimates:

       Cov = (JᵀJ)⁻¹ · S · (JᵀJ)⁻¹,   S = Σ_l w_l Σ_t g_t g_{t-l}ᵀ,   g_t = J_t r_t

   with Bartlett weights ``w_l = 1 - |l|/(L+1)`` and a bandwidth ``L`` set from the residual's
   own correlation time (:func:`bandwidth`). A residual near the noise gives a narrow interval,
   a residual far above it a wide one — and the fit is *flagged*.
3. **Structural bias of the model** that stays hidden in the residual (the plain LF model's
   linear pressure law makes the fit read FDJ about 4 % high at an RMSE equal to the noise).
   It is measured on HF records with known truth (``validation/intervals.py
   --calibrate``) and enters as a relative and an absolute floor per parameter
   (:data:`MODEL_FORM`), added in quadrature.

The half-width is ``z · sqrt(k² σ_HAC² + (rel·θ)² + abs²)`` with ``z`` the two-sided normal
quantile of the level and ``k`` a per-parameter scale measured with the floors; intervals are
clipped to the search bounds. Coverage is measured, not assumed: docs/health.md.

Why not the alternatives (measured, docs/health.md): the white-noise Laplace approximation
(Fisher information with σ = noise) covered FDJ in a few percent of records; posterior sampling
(emcee) costs hundreds of LF runs per record for the same Gaussian-likelihood answer and still
needs the model-form term; a parametric bootstrap over noise and dither needs a refit per
replicate (≥ 20 s per record).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from eha.models.estimate import Interval
from eha.models.faults import Derived, model_form_floors

#: Default confidence level of every interval.
DEFAULT_LEVEL = 0.9
#: A fit is flagged (the model does not explain the record) when its residual RMSE exceeds
#: this multiple of the record's noise level.
FLAG_RATIO = 3.0
#: Residual-to-noise ratio from which the intervals widen: ``std *= max(1, excess /
#: INFLATION_START) ** INFLATION_POWER``. The HAC term treats the residual as stationary noise;
#: a residual far above the noise is structure the model lacks, whose pull on the estimates is
#: larger than its variance suggests (measured on records with an unfitted fault, docs/health.md).
INFLATION_START = 1.5
INFLATION_POWER = 1.5
#: Smallest noise level that the flag and the widening compare the residual with, as a fraction
#: of the record's position spread (an ideal 13-bit position sensor): a noise-free simulated
#: record is not flagged for a model-form residual of a few 1e-5 of its stroke.
NOISE_FLOOR = 1e-4
#: Step of the central differences in the unit cube (fraction of each search range).
JACOBIAN_STEP = 2e-3


def noise_reference(noise: float, reference: np.ndarray) -> float:
    """The noise level [m] a residual is compared with: the record's, floored at
    :data:`NOISE_FLOOR` of its spread."""
    return max(float(noise), NOISE_FLOOR * float(np.std(reference)))


def is_flagged(rmse: float, noise_ref: float) -> bool:
    """Does a residual of ``rmse`` [m] leave the record unexplained (above :data:`FLAG_RATIO`
    times ``noise_ref``, :func:`noise_reference`)?"""
    return bool(noise_ref > 0 and rmse > FLAG_RATIO * noise_ref)


@dataclass(frozen=True)
class ModelForm:
    """Model-form uncertainty of one parameter, measured on HF records with known truth.

    ``scale`` multiplies the HAC standard deviation; ``rel`` (fraction of the estimate) and
    ``abs`` (parameter unit) are floors added in quadrature.
    """

    scale: float = 1.0
    rel: float = 0.0
    abs: float = 0.0


def _model_form() -> dict[str, dict[str, ModelForm]]:
    return {base: {name: ModelForm(rel=rel, abs=abs_) for name, (rel, abs_) in floors.items()}
            for base, floors in model_form_floors().items()}


#: Measured model-form terms per LF base ("plain" = the thesis' LF, "calibrated" = the LF with
#: the effects eha explain found on a healthy-actuator load test) and parameter, declared with
#: each fault (:attr:`eha.models.faults.Fault.model_form`, where their sources are). Source:
#: ``python validation/intervals.py --calibrate`` on calibration records (seeds apart
#: from the benchmark's); see docs/health.md. Parameters absent here get ModelForm().
MODEL_FORM: Mapping[str, dict[str, ModelForm]] = Derived(_model_form, "MODEL_FORM")


#: Model-form floor of a model the residual loop built (``eha explain`` with effects added):
#: relative, in quadrature with the base's terms, on every fitted parameter (the faults and
#: each added effect's). The LF with the right effects is still not the HF: at the best fit of
#: the right model its estimates are biased by a few tenths of a percent to a few percent,
#: more than the HAC term allows at a residual near the noise. Source: ``python
#: validation/explain_coverage.py --calibrate`` (docs/explain.md).
LOOP_MODEL_FORM = ModelForm(rel=0.0075)


def loop_terms(terms: Mapping[str, ModelForm], names: Sequence[str],
               floor: ModelForm = LOOP_MODEL_FORM) -> dict[str, ModelForm]:
    """``terms`` (a base's, :data:`MODEL_FORM`) with ``floor`` (default
    :data:`LOOP_MODEL_FORM`) added to every parameter of ``names``: scales multiplied, floors
    in quadrature."""
    out = {}
    for name in names:
        t = terms.get(name, ModelForm())
        out[name] = ModelForm(scale=t.scale * floor.scale, rel=math.hypot(t.rel, floor.rel),
                              abs=math.hypot(t.abs, floor.abs))
    return out


def inflation(excess: float) -> float:
    """Widening factor of a fit whose residual RMSE is ``excess`` times the noise."""
    return max(1.0, excess / INFLATION_START) ** INFLATION_POWER


def total_std(hac: float, value: float, term: ModelForm, widen: float = 1.0) -> float:
    """Standard uncertainty of one estimate: the HAC part scaled, the model-form floors in
    quadrature, all widened by :func:`inflation` (the one definition, used by the intervals
    and by their calibration in validation/intervals.py)."""
    if not math.isfinite(hac):
        return math.inf
    return widen * math.sqrt((term.scale * hac) ** 2 + (term.rel * value) ** 2 + term.abs ** 2)


def normal_quantile(level: float) -> float:
    """Two-sided standard-normal quantile ``z`` with ``P(|Z| <= z) = level``."""
    from statistics import NormalDist

    return NormalDist().inv_cdf(0.5 + level / 2.0)


def check_level(level: Any) -> float:
    """Validate an interval level; one-line ValueError outside (0, 1)."""
    if isinstance(level, bool) or not isinstance(level, (int, float)) or \
            not math.isfinite(float(level)) or not 0.0 < float(level) < 1.0:
        raise ValueError(f"level={level!r}: allowed range (0, 1), e.g. 0.9")
    return float(level)


def bandwidth(residual: np.ndarray, max_lag: int | None = None) -> int:
    """HAC bandwidth [samples] from the residual's correlation time.

    Twice the integrated autocorrelation time, summing the autocorrelation until it first
    drops below 0.05 (Sokal's window in its simplest form); at least 1, at most n/4.
    """
    r = np.asarray(residual, dtype=np.float64)
    r = r - r.mean()
    n = r.size
    max_lag = max_lag or max(1, n // 4)
    var = float(np.dot(r, r))
    if var <= 0.0:
        return 1
    spec = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(spec * np.conj(spec))[: max_lag + 1] / var
    tau = 1.0
    for lag in range(1, max_lag + 1):
        if acf[lag] < 0.05:
            break
        tau += 2.0 * acf[lag]
    return int(min(max_lag, max(1, math.ceil(2.0 * tau))))


def effective_samples(residual: np.ndarray) -> float:
    """Effective independent samples of a correlated residual: ``n / (bandwidth / 2)``, the
    record length over the integrated autocorrelation time (:func:`bandwidth`); at least 2."""
    r = np.asarray(residual, dtype=np.float64)
    return float(max(2.0, r.size / max(1.0, bandwidth(r) / 2.0)))


def hac_covariance(jac: np.ndarray, residual: np.ndarray, lag: int) -> np.ndarray:
    """Newey–West sandwich covariance of a least-squares estimate.

    Parameters
    ----------
    jac : array (n, k)
        Sensitivity of the model output to each parameter [m per parameter unit].
    residual : array (n,)
        Record minus model at the estimate [m].
    lag : int
        Bartlett bandwidth [samples].

    Returns
    -------
    array (k, k)
        Covariance of the estimate [parameter units²]; NaN where JᵀJ is singular.
    """
    g = jac * residual[:, None]
    meat = g.T @ g
    for lag_i in range(1, lag + 1):
        w = 1.0 - lag_i / (lag + 1.0)
        gamma = g[lag_i:].T @ g[:-lag_i]
        meat += w * (gamma + gamma.T)
    bread = jac.T @ jac
    try:
        inv = np.linalg.inv(bread)
    except np.linalg.LinAlgError:
        return np.full_like(bread, np.nan)
    return inv @ meat @ inv


@dataclass(frozen=True)
class Intervals:
    """Intervals of one identification.

    Attributes
    ----------
    level : float
        Nominal coverage of every interval (e.g. 0.9).
    bounds : dict
        ``name -> (lo, hi)``: the interval of each estimate at ``level`` (not a search
        bound), in the parameter's unit.
    std : dict
        Standard uncertainty of each estimate (HAC, scaled, with the model-form floors).
    hac_std : dict
        The HAC part alone.
    noise_rmse : float
        Sensor noise estimated from the record [m].
    residual_rmse : float
        RMSE of the fit [m].
    lag : int
        HAC bandwidth used [samples].
    flagged : bool
        Residual above :data:`FLAG_RATIO` times the noise: the model does not explain the
        record; the intervals are wide and the estimates are not to be trusted as numbers.
    model_form : str
        Key of :data:`MODEL_FORM` used (``"plain"``, ``"calibrated"`` or ``"none"``).
    """

    level: float
    bounds: dict[str, Interval]
    std: dict[str, float]
    hac_std: dict[str, float]
    noise_rmse: float
    residual_rmse: float
    lag: int
    flagged: bool
    model_form: str = "none"
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def excess(self) -> float:
        """Residual RMSE over the noise level (1 = explained down to the noise)."""
        return self.residual_rmse / self.noise_rmse if self.noise_rmse > 0 else math.inf


def jacobian(simulate_unit: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
             span: np.ndarray, step: float = JACOBIAN_STEP) -> tuple[np.ndarray, np.ndarray]:
    """Model output and its sensitivities at unit-cube point ``x``, in ONE batched call.

    Central differences ``x ± step·e_i`` (one-sided where a bound is reached).

    Returns
    -------
    y0 : array (n,)
        Output at ``x`` [m].
    jac : array (n, k)
        d output / d parameter [m per parameter unit].
    """
    k = x.size
    plus = np.clip(x + step * np.eye(k), 0.0, 1.0)
    minus = np.clip(x - step * np.eye(k), 0.0, 1.0)
    ys = simulate_unit(np.vstack([x[None, :], plus, minus]))
    y0 = ys[0]
    jac = np.empty((y0.size, k))
    for i in range(k):
        du = plus[i, i] - minus[i, i]
        jac[:, i] = (ys[1 + i] - ys[1 + k + i]) / (du * span[i]) if du > 0 else 0.0
    return y0, jac


def estimate_intervals(reference: np.ndarray, simulate_unit: Callable[[np.ndarray], np.ndarray],
                       x: np.ndarray, names: Sequence[str], lo: np.ndarray, span: np.ndarray,
                       level: float = DEFAULT_LEVEL, noise: float | None = None,
                       model_form: str = "none",
                       terms: Mapping[str, ModelForm] | None = None) -> Intervals:
    """Intervals at an estimate ``x`` (unit cube) of a fit to ``reference``.

    Parameters
    ----------
    reference : array (n,)
        Recorded position [m].
    simulate_unit : callable
        Unit-cube points (m, k) -> recorded LF outputs (m, n) in one batch.
    x : array (k,)
        The estimate in the unit cube.
    names, lo, span :
        Parameter names and the bounds ``lo + x·span``.
    level : float
        Nominal coverage.
    noise : float, optional
        Sensor noise [m]; default estimated from ``reference``.
    model_form : str
        Key of :data:`MODEL_FORM` (recorded in the result).
    terms : mapping, optional
        Model-form terms per parameter; default ``MODEL_FORM.get(model_form, {})``.
    """
    from eha.identification.measured import noise_level

    level = check_level(level)
    reference = np.asarray(reference, dtype=np.float64)
    y0, jac = jacobian(simulate_unit, np.asarray(x, dtype=np.float64), np.asarray(span))
    resid = reference - y0
    noise = float(noise_level(reference) if noise is None else noise)
    if not np.all(np.isfinite(resid)):
        # the estimate itself is unstable (NaN/inf trace): nothing is known
        full = {n: (float(lo[i]), float(lo[i] + span[i])) for i, n in enumerate(names)}
        inf = {n: math.inf for n in names}
        return Intervals(level=level, bounds=full, std=inf, hac_std=inf, noise_rmse=noise,
                         residual_rmse=math.inf, lag=0, flagged=True, model_form=model_form,
                         notes=("the model is unstable at the estimate: no interval",))
    rmse = float(np.sqrt(np.mean(resid * resid)))
    noise_ref = noise_reference(noise, reference)
    lag = bandwidth(resid)
    notes: list[str] = []
    active = np.any(jac != 0.0, axis=0) & np.all(np.isfinite(jac), axis=0)
    cov = np.full((len(names), len(names)), np.nan)
    if active.any():
        sub = hac_covariance(jac[:, active], resid, lag)
        cov[np.ix_(active, active)] = sub
    terms = MODEL_FORM.get(model_form, {}) if terms is None else terms
    widen = inflation(rmse / noise_ref if noise_ref > 0 else 1.0)
    z = normal_quantile(level)
    values = lo + np.clip(x, 0.0, 1.0) * span
    out_bounds, std, hac_std = {}, {}, {}
    for i, name in enumerate(names):
        hac = math.sqrt(cov[i, i]) if np.isfinite(cov[i, i]) and cov[i, i] >= 0 else math.nan
        term = terms.get(name, ModelForm())
        if not math.isfinite(hac):
            # the record carries no information on this parameter: the whole search range
            notes.append(f"{name}: the record does not constrain it (no sensitivity)")
            s = math.inf
        else:
            s = total_std(hac, float(values[i]), term, widen)
        a, b = lo[i], lo[i] + span[i]
        half = z * s
        out_bounds[name] = (float(max(a, values[i] - half)), float(min(b, values[i] + half)))
        std[name] = float(s)
        hac_std[name] = float(hac)
    flagged = is_flagged(rmse, noise_ref)
    if flagged:
        notes.append(f"residual {1e6 * rmse:.3g} µm is {rmse / noise_ref:.1f}x the noise "
                     f"{1e6 * noise_ref:.3g} µm: the model does not explain this record; "
                     "the intervals are widened accordingly")
    return Intervals(level=level, bounds=out_bounds, std=std, hac_std=hac_std,
                     noise_rmse=noise, residual_rmse=rmse, lag=lag, flagged=bool(flagged),
                     model_form=model_form, notes=tuple(notes))
