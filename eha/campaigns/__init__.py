"""Campaign infrastructure: the layer below the domain that runs jobs and keeps their results.

Modules, by concern:

- :mod:`~eha.campaigns.files`: campaign TOML files, validation, expansion into jobs with run
  keys (each kind expands its own part of a file); the shipped files are in ``data/``
  (:func:`~eha.campaigns.files.campaigns_dir`).
- :mod:`~eha.campaigns.jobs`: the registry (each job kind is one
  :class:`~eha.campaigns.jobs.JobKind`: its worker function and hooks, its part of a campaign
  file, its result tables and warm-up; one entry point) and the worker's dispatch.
- :mod:`~eha.campaigns.runner`: the resumable runner (parent side).
- :mod:`~eha.campaigns.executors`: where the jobs run (local spawn pool, Dask).
- :mod:`~eha.campaigns.schema`: the core SQL schema of the result database (campaigns, runs)
  and its numbered migrations; :mod:`~eha.campaigns.migrations` applies them
  (``schema_migrations``), in transactions of :mod:`~eha.campaigns.transactions`.
- :mod:`~eha.campaigns.traces`: Parquet trace files (one run or a chunk of runs per file) and
  measured-data tables.
- :mod:`~eha.campaigns.store`: the result database (connections, the parent's writer).
- :mod:`~eha.campaigns.query`: read-only SQL over the database and the traces, CSV export.

Only this package reads or writes Parquet and DuckDB. It imports nothing of the domain (only
:mod:`eha.errors` and the trace columns, :mod:`eha.trace`): the job kinds
(e.g. :mod:`eha.simulations`) use it, never the reverse, and importing it loads nothing of the
simulation stack (numba, the models), so ``eha query`` starts fast.
"""
