"""The result database's core schema (:data:`SCHEMA`: what every job kind has) and its file names.

The store keeps campaigns, runs, chunk files and transactions; ``campaigns`` and ``runs`` are
declared here. Units are SI (cor in mA). A job kind's result tables (and those of the other
writers: a check, a calibration, the residual loop) are declared by the module that writes
them, in its :class:`eha.campaigns.jobs.JobKind` (or, for the other writers, with
:func:`eha.campaigns.jobs.register_table`): its CREATE statement, the columns added after its
first release, and whether its rows belong to runs. A column added to a core table goes in
:data:`ADDED_COLUMNS` too, so that an older database gets it.

This module holds constants only: nothing is imported.
"""

from __future__ import annotations

#: File name of the result database inside a results directory.
DB_NAME = "eha.duckdb"
#: Folder of the Parquet traces inside a results directory.
TRACES = "traces"

#: The SQL schema, in one place: table name -> CREATE statement. Units are SI (cor in mA).
#: ``runs`` holds what every kind's runs have: the run's state and timings, its trace file
#: (the store's chunks), and the descriptive columns each kind's drafts fill (model, command,
#: faults, seed, t_end, label: an actuator on a command with faults, whatever the kind);
#: ``case_key`` is the simulate kind's pairing of HF and LF runs, NULL for the others.
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
            case_key    VARCHAR,              -- simulate: one case's HF and LF runs (else NULL)
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
}
#: Columns added to the core tables after their first release: (table, column, type). A database
#: from an older version gets them when it is opened for writing (its rows keep NULL there). A
#: job kind's table declares its own (:func:`eha.campaigns.jobs.register_table`).
ADDED_COLUMNS: tuple[tuple[str, str, str], ...] = (("runs", "trace_bytes", "BIGINT"),
                                                   ("runs", "trace_rows", "BIGINT"),
                                                   # content hash (issue 43)
                                                   ("runs", "trace_hash", "VARCHAR"),
                                                   ("runs", "trace_mtime", "BIGINT"))
#: The descriptive columns of ``runs`` a job's draft may fill (its ``columns``; see
#: :class:`eha.campaigns.drafts.JobDraft`); the runner fills the others.
DESCRIPTIVE_COLUMNS = frozenset({"model", "command", "faults", "fault_label", "seed", "t_end",
                                 "case_key", "label"})
