"""A designed test command and what it is predicted to show (:class:`DesignResult`), for
either check (:func:`eha.design.api.design`, :func:`eha.design.change.design_change`)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eha.design.predict import Prediction
from eha.design.search import best_library
from eha.design.targets import Target
from eha.models.commands import write_command_file

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


__all__ = ["DesignResult"]
