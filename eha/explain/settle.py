"""Settling a first record's rivals on a second record (``eha explain RECORD --prior FIRST``).

A first record that cannot tell its finding from a rival (``not_excluded`` in its ``--json``:
an external load of 829 N or a motor offset of -0.009 mA) names the test that decides it
(``eha design --around FIRST.json``). The record of that test is explained *with the first
as prior*: the same actuator holds one of the explanations, at about the size the first
record read. Each explanation is a hypothesis (the found effects as found; each rival in the
place of a found effect), fitted on the second record by least squares (the declared faults
and the hypothesis' effects free, the structure at its physical values), and it stands when
all three hold:

1. its best fit (least squares on the whole record) leaves no more than healthy actuators
   leave on this command (the null's residual limit,
   :meth:`eha.explain.null.Null.residual_limit`): it explains this record;
2. each of its effects reads here what it read on the first record, within the two records'
   healthy thresholds and :data:`SAME_EFFECT_SPREAD` of its size, added in quadrature: it is
   the same effect at the same size;
3. the record shows it: each of its effects is beyond the healthy band here (the loop's own
   test, :meth:`~eha.explain.fitting.Fitter.within_healthy_at`: its reading, or for the
   supply pressure its footprint, beyond what healthy actuators reach on this command), or
   the record is beyond the healthy residual without any effect (the declared faults and the
   structure alone). Without this a healthy record "settles" on an effect whose reading is
   too loose on this command to contradict the first record's size (a supply-pressure drop
   of 1.2 MPa read within ±1.8 MPa on the motor-gain design); with the band alone, a record
   of that drop, which no motor gain fits (14x the noise), would not.

The second test is what makes a short designed test decisive where the rival alone is below
what the test shows. On the load / offset design an offset of -0.009 mA is under the
0.014 mA at which the design tells it from a load, so a load fits that record too; but the
load that does is far from the 829 N the first record needs. The first record fixes the
size; the second shows which effect has it.

Exactly one hypothesis standing settles it; the loop then runs with that explanation in its
base (:func:`eha.explain.from_file.explain_file`). None standing (the records contradict
every explanation) or several (the second test could not decide) settles nothing, and the
loop runs on the prior as given. The figures of each hypothesis are kept
(:class:`Settlement`); ``validation/design_settle.py`` measures the decisions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from eha.explain.effects import EFFECTS, missing_requirements
from eha.explain.settings import STRUCTURAL, ExplainError

#: Relative difference between two records' readings of one effect that still reads as the
#: same effect at the same size (of its shift from off): readings move with the command
#: through the LF's model form, by up to 15 % for a hinge moment beside an 800 N jack friction
#: (validation/results/design_reading.json); the rival a second test must rule out differs by
#: a factor (a load of 829 N against the one that mimics a small offset on a design).
SAME_EFFECT_SPREAD = 0.2


@dataclass
class Hypothesis:
    """One explanation of the first record: its non-structural effects at their first-record
    parameters; ``rival`` the effect the first record could not rule out (None: the found
    model as found), in the place of ``replaces``."""

    effects: dict[str, dict[str, float]]
    first_thresholds: dict[str, float]
    rival: str | None = None
    replaces: str | None = None

    @property
    def name(self) -> str:
        return " + ".join(self.effects)


@dataclass
class Settlement:
    """What the second record says of the first record's explanations (:func:`settle`)."""

    hypotheses: list[dict[str, Any]] = field(default_factory=list)
    #: the one standing hypothesis' name, or None
    winner: str | None = None
    #: the winner's effects, as steps for the loop's base (at their values here), or None
    steps: list[dict[str, Any]] | None = None
    #: the residual-to-noise ratio healthy actuators reach on this command
    residual_limit: float = math.nan
    #: the residual-to-noise ratio of the declared faults and the structure alone
    baseline_ratio: float = math.nan

    @property
    def text(self) -> str:
        """One line, the finding first."""
        standing = [h for h in self.hypotheses if h["stands"]]
        falls = "; ".join(f"{h['name']} does not ({h['why']})"
                          for h in self.hypotheses if not h["stands"])
        if self.winner is not None:
            h = standing[0]
            reads = ", ".join(f"{r['param']} {r['here']:.4g}{_unit(r)} here, "
                              f"{r['first']:.4g} on the first record" for r in h["readings"])
            return f"settled: {self.winner} ({reads}); {falls}"
        if not standing:
            return f"not settled: this record fits none of the first record's explanations; " \
                   f"{falls}"
        return ("not settled: this record fits " + " and ".join(h["name"] for h in standing)
                + (f"; {falls}" if falls else ""))

    def to_json(self) -> dict[str, Any]:
        return {"winner": self.winner, "text": self.text, "residual_limit": self.residual_limit,
                "baseline_ratio": self.baseline_ratio,
                "hypotheses": [dict(h) for h in self.hypotheses]}


