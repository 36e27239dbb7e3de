"""The health layer's result tables: the ``health_assessment`` kind's assessments
(:data:`ASSESSMENTS`, listed in the kind's declaration, :data:`eha.health.detection.HEALTH`),
a check's verdicts and a calibration's thresholds (:mod:`eha.health.monitoring`), declared
where the store finds them (:func:`eha.campaigns.jobs.register_table`; entry points
``eha.tables``)."""

from __future__ import annotations

from eha.campaigns.jobs import Table, register_table

#: One row per run of a detection campaign (``[health]`` section).
HEALTH_ASSESSMENTS = """
        CREATE TABLE IF NOT EXISTS health_assessments (
            run_key       VARCHAR PRIMARY KEY,
            command       VARCHAR,
            grp           VARCHAR,   -- 'healthy' or the injected fault 'NAME=value'
            seed          BIGINT,    -- actuator draw, dither, noise and optimizer seed
            t_end         DOUBLE,    -- s
            noise         DOUBLE,    -- m, sensor noise std of the record
            base_model    VARCHAR,   -- LF of the assessment ('calibrated' or 'plain')
            level         DOUBLE,    -- nominal coverage of the intervals
            truth         JSON,      -- true value of every fault (SI)
            hf            JSON,      -- HF parameters of the actuator (dispersion + fault)
            estimates     JSON,      -- assessed value of every fault (SI)
            means         JSON,      -- posterior mean over the hypotheses (detection input)
            spread        JSON,      -- std of each fault in the hypothesis that fits it
            intervals     JSON,      -- {name: [lo, hi]} at level
            weights       JSON,      -- posterior weight of each hypothesis ('none' = H0)
            best          VARCHAR,   -- most probable hypothesis' extra fault or 'none'
            flagged       BOOLEAN,   -- residual well above the noise
            residual_rmse DOUBLE,    -- m
            noise_rmse    DOUBLE,    -- m, estimated from the record
            n_eff         DOUBLE,    -- effective samples of the evidence
            seconds       DOUBLE)    -- s, assessment wall time in the worker"""
#: One row per fault of a check (``eha health check``).
HEALTH_VERDICTS = """
        CREATE TABLE IF NOT EXISTS health_verdicts (
            check_id    VARCHAR,   -- hash of the record, calibration and settings
            record      VARCHAR,   -- the record's path
            created_at  TIMESTAMP,
            calibration VARCHAR,   -- calibration file (NULL: none)
            fault       VARCHAR,
            estimate    DOUBLE,
            lo          DOUBLE,    -- interval at level
            hi          DOUBLE,
            level       DOUBLE,
            healthy     DOUBLE,    -- value of a healthy actuator
            threshold   DOUBLE,    -- of the detection statistic (NULL without calibration)
            statistic   DOUBLE,    -- deviation from healthy in the direction of degradation
            degraded    BOOLEAN,   -- NULL without calibration
            weight      DOUBLE,    -- posterior weight of the fault's hypothesis
            isolated    BOOLEAN,
            flagged     BOOLEAN,
            PRIMARY KEY (check_id, fault))"""
#: One row per fault of a calibration (``eha health calibrate``).
HEALTH_THRESHOLDS = """
        CREATE TABLE IF NOT EXISTS health_thresholds (
            calibration VARCHAR,   -- calibration file
            command     VARCHAR,
            t_end       DOUBLE,
            fault       VARCHAR,
            threshold   DOUBLE,    -- of the detection statistic (fault unit)
            mean        DOUBLE,    -- healthy fleet, statistic
            std         DOUBLE,
            n           INTEGER,
            alpha       DOUBLE,    -- probability that a healthy check raises any alarm
            created_at  TIMESTAMP,
            PRIMARY KEY (calibration, fault))"""

#: The ``health_assessment`` kind's table (its declaration lists it).
ASSESSMENTS = Table("health_assessments", HEALTH_ASSESSMENTS, per_run=True)
#: Columns added after the first release: which check made a row ('fleet': against the
#: healthy fleet; 'baseline': the change since the actuator's own earlier record, whose path
#: ``baseline`` names; then ``estimate``, ``lo``, ``hi`` are the fault's change) and, for a
#: calibration, which check its thresholds are for. Older rows read NULL: the fleet check.
#: ``beside`` (a change check's row): the fault's change read beside the first isolated fault
#: (JSON: fault, change, interval, statistic, threshold, degraded, named; NULL where not judged).
VERDICTS_ADDED = (("reference", "VARCHAR"), ("baseline", "VARCHAR"), ("beside", "JSON"))
THRESHOLDS_ADDED = (("reference", "VARCHAR"),)

register_table("health_verdicts", HEALTH_VERDICTS, added=VERDICTS_ADDED)
register_table("health_thresholds", HEALTH_THRESHOLDS, added=THRESHOLDS_ADDED)

__all__ = ["ASSESSMENTS", "HEALTH_ASSESSMENTS", "HEALTH_VERDICTS", "HEALTH_THRESHOLDS"]
