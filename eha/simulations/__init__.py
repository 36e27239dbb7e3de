"""The ``simulate`` job kind, in one place: a campaign of simulations, models × commands ×
fault sets × seeds, run by the campaign runner.

- :mod:`~eha.simulations.expand`: its part of a campaign file (the top-level keys ``models``,
  ``commands``, ``seeds``, ``t_end``, ``signals``, ``params``, ``faults``), validated and
  expanded into job drafts.
- :mod:`~eha.simulations.batch`: its chunk plan and estimate, its worker (a chunk of runs per
  task, one chunk file), its ``metrics`` table and the HF-vs-LF pairing of a case's runs, the
  worker warm-up, and the kind's one declaration of all of these
  (:data:`eha.simulations.batch.SIMULATE`, a :class:`eha.campaigns.jobs.JobKind`).

Above :mod:`eha.models` (the kernels and ``simulate``) and the campaign infrastructure
(:mod:`eha.campaigns`), which imports neither; the entry point of ``pyproject.toml`` names
the declaration. The package imports nothing itself, so that a worker loads only the module it runs.
"""
