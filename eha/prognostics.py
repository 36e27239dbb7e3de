"""Prognostics: degradation trends of identified faults and remaining useful life (RUL).

Input: a health history, i.e. for each actuator the faults identified at successive checks
(:mod:`eha.manifest` lists the records, :func:`eha.identification.fdi.identify_source` assesses each one with
its intervals). Output: at every check, from the checks up to that one only, the predicted
cycle at which each limited fault reaches its limit, as a distribution.

Degradation model (per actuator and fault)
------------------------------------------
Three laws, all written ``x(t) = a + b·φ(t)`` with ``t`` the age [cycles] and ``φ`` scaled so
that ``φ(0) = 0`` and ``φ(t_k) = 1`` at the latest check ``t_k`` (``a`` is the value when new,
``b`` the increase up to now):

``linear``       ``φ = t/t_k``
``exponential``  ``φ = (exp(κ t/t_k) − 1)/(exp(κ) − 1)``, κ on a grid (:data:`KAPPA_GRID`)
``power``        ``φ = (t/t_k)^p``, p on a grid (:data:`POWER_GRID`)

Given the law, its shape parameter (κ or p) and an extra noise level τ, the model is linear in
``(a, b)``: with a Gaussian prior, the posterior of ``(a, b)`` and the marginal likelihood
(evidence) are exact (conjugate linear-Gaussian regression). Each observation ``y_i`` has the
variance ``σ_i² + τ²``: ``σ_i`` from the identification interval (a ``level`` interval
``[lo, hi]`` gives ``σ = (hi − lo)/(2 z)``, measurement uncertainty) and ``τ`` (on
:data:`TAU_GRID`, a fraction of the fault's scale) for what the intervals miss: process noise
and model error between the monitoring model and the actuator. The grid over (law, shape, τ)
is integrated with a uniform prior per law and equal prior law probabilities: the weights are
the posterior probabilities, i.e. Bayesian model averaging by evidence (no law is "chosen";
the law weights are reported).

Recomputing the posterior from all checks up to ``t_k`` at each check is the Bayesian update
of a conjugate model (the sequential and batch posteriors are the same).

RUL distribution
----------------
:func:`predict_rul` draws ``n_samples`` models from the posterior (a grid point by weight,
then ``(a, b)`` from its Gaussian), solves ``x(t*) = limit`` for each, and combines the faults
with a limit sample by sample (the first to cross ends life, faults independent). A sample
that never crosses (trend away from the limit, or beyond :data:`HORIZON_FACTOR`·t_k) has
RUL = inf. The median and the 5 % / 95 % quantiles are reported (``None`` when infinite);
the driver is the fault that crosses first in most samples. Every draw uses a seed derived
from (seed, actuator, check) and recorded.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

#: Degradation laws.
LAWS = ("linear", "exponential", "power")
#: Shape grids: exponential κ = rate·t_k and power exponent p.
KAPPA_GRID = np.geomspace(0.05, 12.0, 64)
POWER_GRID = np.geomspace(0.3, 6.0, 64)
#: Extra noise levels τ, as fractions of the fault's scale (distance to the limit).
TAU_GRID = np.array([0.0, 0.003, 0.01, 0.03, 0.1])
#: Process-noise levels: relative std of each degradation increment between two checks
#: (the path is a random walk around the trend; see :func:`fit_degradation`).
PROC_GRID = np.array([0.0, 0.05, 0.1, 0.2, 0.4])
#: Prior over the (law, shape) grid: "equal" (each law 1/3, uniform over its shapes) or
#: "grid" (every grid point alike: linear is one point among 49).
LAW_PRIOR = "equal"
#: Crossings later than this multiple of the current age count as "never" (RUL = inf).
HORIZON_FACTOR = 50.0
#: Fewest usable checks before a prediction is made.
MIN_CHECKS = 3
#: RUL samples per check.
N_SAMPLES = 4000
#: Relative standard deviation of the health assessment's systematic error (identified vs
#: true fault value, the same at every check of an actuator). Measured on the HF test bench:
#: robust σ 1.4 % (BKL) and 5.9 % (FDJ); the value trades α-λ accuracy against interval
#: coverage (docs/prognostics.md: 0 to 0.05 compared on two fleets).
LIMIT_ERROR = 0.02
#: Most checks in one fit: longer histories keep their last 10 checks and evenly spaced
#: earlier ones (the cost of a fit grows with the cube of the checks: 0.1 s at 10 checks,
#: 0.3 s at 25, 41 s at 120 on our machine).
MAX_FIT_CHECKS = 30
#: Quantiles reported: 5 %, median, 95 %.
QUANTILES = (0.05, 0.5, 0.95)


class PrognosticsError(ValueError):
    """Bad prognostics input; the message is one line naming the field and allowed values."""


def z_of(level: float) -> float:
    """Two-sided standard-normal quantile of a central interval of probability ``level``."""
    from statistics import NormalDist

    return NormalDist().inv_cdf(0.5 + level / 2.0)


def sigma_from_interval(lo: float, hi: float, level: float = 0.9) -> float:
    """Standard deviation of a Gaussian whose central ``level`` interval is ``[lo, hi]``."""
    return max(float(hi) - float(lo), 0.0) / (2.0 * z_of(level))


# =========================================================================== the model fit
def _basis(law: str, shape: float, t: np.ndarray, t_ref: float) -> np.ndarray:
    s = np.asarray(t, dtype=np.float64) / t_ref
    if law == "linear":
        return s
    if law == "power":
        return np.power(np.maximum(s, 0.0), shape)
    if law == "exponential":
        return np.expm1(shape * s) / math.expm1(shape)
    raise PrognosticsError(f"law {law!r}: allowed {', '.join(LAWS)}")


def _inverse(law: str, shape: float, r: np.ndarray, t_ref: float) -> np.ndarray:
    """Age where φ reaches ``r`` (``r > 0``)."""
    if law == "linear":
        return t_ref * r
    if law == "power":
        return t_ref * np.power(r, 1.0 / shape)
    return t_ref / shape * np.log1p(r * np.expm1(shape))


def _dphi2_integral(law: np.ndarray, shape: np.ndarray, t1: float, t2: np.ndarray,
                    t_ref: float) -> np.ndarray:
    """∫ φ'(t)² dt from ``t1`` to ``t2`` (vectorised over draws) [1/cycle]."""
    s1 = t1 / t_ref
    s2 = np.asarray(t2, dtype=np.float64) / t_ref
    out = np.zeros_like(s2)
    lin = law == "linear"
    out[lin] = (s2[lin] - s1) / t_ref
    pw = law == "power"
    if pw.any():
        p = shape[pw]
        e = 2 * p - 1
        near = np.abs(e) < 1e-6
        val = np.where(near, np.log(np.maximum(s2[pw], 1e-300) / max(s1, 1e-300)),
                       (np.power(s2[pw], e) - s1 ** e) / np.where(near, 1.0, e))
        out[pw] = p * p / t_ref * val
    ex = law == "exponential"
    if ex.any():
        k = shape[ex]
        E = np.expm1(k)
        out[ex] = k / (2 * t_ref * E * E) * (np.exp(2 * k * s2[ex]) - np.exp(2 * k * s1))
    return out


