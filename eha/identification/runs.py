"""The table of ``eha fdi --results`` (``fdi_runs``: one row per identification) and its
writer :func:`save_fdi_run`, declared where the store finds it
(:func:`eha.campaigns.jobs.register_table`; entry points ``eha.tables``).

An FDI campaign's cases go to ``fdi_results`` (:mod:`eha.identification.cases`); a single
``eha fdi`` is not a campaign's run and has its own table.
"""

from __future__ import annotations

import hashlib
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from eha.campaigns.jobs import register_table
from eha.campaigns.store import replace_rows

#: One row per ``eha fdi --results`` (:func:`fdi_row`). SI units as ``eha params``.
FDI_RUNS = """
        CREATE TABLE IF NOT EXISTS fdi_runs (
            run_id        VARCHAR PRIMARY KEY,  -- hash of the reference and the settings
            created_at    TIMESTAMP,
            source        VARCHAR,   -- 'HF <command> ...' or the measured record's path
            base_model    VARCHAR,   -- LF model fitted ('plain' or 'calibrated')
            command_hold  VARCHAR,   -- measured record: how its command was rebuilt
            method        VARCHAR,   -- ga, ga+ps, ps, lm
            seed          BIGINT,
            objective_name VARCHAR,  -- rmse or objfcn
            objective     DOUBLE,    -- m, at the estimate
            level         DOUBLE,    -- nominal coverage of the intervals
            names         JSON,      -- fitted parameters, in order
            bounds        JSON,      -- {name: [lo, hi]} searched (SI)
            estimates     JSON,      -- {name: value} (SI)
            intervals     JSON,      -- {name: [lo, hi]} at level (SI)
            truth         JSON,      -- HF reference: the injected values (SI); NULL measured
            errors_pct    JSON,      -- HF reference: (truth - estimate) / truth x 100
            mean_err_pct  DOUBLE,    -- mean of the |errors_pct|
            flagged       BOOLEAN,   -- residual well above the record's noise
            noise_rmse    DOUBLE,    -- m, noise estimated from the record
            evaluations   BIGINT,
            seconds       DOUBLE)    -- s, wall time of the fit"""

register_table("fdi_runs", FDI_RUNS)


def fdi_row(run: Any) -> dict[str, Any]:
    """The ``fdi_runs`` row of an :class:`eha.identification.fdi.Identification`; its
    ``run_id`` hashes what was fitted and how (the same fit again replaces its row)."""
    res = run.result
    key = {"source": run.source, "names": list(res.names),
           "bounds": {k: list(v) for k, v in res.bounds.items()}, "method": res.method,
           "seed": res.seed, "objective": res.objective_name, "level": res.level,
           "base_model": run.base_model, "command_hold": run.command_hold,
           "truth": run.truth}
    run_id = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()
                            ).hexdigest()[:16]
    return {"run_id": run_id, "created_at": datetime.now(timezone.utc).replace(tzinfo=None),
            "source": run.source, "base_model": run.base_model,
            "command_hold": run.command_hold, "method": res.method, "seed": int(res.seed),
            "objective_name": res.objective_name, "objective": float(res.objective),
            "level": res.level, "names": list(res.names),
            "bounds": {k: list(v) for k, v in res.bounds.items()},
            "estimates": dict(res.estimates),
            "intervals": {k: list(v) for k, v in res.intervals.items()},
            "truth": run.truth, "errors_pct": run.errors_pct,
            "mean_err_pct": run.mean_err_pct, "flagged": bool(res.flagged),
            "noise_rmse": res.noise_rmse, "evaluations": int(res.evaluations),
            "seconds": float(res.seconds)}


def save_fdi_run(results: str | Path, run: Any) -> tuple[Path, str]:
    """Store one identification in ``results/eha.duckdb`` (``fdi_runs``; a fit of the same
    reference with the same settings replaces its row). Returns the database path and the
    run id."""
    row = fdi_row(run)
    return replace_rows(results, "fdi_runs", [row], {"run_id": row["run_id"]}), row["run_id"]


__all__ = ["FDI_RUNS", "fdi_row", "save_fdi_run"]
