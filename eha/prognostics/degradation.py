"""Degradation trends of identified faults: the laws and their Bayesian fit.

Input: one fault's history, the values identified at successive checks with their
intervals. Output: the posterior of its degradation (:class:`DegradationFit`), whose draws
give the age at which it crosses a limit; :mod:`eha.prognostics.rul` turns those into the
remaining useful life.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from eha.errors import InputError

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


class PrognosticsError(InputError):
    """Bad prognostics input; the message is one line naming the field and allowed values."""



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
    t, y, s2, t_ref = _check_history(t, y, sigma, scale, laws)
    labels, phi, logprior = _grid(laws, t, t_ref, tau_grid, proc_grid)
    M, n = phi.shape
    floor = (1e-4 * scale) ** 2        # no observation is exact
    m0 = np.array([float(np.median(y)), 0.0])
    s0 = (2.0 * scale) ** 2
    S0 = np.diag([s0, s0])
    X = np.stack([np.ones_like(phi), phi], axis=-1)          # (M, n, 2)
    tau_abs = np.array([lab[2] for lab in labels]) * scale
    proc = np.array([lab[3] for lab in labels])
    var = s2[None, :] + tau_abs[:, None] ** 2 + floor        # (M, n)
    span = np.maximum(1.0 - phi[:, 0], 1e-9)
    bhat = np.maximum(np.abs(y[-1] - y[0]) / span, 1e-3 * scale)
    cov_of = _Covariances(phi, var, (bhat * proc) ** 2)
    logev = np.empty(M)
    for i0 in range(0, M, cov_of.chunk):
        sl = slice(i0, min(M, i0 + cov_of.chunk))
        Sc, _ = cov_of(sl)
        C = Sc + s0 * (X[sl] @ X[sl].transpose(0, 2, 1))     # + X S0 X^T, S0 = s0 I
        Lc = np.linalg.cholesky(C)
        resid = (y - m0[0])[None, :, None] - X[sl, :, 1:] * m0[1]
        r = np.linalg.solve(Lc, resid)[..., 0]
        logev[sl] = (-0.5 * np.sum(r * r, axis=1)
                     - np.log(np.diagonal(Lc, axis1=1, axis2=2)).sum(1)
                     - 0.5 * n * math.log(2 * math.pi))
    logw = logev + logprior
    w = np.exp(logw - logw.max())
    w /= w.sum()
    keep = np.flatnonzero(w > 1e-6 * w.max())
    mean, cov, w0, wX, wvar = _posteriors(cov_of, X, y, keep, m0, S0)
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


def _check_history(t: Sequence[float], y: Sequence[float], sigma: Sequence[float],
                   scale: float, laws: Sequence[str]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(t, y, sigma², t_ref)`` as arrays after the checks of :func:`fit_degradation`."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    s2 = np.asarray(sigma, dtype=np.float64) ** 2
    if not (t.size == y.size == s2.size) or t.size < 2:
        raise PrognosticsError("fit: t, y and sigma need the same length, at least 2")
    if not scale > 0 or not np.isfinite(scale):
        raise PrognosticsError(f"fit: scale {scale!r} must be a positive number")
    bad = [law for law in laws if law not in LAWS]
    if bad or not laws:
        raise PrognosticsError(f"`laws` {','.join(bad) or '(none)'}: allowed "
                               f"{', '.join(LAWS)}")
    t_ref = float(t[-1])
    if not t_ref > 0:
        raise PrognosticsError("fit: the latest check must be at an age > 0 cycles")
    return t, y, s2, t_ref


def _grid(laws: Sequence[str], t: np.ndarray, t_ref: float, tau_grid: Sequence[float],
          proc_grid: Sequence[float]) -> tuple[list[tuple], np.ndarray, np.ndarray]:
    """The grid over (law, shape, τ, process noise): its labels, the basis φ of each point at
    the ages ``t`` (shape ``(M, n)``) and the log prior of each point."""
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
    return labels, np.array(X_rows), np.array(logprior)


class _Covariances:
    """Covariance of the observations at each grid point: measurement and extra noise
    (``var``, on the diagonal) plus the process noise, ``w_i = b·σ_p·Σ_{m<=i} Δφ_m ε_m``,
    ``Cov(w_i, w_j) = (b̂σ_p)²·S_min(i,j)`` (``kscale`` = (b̂σ_p)²). Called on a slice of grid
    points, in chunks of at most ~4 million numbers (``(M, n, n)`` arrays of long histories).
    """

    def __init__(self, phi: np.ndarray, var: np.ndarray, kscale: np.ndarray):
        n = phi.shape[1]
        dphi = np.diff(phi, axis=1, prepend=0.0)
        self.S = np.cumsum(dphi * dphi, axis=1)              # (M, n)
        self.var = var
        self.kscale = kscale                                 # (M,)
        self.diag = np.arange(n)
        self.chunk = max(1, int(4_000_000 // (n * n)))

    def __call__(self, sl) -> tuple[np.ndarray, np.ndarray]:
        """``(Σ, S_min)`` of the grid points ``sl`` (a slice or index array)."""
        Dc = np.minimum(self.S[sl, :, None], self.S[sl, None, :])      # S_min(i,j)
        Sc = self.kscale[sl, None, None] * Dc
        Sc[:, self.diag, self.diag] += self.var[sl]
        return Sc, Dc


def _posteriors(cov_of: _Covariances, X: np.ndarray, y: np.ndarray, keep: np.ndarray,
                m0: np.ndarray, S0: np.ndarray) -> tuple[np.ndarray, ...]:
    """Posterior of (a, b) at the grid points ``keep`` (mean, covariance) and of the path's
    deviation from the trend at the latest check (``w0``, ``wX``, ``wvar``)."""
    K = keep.size
    mean = np.empty((K, 2))
    cov = np.empty((K, 2, 2))
    w0 = np.empty(K)
    wX = np.empty((K, 2))
    wvar = np.empty(K)
    for j0 in range(0, K, cov_of.chunk):
        idx = keep[j0:j0 + cov_of.chunk]
        js = slice(j0, j0 + idx.size)
        Sk, Dk = cov_of(idx)
        Xk = X[idx]
        SinvX = np.linalg.solve(Sk, Xk)                      # (k, n, 2)
        P = np.linalg.inv(S0)[None] + Xk.transpose(0, 2, 1) @ SinvX
        cov[js] = np.linalg.inv(P)
        rhs = (np.linalg.solve(S0, m0)[None, :, None]
               + SinvX.transpose(0, 2, 1) @ y[None, :, None])
        mean[js] = (cov[js] @ rhs)[..., 0]
        Kk = cov_of.kscale[idx][:, None] * Dk[:, :, -1]      # Cov(w, w_k), (k, n)
        g = np.linalg.solve(Sk, Kk[:, :, None])[..., 0]      # Σ⁻¹ K_k
        w0[js] = g @ y
        wX[js] = np.einsum("kn,knj->kj", g, Xk)
        wvar[js] = Kk[:, -1] - np.sum(Kk * g, axis=1)
    return mean, cov, w0, wX, wvar


def fault_scale(values: np.ndarray, limit: float | None) -> float:
    """Scale of a fault: distance from its first value to the limit (else the data spread)."""
    v = np.asarray(values, dtype=np.float64)
    if limit is not None:
        d = abs(float(limit) - float(v[0]))
        if d > 0:
            return d
    spread = float(np.ptp(v)) if v.size else 0.0
    return max(spread, 0.1 * float(np.max(np.abs(v))) if v.size else 0.0, 1e-12)


__all__ = ["LAWS", "PrognosticsError", "DegradationFit", "fit_degradation", "fault_scale"]
