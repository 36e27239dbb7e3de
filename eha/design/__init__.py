"""Test design (``eha design``): the command that makes chosen faults and effects detectable
and separable within a test's limits, predicted fast and verified by simulation.

- :mod:`~eha.design.family`: the family of commands searched and the test's :class:`Limits`;
- :mod:`~eha.design.targets`: faults and effects as :class:`Target` s;
- :mod:`~eha.design.predict`: predicted detectable and separable sizes on one command;
- :mod:`~eha.design.search`: the search over the family against the library commands;
- :mod:`~eha.design.api`: :func:`design` and :class:`DesignResult`;
- :mod:`~eha.design.library`: the library commands cut to a design's limits, and the rule that
  a design is never worse than the best of them;
- :mod:`~eha.design.change`: the design and its verification for the change check
  (``check="baseline"``);
- :mod:`~eha.design.verify`: the verification campaign (measured sizes, false alarms,
  isolation).
"""

from eha.design.api import DesignResult, design
from eha.design.family import DesignError, Limits

__all__ = ["design", "DesignResult", "Limits", "DesignError"]