def _dphi(law: np.ndarray, shape: np.ndarray, t: np.ndarray, t_ref: float) -> np.ndarray:
    """φ'(t) [1/cycle], vectorised over draws."""
    s = np.asarray(t, dtype=np.float64) / t_ref
    out = np.full_like(s, 1.0 / t_ref)
    pw = law == "power"
    out[pw] = shape[pw] * np.power(s[pw], shape[pw] - 1) / t_ref
    ex = law == "exponential"
    out[ex] = shape[ex] * np.exp(shape[ex] * s[ex]) / (t_ref * np.expm1(shape[ex]))
    return out


@dataclass(frozen=True)
class Component:
    """One grid point of the posterior: law, shape, τ, weight and the Gaussian of (a, b)."""

    law: str
    shape: float
    tau: float
    weight: float
    mean: np.ndarray
    cov: np.ndarray
    #: process noise: relative std of each increment between checks, and the plug-in
    #: increase b̂ that scales it [fault unit]
    proc: float = 0.0
    bhat: float = 0.0
    #: posterior of the path's deviation w_k from the trend at t_ref given (a, b):
    #: mean = w0 - wX·(a, b), variance wvar
    w0: float = 0.0
    wX: np.ndarray | None = None
    wvar: float = 0.0


@dataclass(frozen=True)
class DegradationFit:
    """Posterior of one fault's degradation at one check (a mixture over the grid).

    Attributes
    ----------
    t_ref : float
        Age of the latest check used [cycles]; φ(t_ref) = 1.
    scale : float
        Fault scale (distance to the limit, or data spread) [fault unit].
    components : tuple of Component
        Grid points with non-negligible weight (weights sum to 1).
    law_weights : dict
        Posterior probability of each law.
    n : int
        Observations used.
    step : float
        Mean interval between the checks used [cycles] (the process-noise step).
    """

    t_ref: float
    scale: float
    components: tuple[Component, ...]
    law_weights: dict[str, float]
    n: int
    step: float = 0.0

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(index, ab)``: component index and ``(a, b)`` of ``n`` posterior draws."""
        w = np.array([c.weight for c in self.components])
        idx = rng.choice(len(w), size=n, p=w / w.sum())
        z = rng.standard_normal((n, 2))
        means = np.array([c.mean for c in self.components])
        covs = np.array([c.cov for c in self.components])
        jitter = 1e-12 * np.max(np.abs(covs), axis=(1, 2))[:, None, None] + 1e-300
        chol = np.linalg.cholesky(covs + jitter * np.eye(2))
        ab = means[idx] + np.einsum("nij,nj->ni", chol[idx], z)
        return idx, ab

    def deviation(self, rng: np.random.Generator, idx: np.ndarray, ab: np.ndarray
                  ) -> np.ndarray:
        """Draws of the path's deviation from the trend at ``t_ref`` (process noise)."""
        w0 = np.array([c.w0 for c in self.components])[idx]
        wX = np.array([c.wX if c.wX is not None else np.zeros(2)
                       for c in self.components])[idx]
        sd = np.sqrt(np.maximum(np.array([c.wvar for c in self.components])[idx], 0.0))
        return w0 - np.sum(wX * ab, axis=1) + sd * rng.standard_normal(idx.size)

    def trajectories(self, rng: np.random.Generator, t: np.ndarray, n: int = 400
                     ) -> np.ndarray:
        """Posterior draws of the trend ``x(t)``, shape ``(n, len(t))`` [fault unit]."""
        idx, ab = self.sample(rng, n)
        out = np.empty((n, len(t)))
        for i, c in enumerate(self.components):
            sel = idx == i
            if sel.any():
                phi = _basis(c.law, c.shape, t, self.t_ref)
                out[sel] = ab[sel, :1] + ab[sel, 1:] * phi[None, :]
        return out

    def crossings(self, limit: float, direction: float, rng: np.random.Generator,
                  n: int, limit_error: float = 0.0) -> np.ndarray:
        """Ages [cycles] at which ``n`` posterior draws reach ``limit`` (inf: never).

        ``direction`` is +1 for a fault that grows towards its limit, -1 for one that falls.
        A draw already beyond the limit at ``t_ref`` crosses at ``t_ref`` (RUL 0).
        ``limit_error``: relative standard deviation of the assessment's systematic error;
        each draw compares the trend of the identified values with ``limit·(1 + e)``,
        ``e ~ N(0, limit_error²)`` (the identified value reaches ``limit·(1 + e)`` when the
        true one reaches ``limit``).
        """
        idx, ab = self.sample(rng, n)
        if limit_error > 0:
            limit = limit * (1.0 + limit_error * rng.standard_normal(n))
        w = self.deviation(rng, idx, ab)
        a, b = ab[:, 0] + w, ab[:, 1]                     # the path through its current level
        out = np.full(n, np.inf)
        now = a + b                                       # φ(t_ref) = 1
        past = direction * (now - limit) >= 0
        out[past] = self.t_ref
        ok = ~past & (direction * b > 0)
        r = np.where(ok, (limit - a) / np.where(b == 0, 1.0, b), 1.0)
        law = np.array([c.law for c in self.components])[idx]
        shape = np.array([c.shape for c in self.components])[idx]
        for name in LAWS:
            sel = ok & (law == name)
            if sel.any():
                out[sel] = _inverse(name, shape[sel], r[sel], self.t_ref)
        # future process noise: the path's random walk around the trend shifts the crossing
        # by -η/x'(t*), η ~ N(0, b̂²σ_p²·step·∫φ'² dt) (first-order first passage)
        proc = np.array([c.proc for c in self.components])[idx]
        bhat = np.array([c.bhat for c in self.components])[idx]
        noisy = ok & (proc > 0) & np.isfinite(out) & (self.step > 0)
        if noisy.any():
            tc = out[noisy]
            var = (bhat[noisy] * proc[noisy]) ** 2 * self.step * _dphi2_integral(
                law[noisy], shape[noisy], self.t_ref, tc, self.t_ref)
            slope = np.abs(b[noisy]) * _dphi(law[noisy], shape[noisy], tc, self.t_ref)
            eta = np.sqrt(np.maximum(var, 0.0)) * rng.standard_normal(tc.size)
            out[noisy] = np.maximum(tc - eta / np.maximum(slope, 1e-300), self.t_ref)
        out[out > HORIZON_FACTOR * self.t_ref] = np.inf
        return out


