"""eha: model-based prognostics of flapper-nozzle servo-valve electro-hydraulic actuators.

One package per concern; data flows one way (``tests/test_layering.py`` checks the imports):

- :mod:`eha.models`: parameters, commands, the numba kernels, ``simulate``; the ``simulate``
  job kind and the run metrics.
- :mod:`eha.campaigns`: the infrastructure below the domain: campaign files, job registry,
  runner, executors, traces, the result store and queries. It imports only :mod:`eha.models`
  (trace columns; parameters and commands to validate a file's simulations).
- :mod:`eha.identification`: fit LF parameters to a record with intervals; measured records;
  the healthy reference; the thesis' identification cases.
- :mod:`eha.explain`: the residual loop (which physics the LF model lacks).
- :mod:`eha.health`: assessment, detection and monitoring of one actuator.
- :mod:`eha.prognostics`: degradation trends, RUL, prognostic metrics, limits, fleets.
- :mod:`eha.reports`: the thesis report, simulation figures, the HTML report.
- :mod:`eha.cli`: the command line (``eha``), above everything.

Flat modules that stay flat: :mod:`eha.figures` (matplotlib without a display and saving a
PNG: the one helper every layer's figures use, so it sits below them all) and
:mod:`eha.docgen` (writes ``docs/cli.md`` from the command line; tooling of :mod:`eha.cli`).
Importing ``eha`` or one of its packages imports nothing else: a job kind's worker loads only
the module of its kind.
"""

__version__ = "0.1.0"
