"""The prognostics' result tables (``eha rul``, docs/prognostics.md): one health assessment per
record (:data:`CHECKS`, the table of the runner's job kind ``health``, listed in its
declaration :data:`eha.prognostics.jobs.HEALTH`) and the RUL predictions made from them
(written by the parent), declared where the store finds them
(:func:`eha.campaigns.jobs.register_table`; entry points ``eha.tables``)."""

from __future__ import annotations

from eha.campaigns.jobs import Table, register_table

#: One row per record of a health campaign (a ``health`` job).
HEALTH_CHECKS = """
        CREATE TABLE IF NOT EXISTS health_checks (
            run_key    VARCHAR PRIMARY KEY,
            campaign   VARCHAR,   -- rul-<manifest>-<hash>
            actuator   VARCHAR,
            cycle      DOUBLE,    -- manifest unit (cycles or hours)
            record     VARCHAR,   -- absolute path of the record
            record_sha VARCHAR,   -- SHA-256 (16 hex) of the record file
            fit        JSON,      -- fitted faults and bounds {name: [lo, hi]}
            estimates  JSON,      -- identified values {name: value} (SI)
            intervals  JSON,      -- {name: [lo, hi]} at level (SI)
            level      DOUBLE,    -- probability of the intervals (0.9)
            flagged    BOOLEAN,   -- residual well above noise: the model misses something
            objective  DOUBLE,    -- m, RMSE at the estimate
            seed       BIGINT,    -- optimizer seed
            method     VARCHAR,
            seconds    DOUBLE)    -- s, identification wall time in the worker"""
#: One row per actuator and check of an ``eha rul`` run.
RUL_PREDICTIONS = """
        CREATE TABLE IF NOT EXISTS rul_predictions (
            run_id      VARCHAR,   -- the health campaign (rul-<manifest>-<hash>)
            actuator    VARCHAR,
            cycle       DOUBLE,    -- check, manifest unit
            rul         DOUBLE,    -- median RUL from the checks up to this one (NULL: none)
            rul_lo      DOUBLE,    -- 5 % quantile
            rul_hi      DOUBLE,    -- 95 % quantile (NULL: beyond the horizon)
            driver      VARCHAR,   -- fault that reaches its limit first (most draws)
            estimates   JSON,
            intervals   JSON,
            flagged     BOOLEAN,
            crossings   JSON,      -- per limited fault {median, lo, hi} crossing cycle
            law_weights JSON,      -- per fault posterior weight of each law
            limits      JSON,
            n_used      INTEGER,   -- checks used in the fit
            seed        BIGINT,    -- seed of this check's draws
            created_at  TIMESTAMP,
            PRIMARY KEY (run_id, actuator, cycle))"""

#: The ``health`` kind's table (its declaration lists it).
CHECKS = Table("health_checks", HEALTH_CHECKS, per_run=True)
#: Added after the first release: the check whose health history a prediction came from
#: ('fleet': the identification of every record; 'baseline': the change check, each record's
#: change since the actuator's baseline added to the baseline's identified value). Older rows
#: read NULL: the fleet check.
RUL_ADDED = (("reference", "VARCHAR"),)

register_table("rul_predictions", RUL_PREDICTIONS, added=RUL_ADDED)

__all__ = ["CHECKS", "HEALTH_CHECKS", "RUL_PREDICTIONS"]