def _unit(reading: Mapping[str, Any]) -> str:
    """`` unit`` of a reading, nothing for a dimensionless one."""
    return "" if reading["unit"] in ("", "-") else f" {reading['unit']}"


def _first_threshold(prior: Mapping[str, Any], effect: str) -> float:
    """The first record's healthy threshold on ``effect``'s tested parameter [its unit]; 0
    when its null tested a footprint or the prior has no null."""
    entry = ((prior.get("null") or {}).get("effects") or {}).get(effect) or {}
    if EFFECTS[effect].footprint or "threshold" not in entry:
        return 0.0
    return float(entry["threshold"])


def hypotheses(prior: Mapping[str, Any]) -> list[Hypothesis]:
    """The first record's explanations: the found model, and each rival of ``not_excluded``
    in the place of each found effect (empty when the prior lists no rival)."""
    try:
        rivals = [{"effect": r["effect"], "param": str(r["param"]), "value": float(r["value"])}
                  for r in prior.get("not_excluded") or [] if r.get("effect") in EFFECTS]
        steps = [s for s in prior.get("steps") or []
                 if s.get("effect") in EFFECTS and s["effect"] not in STRUCTURAL]
        found = {s["effect"]: {k: float(v) for k, v in (s.get("params") or {}).items()}
                 for s in steps}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ExplainError(f"`prior`: each rival of 'not_excluded' needs an effect, a param "
                           f"and a numeric value, each step numeric params ({exc})") from None
    if not rivals or not found:
        return []
    names = {*found, *(r["effect"] for r in rivals)}
    thresholds = {n: _first_threshold(prior, n) for n in names}
    out = [Hypothesis(dict(found), thresholds)]
    for r in rivals:
        for replaced in found:
            effects = {n: p for n, p in found.items() if n != replaced}
            effects[r["effect"]] = {r["param"]: float(r["value"])}
            out.append(Hypothesis(effects, thresholds, r["effect"], replaced))
    return out


def _reading(loop, effect: str, fitted, first: Mapping[str, float],
             first_threshold: float) -> dict[str, Any]:
    """The effect's tested parameter here against the first record's (:data:`SAME_EFFECT_SPREAD`)."""
    e = EFFECTS[effect]
    param = e.tested
    # the threshold of the parameter's shift (a footprint effect's second statistic)
    here_threshold = float((loop.thresholds or {}).get(e.shift_key or effect, 0.0))
    value_first = float(first.get(param, getattr(loop.current, param)))
    off = e.off[param]
    tolerance = math.sqrt(first_threshold ** 2 + here_threshold ** 2
                          + (SAME_EFFECT_SPREAD * (value_first - off)) ** 2)
    here = float(getattr(fitted, param))
    return {"effect": effect, "param": param, "unit": e.units()[param], "first": value_first,
            "here": here, "tolerance": tolerance, "same": abs(here - value_first) <= tolerance}


def _fit(loop, h: Hypothesis):
    """The hypothesis fitted on the whole second record by least squares, from its
    first-record values, from its effects off and from their probes; the best kept.

    The whole record, not the loop's fitted part: nothing is chosen among candidates here,
    and a fit on the first 70 % extrapolates a trade into the rest (a motor gain of 0.0096
    against a flow gain of 0.208 fits 70 % of a healthy record on the motor-gain / supply
    design at 1.1 µm and leaves 29 µm on the rest)."""
    members = []
    for name in h.effects:
        members += [EFFECTS[n] for n in missing_requirements(EFFECTS[name], loop.current)
                    if EFFECTS[n] not in members]
        members.append(EFFECTS[name])
    start, free = loop.fitter.candidate_start(members, loop.current, loop.free)
    at_first, probe = start, start
    for name, params in h.effects.items():
        e = EFFECTS[name]
        at_first = at_first.replace(**{p: min(max(v, e.bounds[p][0]), e.bounds[p][1])
                                       for p, v in params.items() if p in e.bounds})
    for e in members:
        probe = probe.replace(**{p: v for p, v in e.probe.items()
                                 if p in e.bounds and e.bounds[p][0] <= v <= e.bounds[p][1]})
    phase = f"settling the prior: {h.name}"
    fits = [loop.fitter.fit_with_cost(s, free, f"{phase} (start {k + 1})", method="lm",
                                      whole=True)
            for k, s in enumerate(dict.fromkeys([at_first, start, probe]))]
    return min(fits, key=lambda fit: fit[1])[0]


