"""Verification of a design by simulation: a health-detection campaign on the designed command
and on library commands, the same fleets and alpha, through the campaign runner.

Per command the healthy fleet is split by seed: the first ``calibration`` actuators set the
thresholds (:func:`eha.health.detection.calibrate_thresholds`), the others, never used to
design or calibrate, measure the false-alarm rate (with its one-sided 95 % Clopper-Pearson
bound). Each fault is injected at levels around its predicted minimum detectable size (0.5,
1, 2 and 4 times, within its search bounds) into actuators of their own; the measured minimum
detectable size is the smallest level detected in at least 95 % of its records, and the
isolation the share of a level's records whose declared fault is the injected one.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.design.family import DesignError
from eha.health.assessment import DEFAULT_NOISE_P12
from eha.health.detection import calibrate_thresholds, isolate_row, statistic
from eha.health.monitoring import _assessments
from eha.identification.healthy import upper_bound
from eha.models.faults import FAULTS

#: Multiples of the predicted minimum detectable size injected.
LEVEL_MULTIPLES = (0.5, 1.0, 2.0, 4.0)
#: Detection rate a measured minimum detectable size needs.
P_DETECT = 0.95


def levels_around(mds: Mapping[str, float], names: Sequence[str] | None = None
                  ) -> dict[str, list[float]]:
    """Fault values (not deviations) at :data:`LEVEL_MULTIPLES` of each predicted detectable
    deviation, inside the fault's search bounds; a fault predicted undetectable gets its
    campaign levels."""
    out = {}
    for name in names or mds:
        f = FAULTS[name]
        d = mds.get(name)
        lo, hi = f.bounds
        if d is None or not math.isfinite(d) or d <= 0:
            out[name] = list(f.levels)
            continue
        sign = -1.0 if f.direction < 0 else 1.0
        vals = sorted({float(f"{min(max(f.healthy + sign * m * d, lo), hi):.4g}")
                       for m in LEVEL_MULTIPLES} - {f.healthy})
        out[name] = vals
    return out


def verification_table(name: str, commands: Sequence[str], levels: Mapping[str, list[float]],
                       healthy: int, per_level: int, t_end: float, noise: float = 1e-6,
                       seed: int = 0, signals: Sequence[str] = ("xu",),
                       noise_p12: float | None = None) -> dict[str, Any]:
    """The campaign table (a ``[health]`` campaign) of a verification; with ``p12`` among
    ``signals`` the checks fit the load pressure too (recorded with ``noise_p12`` [Pa])."""
    health = {"commands": list(commands), "t_end": float(t_end),
              "healthy_actuators": int(healthy), "actuators": int(per_level),
              "seed": int(seed), "noise": float(noise), "base_model": "calibrated",
              "level": 0.9, "faults": {k: list(v) for k, v in levels.items()}}
    if "p12" in signals:
        health |= {"signals": ["xu", "p12"], "noise_p12": float(noise_p12 or DEFAULT_NOISE_P12)}
    return {"name": name, "kind": "health",
            "description": "verification of a designed test command (eha design verify)",
            "health": health}


def measured(rows: Sequence[Mapping[str, Any]], calibration: int, alpha: float
             ) -> dict[str, Any]:
    """Measured figures per command of a verification campaign's assessments."""
    out: dict[str, Any] = {}
    for command in sorted({r["command"] for r in rows}):
        mine = [r for r in rows if r["command"] == command]
        healthy = sorted((r for r in mine if r["grp"] == "healthy"), key=lambda r: r["seed"])
        if len(healthy) <= calibration:
            raise DesignError(f"verification: {len(healthy)} healthy records of {command}; "
                              f"more than the {calibration} of the calibration are needed")
        cal, held = healthy[:calibration], healthy[calibration:]
        thresholds, _ = calibrate_thresholds(cal, alpha)
        alarms = sum(any(statistic(n, r["means"][n]) > t for n, t in thresholds.items())
                     for r in held)
        faults: dict[str, Any] = {}
        for r in mine:
            if r["grp"] == "healthy":
                continue
            name, _, value = r["grp"].partition("=")
            lev = faults.setdefault(name, {}).setdefault(value, {"n": 0, "detected": 0,
                                                                 "isolated": 0})
            lev["n"] += 1
            lev["detected"] += int(statistic(name, r["means"][name]) > thresholds[name])
            lev["isolated"] += int(isolate_row(r, thresholds) == name)
        table = {}
        for name, levs in faults.items():
            entries = sorted(({"value": float(v), "deviation": abs(float(v) - FAULTS[name].healthy),
                               "p_detect": e["detected"] / e["n"],
                               "isolated": e["isolated"] / e["n"], "n": e["n"]}
                              for v, e in levs.items()), key=lambda e: e["deviation"])
            ok = [e["deviation"] for e in entries if e["p_detect"] >= P_DETECT]
            # detected at the smallest level tried: the size is a bound, not a measurement
            table[name] = {"levels": entries, "min_detectable": min(ok) if ok else None,
                           "at_lowest_level": bool(ok) and min(ok) == entries[0]["deviation"]}
        out[command] = {"thresholds": thresholds, "calibration_actuators": len(cal),
                        "false_alarms": {"n": len(held), "alarms": int(alarms),
                                         "rate": alarms / len(held),
                                         "upper_95": upper_bound(alarms, len(held))},
                        "faults": table}
    return out


