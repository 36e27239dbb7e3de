"""Campaign infrastructure: the layer below the domain that runs jobs and keeps their results.

Modules, by concern:

- :mod:`~eha.campaigns.files`: campaign TOML files, validation, expansion into jobs with run
  keys (:mod:`~eha.campaigns.simulations`: the simulation part of a file); the shipped files
  are in ``data/`` (:func:`~eha.campaigns.files.campaigns_dir`).
- :mod:`~eha.campaigns.jobs`: the job registry (each job kind registers its worker function
  and hooks) and the worker's dispatch.
- :mod:`~eha.campaigns.runner`: the resumable runner (parent side).
- :mod:`~eha.campaigns.executors`: where the jobs run (local spawn pool, Dask).
- :mod:`~eha.campaigns.schema`: the one SQL schema of the result database.
- :mod:`~eha.campaigns.traces`: Parquet trace files (one run or a chunk of runs per file) and
  measured-data tables.
- :mod:`~eha.campaigns.store`: the result database (connections, the parent's writer).
- :mod:`~eha.campaigns.query`: read-only SQL over the database and the traces, CSV export.

Only this package reads or writes Parquet and DuckDB. Importing it loads nothing of the
simulation stack (numba, the models), so ``eha query`` starts fast.
"""
