"""The residual loop's verdict as a finding (docs/explain.md, "The verdict").

Four facts of a run, each its own boolean, make the verdict's kind (:data:`KINDS`):

- ``at_noise``: the final model's position residual is at the record's noise (at most the stop
  rule's ``noise_factor`` times it);
- ``at_model_level``: above the noise, but no more than the found model itself leaves on HF
  re-simulations of it (:func:`eha.explain.replicates.explains`: within their prediction
  bound, that bound below the healthy band's limit, no added effect at a bound of its range);
- ``within_healthy_band``: the residual is no more than what faults and structure leave on
  healthy actuators of the record's command (the null's residual limit);
- ``unique_explanation``: no effect outside the model fits the record as well with a size this
  command shows (the exclusion check found no rival).

=======================  ===============================  ===================  ==================
kind                     at_noise or at_model_level       within_healthy_band  unique_explanation
=======================  ===============================  ===================  ==================
explained                yes                              yes                  yes
explained, ambiguous     yes                              yes                  no
partly explained         no                               yes                  (not checked)
unexplained              no                               no                   (not checked)
=======================  ===============================  ===================  ==================

Every output (console, ``--json``, the database, the HTML report) is made from
:class:`Verdict`, so they agree. Its first line says what was found, with values, display units
(:mod:`eha.models.units`) and intervals; then what the record cannot rule out; then what it
could not have shown (:meth:`ExplainResult.undetectable`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from eha.explain.settings import STRUCTURAL
from eha.models.units import show, show_interval

#: the verdict's kinds, best first
KINDS = ("explained", "explained, ambiguous", "partly explained", "unexplained")

#: how an effect is named in a sentence (default: its name with spaces)
LABELS = {"offset": "motor offset", "hysteresis": "motor hysteresis",
          "clogging": "filter clogging", "delay": "position delay",
          "leakage": "internal leakage"}

#: why the structure is added, in one line (docs/explain.md)
STRUCTURE_WHY = ("structure, not a finding: the LF model lacks the HF's orifice law and "
                 "flapper dynamics on any actuator; added to reach the other effects, its own "
                 "RMSE change may be small or negative")


def label(effect: str) -> str:
    """An effect's name in a sentence: ``external_load`` -> ``external load``."""
    return LABELS.get(effect, effect.replace("_", " "))


def kind_of(at_noise: bool, within_healthy_band: bool, unique_explanation: bool,
            at_model_level: bool = False) -> str:
    """The verdict's kind (:data:`KINDS`) from its facts."""
    if not within_healthy_band:
        return "unexplained"
    if not (at_noise or at_model_level):
        return "partly explained"
    return "explained" if unique_explanation else "explained, ambiguous"


@dataclass(frozen=True)
class Verdict:
    """A run's verdict: its facts, its kind and its lines."""

    at_noise: bool
    within_healthy_band: bool
    unique_explanation: bool
    #: first line: what was found and the residual, e.g. ``found external load 829 N [818,
    #: 839] (90 %); residual 1.03 µm, at the noise (1.09 µm)``
    finding: str
    #: the rivals the record cannot rule out, one clause each (empty when unique)
    rivals: tuple[str, ...]
    #: the effects found, with value, display unit and interval (``--json`` ``found``)
    found: tuple[dict[str, Any], ...]
    #: above the noise by no more than the found model itself leaves on the HF
    at_model_level: bool = False

    @property
    def kind(self) -> str:
        return kind_of(self.at_noise, self.within_healthy_band, self.unique_explanation,
                       self.at_model_level)

    @property
    def text(self) -> str:
        """One line (the ``verdict`` of the JSON and the database): ``KIND: FINDING[;
        cannot be told apart on this command from RIVALS]``; an unexplained record opens with
        its lead (``unexplained residual 12.3 µm (8.1× noise), correlated with ...``)."""
        head = self.finding if self.kind == "unexplained" else f"{self.kind}: {self.finding}"
        if self.rivals:
            head += "; cannot be told apart on this command from " + ", ".join(self.rivals)
        return head

    def to_json(self) -> dict[str, Any]:
        return {"verdict_kind": self.kind, "at_noise": self.at_noise,
                "at_model_level": self.at_model_level,
                "within_healthy_band": self.within_healthy_band,
                "unique_explanation": self.unique_explanation, "found": list(self.found)}


