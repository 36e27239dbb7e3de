"""Synthetic measured records: the simulator's output written as a user's record (tests,
examples, the fleet generator). :mod:`eha.identification.measured` re-exports
:func:`synthetic_record`, its historical home."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from eha.models.commands import Command, array_command
from eha.models.simulate import OUTPUT_DT

__all__ = ["synthetic_record", "synthetic_positions"]

#: HF runs per parallel numba call of :func:`synthetic_positions` (bounds its memory: 64 runs
#: of 5 s hold 23 MB).
BATCH_RUNS = 64


def _sampled(command: Command | str, t_end: float, command_hold: str) -> Command:
    """The command as its 1 kHz samples, held or interpolated as a reader of the record
    rebuilds it (a sharp step becomes a 1 ms ramp): the record is self-consistent."""
    from eha.identification.holds import resolve_hold
    from eha.models.commands import as_command

    grid = np.arange(int(round(t_end / OUTPUT_DT)) + 1) * OUTPUT_DT
    values = as_command(command).sample(grid)
    hold, _ = resolve_hold(command_hold, values, "synthetic record")
    return array_command(grid, values, name=as_command(command).name or "array", hold=hold)


def synthetic_record(command: Command | str = "test", overrides: dict[str, float] | None = None,
                     t_end: float = 1.0, noise: float = 1e-6, seed: int = 0,
                     model: str = "hf", command_hold: str = "auto", noise_p12: float = 0.0):
    """A record made by the simulator, for tests and examples: HF (or LF) run plus noise.

    Parameters
    ----------
    command : Command or str
        Position command (preset name or :class:`~eha.models.commands.Command`).
    overrides : dict, optional
        Parameters of the model (faults and the "undeclared" effect, e.g. ``{"FRC": 2000}``).
    t_end : float
        Record length [s] (1 kHz samples).
    noise : float
        Standard deviation of white Gaussian measurement noise on xu [m].
    seed : int
        Seed of the noise and of the HF dither.
    command_hold : {"auto", "zoh", "linear"}
        How the model is driven between the command's 1 kHz samples: held (a digital
        controller) or interpolated; ``auto`` as :func:`eha.identification.measured.load` reads the record back
        (:func:`eha.identification.measured.detect_hold`), so that a record and its reading agree.
    noise_p12 : float
        Standard deviation of white Gaussian noise on the load pressure p12 [Pa] (default 0:
        p12 exact). Drawn after the position's noise from the same seed, so ``xu`` is the same
        with or without it.

    Returns
    -------
    pandas.DataFrame
        Columns ``t``, ``com``, ``xu``, ``p12``, ``xs`` (SI), ready for ``to_csv``.
    """
    import pandas as pd

    from eha.models.simulate import simulate

    sampled = _sampled(command, t_end, command_hold)
    trace = simulate(model, sampled, dict(overrides or {}), t_end=t_end, seed=seed)
    rng = np.random.default_rng(seed)
    xu = trace.xu + rng.normal(0.0, noise, len(trace)) if noise > 0 else trace.xu.copy()
    p12 = trace["p12"] + rng.normal(0.0, noise_p12, len(trace)) if noise_p12 > 0 \
        else trace["p12"]
    return pd.DataFrame({"t": trace.t, "com": trace["com"], "xu": xu, "p12": p12,
                         "xs": trace["xs"]})


def synthetic_positions(command: Command | str, overrides: Sequence[Mapping[str, float]],
                        t_end: float, noise: float, seeds: Sequence[int]) -> np.ndarray:
    """The recorded positions of many HF :func:`synthetic_record` runs on one command, in
    parallel numba calls (:func:`eha.models.simulate.simulate_hf_batch`): row ``j`` equals
    ``synthetic_record(command, overrides[j], t_end, noise, seeds[j])["xu"]`` (the same
    dither and noise seeds), without building a table per run. The change calibration's
    hundreds of HF runs.

    Parameters
    ----------
    command : Command or str
        Position command.
    overrides : sequence of mappings
        HF parameters of each run (faults and nuisances by name).
    t_end : float
        Record length [s] (1 kHz samples).
    noise : float
        Standard deviation of the position's white measurement noise [m].
    seeds : sequence of int
        Noise and dither seed of each run.

    Returns
    -------
    float64 array, shape ``(len(overrides), n_samples)`` [m].
    """
    from eha.models.simulate import OUTPUTS, simulate_hf_batch

    sampled = _sampled(command, t_end, "auto")
    xs = np.empty((len(overrides), int(round(t_end / OUTPUT_DT)) + 1))
    for k in range(0, len(overrides), BATCH_RUNS):
        part = slice(k, k + BATCH_RUNS)
        out = simulate_hf_batch([dict(o) for o in overrides[part]], sampled, t_end,
                                [int(s) for s in seeds[part]])
        xs[part] = out[:, :, OUTPUTS.index("xu")]    # one batch's outputs held at a time
    if noise > 0:
        for j, seed in enumerate(seeds):
            xs[j] += np.random.default_rng(seed).normal(0.0, noise, xs.shape[1])
    return xs