@dataclass
class Verification:
    """Measured figures of a design next to its prediction (see the module docstring)."""

    figures: dict[str, Any]
    predicted: dict[str, Any]
    settings: dict[str, Any]
    campaign: str
    results: str
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"format": 1, "campaign": self.campaign, "results": self.results,
                "settings": self.settings, "predicted": self.predicted,
                "measured": self.figures, "notes": self.notes}

    def save(self, path: str | Path) -> Path:
        from eha.outputs import write_json

        return write_json(path, self.to_dict())  # a temporary name of its own

    def markdown(self) -> str:
        """The table a person reads: per fault and command the measured minimum detectable
        deviation (``<=`` where the smallest level tried was already detected: a bound) and
        its isolation at the first level detected, then false alarms."""
        commands = list(self.figures)
        lines = ["| fault | " + " | ".join(commands) + " |", "|---|" + "---|" * len(commands)]
        for name in FAULTS:
            cells = []
            for c in commands:
                f = self.figures[c]["faults"].get(name)
                if f is None:
                    cells.append("-")
                    continue
                md = f["min_detectable"]
                top = f["levels"][-1]["deviation"] if f["levels"] else float("nan")
                iso = next((e["isolated"] for e in f["levels"]
                            if md is not None and e["deviation"] >= 2 * md), None)
                size = (f"<= {md:.3g}" if f.get("at_lowest_level") else f"{md:.3g}") \
                    if md is not None else f"> {top:.3g}"
                cells.append(size
                             + ("" if iso is None else f" (isolated {iso:.0%} at >= 2x)"))
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines += ["", "| command | held-out healthy | alarms | rate | 95 % upper bound |",
                  "|---|---|---|---|---|"]
        for c in commands:
            fa = self.figures[c]["false_alarms"]
            lines.append(f"| {c} | {fa['n']} | {fa['alarms']} | {fa['rate']:.3f} | "
                         f"{fa['upper_95']:.3f} |")
        return "\n".join(lines) + "\n"


