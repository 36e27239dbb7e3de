"""The result database's core schema (:data:`SCHEMA`: what every job kind has) and its file names.

The store keeps campaigns, runs, chunk files and transactions; ``campaigns`` and ``runs`` are
declared here. Units are SI (cor in mA). A job kind's result tables (and those of the other
writers: a check, a calibration, the residual loop) are declared by the module that writes
them, in its :class:`eha.campaigns.jobs.JobKind` (or, for the other writers, with
:func:`eha.campaigns.jobs.register_table`): its CREATE statement, the columns added after its
first release, and whether its rows belong to runs.

The core schema has a version: :data:`MIGRATIONS` are numbered, and a database records each
one applied in its table ``schema_migrations`` (version, name, time). A change to a core table
is a new migration at the end (its statements, and the CREATE statement of :data:`SCHEMA`
updated for new databases); :func:`eha.campaigns.store.connect` applies the missing ones when
it opens a database for writing, and refuses a database whose version is newer than
:data:`SCHEMA_VERSION`.

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
#: The record of the migrations applied to a database (:data:`MIGRATIONS`).
MIGRATIONS_TABLE = """
        CREATE TABLE IF NOT EXISTS schema_migrations (
            version    INTEGER PRIMARY KEY,  -- number of the migration (MIGRATIONS)
            name       VARCHAR NOT NULL,     -- what it did
            applied_at TIMESTAMP NOT NULL)   -- when it was applied to this database (UTC)"""

#: The numbered migrations of the core schema, oldest first: (version, name, statements). Each
#: is applied once to a database, in one transaction with its row of ``schema_migrations``. A
#: database made before versions (no ``schema_migrations``: version 0) may be at any point of
#: versions 1 to 3, so their statements are idempotent (``IF NOT EXISTS``); a later migration is
#: applied only to databases recorded below it. Rows of an added column keep NULL there. A job
#: kind's tables are its own (:attr:`eha.campaigns.jobs.Table.added`), not versioned here.
MIGRATIONS: tuple[tuple[int, str, tuple[str, ...]], ...] = (
    (1, "campaigns and runs", (SCHEMA["campaigns"], SCHEMA["runs"])),
    (2, "runs: trace file size and rows (integrity)",
     ("ALTER TABLE runs ADD COLUMN IF NOT EXISTS trace_bytes BIGINT",
      "ALTER TABLE runs ADD COLUMN IF NOT EXISTS trace_rows BIGINT")),
    (3, "runs: trace file checksum and time (issue 43)",
     ("ALTER TABLE runs ADD COLUMN IF NOT EXISTS trace_hash VARCHAR",
      "ALTER TABLE runs ADD COLUMN IF NOT EXISTS trace_mtime BIGINT")),
)
#: The version of the core schema this code writes: the number of its last migration.
SCHEMA_VERSION = MIGRATIONS[-1][0]

#: The descriptive columns of ``runs`` a job's draft may fill (its ``columns``; see
#: :class:`eha.campaigns.drafts.JobDraft`); the runner fills the others.
DESCRIPTIVE_COLUMNS = frozenset({"model", "command", "faults", "fault_label", "seed", "t_end",
                                 "case_key", "label"})