def fit_degradation(t: Sequence[float], y: Sequence[float], sigma: Sequence[float],
                    scale: float, laws: Sequence[str] = LAWS,
                    tau_grid: Sequence[float] = tuple(TAU_GRID),
                    proc_grid: Sequence[float] = tuple(PROC_GRID)) -> DegradationFit:
    """Bayesian model averaging of the degradation laws over one fault's history.

    Parameters
    ----------
    t : sequence of float
        Ages of the checks [cycles], increasing, the last > 0.
    y : sequence of float
        Identified fault values [fault unit].
    sigma : sequence of float
        Measurement standard deviations [fault unit] (from the identification intervals).
    scale : float
        Fault scale [fault unit], > 0: the prior widths of ``a`` and ``b`` (2·scale, centred
        on the data's median and on 0) and τ (``tau_grid``·scale) are relative to it. Use the
        distance from the first value to the limit.
    laws : sequence of str
        Subset of :data:`LAWS`.
    tau_grid : sequence of float
        Extra noise levels as fractions of ``scale``.
    proc_grid : sequence of float
        Process-noise levels: relative std of each increment between checks. The path is
        the trend plus a random walk ``w``: ``Cov(w_i, w_j) = (b̂σ_p)²·Σ_{m<=min(i,j)} Δφ_m²``
        with ``b̂`` the observed increase (plug-in), so the checks are correlated and the
        current level is where the path is, not where the trend is.

    Returns
    -------
    DegradationFit
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    s2 = np.asarray(sigma, dtype=np.float64) ** 2
    if not (t.size == y.size == s2.size) or t.size < 2:
        raise PrognosticsError("fit: t, y and sigma need the same length, at least 2")
    if not scale > 0 or not np.isfinite(scale):
        raise PrognosticsError(f"fit: scale {scale!r} must be a positive number")
    bad = [law for law in laws if law not in LAWS]
    if bad or not laws:
        raise PrognosticsError(f"--laws {','.join(bad) or '(none)'}: allowed "
                               f"{', '.join(LAWS)}")
    t_ref = float(t[-1])
    if not t_ref > 0:
        raise PrognosticsError("fit: the latest check must be at an age > 0 cycles")
    floor = (1e-4 * scale) ** 2        # no observation is exact
    m0 = np.array([float(np.median(y)), 0.0])
    s0 = (2.0 * scale) ** 2
    S0 = np.diag([s0, s0])
    grids = {"linear": [1.0], "exponential": list(KAPPA_GRID), "power": list(POWER_GRID)}
    taus = np.asarray(tau_grid, dtype=np.float64)
    procs = np.asarray(proc_grid, dtype=np.float64)
    labels, X_rows, logprior = [], [], []
    for law in laws:
        for shape in grids[law]:
            for tau in taus:
                for proc in procs:
                    labels.append((law, float(shape), float(tau), float(proc)))
                    X_rows.append(_basis(law, shape, t, t_ref))
                    logprior.append((-math.log(len(laws)) - math.log(len(grids[law]))
                                     if LAW_PRIOR == "equal" else 0.0)
                                    - math.log(taus.size) - math.log(procs.size))
    phi = np.array(X_rows)                                   # (M, n)
    M, n = phi.shape
    X = np.stack([np.ones_like(phi), phi], axis=-1)          # (M, n, 2)
    tau_abs = np.array([lab[2] for lab in labels]) * scale
    proc = np.array([lab[3] for lab in labels])
    var = s2[None, :] + tau_abs[:, None] ** 2 + floor        # (M, n)
    # process noise: w_i = b·σ_p·Σ_{m<=i} Δφ_m ε_m, Cov(w_i, w_j) = (b̂σ_p)²·S_min(i,j)
    dphi = np.diff(phi, axis=1, prepend=0.0)
    S = np.cumsum(dphi * dphi, axis=1)                       # (M, n)
    span = np.maximum(1.0 - phi[:, 0], 1e-9)
    bhat = np.maximum(np.abs(y[-1] - y[0]) / span, 1e-3 * scale)
    Kscale = (bhat * proc) ** 2                              # (M,)
    diag = np.arange(n)
    # (M, n, n) arrays in chunks of at most ~4 million numbers (long histories)
    chunk = max(1, int(4_000_000 // (n * n)))

    def sigma_of(sl):
        Dc = np.minimum(S[sl, :, None], S[sl, None, :])      # S_min(i,j)
        Sc = Kscale[sl, None, None] * Dc
        Sc[:, diag, diag] += var[sl]
        return Sc, Dc

    logev = np.empty(M)
    for i0 in range(0, M, chunk):
        sl = slice(i0, min(M, i0 + chunk))
        Sc, _ = sigma_of(sl)
        C = Sc + s0 * (X[sl] @ X[sl].transpose(0, 2, 1))     # + X S0 X^T, S0 = s0 I
        Lc = np.linalg.cholesky(C)
        resid = (y - m0[0])[None, :, None] - X[sl, :, 1:] * m0[1]
        r = np.linalg.solve(Lc, resid)[..., 0]
        logev[sl] = (-0.5 * np.sum(r * r, axis=1)
                     - np.log(np.diagonal(Lc, axis1=1, axis2=2)).sum(1)
                     - 0.5 * n * math.log(2 * math.pi))
    logw = logev + np.array(logprior)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    keep = np.flatnonzero(w > 1e-6 * w.max())
    K = keep.size
    mean = np.empty((K, 2))
    cov = np.empty((K, 2, 2))
    w0 = np.empty(K)
    wX = np.empty((K, 2))
    wvar = np.empty(K)
    for j0 in range(0, K, chunk):
        idx = keep[j0:j0 + chunk]
        js = slice(j0, j0 + idx.size)
        Sk, Dk = sigma_of(idx)
        Xk = X[idx]
        SinvX = np.linalg.solve(Sk, Xk)                      # (k, n, 2)
        P = np.linalg.inv(S0)[None] + Xk.transpose(0, 2, 1) @ SinvX
        cov[js] = np.linalg.inv(P)
        rhs = (np.linalg.solve(S0, m0)[None, :, None]
               + SinvX.transpose(0, 2, 1) @ y[None, :, None])
        mean[js] = (cov[js] @ rhs)[..., 0]
        Kk = Kscale[idx][:, None] * Dk[:, :, -1]             # Cov(w, w_k), (k, n)
        g = np.linalg.solve(Sk, Kk[:, :, None])[..., 0]      # Σ⁻¹ K_k
        w0[js] = g @ y
        wX[js] = np.einsum("kn,knj->kj", g, Xk)
        wvar[js] = Kk[:, -1] - np.sum(Kk * g, axis=1)
    wk = w[keep] / w[keep].sum()
    comps = tuple(Component(labels[i][0], labels[i][1], labels[i][2] * scale, float(wk[j]),
                            mean[j], 0.5 * (cov[j] + cov[j].T), proc=labels[i][3],
                            bhat=float(bhat[i]), w0=float(w0[j]), wX=wX[j],
                            wvar=float(max(wvar[j], 0.0)))
                  for j, i in enumerate(keep))
    law_w = {law: float(sum(wi for lab, wi in zip(labels, w) if lab[0] == law))
             for law in laws}
    step = float((t[-1] - t[0]) / (t.size - 1))
    return DegradationFit(t_ref, float(scale), comps, law_w, int(t.size), step)


# =========================================================================== one history
@dataclass
class FaultHistory:
    """One fault of one actuator: checks in cycle order.

    ``sigma`` [fault unit] is the measurement standard deviation; ``used`` marks the checks
    that enter the fit (flagged records are tracked but not used).
    """

    name: str
    cycles: np.ndarray
    values: np.ndarray
    sigma: np.ndarray
    used: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None

    def interval(self, k: int) -> list[float] | None:
        """The identification interval of check ``k`` as given, or None."""
        if self.lo is None or self.hi is None or not np.isfinite(self.lo[k]):
            return None
        return [float(self.lo[k]), float(self.hi[k])]


@dataclass
class Prediction:
    """RUL prediction at one check (from the checks up to it).

    ``rul``, ``rul_lo``, ``rul_hi``: median, 5 % and 95 % quantiles [cycles] or None (never
    within the horizon, or not enough checks yet); ``crossings``: per limited fault the same
    three quantiles of the crossing age; ``samples``: the RUL draws (not serialised).
    """

    cycle: float
    rul: float | None
    rul_lo: float | None
    rul_hi: float | None
    driver: str | None
    estimates: dict[str, float]
    intervals: dict[str, list[float]]
    flagged: bool = False
    crossings: dict[str, dict[str, float | None]] = field(default_factory=dict)
    law_weights: dict[str, dict[str, float]] = field(default_factory=dict)
    seed: int = 0
    n_used: int = 0
    samples: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"cycle": self.cycle, "rul": self.rul, "rul_lo": self.rul_lo,
                "rul_hi": self.rul_hi, "driver": self.driver, "estimates": self.estimates,
                "intervals": self.intervals, "flagged": self.flagged,
                "crossings": self.crossings, "law_weights": self.law_weights,
                "n_used": self.n_used, "seed": self.seed}


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def thin(n: int, most: int | None = None, recent: int = 10) -> np.ndarray:
    """Indices of at most ``most`` (:data:`MAX_FIT_CHECKS`) of ``n`` checks: the last
    ``recent`` and evenly spaced earlier ones, the first included."""
    most = MAX_FIT_CHECKS if most is None else most
    if n <= most:
        return np.arange(n)
    early = np.unique(np.round(np.linspace(0, n - recent - 1, most - recent)).astype(int))
    return np.concatenate([early, np.arange(n - recent, n)])


def check_seed(seed: int, actuator: str, index: int) -> int:
    """The seed of one check's draws: a hash of (seed, actuator, check index)."""
    text = json.dumps([int(seed), str(actuator), int(index)])
    return int(hashlib.sha256(text.encode()).hexdigest()[:8], 16)


