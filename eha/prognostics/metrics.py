"""Prognostic metrics (Saxena et al., "Metrics for offline evaluation of prognostic
performance", IJPHM 2010; the definitions NASA ProgPy's ``progpy.metrics`` implements).

Notation for one actuator: predictions at checks ``t_i`` (cycles), each a set of RUL draws;
``EOL`` the true end of life; ``t_P`` the first check (start of monitoring); the true RUL
``r*_i = EOL − t_i``; ``λ_i = (t_i − t_P)/(EOL − t_P)``. Only checks before EOL count.

alpha-lambda (α, λ, β)
    At the first check with ``t_i >= t_P + λ (EOL − t_P)`` (ProgPy: "at this time or the next
    prediction following"): met when at least ``β`` of the RUL distribution lies within
    ``[(1 − α) r*, (1 + α) r*]`` (ProgPy: ToE within ``gt ± α (gt − t_pred)``, the same).
    :func:`alpha_lambda_fraction` is the share of checks with λ in a window meeting it.
prognostic horizon (PH)
    ``EOL − t_i`` for the first check whose RUL distribution has at least ``β`` within
    ``r* ± α_PH·(EOL − t_P)`` (Saxena's α-bounds, a constant band around EOL); ProgPy's
    ``prognostic_horizon`` with that criterion. None when never met.
relative accuracy (RA)
    ``1 − |r* − r̂| / r*`` with ``r̂`` the prediction's centre (median by default; ProgPy
    uses the mean); a prediction that never crosses (r̂ infinite) counts as RA = 0.
cumulative relative accuracy (CRA)
    Mean of RA over the checks with λ in a window (ProgPy: over every prediction given).
coverage
    Share of checks (λ in the window) whose 5-95 % interval contains ``r*``.

Defaults: α = 0.2, β = 0.5, λ = 0.5 and 0.75, window [0.5, 0.95].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

ALPHA = 0.2
BETA = 0.5
LAMBDAS = (0.5, 0.75)
WINDOW = (0.5, 0.95)


@dataclass(frozen=True)
class Profile:
    """One actuator's predictions: check cycles and RUL draws (inf = never) at each."""

    cycles: np.ndarray
    samples: list[np.ndarray]
    eol: float

    @property
    def t_p(self) -> float:
        return float(self.cycles[0])

    def lam(self) -> np.ndarray:
        return (self.cycles - self.t_p) / (self.eol - self.t_p)

    def valid(self) -> np.ndarray:
        """Checks before EOL that carry a prediction."""
        return np.array([c < self.eol and s is not None and len(s) > 0
                         for c, s in zip(self.cycles, self.samples)])


def mass_in(samples: np.ndarray, lo: float, hi: float) -> float:
    """Share of ``samples`` strictly within ``(lo, hi)`` (as ProgPy counts)."""
    s = np.asarray(samples, dtype=np.float64)
    return float(np.mean((s > lo) & (s < hi))) if s.size else 0.0


def centre(samples: np.ndarray, how: str = "median") -> float:
    s = np.asarray(samples, dtype=np.float64)
    if how == "mean":
        return float(np.mean(s))
    return float(np.quantile(s, 0.5, method="inverted_cdf"))


def alpha_lambda(p: Profile, lam: float, alpha: float = ALPHA, beta: float = BETA
                 ) -> bool | None:
    """α-λ accuracy at ``lam`` (see the module docstring); None when no check qualifies."""
    ok = p.valid()
    t_lam = p.t_p + lam * (p.eol - p.t_p)
    for i in np.flatnonzero(ok):
        if p.cycles[i] >= t_lam - 1e-9:
            r = p.eol - p.cycles[i]
            return mass_in(p.samples[i], (1 - alpha) * r, (1 + alpha) * r) >= beta
    return None


def _window(p: Profile, window: tuple[float, float]) -> np.ndarray:
    lam = p.lam()
    return np.flatnonzero(p.valid() & (lam >= window[0] - 1e-9) & (lam <= window[1] + 1e-9))


def alpha_lambda_checks(p: Profile, alpha: float = ALPHA, beta: float = BETA,
                        window: tuple[float, float] = WINDOW) -> list[bool]:
    """α-λ met or not at every check with λ in ``window``."""
    out = []
    for i in _window(p, window):
        r = p.eol - p.cycles[i]
        out.append(mass_in(p.samples[i], (1 - alpha) * r, (1 + alpha) * r) >= beta)
    return out


def prognostic_horizon(p: Profile, alpha: float = ALPHA, beta: float = BETA) -> float | None:
    """PH [cycles] (see the module docstring); None when the criterion is never met."""
    band = alpha * (p.eol - p.t_p)
    for i in np.flatnonzero(p.valid()):
        r = p.eol - p.cycles[i]
        if mass_in(p.samples[i], r - band, r + band) >= beta:
            return float(p.eol - p.cycles[i])
    return None


def relative_accuracy(samples: np.ndarray, true_rul: float, how: str = "median") -> float:
    """RA = 1 − |r* − r̂|/r*; 0 for a prediction whose centre is infinite."""
    c = centre(samples, how)
    if not math.isfinite(c):
        return 0.0
    return 1.0 - abs(true_rul - c) / true_rul


