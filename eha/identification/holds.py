"""How a record's command was produced between its samples (held or interpolated): shared by
measured records (:mod:`eha.identification.measured`) and the records the simulator makes
(:mod:`eha.identification.synthetic`), so that neither imports the other."""

from __future__ import annotations

import numpy as np

from eha.identification.columns import MeasuredDataError


#: ``command_hold`` values: decide from the record, or force one rebuild of the command.
COMMAND_HOLDS = ("auto", "zoh", "linear")
#: A command is read as held (``auto`` -> ``zoh``) when at least this fraction of its sample
#: differences are exactly zero (flat runs between changes) and at least one change is an
#: isolated jump between flat runs.
HELD_FLAT_FRACTION = 0.2


def detect_hold(com: np.ndarray) -> tuple[str, str]:
    """How a recorded command was produced between its samples: ``"zoh"`` or ``"linear"``.

    A digital controller holds its output between samples, so a held command is piecewise
    constant on its samples: most sample differences are exactly zero and every change is a jump
    between flat runs. Interpolating such a record linearly drives the model up to one sample
    early at every step (the residual loop then "explains" that with a delay). A command that
    changes at every sample (a sine or chirp recorded at the controller's rate) carries no such
    evidence: it is rebuilt linearly, which is unbiased for a step at an unknown instant
    between samples.

    Parameters
    ----------
    com : float64 array
        Command samples [m] as recorded.

    Returns
    -------
    hold : {"zoh", "linear"}
    reason : str
        One line for reports, e.g. ``"held: 96 % of sample differences are zero, 4 jumps"``.
    """
    com = np.asarray(com, dtype=np.float64)
    d = np.diff(com)
    if d.size < 3:
        return "linear", "too few samples to tell; interpolated"
    span = float(np.max(com) - np.min(com))
    flat = np.abs(d) <= 1e-9 * span + 1e-15
    isolated = ~flat[1:-1] & flat[:-2] & flat[2:]
    jumps = int(np.count_nonzero(isolated)) + int(not flat[0] and flat[1]) \
        + int(not flat[-1] and flat[-2])
    fraction = float(np.mean(flat))
    if span > 0 and jumps >= 1 and fraction >= HELD_FLAT_FRACTION:
        return "zoh", (f"held: {fraction:.0%} of sample differences are zero, {jumps} jump"
                       f"{'s' if jumps != 1 else ''} between flat runs")
    return "linear", (f"interpolated: {fraction:.0%} of sample differences are zero, "
                      f"{jumps} isolated jump{'s' if jumps != 1 else ''}")


def resolve_hold(command_hold: str, com: np.ndarray, source: str = "data") -> tuple[str, str]:
    """``command_hold`` resolved for a record's command samples (``auto`` -> detected)."""
    if command_hold not in COMMAND_HOLDS:
        raise MeasuredDataError(source, [f"`command_hold` {command_hold!r}: allowed: "
                                         f"{', '.join(COMMAND_HOLDS)}"])
    if command_hold == "auto":
        return detect_hold(com)
    return command_hold, f"{command_hold} (given)"


__all__ = ["COMMAND_HOLDS", "HELD_FLAT_FRACTION", "detect_hold", "resolve_hold"]