def _found(res) -> list[dict[str, Any]]:
    """The non-structural effects of the final model, each parameter with its value, display
    unit and interval (display unit)."""
    out = []
    for step in res.steps:
        if step.effect in STRUCTURAL:
            continue
        for name, value in res.final_params(step).items():
            lo_hi = res.intervals.get(name)
            out.append({"effect": step.effect, "param": name, "value": value,
                        "text": show(name, value) + _change(name, value),
                        "interval": list(lo_hi) if lo_hi is not None else None,
                        "interval_text": show_interval(name, *lo_hi) if lo_hi else ""})
    return out


def _change(name: str, value: float) -> str:
    """`` (-10 % of its nominal 0.01 N/mA)`` for a parameter whose nominal is not zero (a
    motor gain, a supply pressure: the value alone does not say how far it moved); else
    nothing."""
    from eha.models.params import SPECS

    spec = SPECS.get(name)
    nominal = spec.nominal_for("lf") if spec is not None and "lf" in spec.models else None
    if not nominal or not math.isfinite(value):
        return ""
    return f" ({100 * (value - nominal) / nominal:+.0f} % of its nominal {show(name, nominal)})"


def _effects_text(found: list[dict[str, Any]], level: float | None) -> str:
    """``external load 829 N [818, 839] (90 %)``; an effect of several parameters names
    them: ``supply pressure PSR 17.1 MPa [16.8, 17.4], XSSK 0.02 [0, 0.1] (90 %)``."""
    by_effect: dict[str, list[dict[str, Any]]] = {}
    for f in found:
        by_effect.setdefault(f["effect"], []).append(f)
    parts = []
    for effect, items in by_effect.items():
        values = ", ".join((f"{f['param']} " if len(items) > 1 else "") + f["text"]
                           + (f" {f['interval_text']}" if f["interval_text"] else "")
                           for f in items)
        parts.append(f"{label(effect)} {values}")
    text = ", ".join(parts)
    if level and any(f["interval_text"] for f in found):
        text += f" ({100 * level:g} %)"
    return text


def _residual_text(res, at_noise: bool) -> str:
    """``residual 1.03 µm (0.9× noise), at the noise (1.09 µm)``, at the found model's own
    level (what it leaves on HF re-simulations of itself), or above it within the healthy
    band."""
    noise = 1e6 * res.noise_rmse
    ratio = res.rmse_after / res.noise_rmse if res.noise_rmse > 0 else math.inf
    head = f"residual {1e6 * res.rmse_after:.3g} µm ({ratio:.1f}× noise)"
    if at_noise:
        return f"{head}, at the noise ({noise:.3g} µm)"
    limit = (res.null or {}).get("residual_limit")
    band = (f"within what healthy actuators leave on this command (up to {limit:.2g}×)"
            if limit is not None else "below the flag ratio")
    own = getattr(res, "model_level", None) or {}
    if not own:
        return (f"{head}, above the noise ({noise:.3g} µm) but {band}: an effect that small "
                f"may be missing")
    # what the found model itself leaves on the HF decides what the rest is
    level = (f"the found model, simulated again on the HF, leaves {own['mean']:.2f} ± "
             f"{own['std']:.2f}× ({len(own['ratios'])} re-simulations, up to "
             f"{own['bound']:.2f}×)")
    loop_ratio = own.get("record_loop", own["record"])
    if own["record"] < loop_ratio - 0.005:
        # the record refitted from the re-simulations' spread of starts reaches lower
        starts = len(own.get("restarts", ()))
        level = (f"the found model, refitted from {starts} more starts, leaves "
                 f"{own['record']:.2f}× here and, simulated again on the HF, "
                 f"{own['mean']:.2f} ± {own['std']:.2f}× ({len(own['ratios'])} "
                 f"re-simulations, up to {own['bound']:.2f}×)")
    if own.get("explains"):
        # explained at the model's own level (eha.explain.replicates.explains)
        return f"{head}, at the found model's own level ({level}; the noise {noise:.3g} µm)"
    if limit is not None and own["bound"] >= limit:
        # re-simulations that scatter as widely as healthy actuators do decide nothing
        rest = "no sharper than the healthy band: it does not say whether an effect is missing"
    elif own["within"] and own.get("at_bound"):
        # re-simulations refitted within the same range do not test a model pinned at it
        rest = (f"within it, but {', '.join(own['at_bound'])} at the bound of its range: the "
                f"re-simulations do not test a model pinned there")
    elif own["within"]:
        rest = "the rest is within the model's own model form"
    else:
        rest = "more than that: an effect that small may be missing"
    return f"{head}, above the noise ({noise:.3g} µm) but {band}; {level}: {rest}"


