"""Display units: the one unit a quantity is shown in, wherever it is shown (console, JSON
names, CSV headers, figures, the report).

Parameters are declared in SI (:data:`eha.models.params.PARAMETERS`, currents in mA); people
read positions and lengths in µm, pressures in MPa, delays in ms. :func:`display_unit` maps a
parameter to its display unit and the factor from its declared unit; :func:`show` formats a
value (and :func:`show_interval` an interval) in it.

Examples
--------
>>> display_unit("BKL")
('µm', 1000000.0)
>>> show("FRC", 829.4)
'829 N'
>>> show("PSR", 1.71e7)
'17.1 MPa'
>>> show("Kintas", 0.0741)
'0.0741'
>>> show_interval("FRC", 818.2, 839.0)
'[818, 839]'
"""

from __future__ import annotations

import math

from eha.models.faults import FAULTS
from eha.models.params import SPECS



def display_unit(name: str) -> tuple[str, float]:
    """The display unit of parameter ``name`` and the factor from its declared unit
    (``value_shown = factor * value``): positions and lengths µm, pressures MPa, delays ms,
    forces N, currents mA, dimensionless ``""``; a health fault that declares a display unit
    of its own (:attr:`eha.models.faults.Fault.display`) in that one. An unknown name:
    ``("", 1.0)``.

    The one home of display units: the console, the JSON and CSV names, the figures, the
    report and ``eha faults`` all read it (the table by declared unit is
    :data:`eha.models.params.DISPLAY_OF_UNIT`)."""
    if name in FAULTS:
        return FAULTS[name].display_unit
    spec = SPECS.get(name)
    return ("", 1.0) if spec is None else spec.display


def plain(x: float, digits: int = 3) -> str:
    """``x`` with ``digits`` significant digits, without an exponent from 1e-3 to 1e6
    (``1720``, not ``1.72e+03``): one format for a column of numbers of mixed sizes."""
    if not math.isfinite(x):
        return str(x)
    if x == 0:
        return "0"
    text = f"{x:.{digits}g}"
    if "e" in text:         # 1.2e+03 reads worse than 1200: plain up to 1e6, down to 1e-3
        if 1e-3 <= abs(x) < 1e6:
            text = f"{x:.{max(digits - 1 - math.floor(math.log10(abs(x))), 0)}f}"
    return text


def number(name: str, value: float, digits: int = 3) -> str:
    """``value`` of parameter ``name`` in its display unit, without the unit."""
    return plain(display_unit(name)[1] * float(value), digits)


def show(name: str, value: float, digits: int = 3) -> str:
    """``value`` (declared unit) of parameter ``name`` with its display unit:
    ``show("BKL", 1.2e-4) == "120 µm"``."""
    unit = display_unit(name)[0]
    return number(name, value, digits) + (f" {unit}" if unit else "")


def show_interval(name: str, lo: float, hi: float, digits: int = 3) -> str:
    """An interval in the display unit, without the unit: ``[818, 839]``."""
    return f"[{number(name, lo, digits)}, {number(name, hi, digits)}]"


def unit_suffix(name: str) -> str:
    """A JSON or CSV name's unit suffix for parameter ``name``: ``"_um"``, ``"_N"``, ``""``
    for a dimensionless one (ASCII: µm is ``um``)."""
    unit = display_unit(name)[0]
    if not unit:
        return ""
    return "_" + unit.replace("µ", "u").replace("·", "*").replace("³", "^3").replace("²", "^2")


def duration(seconds: float) -> str:
    """A duration as people say it: ``0.4 s``, ``25 s``, ``4 min 10 s``, ``1 h 05 min``."""
    if not math.isfinite(seconds):
        return "unknown"
    if seconds < 10:
        return f"{seconds:.1g} s" if seconds < 1 else f"{seconds:.0f} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        m, s = divmod(int(round(seconds)), 60)
        return f"{m} min {s:02d} s" if m < 10 and s else f"{round(seconds / 60)} min"
    h, m = divmod(int(round(seconds / 60)), 60)
    return f"{h} h {m:02d} min"


__all__ = ["display_unit", "show", "show_interval", "number", "plain", "unit_suffix",
           "duration"]
