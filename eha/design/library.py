"""The library commands a design is measured against, cut to the design's limits, and the rule
that a design is never worse than the best of them.

A library command (``chirp_1cm``, ``mixed``, ``test``, ``sine``) is defined for its own length
and stroke; a design is asked for within limits the library may exceed (``chirp_1cm`` moves
faster than 0.1 m/s). Comparing a design with a command the user may not run is no comparison:
:func:`cut_to_limits` makes each library command a test within the same limits (its first
``duration`` seconds, scaled down to the stroke and the rate, brought to rest over the closing
rest with a raised-cosine fade). A command that still has more than 1 % of its energy above
``max_freq`` is marked (:attr:`CutCommand.beyond`) and never offered as the design.

:func:`dominated_by` is the rule: a designed command on which any target is predicted harder
to detect than on the best library command (by the search's own score) is replaced by that
library command, and the design says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Collection, Mapping, Sequence

import numpy as np

from eha.design.family import COMMAND_DT, Limits, outside_limits, rest_length
from eha.design.predict import Prediction
from eha.design.targets import Target


@dataclass(frozen=True)
class CutCommand:
    """A library command cut to a design's limits.

    Attributes
    ----------
    name : str
        The library command.
    t, com : float64 arrays
        Its samples at 1 kHz over the test [s, m].
    scale : float
        The amplitude factor applied (1: within the stroke and rate as it is).
    beyond : str or None
        Why the cut command is still outside the limits (its frequency content), or None.
    """

    name: str
    t: np.ndarray
    com: np.ndarray
    scale: float
    beyond: str | None

    @property
    def label(self) -> str:
        cut = "" if self.scale >= 0.999 else f" x{self.scale:.2f}"
        return f"{self.name}{cut}"

    def command(self):
        from eha.models.commands import array_command

        return array_command(self.t, self.com, self.name)


def cut_to_limits(name: str, limits: Limits) -> CutCommand:
    """Library command ``name`` as a test within ``limits`` (see the module docstring)."""
    from eha.models.commands import make_command

    n = int(round(limits.duration / COMMAND_DT))
    t = np.arange(n + 1) * COMMAND_DT
    com = make_command(name).sample(t)
    rest = max(int(round(rest_length(limits) / COMMAND_DT)), 3)
    fade = np.ones_like(com)
    ramp = max(rest // 2, 2)
    # a raised-cosine fade over the first half of the closing rest, then still at zero
    fade[n + 1 - rest:n + 1 - rest + ramp] = 0.5 * (1 + np.cos(np.linspace(0, math.pi, ramp)))
    fade[n + 1 - rest + ramp:] = 0.0
    com = com * fade
    com[0] = 0.0
    peak = float(np.max(np.abs(com))) or 1.0
    rate = float(np.max(np.abs(np.diff(com)))) / COMMAND_DT if com.size > 1 else 0.0
    scale = min(1.0, limits.max_stroke / peak, limits.max_rate / rate if rate > 0 else 1.0)
    com = com * scale
    return CutCommand(name, t, com, scale, outside_limits(com, limits))


def within_limits(limits: Limits, say=None) -> tuple[dict[str, CutCommand],
                                                     dict[str, CutCommand]]:
    """The library commands cut to ``limits``: those within them (the design's references)
    and those still beyond (named, with why, never a reference or the design)."""
    from eha.design.search import LIBRARY

    cuts = {name: cut_to_limits(name, limits) for name in LIBRARY}
    inside = {n: c for n, c in cuts.items() if c.beyond is None}
    beyond = {n: c for n, c in cuts.items() if c.beyond is not None}
    if say is not None:
        for n, c in beyond.items():
            say(f"library command {n} is beyond the limits even cut to them ({c.beyond}): "
                "not compared")
    if not inside:     # nothing fits: compare with all, marked (a design still needs a yardstick)
        return cuts, {}
    return inside, beyond


def library_cut(cuts: Mapping[str, CutCommand]) -> dict[str, dict]:
    """What a design's settings record of each library command cut to its limits."""
    return {n: {"scale": c.scale, "beyond": c.beyond} for n, c in cuts.items()}


def best_by_score(library: Mapping[str, Prediction], targets: Sequence[Target],
                  reference: Mapping[str, tuple[str, float]],
                  detect: Collection[str] | None = None,
                  cuts: Mapping[str, CutCommand] | None = None) -> str:
    """The library command with the best search score (:func:`eha.design.search.score`)
    among those within the limits."""
    from eha.design.search import score

    usable = [c for c in library if cuts is None or cuts[c].beyond is None] or list(library)
    return min(usable, key=lambda c: score(library[c], targets, reference, (), False, detect))


def dominated_by(design: Prediction, library: Prediction, targets: Sequence[Target],
                 detect: Collection[str] | None = None, tolerance: float = 1e-6) -> list[str]:
    """The targets (of ``detect``, default all) predicted harder to detect on the design than
    on the library command: [] when the design is at least as good on every one."""
    worse = []
    for t in targets:
        if detect is not None and t.name not in detect:
            continue
        d, lib = design.mds[t.name], library.mds[t.name]
        if not math.isfinite(lib) and not math.isfinite(d):
            continue
        if min(d, 10 * t.limit) > min(lib, 10 * t.limit) * (1 + tolerance):
            worse.append(t.name)
    return worse


__all__ = ["CutCommand", "cut_to_limits", "within_limits", "library_cut", "best_by_score", "dominated_by"]