def _rival(e: dict[str, Any]) -> str:
    """``a motor offset of -0.009 mA (beyond the 0.0073 mA this command shows)``."""
    param, value = e["param"], e["value"]
    if e["unit"] == "m" and e.get("value_unit", "m") != "m":        # a footprint
        beyond = (f"a footprint of {1e6 * e['shift']:.3g} µm, beyond the "
                  f"{1e6 * e['detectable']:.3g} µm this command shows")
    else:
        beyond = f"beyond the {show(param, e['detectable'])} change this command shows"
    name = label(e["effect"])
    article = "an" if name[0] in "aeiou" else "a"
    return f"{article} {name} of {show(param, value)} ({beyond})"


def _settled_text(res) -> str:
    """``the first record's motor offset, settled here at -0.0085 mA`` when a ``--prior``'s
    rivals were settled on this record (:mod:`eha.explain.settle`; the effect is then in the
    loop's base, not among its steps), else ``""``."""
    settled = getattr(res, "settled", None) or {}
    standing = [h for h in settled.get("hypotheses", []) if h.get("stands")]
    if settled.get("winner") is None or len(standing) != 1:
        return ""
    values = ", ".join(show(r["param"], r["here"]) for r in standing[0]["readings"])
    names = " + ".join(label(r["effect"]) for r in standing[0]["readings"])
    return f"the first record's {names}, settled here at {values}"


def verdict_of(res) -> Verdict:
    """The verdict of an :class:`eha.explain.results.ExplainResult`."""
    within = not res.beyond_healthy
    own = getattr(res, "model_level", None) or {}
    at_level = within and bool(own.get("explains"))
    at_noise = within and not at_level and (bool(res.not_excluded) or not res.unexplained)
    unique = not res.not_excluded
    found = _found(res)
    effects = _effects_text(found, res.level)
    settled = _settled_text(res)
    if not within and res.leads is not None:
        finding = res.leads.describe()
        limit = (res.null or {}).get("residual_limit")
        if limit is not None:
            finding += f"; healthy actuators leave up to {limit:.2g}× noise on this command"
        if effects:
            finding += f"; tentative: {effects}"
    elif not within:
        finding = (f"unexplained residual {1e6 * res.rmse_after:.3g} µm"
                   + (f"; tentative: {effects}" if effects else ""))
    else:
        what = effects or ("nothing further" if settled else "nothing beyond the healthy band")
        finding = (f"found {what}" + ("" if at_noise or at_level or not effects
                                      else " (tentative)")
                   + "; " + _residual_text(res, at_noise))
    if settled:
        finding = f"{settled}; {finding}"
    return Verdict(at_noise=at_noise, within_healthy_band=within, unique_explanation=unique,
                   finding=finding, rivals=tuple(_rival(e) for e in res.not_excluded),
                   found=tuple(found), at_model_level=at_level)


def unseen_summary(lines: list[str], limit: int = 4) -> str:
    """The undetectable lines folded to one: ``could not have been seen on this command below
    the sizes it shows: leakage, hinge moment, ... (11 effects; each size in --json
    'undetectable')``."""
    names = [label(line.split(":", 1)[0]) for line in lines]
    shown = ", ".join(names[:limit]) + (", ..." if len(names) > limit else "")
    return (f"not visible on this command below the sizes it shows: {shown} "
            f"({len(names)} effect{'s' if len(names) != 1 else ''}; each size in "
            f"explain.json 'undetectable')")


def structure_note(res) -> str | None:
    """One line on the structure the model added, or None."""
    added = [label(s.effect) for s in res.steps if s.effect in STRUCTURAL]
    if not added:
        return None
    return f"{' and '.join(added)}: {STRUCTURE_WHY}"


__all__ = ["KINDS", "Verdict", "verdict_of", "kind_of", "label", "unseen_summary",
           "structure_note"]
