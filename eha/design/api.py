"""``eha.design(...)``: the test command that makes the chosen faults and effects detectable and
separable within a test's limits, with its predicted figures next to the library commands'.

Compute, save and plot are separate steps: :func:`design` returns a :class:`DesignResult`;
``result.save(folder)`` writes the command file, the JSON report and the figure;
``result.to_pandas()`` is the per-target table.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Mapping, Sequence

import numpy as np

from eha.design.family import COMMAND_DT, DesignError, Limits, command_samples, decode
from eha.design.result import DesignResult
from eha.design.predict import FOLLOW_RATIO, Prediction, predict
from eha.design.library import best_by_score, dominated_by, library_cut, within_limits
from eha.design.search import best_library, score, search
from eha.design.targets import SIGNALS, resolve_targets, with_probes
from eha.models.faults import FAULTS
from eha.models.commands import array_command

#: A test load the "what would make it visible" line tries [N] (an eighth of the jack's
#: 16 kN stall force).
TEST_LOAD = 2000.0


def _pairs(separate: Sequence[Sequence[str]] | str) -> list[tuple[str, str]]:
    if isinstance(separate, str):
        separate = [p.split(",") for p in separate.split(";") if p.strip()]
    return [tuple(s.strip() for s in p) for p in separate]


def design(faults: Sequence[str] | None = None, effects: Sequence[str] = (),
           separate: Sequence[Sequence[str]] = (), around: Mapping[str, float] | None = None,
           limits: Limits | None = None, signals: Sequence[str] = ("xu",),
           sampling: float = 1000.0, noise: Mapping[str, float] | None = None,
           alpha: float = 0.01, seed: int = 0, actuators: int = 3, population: int = 32,
           generations: int = 30, check: str = "fleet",
           on_progress: Callable[[str], None] | None = None) -> DesignResult:
    """Design a test command (docs/design.md).

    Parameters
    ----------
    faults : sequence of str, optional
        Health faults to detect (default: every registered fault, ``eha faults``); ``[]`` for
        none.
    effects : sequence of str
        Effects of the residual loop's library to detect.
    separate : sequence of pairs
        Pairs of faults or effects to tell apart (``[("external_load", "offset")]``).
    around : mapping, optional
        Deviation from healthy of targets to take their signatures at (a record's fitted
        rivals, ``eha explain``'s JSON) [parameter unit].
    limits : Limits
        Duration, stroke, rate and frequency of the test.
    signals : sequence of str
        Recorded signals: ``xu`` and optionally ``p12``, ``cor``.
    sampling : float
        Recorded sampling rate [Hz], a divisor of 1000.
    noise : mapping, optional
        White-noise std per signal (default ``SIGNALS``) [signal unit].
    alpha : float
        False-alarm probability of one check, in (0, 0.5).
    seed : int
        Seed of the search (the same seed gives the same command).
    actuators : int
        Actuators the design must work on (the nominal and scattered ones), 1 to 10.
    population, generations : int
        Search budget.
    check : {"fleet", "baseline"}
        The health check the test is for: against the healthy fleet, or the change since the
        actuator's own earlier record (:mod:`eha.design.change`; health faults only).

    Raises
    ------
    DesignError
        Bad limits, an unknown fault, effect or signal, a pair of one.
    """
    limits = (limits or Limits()).check()
    options = _check(signals, sampling, noise, alpha, actuators, population, generations, seed)
    if check != "fleet":
        return _for_the_change_check(check, faults, effects, separate, around, signals,
                                     sampling, limits, options, seed, population, generations,
                                     on_progress)
    pairs = _pairs(separate)
    targets = resolve_targets(faults, effects, pairs)
    if around:
        targets = with_probes(targets, around)
    say = on_progress or (lambda message: None)
    start = time.perf_counter()
    cuts, beyond, library, reference = _library(targets, limits, options, say)
    # the targets asked for in their own right; a pair's other members count through it
    detect = {t.name for t in targets if t.name in set(effects) | set(
        FAULTS if faults is None else faults)}
    x, _, history = search(targets, limits, reference, pairs, seed=seed, pop=population,
                           generations=generations, on_progress=say,
                           at_size=bool(around), detect=detect, **options)
    t, com = command_samples(x, limits)
    segments = decode(x, limits)
    incumbent = _better_library_command(t, com, targets, limits, reference, pairs,
                                        bool(around), library, options, detect, cuts)
    if incumbent is not None:   # the search found nothing better: the library's command is
        name, com = incumbent   # the design (never worse than what the user already has)
        segments = [{"shape": f"library command {cuts[name].label} (cut to the limits)",
                     "start": 0.0, "length": limits.duration}]
        say(f"no member of the family found is at least as good as the library command "
            f"{cuts[name].label} (cut to the limits) on every target: it is the design")
    command = array_command(t, com, "design")
    if incumbent is not None:   # the library command's own prediction: the same yardstick
        refined, prediction = targets, library[incumbent[0]]
    else:
        say("final prediction: signatures at the predicted sizes")
        first = predict(command, targets, limits.duration, **options)
        # signatures at the predicted sizes, but at the record's own sizes where given
        refined = with_probes(targets, {n: v for n, v in first.mds.items()
                                        if math.isfinite(v) and n not in (around or {})})
        prediction = predict(command, refined, limits.duration, **options)
    alternatives = _alternatives(command, t, com, refined, prediction, limits, options)
    pair_alternatives = _apart(command, com, refined, prediction, pairs, limits, options, say)
    settings = {"faults": [x.name for x in targets if x.kind == "fault"],
                "effects": [x.name for x in targets if x.kind == "effect"],
                "separate": [list(p) for p in pairs], "around": dict(around or {}),
                **limits.to_dict(), "signals": list(signals), "sampling": sampling,
                "noise": options["noise"], "alpha": alpha, "seed": seed,
                "actuators": actuators, "population": population, "generations": generations,
                "p_detect": 0.95, "follow_ratio": FOLLOW_RATIO, "check": "fleet",
                "library_cut": library_cut({**cuts, **beyond}),
                "chosen": (f"library command {incumbent[0]}" if incumbent is not None
                           else "searched")}
    return DesignResult(t, com, refined, prediction, library, settings, segments,
                        alternatives, history, time.perf_counter() - start,
                        pair_alternatives)


def _apart(command, com, refined, prediction, pairs, limits, options, say) -> dict:
    """For each pair the design does not tell apart: what would (:func:`_pair_alternatives`),
    keyed ``"f,g"``."""
    apart = [(f, g) for f, g in pairs if not _told_apart(prediction, refined, f, g)]
    if apart:
        say(f"what would tell apart {', '.join(f'{f}/{g}' for f, g in apart)}: the load "
            f"pressure, a test load, a 4x longer test")
    return {f"{f},{g}": sizes for (f, g), sizes in zip(apart, _pair_alternatives(
        command, com, refined, apart, limits, options))}


def _library(targets, limits, options, say):
    """The library commands cut to the limits (:func:`eha.design.library.within_limits`),
    their predictions and the best one per target."""
    cuts, beyond = within_limits(limits, say)
    say(f"library commands cut to the limits: predicting {len(targets)} targets on "
        f"{', '.join(c.label for c in cuts.values())}")
    library = {name: predict(c.command(), targets, limits.duration, **options)
               for name, c in cuts.items()}
    return cuts, beyond, library, best_library(targets, library)


def _for_the_change_check(check, faults, effects, separate, around, signals, sampling, limits,
                          options, seed, population, generations, on_progress) -> DesignResult:
    """``check="baseline"``: :func:`eha.design.change.design_change`, for the health faults on
    the position at 1 kHz only."""
    from eha.design.change import design_change

    if check != "baseline":
        raise DesignError(f"check={check!r}: allowed fleet or baseline")
    if effects or separate or around or tuple(signals) != ("xu",) or sampling != 1000.0:
        raise DesignError("check=baseline: the change check judges the health faults on the "
                          "position at 1 kHz (no effects, pairs to separate, sizes of an explain "
                          "or other signals)")
    return design_change(faults, limits, options["noise"]["xu"], options["alpha"], seed,
                         population, generations, on_progress)


def _better_library_command(t, com, targets, limits, reference, pairs, at_size, library,
                            options, detect=None, cuts=None) -> tuple[str, np.ndarray] | None:
    """The library command cut to ``limits`` (:func:`eha.design.library.cut_to_limits`) that
    the LF model follows and that the searched command does not beat, with its samples; None
    when the searched command is at least as good. Beaten means: by the search's own objective
    (:func:`eha.design.search.score`), or on any one target of ``detect`` against the library
    command with the best score (:func:`eha.design.library.dominated_by`: a design never
    makes a chosen target harder to see than the best library command does). A search over a
    family is a local answer: the incumbent designs are candidates too."""
    all_pairs = [q for f, g in pairs for q in ((f, g), (g, f))]
    searched = predict(array_command(t, com, "design"), targets, limits.duration,
                       pairs=all_pairs, **options)
    best = score(searched, targets, reference, pairs, at_size, detect)
    chosen = None
    usable = {n: p for n, p in library.items() if p.followed and cuts[n].beyond is None}
    for name, pred in usable.items():
        value = score(pred, targets, reference, pairs, at_size, detect)
        if value < best - 1e-9:
            best, chosen = value, (name, cuts[name].com)
    if chosen is None and usable and not pairs:
        top = best_by_score(usable, targets, reference, detect, cuts)
        if dominated_by(searched, usable[top], targets, detect):
            chosen = (top, cuts[top].com)
    return chosen


def _check(signals, sampling, noise, alpha, actuators, population, generations, seed) -> dict:
    for s in signals:
        if s not in SIGNALS:
            raise DesignError(f"signals: {s!r}; allowed {', '.join(SIGNALS)}")
    if "xu" not in signals:
        raise DesignError("signals: the position xu is always recorded (e.g. xu or xu,p12)")
    if not (isinstance(sampling, (int, float)) and sampling > 0 and
            abs(1000.0 / sampling - round(1000.0 / sampling)) < 1e-9 and sampling <= 1000):
        raise DesignError(f"sampling={sampling!r}: allowed a divisor of 1000 Hz (1000, 500, "
                          "250, 200, 100, ...)")
    noise = {s: SIGNALS[s][1] for s in signals} | dict(noise or {})
    for s, v in noise.items():
        if s not in SIGNALS or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise DesignError(f"noise.{s}={v!r}: allowed a positive number "
                              f"[{SIGNALS.get(s, ('?',))[0]}]")
    if not (isinstance(alpha, (int, float)) and 0 < alpha < 0.5):
        raise DesignError(f"alpha={alpha!r}: allowed range (0, 0.5)")
    for name, value, lo, hi in (("actuators", actuators, 1, 10),
                                ("population", population, 4, 500),
                                ("generations", generations, 1, 500),
                                ("seed", seed, 0, 2**31 - 1)):
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise DesignError(f"{name}={value!r}: allowed range [{lo}, {hi}]")
    return {"signals": tuple(signals), "noise": noise, "alpha": float(alpha),
            "n_actuators": actuators, "decimate": int(round(1000.0 / sampling))}


def _told_apart(prediction: Prediction, targets, f: str, g: str) -> bool:
    """Whether ``prediction`` tells ``f`` and ``g`` apart, both ways, at their probes."""
    by = {t.name: t for t in targets}
    return all(prediction.separable_size(a, b) <= abs(by[a].probe) for a, b in ((f, g), (g, f)))


def _tries(command, com, limits, options) -> list[tuple]:
    """What would show more: ``(label, command, t_end, options, setting)`` with P12 recorded
    (when it is not), with a :data:`TEST_LOAD` and on the command repeated four times."""
    tries = []
    if "p12" not in options["signals"]:
        tries.append(("the load pressure P12 recorded", command, limits.duration,
                      {**options, "signals": (*options["signals"], "p12"),
                       "noise": {**options["noise"], "p12": SIGNALS["p12"][1]}}, None))
    tries.append((f"a {TEST_LOAD:g} N test load", command, limits.duration, options,
                  {"FRC": TEST_LOAD}))
    n = com.size - 1
    long_t = np.arange(4 * n + 1) * COMMAND_DT
    long_com = np.concatenate([com[:-1]] * 4 + [com[-1:]])
    tries.append(("a 4x longer test", array_command(long_t, long_com, "design x4"),
                  4 * limits.duration, options, None))
    return tries


def _alternatives(command, t, com, targets, prediction, limits, options) -> dict:
    """For each target the design does not show: its predicted size with P12 recorded, with
    a test load and on the command repeated four times (a 4x longer test)."""
    hidden = [x for x in targets if not prediction.detectable(x)]
    if not hidden:
        return {}
    out: dict[str, dict[str, float]] = {x.name: {} for x in hidden}
    for label, cmd, t_end, opts, setting in _tries(command, com, limits, options):
        pred = predict(cmd, hidden, t_end, pairs=[], setting=setting, **opts)
        for x in hidden:
            out[x.name][label] = pred.mds[x.name]
    return out


def _pair_alternatives(command, com, targets, pairs, limits, options) -> list[dict]:
    """For each pair of ``pairs``: the separable sizes of both members [their units] under
    each of :func:`_tries`' alternatives, ``{label: {f: size, g: size}}``."""
    out: list[dict[str, dict[str, float]]] = [{} for _ in pairs]
    if not pairs:
        return out
    both = [o for f, g in pairs for o in ((f, g), (g, f))]
    for label, cmd, t_end, opts, setting in _tries(command, com, limits, options):
        pred = predict(cmd, targets, t_end, pairs=both, setting=setting, **opts)
        for row, (f, g) in zip(out, pairs):
            row[label] = {f: pred.separable_size(f, g), g: pred.separable_size(g, f)}
    return out


__all__ = ["design", "DesignResult", "TEST_LOAD"]
