"""The result database's SQL schema, in one place (:data:`SCHEMA`), and its file names.

Units are SI (cor in mA). A new kind of result (e.g. FDI) adds its table here and, when its rows
belong to runs, its name to :data:`RESULT_TABLES` (the runner's workers return rows for those
tables only; :meth:`eha.campaigns.store.ResultStore.record`). A column added to a released
table goes in :data:`ADDED_COLUMNS` too, so that an older database gets it.

This module holds constants only: nothing is imported.
"""

from __future__ import annotations

#: File name of the result database inside a results directory.
DB_NAME = "eha.duckdb"
#: Folder of the Parquet traces inside a results directory.
TRACES = "traces"

#: The SQL schema, in one place: table name -> CREATE statement. Units are SI (cor in mA).
SCHEMA: dict[str, str] = {
    "campaigns": """
        CREATE TABLE IF NOT EXISTS campaigns (
            name          VARCHAR PRIMARY KEY,
            description   VARCHAR,
            source        VARCHAR,      -- campaign file it was first run from
            spec_hash     VARCHAR NOT NULL,  -- hash of the sorted run keys
            model_version VARCHAR,
            n_runs        INTEGER,
            definition    JSON,         -- the parsed campaign file
            created_at    TIMESTAMP,
            updated_at    TIMESTAMP)""",
    "runs": """
        CREATE TABLE IF NOT EXISTS runs (
            run_key     VARCHAR PRIMARY KEY,  -- hash of the resolved job spec + model version
            campaign    VARCHAR NOT NULL,
            kind        VARCHAR NOT NULL,     -- 'simulate' (others: eha.campaigns.jobs)
            status      VARCHAR NOT NULL,     -- 'pending', 'done', 'failed'
            model       VARCHAR,
            command     VARCHAR,
            faults      JSON,                 -- fault overrides, e.g. {"BKL": 0.0001}
            fault_label VARCHAR,
            seed        BIGINT,
            t_end       DOUBLE,               -- s
            case_key    VARCHAR,              -- same command/faults/seed/t_end across models
            label       VARCHAR,
            trace_path  VARCHAR,              -- relative to the results directory
            error       VARCHAR,
            worker      VARCHAR,              -- host:pid that ran it
            queued_at   TIMESTAMP,
            started_at  TIMESTAMP,
            finished_at TIMESTAMP,
            sim_s       DOUBLE,               -- s of simulation
            elapsed_s   DOUBLE,               -- s in the worker (simulation + metrics + write)
            spec        JSON,
            trace_bytes BIGINT,               -- size of the trace file at commit (integrity)
            trace_rows  BIGINT,               -- samples in the trace file at commit
            trace_hash  VARCHAR,              -- SHA-256 of the trace file's bytes (128 bits)
            trace_mtime BIGINT)               -- its modification time at commit [ns]""",
    "metrics": """
        CREATE TABLE IF NOT EXISTS metrics (
            run_key          VARCHAR PRIMARY KEY,
            rmse_xu_com      DOUBLE,  -- m, RMS of xu - com
            max_err_xu_com   DOUBLE,  -- m, max |xu - com|
            final_err_xu_com DOUBLE,  -- m, xu - com at t_end
            settling_time    DOUBLE,  -- s, from which |xu - com| stays within 2 % of max|com|
            lag              DOUBLE,  -- s, shift of xu best matching com (0 to 0.2 s)
            xu_min           DOUBLE,  -- m
            xu_max           DOUBLE,  -- m
            xs_abs_max       DOUBLE,  -- m, spool peak
            p12_min          DOUBLE,  -- Pa
            p12_max          DOUBLE,  -- Pa
            p12_abs_max      DOUBLE,  -- Pa
            cor_abs_max      DOUBLE,  -- mA
            rmse_xu_hf_lf    DOUBLE,  -- m, HF vs LF of the same case (both runs get it)
            max_err_xu_hf_lf DOUBLE,  -- m
            rmse_p12_hf_lf   DOUBLE)  -- Pa""",
    "fdi_results": """
        CREATE TABLE IF NOT EXISTS fdi_results (
            run_key        VARCHAR PRIMARY KEY,
            case_id        INTEGER,   -- case number (thesis Figure 6.17 numbering)
            command        VARCHAR,
            seed           BIGINT,    -- HF dither and optimizer seed
            method         VARCHAR,   -- eha.identification.problem.METHODS ('ga': thesis)
            objective_name VARCHAR,   -- 'rmse' or 'objfcn' (thesis' mean absolute error)
            fit            JSON,      -- fitted LF parameters, e.g. ["BKL", "FDJ"]
            truth          JSON,      -- injected values (SI)
            estimates      JSON,      -- identified values (SI)
            errors_pct     JSON,      -- (input - output)/input*100, 0 when input is 0
            bounds         JSON,      -- search bounds {name: [lo, hi]}
            bkl_true DOUBLE, bkl_est DOUBLE, err_bkl_pct DOUBLE,  -- m, m, %
            fdj_true DOUBLE, fdj_est DOUBLE, err_fdj_pct DOUBLE,  -- N, N, %
            mean_err_pct   DOUBLE,    -- mean of the absolute percent errors
            objective      DOUBLE,    -- m, at the estimate
            evaluations    INTEGER,   -- LF simulations
            seconds        DOUBLE,    -- s, identification wall time in the worker
            pop            INTEGER,   -- GA population
            history        JSON,      -- best objective per generation/poll [m]
            level          DOUBLE,    -- nominal coverage of the intervals (0.9)
            intervals      JSON,      -- {name: [lo, hi]} at level (SI)
            flagged        BOOLEAN,   -- residual well above the noise: not a confident fit
            noise_rmse     DOUBLE)    -- m, sensor noise estimated from the reference""",
    "explain_runs": """
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
            seconds         DOUBLE)""",
    "explain_steps": """
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
            PRIMARY KEY (run_id, step))""",
}
#: Columns added to tables after their first release: (table, column, type). A database from an
#: older version gets them when it is opened for writing (its rows keep NULL there).
ADDED_COLUMNS: tuple[tuple[str, str, str], ...] = (("fdi_results", "level", "DOUBLE"),
                                                   ("fdi_results", "intervals", "JSON"),
                                                   ("fdi_results", "flagged", "BOOLEAN"),
                                                   ("fdi_results", "noise_rmse", "DOUBLE"),
                                                   ("runs", "trace_bytes", "BIGINT"),
                                                   ("runs", "trace_rows", "BIGINT"),
                                                   # content hash (issue 43)
                                                   ("runs", "trace_hash", "VARCHAR"),
                                                   ("runs", "trace_mtime", "BIGINT"),
                                                   # residual loop: its verdict (issue 11)
                                                   ("explain_runs", "unexplained", "BOOLEAN"),
                                                   ("explain_runs", "verdict", "VARCHAR"),
                                                   ("explain_runs", "command_hold", "VARCHAR"),
                                                   ("explain_runs", "leads", "JSON"),
                                                   # above the healthy band, not only the
                                                   # noise (issue 24)
                                                   ("explain_runs", "beyond_healthy",
                                                    "BOOLEAN"),
                                                   # the verdict's kind and facts (issue 42)
                                                   ("explain_runs", "verdict_kind", "VARCHAR"),
                                                   ("explain_runs", "at_noise", "BOOLEAN"),
                                                   ("explain_runs", "within_healthy_band",
                                                    "BOOLEAN"),
                                                   ("explain_runs", "unique_explanation",
                                                    "BOOLEAN"))
#: Tables whose rows belong to one run each (key ``run_key``); filled from worker results.
RESULT_TABLES: tuple[str, ...] = ("metrics", "fdi_results")

# prognostics (eha rul; docs/prognostics.md): one health assessment per record (a runner job
# of kind "health"), and the RUL predictions made from them (written by the parent).
SCHEMA["health_checks"] = """
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
SCHEMA["rul_predictions"] = """
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
RESULT_TABLES = RESULT_TABLES + ("health_checks",)
SCHEMA["health_assessments"] = """
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
SCHEMA["health_verdicts"] = """
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
SCHEMA["health_thresholds"] = """
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
RESULT_TABLES = RESULT_TABLES + ("health_assessments",)
