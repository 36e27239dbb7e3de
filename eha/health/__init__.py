"""Health: is an actuator degraded, and which fault? Assessment, detection, monitoring.

Modules, by concern:

- :mod:`~eha.health.assessment`: one record's assessment: the bank of fault hypotheses, each
  an identification with intervals, weighed by information criterion (``FAULTS``).
- :mod:`~eha.health.detection`: decisions with a known false-alarm rate: healthy fleets (the
  ``health_assessment`` job kind and the ``[health]`` campaign section), thresholds and
  calibration files, a check's verdicts, ROC and isolation performance.
- :mod:`~eha.health.monitoring`: the workflows behind ``eha health`` (calibrate, check,
  report) through the campaign runner and the store.
- :mod:`~eha.health.tables`: their result tables (assessments, verdicts, thresholds), declared
  for the store.
- :mod:`~eha.health.plots`: their figures (ROC, confusion matrices, a check's estimates).

Above :mod:`eha.identification` and :mod:`eha.explain` (the assessment starts the LF model
where a record starts, as the residual loop does); beside :mod:`eha.prognostics`, which it does
not import. The healthy reference that the residual loop's null shares with detection is
:mod:`eha.identification.healthy`, below both. The package imports nothing itself.
"""
