"""Tracing the residual (step b of the loop): how much of it each effect's *signature* could
explain (the change of the LF output when the effect is switched on at its probe value, and at
its other starts (:attr:`~eha.explain.effects.Effect.other_starts`), a secant sensitivity, all
effects in one batch of LF runs), and its correlation with signals.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from eha.explain.effects import Effect, switch_on_with_requirements
from eha.explain.record import Record, corr, rmse
from eha.explain.results import Candidate, Evaluation, Round
from eha.models.params import LFParams

#: Signals the residual is correlated with (name -> meaning).
SIGNALS = {
    "position": "LF position xu",
    "velocity_sign": "sign of the LF jack velocity",
    "command": "position command",
    "tracking_error": "command - LF position",
    "p12": "load pressure P12 (measured when the record has it, else LF)",
}


def signatures(record: Record, current: LFParams, effects: Sequence[Effect],
               free: Mapping[str, tuple[float, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Effect signatures and free-parameter sensitivities of xu, one batch of LF runs.

    Returns
    -------
    S : array (n_effects, n_out)
        ``xu(effect on at its probe value) - xu(current)`` [m], with the effects it requires
        switched on too (the candidate the loop tries, :attr:`Effect.requires`).
    J : array (n_free, n_out)
        Finite-difference sensitivity of xu to each free parameter, scaled to 2 % of its
        search range [m].
    """
    rows = [current] + [switch_on_with_requirements(e, current) for e in effects]
    for name, (lo, hi) in free.items():
        value = getattr(current, name)
        h = 0.02 * (hi - lo)
        step = value + h if value + h <= hi else value - h
        rows.append(current.replace(**{name: step}))
    xu = record.run(rows)
    ref = xu[0]
    m = len(effects)
    return xu[1:1 + m] - ref, xu[1 + m:] - ref


def trace_residual(record: Record, cur: Evaluation, free: Mapping[str, tuple[float, float]],
                   effects: Sequence[Effect], n_fit: int) -> Round:
    """Correlate the residual with every effect's signature and with signals (step b).

    ``explained`` of a candidate is the fraction of the residual's energy (on the fitted part)
    that the linearised fit over the free parameters *and* the effect explains, minus what the
    free parameters alone explain.
    """
    r = (record.data.xu - cur.xu)[:n_fit]
    S, J = signatures(record, cur.params, effects, free)
    S, J = S[:, :n_fit], J[:, :n_fit]

    def explained(columns: np.ndarray) -> float:
        # unit-norm columns (sensitivities differ by orders of magnitude); unusable ones dropped
        norms = np.linalg.norm(columns, axis=1) if columns.size else np.zeros(0)
        keep = np.isfinite(norms) & (norms > 0)
        rr = float(r @ r)
        if not keep.any() or rr <= 0.0:
            return 0.0
        A = (columns[keep] / norms[keep, None]).T
        coef, *_ = np.linalg.lstsq(A, r, rcond=1e-10)
        return float(np.clip(1.0 - float(np.sum((r - A @ coef) ** 2)) / rr, 0.0, 1.0))

    # an effect with other starts (the supply pressure's two laws) spans the signature of
    # each: its probe's alone would hide the law it does not take
    other = [(i, switch_on_with_requirements(e, cur.params).replace(**values))
             for i, e in enumerate(effects) for values in e.other_starts]
    columns = {i: [S[i]] for i in range(len(effects))}
    if other:
        xu = record.run([cur.params, *(params for _, params in other)])
        for (i, _), row in zip(other, xu[1:]):
            columns[i].append((row - xu[0])[:n_fit])
    base_explained = explained(J)
    cands = [Candidate(e.name, corr(r, S[i]) if np.all(np.isfinite(S[i])) else 0.0,
                       max(explained(np.vstack([J, *columns[i]])) - base_explained, 0.0))
             for i, e in enumerate(effects)]
    full = record.full(cur.params)
    dxj = full["dxj"][:n_fit]
    p12 = record.data.p12[:n_fit] if record.data.p12 is not None else full["p12"][:n_fit]
    signals = {"position": corr(r, cur.xu[:n_fit]),
               "velocity_sign": corr(r, np.sign(np.where(np.abs(dxj) > 1e-6, dxj, 0.0))),
               "command": corr(r, record.data.com[:n_fit]),
               "tracking_error": corr(r, (record.data.com - cur.xu)[:n_fit]),
               "p12": corr(r, p12)}
    return Round(rmse(r, 0.0), signals, cands)
