"""What ``eha design`` and ``eha design verify`` say around their tables: how the library
commands were brought within the user's own limits for the comparison, and the verification's
finding per fault, in each fault's display unit.

Text only: nothing here computes a figure that the design or its verification did not.
"""

from __future__ import annotations

import math
from typing import Any

from eha.models.faults import FAULTS


def beyond_limits(result: Any) -> dict[str, str]:
    """``{library command: why}`` for each library command of ``result`` (a
    :class:`eha.design.api.DesignResult`) that the comparison changed or could not bring
    within the design's limits: scaled down to the stroke and rate (``cut to x0.49``), or
    still beyond them once cut (its frequency content; never offered as the design), as
    :func:`eha.design.library.cut_to_limits` recorded in ``settings["library_cut"]``."""
    compared = getattr(result, "library", None) or {}
    out = {}
    for name, cut in (result.settings.get("library_cut") or {}).items():
        why = []
        if cut.get("scale", 1.0) < 0.999:
            why.append(f"scaled to x{cut['scale']:.2f}")
        if cut.get("beyond"):
            # left out of the comparison, unless no library command fits (then all are in)
            why.append(f"still beyond them ({cut['beyond']})"
                       + (", compared all the same" if name in compared else ", not compared"))
        if why:
            out[name] = ", ".join(why)
    return out


def beyond_limits_lines(result: Any) -> list[str]:
    """The line under the design's table saying how the library commands it was compared
    with were brought within the user's limits (every one cut to the design's length)."""
    beyond = beyond_limits(result)
    if not beyond:
        return []
    d = float(result.settings["duration"])
    return [f"library commands compared within your limits (each cut to {d:g} s): "
            + "; ".join(f"{name} {why}" for name, why in beyond.items())]


def _size(name: str, value: float | None) -> str:
    """A deviation from the nominal value in the fault's display unit (``97.7 N``)."""
    unit, k = FAULTS[name].display_unit
    return f"{k * value:.3g} {unit}".strip()


def verification_headline(v: Any) -> list[str]:
    """The finding of a :class:`eha.design.verify.Verification` first: per fault, the
    measured minimum detectable deviation from nominal on the design and on the best library
    command, in the fault's unit, with the prediction beside it; then what the table's numbers
    are (their unit) and the false alarms in one line."""
    from eha.design.verify import P_DETECT

    library = v.settings.get("library", [])
    # the design first, then the library commands in the order given
    commands = sorted(v.figures, key=lambda c: (c in library, library.index(c)
                                                if c in library else 0))
    design = next((c for c in commands if c not in library), None)
    lines = []
    for name in FAULTS:
        per = {c: v.figures[c]["faults"].get(name) for c in commands}
        if all(f is None for f in per.values()):
            continue
        shown = []
        for c, f in per.items():
            if f is None:
                continue
            md = f["min_detectable"]
            top = f["levels"][-1]["deviation"] if f["levels"] else math.nan
            text = (("at most " if f.get("at_lowest_level") else "") + _size(name, md)
                    if md is not None else f"not detected up to {_size(name, top)}")
            predicted = (v.predicted.get("design") or {}).get(name) if c == design else None
            pred = f" (predicted {_size(name, predicted)})" if predicted is not None else ""
            shown.append(f"{'the design' if c == design else c}: {text}{pred}")
        lines.append(f"{name} detected (P_D >= {P_DETECT:g}) from a change of: "
                     f"{'; '.join(shown)}")
    units = ", ".join(f"{n} {FAULTS[n].unit}" for n in FAULTS if FAULTS[n].unit)
    alarms = "; ".join(f"{c}: {fa['alarms']} of {fa['n']}" for c, fa in
                       ((c, v.figures[c]["false_alarms"]) for c in commands))
    lines.append(f"false alarms on held-out healthy actuators: {alarms}; the table below: "
                 f"the smallest change from nominal detected, in SI ({units})")
    return lines


__all__ = ["beyond_limits", "beyond_limits_lines", "verification_headline"]