def fault_scale(values: np.ndarray, limit: float | None) -> float:
    """Scale of a fault: distance from its first value to the limit (else the data spread)."""
    v = np.asarray(values, dtype=np.float64)
    if limit is not None:
        d = abs(float(limit) - float(v[0]))
        if d > 0:
            return d
    spread = float(np.ptp(v)) if v.size else 0.0
    return max(spread, 0.1 * float(np.max(np.abs(v))) if v.size else 0.0, 1e-12)


def predict_history(actuator: str, histories: Mapping[str, FaultHistory],
                    limits: Mapping[str, float], seed: int = 0,
                    laws: Sequence[str] = LAWS, min_checks: int = MIN_CHECKS,
                    n_samples: int = N_SAMPLES, keep_fits: bool = False,
                    limit_error: float = None
                    ) -> tuple[list[Prediction], list[dict[str, DegradationFit]]]:
    """Predictions of one actuator at each of its checks, each from the checks up to it.

    Parameters
    ----------
    actuator : str
    histories : mapping name -> FaultHistory
        Every tracked fault, on the same cycles.
    limits : mapping name -> float
        Limits of the faults that end life [fault unit]; others are tracked only.
    seed : int
        Base seed (each check's draws use :func:`check_seed`).
    laws, min_checks, n_samples :
        Laws averaged, fewest usable checks before predicting, draws per check.
    keep_fits : bool
        Also return the fits of each check (for plots).
    limit_error : float, optional
        Relative standard deviation of the health assessment's systematic error (identified
        vs true fault value), default :data:`LIMIT_ERROR`; see :meth:`DegradationFit.crossings`.

    Returns
    -------
    (list of Prediction, list of dict name -> DegradationFit)
    """
    if limit_error is None:
        limit_error = LIMIT_ERROR
    if not 0 <= limit_error < 1:
        raise PrognosticsError(f"--limit-error {limit_error:g}: allowed range [0, 1) "
                               "(relative standard deviation)")
    names = list(histories)
    first = histories[names[0]]
    cycles = first.cycles
    direction = {n: (-1.0 if histories[n].used.any() and
                     limits[n] < histories[n].values[histories[n].used][0] else 1.0)
                 for n in limits}
    preds, fits_all = [], []
    for k in range(cycles.size):
        used = first.used[:k + 1]
        n_used = int(used.sum())
        s = check_seed(seed, actuator, k)
        est = {n: float(histories[n].values[k]) for n in names}
        intervals = {n: histories[n].interval(k) for n in names}
        pred = Prediction(float(cycles[k]), None, None, None, None, est, intervals,
                          flagged=bool(getattr(first, "flags", np.zeros(cycles.size,
                                                                         bool))[k]),
                          seed=s, n_used=n_used)
        fits: dict[str, DegradationFit] = {}
        if n_used >= min_checks and cycles[k] > 0:
            rng = np.random.default_rng(s)
            total = np.full(n_samples, np.inf)
            which = np.full(n_samples, -1)
            for j, name in enumerate(names):
                h = histories[name]
                sel = h.used[:k + 1]
                tt, yy, ss = h.cycles[:k + 1][sel], h.values[:k + 1][sel], h.sigma[:k + 1][sel]
                if tt.size > MAX_FIT_CHECKS:
                    pick = thin(tt.size)
                    tt, yy, ss = tt[pick], yy[pick], ss[pick]
                lim = limits.get(name)
                fit = fit_degradation(tt, yy, ss, fault_scale(yy, lim), laws)
                fits[name] = fit
                pred.law_weights[name] = {law: round(w, 6) for law, w in
                                          fit.law_weights.items()}
                if lim is None:
                    continue
                cross = fit.crossings(float(lim), direction[name], rng, n_samples,
                                      limit_error)
                q = np.quantile(cross, QUANTILES, method="inverted_cdf")
                pred.crossings[name] = {"median": _finite_or_none(q[1]),
                                        "lo": _finite_or_none(q[0]),
                                        "hi": _finite_or_none(q[2])}
                first_here = cross < total
                which[first_here] = j
                total = np.minimum(total, cross)
            if limits:
                rul = np.maximum(total - cycles[k], 0.0)
                q = np.quantile(rul, QUANTILES, method="inverted_cdf")
                pred.rul, pred.rul_lo, pred.rul_hi = (_finite_or_none(q[1]),
                                                      _finite_or_none(q[0]),
                                                      _finite_or_none(q[2]))
                finite = which[np.isfinite(total)]
                if finite.size:
                    counts = np.bincount(finite, minlength=len(names))
                    pred.driver = names[int(np.argmax(counts))]
                pred.samples = rul
        preds.append(pred)
        fits_all.append(fits if keep_fits else {})
    return preds, fits_all


