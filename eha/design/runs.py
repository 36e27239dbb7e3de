"""The table of ``eha design --results`` (``design_runs``: one row per designed command) and
its writer :func:`save_design_run`, declared where the store finds it
(:func:`eha.campaigns.jobs.register_table`; entry points ``eha.tables``).

``eha design verify`` needs no table of its own: its campaign's assessments are a detection
campaign's (``health_assessments``).
"""

from __future__ import annotations

import hashlib
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

from eha.campaigns.jobs import register_table
from eha.campaigns.store import replace_rows

#: One row per ``eha design --results`` (:func:`design_row`).
DESIGN_RUNS = """
        CREATE TABLE IF NOT EXISTS design_runs (
            run_id        VARCHAR PRIMARY KEY,  -- hash of the design's settings
            created_at    TIMESTAMP,
            name          VARCHAR,   -- base name of the files (the design's name)
            command_file  VARCHAR,   -- the designed command (t,com in SI)
            json_file     VARCHAR,   -- the design's JSON report
            duration      DOUBLE,    -- s
            settings      JSON,      -- every input: limits (SI), signals, noise, alpha, seed
            targets       JSON,      -- per target: predicted minimum detectable size (SI),
                                     -- the best library command's, ratio, verdict
            pairs         JSON,      -- the pairs to tell apart and at which sizes
            detectable    INTEGER,   -- targets the design shows
            n_targets     INTEGER,
            model_form    DOUBLE,    -- the check's LF healthy residual [noise stds]
            seconds       DOUBLE)    -- s, wall time of the design"""

register_table("design_runs", DESIGN_RUNS)


def design_row(result: Any, paths: Mapping[str, Path], name: str) -> dict[str, Any]:
    """The ``design_runs`` row of a :class:`eha.design.api.DesignResult` saved to ``paths``
    (:meth:`~eha.design.api.DesignResult.save`)."""
    doc = result.to_dict()
    key = json.dumps({"settings": result.settings, "name": name,
                      "file": str(Path(paths["command"]).resolve())}, sort_keys=True,
                     default=str)
    targets = doc["targets"]
    for t in result.targets:  # the report shows each size as the console does
        targets[t.name]["display_factor"] = float(t.display[1])
    return {"run_id": hashlib.sha256(key.encode()).hexdigest()[:16],
            "created_at": datetime.now(timezone.utc).replace(tzinfo=None), "name": name,
            "command_file": str(Path(paths["command"]).resolve()),
            "json_file": str(Path(paths["json"]).resolve()),
            "duration": float(result.settings.get("duration", len(result.t) * 1e-3)),
            "settings": json.loads(json.dumps(result.settings, default=str)),
            "targets": targets, "pairs": doc["pairs"],
            "detectable": sum(bool(t["detectable"]) for t in targets.values()),
            "n_targets": len(targets), "model_form": doc["model_form_rms_in_noise"],
            "seconds": float(result.seconds)}


def save_design_run(results: str | Path, result: Any, paths: Mapping[str, Path],
                    name: str) -> tuple[Path, str]:
    """Store one design in ``results/eha.duckdb`` (``design_runs``; the same design saved to
    the same file replaces its row). Returns the database path and the run id."""
    row = design_row(result, paths, name)
    return replace_rows(results, "design_runs", [row], {"run_id": row["run_id"]}), row["run_id"]


__all__ = ["DESIGN_RUNS", "design_row", "save_design_run"]
