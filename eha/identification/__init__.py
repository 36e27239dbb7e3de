"""Identification: fit LF model parameters to a record, with intervals (thesis chapter 6).

Modules, by concern:

- :mod:`~eha.identification.fdi`: :func:`~eha.identification.fdi.identify` (the fit of chosen
  LF parameters to a recorded position), intervals at a given estimate, the HF reference of
  the thesis reproduction and one identification from the command line (``eha fdi``).
- :mod:`~eha.identification.problem`: what is asked and answered: methods, objectives,
  search bounds, the named LF bases, method options, the result
  (:class:`~eha.identification.problem.FitResult`).
- :mod:`~eha.identification.optimizers`: the batched objective and the optimizers (GA,
  pattern search, least squares) in the unit cube.
- :mod:`~eha.identification.intervals`: the parameter intervals (HAC, noise and model-form
  terms) and the residual flag.
- :mod:`~eha.identification.measured`: measured records: read, validate, resample (the input
  of every layer above).
- :mod:`~eha.identification.healthy`: the healthy reference shared by detection
  (:mod:`eha.health`) and the residual loop's null (:mod:`eha.explain`): manufacturing
  dispersion, the tail threshold of a healthy statistic, command signatures.
- :mod:`~eha.identification.cases`: the thesis' identification cases (the ``fdi`` job kind
  and the ``[fdi]`` campaign section).

Above :mod:`eha.models`, below :mod:`eha.explain`, :mod:`eha.health.assessment` and
:mod:`eha.prognostics`: nothing here imports them (``tests/test_layering.py``).
The package imports nothing itself, so that a job kind's worker loads only its module.
"""
