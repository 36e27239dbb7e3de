"""A measured record as the residual loop sees it: where the LF model starts on it, the
means to simulate parameter sets on it in batches, the weight of its measured P12 in the fits,
and the few numbers every part of the loop compares signals with (RMSE, correlation).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from eha.explain.effects import get as get_effects
from eha.explain.settings import P12_NOISE_FLOOR, START_TOLERANCE, ExplainError
from eha.identification.measured import MeasuredData, noise_level
from eha.models.params import LFParams, ParameterError
from eha.models.simulate import (OUTPUT_DT, command_on_grid, grid, simulate, simulate_lf_batch,
                                 xj0_for_recorded)


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    d = np.asarray(a) - np.asarray(b)
    return float(np.sqrt(np.mean(d * d))) if d.size else math.nan


def corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b / den) if den > 0 else 0.0


class Record:
    """A record and the means to simulate the LF model on it in batches."""

    def __init__(self, data: MeasuredData, base: LFParams):
        self.data = data
        self.recorded_start = recorded_start(data)
        self.base = base
        self.t_end = (len(data) - 1) * OUTPUT_DT
        self.steps_per_out, self.n_out, t_steps = grid(base, self.t_end)
        self.com = command_on_grid(data.command, t_steps)
        # footprints already simulated, by (effect, parameters): a candidate's gate and its
        # reported statistic ask for the same one
        self._footprints: dict[tuple[str, LFParams], float] = {}

    def run(self, params: Sequence[LFParams], with_p12: bool = False):
        """Recorded xu of each parameter set, shape (n, n_out) (and P12 with ``with_p12``)."""
        rows = np.stack([p.to_array() for p in params])
        return simulate_lf_batch(rows, self.com, self.steps_per_out, self.n_out, self.base,
                                 self.recorded_start, with_p12=with_p12)

    def footprint(self, effect, params: LFParams) -> float:
        """The effect's footprint on this record [m]: the RMS difference of the recorded
        position between ``params`` and ``params`` with ``effect`` switched off (what the
        effect as fitted does to the record, whatever its parameters trade;
        :attr:`eha.explain.effects.Effect.footprint`)."""
        key = (effect.name, params)
        if key not in self._footprints:
            if len(self._footprints) > 4096:    # a bound, not a policy: rarely reached
                self._footprints.clear()
            xu = self.run([params, effect.switch_off(params)])
            self._footprints[key] = rmse(xu[0], xu[1]) if np.all(np.isfinite(xu)) else math.inf
        return self._footprints[key]

    def footprint_size(self, effect, footprint: float, base: LFParams
                       ) -> list[tuple[dict[str, float], float | None]]:
        """The tested parameter's value (:attr:`~eha.explain.effects.Effect.tested`, moved
        from off towards its lower bound: a supply-pressure drop) at which ``effect`` leaves
        a footprint of ``footprint`` m on this record from ``base``, for each setting of its
        other parameters the loop starts from (the probe's and ``other_starts``: the supply
        pressure's two laws). Bisection; None where even the bound leaves less.

        Returns
        -------
        list of (setting, value)
            ``setting`` the other parameters' values, ``value`` the tested parameter's.
        """
        name = effect.tested
        off, lo = effect.off[name], effect.bounds[name][0]
        out = []
        for start in (effect.probe, *effect.other_starts):
            setting = {p: v for p, v in {**effect.probe, **start}.items() if p != name}

            def fp(value: float) -> float:
                return self.footprint(effect, effect.switch_on(base, {**setting, name: value}))

            if not fp(lo) >= footprint:
                out.append((setting, None))
                continue
            near, far = off, lo
            for _ in range(24):             # 1e-7 of the range: well below any fit's spread
                mid = 0.5 * (near + far)
                near, far = (mid, far) if fp(mid) < footprint else (near, mid)
            out.append((setting, far))
        return out

    def full(self, params: LFParams):
        if self.recorded_start is not None:
            params = params.replace(XJ0=float(xj0_for_recorded(
                self.recorded_start, params.sensor_bias, params.sensor_gain, params.XJM)))
        return simulate("lf", self.data.command, params, t_end=self.t_end)


def recorded_start(data: MeasuredData) -> float | None:
    """The measured first position (median of 3 samples, against noise) when the record starts
    away from its command, else None (see :func:`initial_position`)."""
    measured = float(np.median(data.xu[:3]))
    return None if abs(measured - data.com[0]) <= START_TOLERANCE else measured


def initial_position(data: MeasuredData, base: LFParams) -> LFParams:
    """The LF model starts at rest: on the first command when the record starts near it (the
    small difference is then left to the model to explain: friction, offset, sensor bias),
    else where its *recorded* position is the measured first position, e.g. a command that
    steps away at t = 0 or a record that starts elsewhere (every LF run of the loop then sets
    XJ0 from its own sensor bias and gain, so a sensor bias is not mistaken for a shifted
    start)."""
    start = recorded_start(data)
    if start is None:
        start = float(data.com[0])
    return base.replace(XJ0=float(np.clip(start, -base.XJM, base.XJM)))


def p12_objective_weight(noise_xu: float, p12: np.ndarray | None, weight: float = 1.0
                         ) -> tuple[float, float]:
    """Metres of position per pascal of P12 residual in the fits, and the P12 noise [Pa].

    Each signal is measured in its own noise (``noise_xu`` [m], the P12 noise from
    :func:`eha.identification.measured.noise_level`): ``weight * noise_xu / noise_p12``, the P12
    noise floored at :data:`P12_NOISE_FLOOR` of its standard deviation. ``(0, nan)`` when the
    record has no P12, ``weight`` is 0, or either signal is noise-free and flat.
    """
    if p12 is None or weight <= 0:
        return 0.0, math.nan
    p12 = np.asarray(p12, dtype=np.float64)
    sigma_p = max(noise_level(p12), P12_NOISE_FLOOR * float(np.std(p12)))
    if not (sigma_p > 0 and noise_xu > 0):
        return 0.0, sigma_p
    return weight * noise_xu / sigma_p, sigma_p


def augmented_base(prior: Mapping[str, Any] | Sequence[Mapping[str, Any]],
                   base: LFParams | None = None) -> LFParams:
    """LF parameters with the effects of a previous run switched on.

    Parameters
    ----------
    prior : dict or list
        The ``--json`` output of an earlier ``eha explain`` (its ``steps``), or the list of
        steps itself (``{"effect": name, "params": {...}}``).
    base : LFParams, optional
        Starting set (nominal LF by default).
    """
    steps = prior.get("steps", []) if isinstance(prior, Mapping) else prior
    params = base if base is not None else LFParams()
    try:
        for step in steps:
            params = get_effects([step["effect"]])[0].switch_on(params, step.get("params", {}))
    except (KeyError, TypeError) as exc:
        raise ExplainError(f"prior: each step needs an 'effect' and 'params' ({exc})") from None
    except ParameterError as exc:
        raise ExplainError(f"prior: {exc}") from None
    return params
