"""The objective of an identification and the optimizers that minimise it.

Every decision variable is normalised to [0, 1] within its bounds; :class:`BatchObjective`
maps a batch of unit-cube points to LF runs simulated in ONE parallel numba call
(:func:`eha.models.simulate.simulate_lf_batch`). The optimizers (:func:`run_ga`,
:func:`pattern_search`, :func:`least_squares_polish`) work in the unit cube and evaluate whole
batches; the methods that combine them are described in :mod:`eha.identification.fdi`.
"""

from __future__ import annotations

import math
from typing import Callable, Mapping, Sequence

import numpy as np

from eha.identification.problem import OBJECTIVES, FDIError
from eha.models.params import LF, LFParams
from eha.models.simulate import simulate_lf_batch

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


def run_ga(obj: BatchObjective, k: int, pop: int, seed: int, max_gen: int, stall: int,
            ftol: float, max_evals: int, history: list[float],
            on_generation: Callable[[int, float], None] | None = None,
            x0: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    # pymoo is imported where a GA runs: the other methods and eha's start do without it
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


def pattern_search(obj: BatchObjective, x: np.ndarray, f: float, step0: float, xtol: float,
                    max_evals: int, history: list[float]) -> tuple[np.ndarray, float]:
    """Compass search with pattern moves: poll ``x ± step·e_i`` (one batch), move to the best
    improving point, else halve the step; stop below ``xtol`` or at the evaluation budget.

    Each poll after a move also tries the pattern moves of Hooke and Jeeves, in the same
    batch: ``x + v`` and ``x + 2v`` for ``v`` the last move and the last two moves together.
    Along a valley that no coordinate follows, a compass search crawls one coordinate and one
    step at a time (measured on the residual loop's refits: 80-87 % of polls were moves, 39
    to 65 moves a search); the pattern moves follow the valley and double along it, which
    cuts the polls by 40-50 % for 4 more runs in a batch of ``2k`` (measured on three
    foreign-physics records: docs/decisions.md)."""
    k = x.size
    step = step0
    eye = np.eye(k)
    trail = [x]                 # the last three points moved to at this step size, last last
    while step >= xtol and obj.evaluations < max_evals:
        polls = [x + step * eye, x - step * eye]
        for back in (2, 3):
            if len(trail) >= back:
                v = x - trail[-back]
                polls.append(np.vstack([x + v, x + 2.0 * v]))
        polls = np.clip(np.vstack(polls), 0.0, 1.0)
        polls = polls[np.any(polls != x, axis=1)]          # drop points clipped onto x
        if polls.shape[0] == 0:
            step *= 0.5
            continue
        values = obj(polls)
        i = int(np.argmin(values))
        if values[i] < f:
            x, f = polls[i], float(values[i])
            trail = trail[-2:] + [x]          # the pattern moves look two moves back
        else:
            step *= 0.5
            trail = [x]
        history.append(f)
    return x, f


def least_squares_polish(obj: BatchObjective, x: np.ndarray, f: float, fd_step: float, xtol: float,
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
    # scipy.optimize is imported where the polish runs (it is slow to import)
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

