"""One simulated record like the user's: a healthy actuator of the fleet behind the loop's
null (:mod:`eha.explain.healthy_fleet`), or the final model on the nominal HF (the interval
replicates, :mod:`eha.explain.replicates`), on the record's command, sampling, length and
noise.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from eha.explain.settings import DECLARED_DRAW, NOISE_CLASSES_PER_DECADE
from eha.identification.healthy import draw_actuator
from eha.models.params import SPECS


def noise_class(noise: float) -> float:
    """The noise level [the unit of ``noise``] a null is simulated with for a record whose
    noise is estimated at ``noise``: the nearest class 10**(k/5) (0 stays 0)."""
    if not noise > 0:
        return 0.0
    k = round(math.log10(noise) * NOISE_CLASSES_PER_DECADE)
    return float(10.0 ** (k / NOISE_CLASSES_PER_DECADE))


def _declared_values(rng: np.random.Generator, fit: Mapping[str, tuple[float, float]]
                     ) -> dict[str, float]:
    out = {}
    for name, (lo, hi) in fit.items():
        law, a, b = DECLARED_DRAW.get(name, ("uniform", lo, hi))
        a, b = max(a, lo), min(b, hi)
        if law == "loguniform" and a > 0:
            out[name] = float(math.exp(rng.uniform(math.log(a), math.log(b))))
        else:
            out[name] = float(rng.uniform(a, b))
    return out


def healthy_record(data, fit: Mapping[str, tuple[float, float]], seed: int,
                   known: Mapping[str, float] | None = None, scatter: bool = True,
                   started: Mapping[str, float] | None = None):
    """One simulated healthy record like ``data``: same command (its original samples and
    hold), sampling, length and noise (position; P12 when ``data`` has it).

    The actuator is :func:`eha.identification.healthy.draw_actuator` ``(seed)`` with the declared
    faults drawn by :data:`DECLARED_DRAW` (``default_rng([seed, 3])``); ``seed`` is also the HF's
    dither seed and, with ``[seed, 4]``, the noise's. ``known`` HF parameters (test conditions) are
    set on every actuator. ``started`` HF parameters (the effects a prior says the actuator
    has) replace their nominal values, each actuator's manufacturing scatter kept relative to
    them (a motor gain read at 0.0085 N/mA is drawn within 1 % of it, as 0.01 is). Without
    ``scatter`` the actuator is the nominal HF (the loop's interval replicates,
    :mod:`eha.explain.replicates`).
    """
    from eha.identification.measured import from_arrays, noise_level
    from eha.models.simulate import simulate

    overrides = draw_actuator(seed) if scatter else {}
    overrides.update(_declared_values(np.random.default_rng([seed, 3]), fit))
    for name, value in (started or {}).items():
        nominal = SPECS[name].nominal
        overrides[name] = (value * overrides[name] / nominal if name in overrides and nominal
                           else float(value))
    overrides.update(known or {})
    t_cmd, com = data.command.samples
    trace = simulate("hf", data.command, overrides, t_end=float(t_cmd[-1] - t_cmd[0]),
                     seed=seed)
    rng = np.random.default_rng([seed, 4])
    t = np.asarray(t_cmd, dtype=np.float64) - float(t_cmd[0])
    noise = noise_class(float(data.info.get("noise_m", noise_level(data.xu))))
    xu = np.interp(t, trace.t, trace.xu) + rng.normal(0.0, noise, t.size)
    p12 = None
    if data.p12 is not None:
        sigma_p = noise_class(noise_level(data.p12))
        p12 = np.interp(t, trace.t, trace["p12"]) + rng.normal(0.0, sigma_p, t.size)
    record = from_arrays(t, np.asarray(com, dtype=np.float64), xu, p12,
                         source=f"healthy actuator {seed}",
                         command_hold=data.info.get("command_hold", "auto"))
    return record, overrides
