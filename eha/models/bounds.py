"""Search bounds: the type every fit's bounds are (:class:`Bounds`).

A search bound is where an optimizer may look for a parameter, not what a record says of it
(that is an interval, :class:`eha.models.estimate.Estimate`). The bounds of the health faults
are declared with each fault (:mod:`eha.models.faults`: :attr:`~eha.models.faults.Fault.bounds`
for the health assessment, ``thesis_bounds`` for ``eha fdi``, ``loop_bounds`` for
``eha explain``); :func:`eha.models.faults.search_bounds` reads them, every other table of
bounds derives from it.

Examples
--------
>>> b = Bounds({"BKL": (0.0, 1.25e-3), "FDJ": (200.0, 4000.0)})
>>> b["FDJ"]
(200.0, 4000.0)
>>> b.to_dict()
{'BKL': [0.0, 0.00125], 'FDJ': [200.0, 4000.0]}
>>> b.span("FDJ")
3800.0
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping


class Bounds(dict):
    """Parameter name -> ``(lower, upper)`` search bound [parameter unit, ``eha params``].

    A plain dict underneath (JSON, pickling, ``dict(...)`` and updates work as on one); each
    bound is kept as a ``(lower, upper)`` tuple as given. Checking a bound against the
    parameter's allowed range is the caller's (:func:`eha.identification.problem.check_bounds`
    says what is wrong in its own words).
    """

    def __init__(self, pairs: Mapping[str, Iterable[float]] | Iterable[Any] = (), /,
                 **named: Iterable[float]):
        items = pairs.items() if isinstance(pairs, Mapping) else pairs
        super().__init__()
        for name, pair in (*items, *named.items()):
            self[name] = pair

    def __setitem__(self, name: str, pair: Iterable[float]) -> None:
        super().__setitem__(name, pair if isinstance(pair, tuple) else tuple(pair))

    def update(self, *others: Any, **named: Any) -> None:
        for other in (*others, named):
            for name, pair in (other.items() if isinstance(other, Mapping) else other):
                self[name] = pair

    def copy(self) -> "Bounds":
        return Bounds(self)

    def lower(self, name: str) -> float:
        """Lower bound of ``name``."""
        return self[name][0]

    def upper(self, name: str) -> float:
        """Upper bound of ``name``."""
        return self[name][1]

    def span(self, name: str) -> float:
        """Width of ``name``'s bound (upper - lower)."""
        lo, hi = self[name]
        return hi - lo

    def to_dict(self) -> dict[str, list[float]]:
        """Plain-JSON form: ``name -> [lower, upper]``."""
        return {k: list(v) for k, v in self.items()}

    def __repr__(self) -> str:
        return f"Bounds({dict.__repr__(self)})"


__all__ = ["Bounds"]
