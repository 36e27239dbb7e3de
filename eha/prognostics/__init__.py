"""Prognostics: degradation trends of identified faults and the remaining useful life (RUL).

Modules, by concern:

- :mod:`~eha.prognostics.degradation`: the degradation laws and their Bayesian fit on one
  fault's history (model averaging over law, shape and noise levels).
- :mod:`~eha.prognostics.rul`: fault histories from health checks, and at every check the RUL
  distribution from the checks up to it.
- :mod:`~eha.prognostics.jobs`: ``eha rul``: the ``health`` job kind (one assessment per
  record of a manifest, through the campaign runner), predictions, evaluation, the tables;
  :mod:`~eha.prognostics.tables`: its result tables, declared for the store.
- :mod:`~eha.prognostics.metrics`: prognostic metrics against known ends of life (α-λ,
  relative accuracy, coverage) and their fleet summary.
- :mod:`~eha.prognostics.limits`: ``eha limits``: the fault value at which a requirement on
  the simulated response fails.
- :mod:`~eha.prognostics.fleet`: synthetic fleets with known degradation (the
  ``fleet_record`` job kind, ``eha fleet``) and :mod:`~eha.prognostics.manifest`, the list of
  an actuator's records that ``eha rul`` reads.
- :mod:`~eha.prognostics.plots`: an actuator's trends, RUL and metrics as figures.

Above :mod:`eha.identification` (each check is an identification with intervals); beside
:mod:`eha.health`, which it does not import. The package imports nothing itself, so that a
fleet-record worker loads only :mod:`~eha.prognostics.fleet`.
"""