def ra_at(p: Profile, lam: float, how: str = "median") -> float | None:
    """RA at the α-λ check of ``lam``."""
    t_lam = p.t_p + lam * (p.eol - p.t_p)
    for i in np.flatnonzero(p.valid()):
        if p.cycles[i] >= t_lam - 1e-9:
            return relative_accuracy(p.samples[i], p.eol - p.cycles[i], how)
    return None


def cumulative_relative_accuracy(p: Profile, window: tuple[float, float] = WINDOW,
                                 how: str = "median") -> float | None:
    """CRA: mean RA over the checks with λ in ``window``."""
    idx = _window(p, window)
    if idx.size == 0:
        return None
    return float(np.mean([relative_accuracy(p.samples[i], p.eol - p.cycles[i], how)
                          for i in idx]))


def coverage_checks(p: Profile, window: tuple[float, float] = WINDOW,
                    q: tuple[float, float] = (0.05, 0.95)) -> list[bool]:
    """Whether the ``q`` interval contains the true RUL, at every check in ``window``."""
    out = []
    for i in _window(p, window):
        lo, hi = np.quantile(p.samples[i], q, method="inverted_cdf")
        out.append(bool(lo <= p.eol - p.cycles[i] <= hi))
    return out


def width_at(p: Profile, lam: float, q: tuple[float, float] = (0.05, 0.95)) -> float | None:
    """Interval width at the α-λ check of ``lam``, relative to the true RUL (inf if open)."""
    t_lam = p.t_p + lam * (p.eol - p.t_p)
    for i in np.flatnonzero(p.valid()):
        if p.cycles[i] >= t_lam - 1e-9:
            lo, hi = np.quantile(p.samples[i], q, method="inverted_cdf")
            return float((hi - lo) / (p.eol - p.cycles[i]))
    return None


def evaluate(p: Profile, alpha: float = ALPHA, beta: float = BETA,
             lambdas: Sequence[float] = LAMBDAS, window: tuple[float, float] = WINDOW
             ) -> dict[str, Any]:
    """Every metric of one actuator (JSON-ready; None where undefined)."""
    checks = alpha_lambda_checks(p, alpha, beta, window)
    cover = coverage_checks(p, window)
    ph = prognostic_horizon(p, alpha, beta)
    life = p.eol - p.t_p
    out: dict[str, Any] = {
        "eol": p.eol,
        "alpha_lambda": {f"{lam:g}": alpha_lambda(p, lam, alpha, beta) for lam in lambdas},
        "alpha_lambda_fraction": float(np.mean(checks)) if checks else None,
        "alpha_lambda_checks": len(checks),
        "prognostic_horizon": ph,
        "prognostic_horizon_fraction": None if ph is None or life <= 0 else ph / life,
        "relative_accuracy": {f"{lam:g}": ra_at(p, lam) for lam in lambdas},
        "cra": cumulative_relative_accuracy(p, window),
        "coverage": float(np.mean(cover)) if cover else None,
        "coverage_checks": len(cover),
        "width_rel_at_0.5": width_at(p, 0.5),
    }
    out["_checks"] = (checks, cover)
    return out


def fleet_summary(per_actuator: Mapping[str, Mapping[str, Any]],
                  lambdas: Sequence[float] = LAMBDAS) -> dict[str, Any]:
    """Fleet figures: pooled α-λ fraction and coverage over all window checks, α-λ pass
    rates at each λ, medians of PH fraction and of the relative width at λ = 0.5, mean RA
    and CRA."""
    checks = [c for m in per_actuator.values() for c in m["_checks"][0]]
    cover = [c for m in per_actuator.values() for c in m["_checks"][1]]

    def vals(key, sub=None):
        v = [(m[key] if sub is None else m[key].get(sub)) for m in per_actuator.values()]
        return [x for x in v if x is not None]

    def mean(v):
        return float(np.mean(v)) if v else None

    widths = vals("width_rel_at_0.5")
    return {
        "actuators": len(per_actuator),
        "alpha_lambda_fraction": mean(checks),
        "alpha_lambda_checks": len(checks),
        "alpha_lambda": {f"{lam:g}": mean(vals("alpha_lambda", f"{lam:g}")) for lam in lambdas},
        "coverage": mean(cover),
        "coverage_checks": len(cover),
        "median_width_rel_at_0.5": float(np.median(widths)) if widths else None,
        "median_prognostic_horizon_fraction": (float(np.median(vals(
            "prognostic_horizon_fraction"))) if vals("prognostic_horizon_fraction") else None),
        "ph_not_met": sum(1 for m in per_actuator.values() if m["prognostic_horizon"] is None),
        "relative_accuracy": {f"{lam:g}": mean(vals("relative_accuracy", f"{lam:g}"))
                              for lam in lambdas},
        "cra": mean(vals("cra")),
    }


def public(metrics: Mapping[str, Any]) -> dict[str, Any]:
    """Metrics without the private per-check lists."""
    return {k: v for k, v in metrics.items() if not k.startswith("_")}


__all__ = ["Profile", "alpha_lambda", "alpha_lambda_checks", "prognostic_horizon",
           "relative_accuracy", "ra_at", "cumulative_relative_accuracy", "coverage_checks",
           "width_at", "evaluate", "fleet_summary", "public", "ALPHA", "BETA", "LAMBDAS",
           "WINDOW"]
