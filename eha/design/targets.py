"""What a test is designed to see: the health faults (:mod:`eha.models.faults`) and the residual
loop's effects (:mod:`eha.explain.effects`) as :class:`Target` s, each one HF parameter moved
away from its healthy value."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

from eha.design.family import DesignError
from eha.explain.effects import EFFECTS
from eha.health.assessment import DEFAULT_NOISE_P12
from eha.models.faults import FAULTS, core_faults
from eha.models.params import SPECS

#: Signals a test may record, with their unit and default white-noise std: the position [m],
#: the load pressure P12 [Pa] and the motor current [mA].
SIGNALS: dict[str, tuple[str, float]] = {"xu": ("m", 1e-6), "p12": ("Pa", DEFAULT_NOISE_P12),
                                         "cor": ("mA", 1e-3)}


@dataclass(frozen=True)
class Target:
    """One fault or effect a test should show.

    Attributes
    ----------
    name : str
        The fault's name (its parameter) or the effect's (``external_load``).
    param : str
        The HF parameter that carries it.
    healthy : float
        Its value on a healthy actuator (HF nominal) [parameter unit].
    probe : float
        Signed deviation from ``healthy`` the signature is taken at [parameter unit].
    limit : float
        Largest deviation the identification can report (its search bounds) [parameter unit]:
        a minimum detectable size beyond it is "not detectable here".
    kind : str
        ``"fault"`` (the health check's bank) or ``"effect"`` (the residual loop's library).
    """

    name: str
    param: str
    healthy: float
    probe: float
    limit: float
    kind: str

    @property
    def unit(self) -> str:
        return SPECS[self.param].unit

    @property
    def display(self) -> tuple[str, float]:
        """Display unit and factor from SI (:func:`eha.models.units.display_unit`)."""
        from eha.models.units import display_unit

        return display_unit(self.param)

    def shown(self, value: float, digits: int = 3) -> str:
        """``value`` (a deviation, SI) in the display unit, with the unit."""
        unit, k = self.display
        return f"{value * k:.{digits}g} {unit}"


def fault_target(name: str) -> Target:
    f = FAULTS[name]
    mid = f.levels[len(f.levels) // 2] if f.levels else f.bounds[1]
    lo, hi = f.bounds
    limit = {1: hi - f.healthy, -1: f.healthy - lo}.get(f.direction,
                                                         max(abs(hi - f.healthy),
                                                             abs(lo - f.healthy)))
    return Target(name, name, f.healthy, mid - f.healthy, limit, "fault")


def effect_target(name: str) -> Target:
    e = EFFECTS[name]
    param = e.tested
    if param is None or "hf" not in SPECS[param].models:
        raise DesignError(f"effect {name!r}: structure of the LF model, not a property of the "
                          "actuator a test can show; allowed: " + ", ".join(designable_effects()))
    healthy = SPECS[param].nominal
    off = e.off[param]
    lo, hi = e.bounds[param]
    return Target(name, param, healthy, e.probe.get(param, hi) - off,
                  max(abs(hi - off), abs(lo - off)), "effect")


def designable_effects() -> list[str]:
    """Effects of the library whose tested parameter the HF model carries."""
    return [n for n, e in EFFECTS.items() if e.tested and "hf" in SPECS[e.tested].models]


def resolve_targets(faults: Sequence[str] | None, effects: Sequence[str] = (),
                    separate: Iterable[Sequence[str]] = ()) -> list[Target]:
    """The targets of a design: ``faults`` (default every registered fault), ``effects``, and
    both members of every pair in ``separate`` (fault or effect names)."""
    names = list(FAULTS) if faults is None else list(faults)
    out: dict[str, Target] = {}
    for n in names:
        if n not in FAULTS:
            raise DesignError(f"faults: {n!r} is not a health fault; allowed "
                              f"{', '.join(FAULTS)} (eha faults)")
        out[n] = fault_target(n)
    for n in effects:
        if n not in EFFECTS:
            raise DesignError(f"effects: {n!r} is not an effect; allowed "
                              f"{', '.join(designable_effects())}")
        out[n] = effect_target(n)
    for pair in separate:
        if len(pair) != 2 or pair[0] == pair[1]:
            raise DesignError(f"separate: {','.join(pair)!r} must be two different names, "
                              "e.g. external_load,offset")
        for n in pair:
            if n in out:
                continue
            if n in FAULTS:
                out[n] = fault_target(n)
            elif n in EFFECTS:
                out[n] = effect_target(n)
            else:
                raise DesignError(f"separate: {n!r} is neither a fault ({', '.join(FAULTS)}) "
                                  f"nor an effect ({', '.join(designable_effects())})")
    if not out:
        raise DesignError("faults, effects, separate: nothing to design for")
    return list(out.values())


def with_probes(targets: Sequence[Target], probes: Mapping[str, float]) -> list[Target]:
    """``targets`` with the signatures taken at other deviations (``name -> deviation``), kept
    between a hundredth of the original probe and the limit."""
    out = []
    for t in targets:
        if t.name in probes and math.isfinite(probes[t.name]):
            size = min(max(abs(probes[t.name]), abs(t.probe) / 100.0), t.limit)
            sign = math.copysign(1.0, probes[t.name] if probes[t.name] else t.probe)
            t = Target(t.name, t.param, t.healthy, sign * size, t.limit, t.kind)
        out.append(t)
    return out


def _deviation(name: str, value, where: str) -> float:
    """The deviation from off of an effect's fitted ``value`` in an explain JSON: a finite
    number inside the effect's search bounds and not its off value (a NaN, an infinity, a
    ``true`` or the off value would design at no size, or write NaN)."""
    param = EFFECTS[name].tested
    lo, hi = EFFECTS[name].bounds.get(param, (-math.inf, math.inf))
    off = EFFECTS[name].off[param]
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value) and lo <= value <= hi and value != off
    if not ok:
        raise DesignError(f"around: {where} = {value!r}: allowed a number in [{lo:g}, {hi:g}] "
                          f"other than the effect's off value {off:g}")
    return float(value) - off


def from_explain(doc: Mapping) -> tuple[list[tuple[str, str]], dict[str, float]]:
    """The pairs to tell apart and the sizes to design at, from ``eha explain``'s JSON: each
    effect the record's model added (its fitted value) against each rival the record could
    not rule out (``not_excluded``, its fitted value); deviations from the effect's off value.
    """
    if not isinstance(doc, Mapping) or not isinstance(doc.get("steps"), list):
        raise DesignError("around: not an eha explain JSON (no 'steps')")
    found: dict[str, float] = {}
    for i, step in enumerate(doc["steps"]):
        name = step.get("effect") if isinstance(step, Mapping) else None
        if name in designable_effects():
            param = EFFECTS[name].tested
            params = step.get("params") or {}
            if not isinstance(params, Mapping):
                raise DesignError(f"around: steps[{i}].params: an object of parameter values "
                                  f"expected, not {type(params).__name__}")
            if params.get(param) is not None:
                found[name] = _deviation(name, params[param], f"steps[{i}].params.{param}")
    rivals: dict[str, float] = {}
    excluded = doc.get("not_excluded") or []
    if not isinstance(excluded, list):
        raise DesignError("around: not_excluded: a list of effects expected, not "
                          f"{type(excluded).__name__}")
    for i, e in enumerate(excluded):
        name = e.get("effect") if isinstance(e, Mapping) else None
        if name in designable_effects() and e.get("value") is not None:
            rivals[name] = _deviation(name, e["value"], f"not_excluded[{i}].value")
    pairs = [(f, r) for f in found for r in rivals if f != r]
    if not pairs:
        raise DesignError("around: the record's answer has no rival it could not rule out "
                          "(nothing to separate)")
    return pairs, {**rivals, **found}


def nuisance_params(kind: str) -> tuple[str, ...]:
    """Parameters a check fits beside the target: the core faults (every hypothesis of the
    health bank, the loop's declared faults); the loop also fits the flow gain GQ."""
    return core_faults() + (("GQ",) if kind == "effect" else ())


__all__ = ["Target", "SIGNALS", "resolve_targets", "fault_target", "effect_target", "from_explain",
           "designable_effects", "with_probes", "nuisance_params"]