def histories_from_checks(rows: Sequence[Mapping[str, Any]], names: Sequence[str],
                          level_default: float = 0.9, skip_flagged: bool = False
                          ) -> dict[str, dict[str, FaultHistory]]:
    """Group health-check rows into per-actuator fault histories.

    Each row: ``actuator``, ``cycle``, ``estimates`` {name: value}, ``intervals``
    {name: [lo, hi]} (may be empty: σ = 0, the τ grid then carries the uncertainty),
    ``level`` (of the intervals), ``flagged`` (bool), ``status`` ("done" or "failed").
    Failed assessments are dropped. Flagged ones (the monitoring model does not explain the
    record) are used unless ``skip_flagged``: a model error that is the same at every check
    still shows the trend, and the τ grid widens the fit when the points scatter.
    """
    out: dict[str, dict[str, FaultHistory]] = {}
    by_act: dict[str, list] = {}
    for r in rows:
        if r.get("status", "done") != "done":
            continue
        by_act.setdefault(str(r["actuator"]), []).append(r)
    for act, rs in by_act.items():
        rs.sort(key=lambda r: float(r["cycle"]))
        cyc = np.array([float(r["cycle"]) for r in rs])
        flags = np.array([bool(r.get("flagged", False)) for r in rs])
        used = ~flags if skip_flagged else np.ones(len(rs), dtype=bool)
        out[act] = {}
        for n in names:
            vals, sig, lo, hi = [], [], [], []
            for r in rs:
                vals.append(float(r["estimates"][n]))
                iv = (r.get("intervals") or {}).get(n)
                level = float(r.get("level") or level_default)
                sig.append(sigma_from_interval(iv[0], iv[1], level) if iv else 0.0)
                lo.append(float(iv[0]) if iv else math.nan)
                hi.append(float(iv[1]) if iv else math.nan)
            out[act][n] = FaultHistory(n, cyc, np.array(vals), np.array(sig), used.copy(),
                                       np.array(lo), np.array(hi))
            out[act][n].flags = flags
    return out


__all__ = ["LAWS", "PrognosticsError", "DegradationFit", "fit_degradation", "FaultHistory",
           "Prediction", "predict_history", "histories_from_checks", "sigma_from_interval",
           "check_seed", "fault_scale"]