def verify(design_json: str | Path, command_file: str | Path | None = None,
           library: Sequence[str] = ("chirp_1cm",), healthy: int = 230,
           calibration: int = 30, per_level: int = 10, results: str | Path = "results",
           workers: int = 2, progress: bool = True, seed: int = 0,
           with_design: bool = True) -> Verification:
    """Run the verification campaign of a design (its JSON and command file, as
    :meth:`eha.design.DesignResult.save` wrote them) and measure it; ``with_design=False``
    runs the library commands alone on the design's fault levels (another fleet size)."""
    from eha.campaigns.files import CampaignError, build_campaign
    from eha.campaigns.runner import run_campaign
    from eha.models.commands import command_label

    design_json = Path(design_json)
    try:
        doc = json.loads(design_json.read_text(encoding="utf-8"))
        targets = doc["targets"]
        settings = doc["settings"]
    except FileNotFoundError:
        raise DesignError(f"design {design_json}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError):
        raise DesignError(f"design {design_json}: not an eha design report (eha design "
                          "writes one)") from None
    command = str(command_file or design_json.with_suffix(".csv"))
    if not 5 <= calibration < healthy:
        raise DesignError(f"calibration={calibration}: allowed range [5, healthy - 1]")
    if settings.get("check") == "baseline":    # the change check: simulated pairs, seconds
        if not Path(command).is_file() and with_design:
            raise DesignError(f"command {command}: no such file (the design's .csv)")
        return verify_change(doc, command, library, healthy - calibration, calibration,
                             per_level, seed, with_design)
    faults = [n for n, t in targets.items() if t.get("kind") == "fault" and n in FAULTS]
    if not faults:
        raise DesignError(f"design {design_json}: no health fault to verify")
    mds = {n: targets[n].get("min_detectable") for n in faults}
    levels = levels_around({n: (v if v is not None else math.inf) for n, v in mds.items()},
                           faults)
    commands = ([command] if with_design else []) + list(library)
    if not commands:
        raise DesignError("library: no command to verify (give the design or a library "
                          "command)")
    signals = tuple(settings.get("signals", ["xu"]))
    noise = settings.get("noise", {})
    # a position-only design keeps the campaign name it always had
    tag = hashlib.sha256(json.dumps([commands, healthy, per_level, seed]
                                    + ([list(signals)] if "p12" in signals else []))
                         .encode()).hexdigest()
    name = f"verify-{command_label(command)}-{tag[:6]}"
    table = verification_table(name, commands, levels, healthy, per_level,
                               float(settings.get("duration", 1.0)),
                               float(noise.get("xu", 1e-6)), seed, signals,
                               noise.get("p12"))
    try:
        camp = build_campaign(table)
    except CampaignError as exc:
        raise DesignError(f"verification: {str(exc).splitlines()[0]}") from None
    run_campaign(camp, results, workers=workers, progress=progress)
    rows = _assessments(results, name)
    figures = measured(rows, calibration, float(settings.get("alpha", 0.01)))
    predicted = {"design": {n: targets[n].get("min_detectable") for n in faults},
                 "library": {n: targets[n].get("library") for n in faults}}
    return Verification(figures, predicted, {"healthy": healthy, "calibration": calibration,
                                             "per_level": per_level, "levels": levels,
                                             "library": list(library), "seed": seed,
                                             "signals": list(signals)},
                        name, str(results))


def verify_change(doc: Mapping[str, Any], command: str, library: Sequence[str],
                  held_out: int, calibration: int, per_level: int, seed: int = 0,
                  with_design: bool = True, on_progress=None):
    """``eha design verify`` of a design for the change check (its JSON ``doc`` and command
    file): :func:`measure` on the design and on each library command cut to the design's
    limits, every command at the same sizes (:data:`MEASURE_MULTIPLES` of the design's
    predicted detectable change). Returns a :class:`eha.design.verify.Verification`."""
    from eha.design.change import MEASURE_MULTIPLES, _target, measure
    from eha.design.family import Limits
    from eha.design.library import cut_to_limits

    settings, targets = doc["settings"], doc["targets"]
    faults = [n for n, t in targets.items() if t.get("kind") == "fault" and n in FAULTS]
    limits = Limits(**{k: float(settings[k]) for k in ("duration", "max_stroke", "max_rate",
                                                       "max_freq")})
    noise = float(settings.get("noise", {}).get("xu", 1e-6))
    alpha = float(settings.get("alpha", 0.01))
    sizes = {}
    for n in faults:
        md = targets[n].get("min_detectable") or _target(n).limit
        sizes[n] = [m * md for m in MEASURE_MULTIPLES]
    commands = ([("design", command)] if with_design else []) + \
        [(name, cut_to_limits(name, limits).command()) for name in library]
    figures = {}
    for label, cmd in commands:
        m = measure(cmd, limits.duration, faults, sizes, per_level, held_out, calibration,
                    alpha, noise, seed=seed, on_progress=on_progress)
        table = {}
        for n, f in m["faults"].items():
            levels = [{"value": r["size"], "deviation": r["size"], "p_detect": r["p_detect"],
                       "isolated": r["isolated"], "coverage": r["coverage"], "n": r["n"]}
                      for r in f["levels"]]
            md = f["min_detectable"]
            table[n] = {"levels": levels, "min_detectable": md,
                        "at_lowest_level": md is not None and bool(levels) and
                        md == levels[0]["deviation"], "at_twice": f["at_twice"]}
        figures[label] = {"thresholds": m["thresholds"], "calibration_actuators": calibration,
                          "false_alarms": m["false_alarms"], "faults": table}
    predicted = {"design": {n: targets[n].get("min_detectable") for n in faults},
                 "library": {n: targets[n].get("library") for n in faults}}
    return Verification(figures, predicted, {"check": "baseline", "held_out": held_out,
                                             "calibration": calibration,
                                             "per_level": per_level, "sizes": sizes,
                                             "library": list(library), "seed": seed,
                                             "library_cut_to": limits.to_dict()},
                        "change check (simulated pairs, no campaign)", "")


__all__ = ["verify", "verify_change", "Verification", "measured", "levels_around", "verification_table",
           "upper_bound", "LEVEL_MULTIPLES"]