def settle(loop, prior: Mapping[str, Any]) -> Settlement | None:
    """Decide between the first record's explanations on ``loop``'s record (see the module).

    Parameters
    ----------
    loop : ResidualLoop
        On the second record, with the nominal base (no prior) and its healthy null; its
        declared faults are fitted here (:meth:`~ResidualLoop.baseline`, the structure
        pinned when ``loop`` pins it).
    prior : dict
        The first record's ``eha explain --json``.

    Returns
    -------
    Settlement or None
        None when the prior lists no rival (nothing to settle).

    Raises
    ------
    ExplainError
        The loop has no healthy null: without it nothing says what this command shows.
    """
    hyps = hypotheses(prior)
    if not hyps:
        return None
    if loop.null is None:
        raise ExplainError("`prior` lists rivals to settle, which needs the healthy null of "
                           "this command; run with a null (simulated or records)")
    loop.baseline()
    limit = loop.residual_limit
    reference = loop.problem.noise_ref
    # without any effect (the declared faults and the structure): beyond the healthy residual,
    # the record needs an effect, whatever the effects' own readings say
    base_ratio = float(loop.cur.rmse_all / reference) if reference > 0 else math.inf
    out = Settlement(residual_limit=float(limit), baseline_ratio=base_ratio)
    for h in hyps:
        fitted = _fit(loop, h)
        ev = loop.fitter.evaluate([fitted])[0]
        ratio = float(ev.rmse_all / reference) if reference > 0 else math.inf
        readings = [_reading(loop, n, fitted, h.effects[n], h.first_thresholds.get(n, 0.0))
                    for n in h.effects]
        fits = ratio <= limit
        off = [r for r in readings if not r["same"]]
        for r in readings:
            # shown: the loop's own test (beyond what healthy actuators read on this
            # command), or a record that no model without an effect explains
            r["present"] = (base_ratio > limit
                            or not loop.fitter.within_healthy_at(EFFECTS[r["effect"]], fitted))
        absent = [r for r in readings if not r["present"]]
        why = "" if fits else f"its best fit leaves {ratio:.2g}x the noise, beyond the " \
                              f"{limit:.2g}x healthy actuators leave"
        if off:
            why = (why + "; " if why else "") + "; ".join(
                f"{r['param']} reads {r['here']:.4g}{_unit(r)} here against "
                f"{r['first']:.4g} on the first record (± {r['tolerance']:.2g})" for r in off)
        if absent:
            why = (why + "; " if why else "") + "; ".join(
                f"{r['effect']} reads within what healthy actuators read on this command "
                f"({r['param']} {r['here']:.4g}{_unit(r)}): not shown here" for r in absent)
        out.hypotheses.append({
            "name": h.name, "rival": h.rival, "replaces": h.replaces,
            "residual_ratio": ratio, "fits": fits, "readings": readings,
            "stands": fits and not off and not absent, "why": why,
            "params": {p: float(getattr(fitted, p)) for n in h.effects
                       for p in EFFECTS[n].params}})
    standing = [h for h in out.hypotheses if h["stands"]]
    if len(standing) == 1:
        out.winner = standing[0]["name"]
        out.steps = _winner_steps(standing[0])
    return out


def _winner_steps(standing: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The standing hypothesis' effects at their values here. The prior's structure stays
    out: it was fitted on the first record's command, and the loop finds this record's (the
    settlement's fits had it at its physical values)."""
    names = [r["effect"] for r in standing["readings"]]
    return [{"effect": n, "params": {p: standing["params"][p] for p in EFFECTS[n].params}}
            for n in names]


def excluded_of(prior: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """What the first record's exclusion check excluded (its ``--json``'s ``excluded``:
    effect -> ``{"param", "beyond", "unit"}``), the effects of the library only; empty for a
    JSON without it (an older run, or a first record whose model was not at the noise).

    Raises
    ------
    ExplainError
        ``excluded`` present but not of that shape (one line naming it).
    """
    out = {}
    try:
        for name, entry in (prior.get("excluded") or {}).items():
            if name in EFFECTS:
                beyond = float(entry["beyond"])
                if math.isfinite(beyond):
                    out[name] = {**dict(entry), "beyond": beyond}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ExplainError(f"`prior`: 'excluded' must map each effect to its param, a numeric "
                           f"'beyond' and a unit ({exc})") from None
    return out


def rivals_of(prior: Mapping[str, Any] | Sequence[Any]) -> bool:
    """Does an earlier run's JSON list rivals a second record can settle?"""
    return isinstance(prior, Mapping) and bool(hypotheses(prior))
