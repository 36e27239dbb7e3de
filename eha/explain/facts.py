"""What a run of the residual loop did, beside what it was asked (:class:`RunFacts`): the
settings say how the loop was told to run (``ExplainResult.settings``), the facts how this
run went — how many samples it fitted, which candidates it had, whether the record's P12
entered the fit, how many passes it took, whether the flow gain was fitted or released.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class RunFacts:
    """The facts of one run of :class:`eha.explain.loop.ResidualLoop` (and of
    :func:`eha.explain.api.explain`'s passes)."""

    #: samples fitted (the rest of the record is held out); None: the whole record
    n_fit: int | None = None
    #: the candidate effects the run could add (names of :data:`eha.explain.effects.EFFECTS`)
    candidates: list[str] = field(default_factory=list)
    #: how the record's command is held between samples ("linear" or "zoh")
    command_hold: str = "linear"
    #: the record's measured P12 entered the fits
    p12_used: bool = False
    #: the P12 noise estimated from the record [Pa] (None without a P12)
    p12_noise_pa: float | None = None
    #: the P12 residual's weight against the position's [m/Pa] (0: position only)
    p12_m_per_pa: float = 0.0
    #: structure effects pinned at their physical values (the second pass)
    structure_pinned: list[str] = field(default_factory=list)
    #: passes of the loop: 1, or 2 when the second pass from the pinned structure ran
    passes: int = 1
    #: the flow gain GQ was fitted within the healthy spread
    flow_gain_fitted: bool = False
    #: why GQ went back to its nominal value (it reached the edge of its spread), or None
    flow_gain_released: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The facts as plain JSON types."""
        return asdict(self)
