"""Synthetic measured records: the simulator's output written as a user's record (tests,
examples, the fleet generator). :mod:`eha.identification.measured` re-exports
:func:`synthetic_record`, its historical home."""

from __future__ import annotations

import numpy as np

from eha.models.commands import Command, array_command
from eha.models.simulate import OUTPUT_DT

__all__ = ["synthetic_record"]


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

    from eha.identification.holds import resolve_hold
    from eha.models.commands import as_command
    from eha.models.simulate import simulate

    # The model is driven by the 1 kHz samples of the command, exactly what a reader of the
    # record can rebuild (held, or a sharp step becomes a 1 ms ramp): the record is
    # self-consistent.
    grid = np.arange(int(round(t_end / OUTPUT_DT)) + 1) * OUTPUT_DT
    values = as_command(command).sample(grid)
    hold, _ = resolve_hold(command_hold, values, "synthetic record")
    sampled = array_command(grid, values, name=as_command(command).name or "array", hold=hold)
    trace = simulate(model, sampled, dict(overrides or {}), t_end=t_end, seed=seed)
    rng = np.random.default_rng(seed)
    xu = trace.xu + rng.normal(0.0, noise, len(trace)) if noise > 0 else trace.xu.copy()
    p12 = trace["p12"] + rng.normal(0.0, noise_p12, len(trace)) if noise_p12 > 0 \
        else trace["p12"]
    return pd.DataFrame({"t": trace.t, "com": trace["com"], "xu": xu, "p12": p12,
                         "xs": trace["xs"]})
