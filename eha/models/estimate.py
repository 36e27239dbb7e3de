"""What a fit says of a parameter: :class:`Estimate`, its value and its interval at a nominal
coverage (level), in a unit.

The identification (``eha fdi``), the health assessment, the residual loop (``eha explain``)
and the remaining-useful-life prediction (``eha rul``) each report estimates with intervals;
they hand them out as :class:`Estimate` (``.estimates()`` on each result) and build their
``to_pandas()`` tables and the intervals of their JSON from them. The JSON keys stay those of
each result (``intervals: {name: [lo, hi]}``, ``rul_lo``/``rul_hi``, ...); an estimate's own
plain form is :meth:`Estimate.to_dict`.

Examples
--------
>>> e = Estimate("FDJ", 412.0, 398.0, 431.0, level=0.9, unit="N")
>>> e.interval, e.width
((398.0, 431.0), 33.0)
>>> e.to_dict()["hi"]
431.0
>>> list(frame([e]).columns)
['name', 'unit', 'estimate', 'lo', 'hi', 'level']
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

#: An interval ``(lo, hi)`` at a result's level [parameter unit]: what a result's
#: ``intervals`` map each name to (:attr:`Estimate.interval`).
Interval = tuple[float, float]
#: The columns :func:`frame` gives every estimate, after its name.
COLUMNS = ("unit", "estimate", "lo", "hi", "level")


@dataclass(frozen=True)
class Estimate:
    """A parameter's (or a quantity's) estimate and its interval.

    Attributes
    ----------
    name : str
        The parameter (``eha params``) or the quantity (``"RUL"``).
    value : float
        The estimate [unit].
    lo, hi : float
        The interval at :attr:`level` [unit]; NaN when none was computed.
    level : float or None
        Nominal coverage of the interval (0.9: 90 %); None when there is no interval.
    unit : str
        Unit of ``value``, ``lo`` and ``hi`` (SI as ``eha params`` for parameters; ``cycles``
        for a RUL).
    std : float
        Standard uncertainty of the estimate [unit]; NaN when not known.
    """

    name: str
    value: float
    lo: float = math.nan
    hi: float = math.nan
    level: float | None = None
    unit: str = ""
    std: float = math.nan

    @property
    def interval(self) -> tuple[float, float]:
        """``(lo, hi)`` [unit]."""
        return (self.lo, self.hi)

    @property
    def width(self) -> float:
        """``hi - lo`` [unit]."""
        return self.hi - self.lo

    def contains(self, value: float) -> bool:
        """Whether ``value`` lies inside the interval (ends included); False without one."""
        return bool(self.lo <= value <= self.hi)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form: ``name``, ``value``, ``lo``, ``hi``, ``level``, ``unit``, ``std``
        (NaN written as None)."""
        def num(v):
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v
        return {"name": self.name, "value": num(self.value), "lo": num(self.lo),
                "hi": num(self.hi), "level": self.level, "unit": self.unit,
                "std": num(self.std)}

    def row(self) -> dict[str, Any]:
        """The :data:`COLUMNS` of this estimate (a ``to_pandas()`` row)."""
        return {"unit": self.unit, "estimate": self.value, "lo": self.lo, "hi": self.hi,
                "level": math.nan if self.level is None else self.level}


def si_unit(name: str) -> str:
    """The declared (SI) unit of parameter ``name`` (``eha params``), ``""`` if unknown."""
    from eha.models.params import SPECS

    return SPECS[name].unit if name in SPECS else ""


def estimates(values: Mapping[str, float], intervals: Mapping[str, Sequence[float]],
              level: float | None, std: Mapping[str, float] | None = None
              ) -> dict[str, Estimate]:
    """Name -> :class:`Estimate` of each of ``values``, with its interval in ``intervals``
    (NaN where it has none) at ``level``, its ``std`` and its SI unit."""
    out = {}
    for name, v in values.items():
        lo, hi = intervals.get(name, (math.nan, math.nan))
        # an estimate has an interval exactly when ``intervals`` names it (level NaN if the
        # result gives none): :func:`intervals_json` writes back what was given
        has = name in intervals
        out[name] = Estimate(name, float(v), float(lo), float(hi),
                             (math.nan if level is None else level) if has else None,
                             si_unit(name),
                             float((std or {}).get(name, math.nan)))
    return out


def intervals_json(items: Mapping[str, Estimate] | Iterable[Estimate]) -> dict[str, list]:
    """The ``intervals`` of a result's JSON, ``name -> [lo, hi]``, from its estimates (those
    without an interval left out)."""
    ests = items.values() if isinstance(items, Mapping) else items
    return {e.name: [e.lo, e.hi] for e in ests if e.level is not None}


def frame(items: Mapping[str, Estimate] | Iterable[Estimate], key: str = "name",
          extra: Mapping[str, Mapping[str, Any]] | None = None,
          columns: Sequence[str] = COLUMNS):
    """A pandas DataFrame of estimates: one row each, ``key`` (their name), then ``columns``
    (of :data:`COLUMNS`), then each ``extra`` column (name -> per-estimate value, NaN where
    missing)."""
    import pandas as pd

    ests = list(items.values() if isinstance(items, Mapping) else items)
    extra = extra or {}
    rows = []
    for e in ests:
        row = e.row()
        rows.append({key: e.name, **{c: row[c] for c in columns},
                     **{c: vals.get(e.name, math.nan) for c, vals in extra.items()}})
    return pd.DataFrame(rows, columns=[key, *columns, *extra])


__all__ = ["Estimate", "Interval", "COLUMNS", "estimates", "frame", "intervals_json", "si_unit"]
