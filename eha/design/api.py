"""``eha.design(...)``: the test command that makes the chosen faults and effects detectable and
separable within a test's limits, with its predicted figures next to the library commands'.

Compute, save and plot are separate steps: :func:`design` returns a :class:`DesignResult`;
``result.save(folder)`` writes the command file, the JSON report and the figure;
``result.to_pandas()`` is the per-target table.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from eha.design.family import COMMAND_DT, DesignError, Limits, command_samples, decode
from eha.design.predict import FOLLOW_RATIO, Prediction, predict
from eha.design.library import best_by_score, dominated_by, within_limits
from eha.design.search import best_library, score, search
from eha.design.targets import SIGNALS, Target, resolve_targets, with_probes
from eha.models.faults import FAULTS
from eha.models.commands import array_command, write_command_file

#: A test load the "what would make it visible" line tries [N] (an eighth of the jack's
#: 16 kN stall force).
TEST_LOAD = 2000.0


@dataclass
class DesignResult:
    """A designed test command and what it is predicted to show.

    Attributes
    ----------
    t, com : float64 arrays
        The command at 1 kHz [s, m].
    targets : list of Target
    prediction : Prediction
        On the designed command (signatures re-taken at the predicted sizes).
    library : dict
        Library command name -> its :class:`Prediction` (same targets, actuators, alpha).
    settings : dict
        Every input of the design (limits, signals, noise, alpha, seed, search budget).
    segments : list of dict
        What the command is made of (shape, start, length, centre, amplitude, frequency).
    alternatives : dict
        For each target the design does not show: its predicted size with the load pressure
        recorded, with a test load, and on a test four times as long.
    pair_alternatives : dict
        For each pair the design does not tell apart at its sizes (``"A,B"``): the separable
        sizes of both members under the same three alternatives.
    history : list of float
        Best search score per generation.
    seconds : float
        Wall time of the design [s].
    """

    t: np.ndarray
    com: np.ndarray
    targets: list[Target]
    prediction: Prediction
    library: dict[str, Prediction]
    settings: dict[str, Any]
    segments: list[dict[str, Any]]
    alternatives: dict[str, dict[str, float]] = field(default_factory=dict)
    history: list[float] = field(default_factory=list)
    seconds: float = 0.0
    pair_alternatives: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    # -- reading

    def best_library(self) -> dict[str, tuple[str, float]]:
        return best_library(self.targets, self.library)

    def ratio(self, name: str) -> float:
        """Designed over best library detectable size of target ``name``."""
        return self.prediction.mds[name] / self.best_library()[name][1]

    def verdict(self, target: Target) -> str:
        """One line on what the design shows of ``target``, or why not and what would."""
        size = self.prediction.mds[target.name]
        if self.prediction.detectable(target):
            lib, ref = self.best_library()[target.name]
            if ref >= target.limit:
                return f"detectable from {target.shown(size)}; no library command shows it"
            return (f"detectable from {target.shown(size)} ({size / ref:.2f}x the best library "
                    f"command's, {lib})")
        alt = self.alternatives.get(target.name, {})
        helps = [f"{how}: {target.shown(v)}" for how, v in alt.items()
                 if math.isfinite(v) and v <= target.limit]
        return (f"not detectable here: needs {target.shown(size)}, beyond the largest size the "
                f"check reports ({target.shown(target.limit)}); its footprint at the probe "
                f"{target.shown(abs(target.probe))} is "
                f"{self.prediction.footprint[target.name] * 1e6:.2g} µm RMS"
                + (f"; visible with {'; '.join(helps)}" if helps else
                   "; none of the load pressure, a test load or a 4x longer test shows it"))

    def pairs(self) -> list[dict[str, Any]]:
        """Each requested pair: the size of each member at which it is told from the other,
        on the design and on the best library command for it, and whether the design tells
        them apart at the sizes it was designed around."""
        by = {t.name: t for t in self.targets}
        out = []
        for f, g in (tuple(p) for p in self.settings.get("separate", [])):
            row = {"pair": [f, g], "at": {f: by[f].probe, g: by[g].probe}}
            for label, pred in {"design": self.prediction, **self.library}.items():
                row[label] = {f: _finite(pred.separable_size(f, g)),
                              g: _finite(pred.separable_size(g, f))}
            row["told_apart_at_these_sizes"] = all(
                self.prediction.separable_size(a, b) <= abs(by[a].probe)
                for a, b in ((f, g), (g, f)))
            row["alternatives"] = {how: {k: _finite(v) for k, v in sizes.items()}
                                   for how, sizes in
                                   self.pair_alternatives.get(f"{f},{g}", {}).items()}
            out.append(row)
        return out

    def to_dict(self) -> dict[str, Any]:
        ref = self.best_library()
        rows = {}
        for t in self.targets:
            unit, k = t.display
            rows[t.name] = {
                "kind": t.kind, "parameter": t.param, "unit": t.unit, "display_unit": unit,
                "healthy": t.healthy, "limit": t.limit,
                "min_detectable": _finite(self.prediction.mds[t.name]),
                "detectable": self.prediction.detectable(t),
                "library": {c: _finite(p.mds[t.name]) for c, p in self.library.items()},
                "best_library": {"command": ref[t.name][0], "min_detectable": ref[t.name][1]},
                "ratio_to_best_library": _finite(self.ratio(t.name)),
                "alternatives": {k2: _finite(v) for k2, v in
                                 self.alternatives.get(t.name, {}).items()},
                "verdict": self.verdict(t)}
        return {"format": 1, "settings": self.settings, "segments": self.segments,
                "model_form_rms_in_noise": self.prediction.model_form,
                "library_followed": {c: p.followed for c, p in self.library.items()},
                "targets": rows,
                "separable": {f: {g: _finite(v) for g, v in row.items()}
                              for f, row in self.prediction.separable.items()},
                "separable_size": {f: {g: _finite(v) for g, v in row.items()}
                                   for f, row in self.prediction.separable_at.items()},
                "pairs": self.pairs(),
                "search_history": self.history, "seconds": self.seconds}

    def to_pandas(self):
        """One row per target: predicted detectable size on the design and on each library
        command, in the parameter's unit."""
        import pandas as pd

        rows = []
        for t in self.targets:
            row = {"target": t.name, "kind": t.kind, "unit": t.unit,
                   "design": self.prediction.mds[t.name]}
            row |= {c: p.mds[t.name] for c, p in self.library.items()}
            row["ratio_to_best_library"] = self.ratio(t.name)
            rows.append(row)
        return pd.DataFrame(rows)

    # -- writing

    def save(self, folder: str | Path, name: str = "design") -> dict[str, Path]:
        """Write ``NAME.csv`` (the command file), ``NAME.json`` and ``NAME.png`` into
        ``folder``; returns their paths."""
        from eha.design.plots import plot_design
        from eha.outputs import atomic_set

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        header = {"eha": "designed test command (eha design)", "units": "t in s, com in m"}
        header |= {k: json.dumps(v) if not isinstance(v, (int, float, str)) else v
                   for k, v in self.settings.items()}
        paths = {k: folder / f"{name}.{ext}"
                 for k, ext in (("command", "csv"), ("json", "json"), ("png", "png"))}
        # the three replaced together or not at all (two runs on one folder never mix)
        with atomic_set(list(paths.values())) as (csv_tmp, json_tmp, png_tmp):
            write_command_file(csv_tmp, self.t, self.com, header)
            json_tmp.write_text(json.dumps(self.to_dict(), indent=2))
            plot_design(self, png_tmp)
        return paths

    def plot(self, path: str | Path) -> Path:
        from eha.design.plots import plot_design

        return plot_design(self, Path(path))


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


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
    if check not in ("fleet", "baseline"):
        raise DesignError(f"check={check!r}: allowed fleet or baseline")
    if check == "baseline":
        from eha.design.change import design_change

        if effects or separate or around or tuple(signals) != ("xu",) or sampling != 1000.0:
            raise DesignError("check=baseline: the change check judges the health faults on "
                              "the position at 1 kHz (no effects, pairs, --around or other "
                              "signals)")
        return design_change(faults, limits, options["noise"]["xu"], alpha, seed, population,
                             generations, on_progress)
    pairs = _pairs(separate)
    targets = resolve_targets(faults, effects, pairs)
    if around:
        targets = with_probes(targets, around)
    say = on_progress or (lambda message: None)
    start = time.perf_counter()
    cuts, beyond = within_limits(limits, say)
    say(f"library commands cut to the limits: predicting {len(targets)} targets on "
        f"{', '.join(c.label for c in cuts.values())}")
    library = {name: predict(c.command(), targets, limits.duration, **options)
               for name, c in cuts.items()}
    reference = best_library(targets, library)
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
    say("final prediction: signatures at the predicted sizes")
    first = predict(command, targets, limits.duration, **options)
    # signatures at the predicted sizes, but at the record's own sizes where given (around)
    refined = with_probes(targets, {n: v for n, v in first.mds.items()
                                    if math.isfinite(v) and n not in (around or {})})
    prediction = predict(command, refined, limits.duration, **options)
    alternatives = _alternatives(command, t, com, refined, prediction, limits, options)
    apart = [(f, g) for f, g in pairs if not _told_apart(prediction, refined, f, g)]
    if apart:
        say(f"what would tell apart {', '.join(f'{f}/{g}' for f, g in apart)}: the load "
            f"pressure, a test load, a 4x longer test")
    pair_alternatives = {f"{f},{g}": sizes for (f, g), sizes in zip(apart, _pair_alternatives(
        command, com, refined, apart, limits, options))}
    settings = {"faults": [x.name for x in targets if x.kind == "fault"],
                "effects": [x.name for x in targets if x.kind == "effect"],
                "separate": [list(p) for p in pairs], "around": dict(around or {}),
                **limits.to_dict(), "signals": list(signals), "sampling": sampling,
                "noise": options["noise"], "alpha": alpha, "seed": seed,
                "actuators": actuators, "population": population, "generations": generations,
                "p_detect": 0.95, "follow_ratio": FOLLOW_RATIO, "check": "fleet",
                "library_cut": {n: {"scale": c.scale, "beyond": c.beyond}
                                for n, c in {**cuts, **beyond}.items()},
                "chosen": (f"library command {incumbent[0]}" if incumbent is not None
                           else "searched")}
    return DesignResult(t, com, refined, prediction, library, settings, segments,
                        alternatives, history, time.perf_counter() - start,
                        pair_alternatives)


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
