"""What :func:`eha.prognostics.jobs.run_rul` returns (:class:`RulResult`): the predictions,
the metrics against a truth, and the separate steps that write them (``.save()``,
``.plot()``) or hand them to pandas (``.to_pandas()``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eha.prognostics.degradation import LAWS, PrognosticsError


@dataclass
class RulResult:
    """What :func:`eha.prognostics.jobs.run_rul` produced: ``output`` is the JSON document
    (cycles; fault values in SI), ``predictions`` per actuator its
    :class:`eha.prognostics.rul.Prediction` at every check, ``metrics`` the prognostic
    metrics (with a truth, else None), ``histories`` the tracked faults' histories the
    predictions came from, ``truth`` the true end of life per actuator (or None)."""

    run_id: str
    output: dict[str, Any]
    predictions: dict[str, list]
    metrics: dict[str, Any] | None
    paths: dict[str, Path] = field(default_factory=dict)
    failed: list[str] = field(default_factory=list)
    assessed: int = 0
    reused: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    histories: dict[str, Any] = field(default_factory=dict, repr=False)
    truth: dict[str, float | None] | None = None

    def to_pandas(self):
        """One row per actuator and check: ``actuator``, ``cycle``, ``rul``, ``rul_lo``,
        ``rul_hi`` (median, 5 % and 95 % quantiles, in cycles; NaN where not predicted) and
        the fault that ``driver`` ends life first."""
        import pandas as pd

        rows = [{"actuator": aid, "cycle": p.cycle, "rul": e.value, "rul_lo": e.lo,
                 "rul_hi": e.hi, "driver": p.driver}
                for aid, preds in self.predictions.items() for p in preds
                for e in (p.rul_estimate,)]
        return pd.DataFrame(rows, columns=["actuator", "cycle", "rul", "rul_lo", "rul_hi",
                                           "driver"])

    def save(self, json_path: str | Path) -> Path:
        """Write :attr:`output` as JSON at ``json_path`` (whole or not at all); returns it.

        Raises
        ------
        PrognosticsError
            ``json_path`` does not end in ``.json``.
        """
        from eha.outputs import write_json

        if Path(json_path).suffix.lower() != ".json":
            raise PrognosticsError(f"`json_path` {json_path}: the file must end in .json")
        self.paths["json"] = write_json(json_path, self.output, indent=1,
                                        default=_json_default)
        return self.paths["json"]

    def plot(self, folder: str | Path) -> dict[str, Path]:
        """Every plot (one PNG per actuator: the faults' trends and the RUL; with a truth
        the alpha-lambda plot) and the fleet summary table into ``folder``; returns
        ``{kind: path}``."""
        from eha.prognostics.plots import write_plots

        laws = self.output.get("laws") or LAWS
        written = write_plots(Path(folder), self.histories, self.predictions,
                              self.output["limits"], self.truth, self.metrics,
                              seed=self.output.get("seed", 0), laws=laws)
        self.paths.update(written)
        return written


def _json_default(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.bool_):
        return bool(v)
    raise TypeError(type(v).__name__)
