"""Remaining useful life (RUL) of an actuator from its health history.

Input: a health history, i.e. for each actuator the faults identified at successive checks
(:mod:`eha.prognostics.manifest` lists the records,
:func:`eha.identification.fdi.identify_source` assesses each one with its intervals). Output:
at every check, from the checks up to that one only, the predicted cycle at which each limited
fault reaches its limit, as a distribution. Each fault's trend is
:func:`eha.prognostics.degradation.fit_degradation`.

RUL distribution
----------------
:func:`predict_rul` draws ``n_samples`` models from the posterior (a grid point by weight,
then ``(a, b)`` from its Gaussian), solves ``x(t*) = limit`` for each, and combines the faults
with a limit sample by sample (the first to cross ends life, faults independent). A sample
that never crosses (trend away from the limit, or beyond
:data:`~eha.prognostics.degradation.HORIZON_FACTOR`·t_k) has RUL = inf. The median and the 5 % / 95
% quantiles are reported (``None`` when infinite); the driver is the fault that crosses first in
most samples. Every draw uses a seed derived from (seed, actuator, check) and recorded.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any, Mapping, Sequence

import numpy as np

from eha.models.estimate import Estimate, estimates
from eha.prognostics.degradation import (LAWS, DegradationFit, PrognosticsError, fault_scale,
                                         fit_degradation)

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


def z_of(level: float) -> float:
    """Two-sided standard-normal quantile of a central interval of probability ``level``."""
    return NormalDist().inv_cdf(0.5 + level / 2.0)


def sigma_from_interval(lo: float, hi: float, level: float = 0.9) -> float:
    """Standard deviation of a Gaussian whose central ``level`` interval is ``[lo, hi]``."""
    return max(float(hi) - float(lo), 0.0) / (2.0 * z_of(level))

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

    @property
    def rul_estimate(self) -> Estimate:
        """The RUL as an :class:`~eha.models.estimate.Estimate` [cycles]: the median and its
        5-95 % interval (:data:`QUANTILES`, level 0.9); NaN where not predicted."""
        def num(v):
            return math.nan if v is None else float(v)
        return Estimate("RUL", num(self.rul), num(self.rul_lo), num(self.rul_hi),
                        level=QUANTILES[2] - QUANTILES[0], unit="cycles")

    def as_estimates(self) -> dict[str, Estimate]:
        """The tracked faults' estimates at this check with their intervals (SI units)."""
        return estimates(self.estimates, self.intervals, None)

    def to_dict(self) -> dict[str, Any]:
        rul = self.rul_estimate
        return {"cycle": self.cycle, "rul": self.rul, "rul_lo": _none(rul.lo),
                "rul_hi": _none(rul.hi), "driver": self.driver, "estimates": self.estimates,
                "intervals": self.intervals, "flagged": self.flagged,
                "crossings": self.crossings, "law_weights": self.law_weights,
                "n_used": self.n_used, "seed": self.seed}


def _none(x: float) -> float | None:
    """NaN (not predicted) as None, as the JSON writes it."""
    return None if math.isnan(x) else x


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
        raise PrognosticsError(f"`limit_error` {limit_error:g}: allowed range [0, 1) "
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


__all__ = ["FaultHistory", "Prediction", "predict_history", "histories_from_checks",
           "sigma_from_interval", "check_seed"]
