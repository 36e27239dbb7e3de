"""The residual loop's result tables (``explain_runs``, ``explain_steps``) and their writer
:func:`save_explain`, declared where the store finds them
(:func:`eha.campaigns.jobs.register_table`; entry points ``eha.tables``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.campaigns.jobs import register_table
from eha.campaigns.store import replace_parts

#: One row per run of the loop (:meth:`eha.explain.results.ExplainResult.run_row`).
EXPLAIN_RUNS = """
        CREATE TABLE IF NOT EXISTS explain_runs (
            run_id          VARCHAR PRIMARY KEY,  -- hash of the inputs and settings
            source          VARCHAR,   -- measured-data file
            created_at      TIMESTAMP,
            fit             JSON,      -- declared faults and bounds {name: [lo, hi]}
            holdout         VARCHAR,   -- what the held-out data was
            settings        JSON,      -- loop settings, method, pop, seed
            rmse_before     DOUBLE,    -- m, whole record, declared faults only
            rmse_after      DOUBLE,    -- m, whole record, with the added effects
            noise_rmse      DOUBLE,    -- m, measurement noise estimated from the record
            unexplained_rmse DOUBLE,   -- m, sqrt(max(rmse_after^2 - noise^2, 0))
            faults_before   JSON,
            faults_after    JSON,
            effects         JSON,      -- added effects, in order
            stop_reason     VARCHAR,
            seconds         DOUBLE)"""
#: One row per added effect (:meth:`eha.explain.results.ExplainResult.step_rows`).
EXPLAIN_STEPS = """
        CREATE TABLE IF NOT EXISTS explain_steps (
            run_id            VARCHAR,
            step              INTEGER,  -- 1, 2, ... in the order the effects were added
            effect            VARCHAR,  -- effect name (docs/model.md §6)
            params            JSON,     -- estimated effect parameters (SI)
            rmse_before       DOUBLE,   -- m, whole record
            rmse_after        DOUBLE,
            rmse_fit_before   DOUBLE,   -- m, fitted part
            rmse_fit_after    DOUBLE,
            rmse_hold_before  DOUBLE,   -- m, held-out part or validation record
            rmse_hold_after   DOUBLE,
            faults_before     JSON,
            faults_after      JSON,
            gain              DOUBLE,   -- relative held-out RMSE reduction
            score             DOUBLE,   -- gain minus the parameter penalty
            PRIMARY KEY (run_id, step))"""

register_table("explain_runs", EXPLAIN_RUNS,
               added=(("unexplained", "BOOLEAN"), ("verdict", "VARCHAR"),
                      ("command_hold", "VARCHAR"), ("leads", "JSON"),
                      # above the healthy band, not only the noise (issue 24)
                      ("beyond_healthy", "BOOLEAN"),
                      # the verdict's kind and facts (issue 42)
                      ("verdict_kind", "VARCHAR"), ("at_noise", "BOOLEAN"),
                      ("within_healthy_band", "BOOLEAN"), ("unique_explanation", "BOOLEAN"),
                      # how the run went, apart from its settings (issue 40)
                      ("facts", "JSON"),
                      # above the noise, at the found model's own level (issue 41)
                      ("at_model_level", "BOOLEAN")))
register_table("explain_steps", EXPLAIN_STEPS)


def save_explain(results: str | Path, run: Mapping[str, Any],
                 steps: Sequence[Mapping[str, Any]]) -> Path:
    """Store one residual-loop run (``explain_runs``) and its steps (``explain_steps``).

    One transaction; a run with the same ``run_id`` is replaced. Returns the database path.
    """
    return replace_parts(results, [("explain_runs", [run], {"run_id": run["run_id"]}),
                                   ("explain_steps", steps, {"run_id": run["run_id"]})])


__all__ = ["EXPLAIN_RUNS", "EXPLAIN_STEPS", "save_explain"]
