"""The residual loop: fit the declared faults, trace the residual to a missing effect, add it.

Given a measured record (:mod:`eha.identification.measured`), :func:`explain`

a. fits the declared fault parameters of the LF model (:func:`eha.identification.fdi.identify`) on
   the fitted part of the record: the baseline and its residual ``r = y_measured - y_LF``;
b. traces the residual: its correlation with the *signature* of every effect of
   :data:`eha.explain.effects.EFFECTS` (the change of the LF output xu when the effect is switched
   on at its probe value, a secant sensitivity computed by finite differences, all in one parallel
   batch) and with signals (position, sign of the jack velocity, command, tracking error, P12); the
   linearised fit ``r ~ J_faults*d_faults + a*signature`` gives the fraction of the residual each
   effect could explain, which ranks the candidates;
c. refits the faults together with each of the best-ranked candidates (its parameters free
   within their bounds) and scores it by the relative reduction of the RMSE (fitted and
   *held-out* parts weighted equally, :attr:`Evaluation.rmse_score`) minus a
   penalty per added parameter;
d. adds the best candidate when that penalised gain is significant (>= ``min_gain``), and
   repeats from (b) with the augmented model;
e. stops when no candidate is significant, when the residual is at the measurement-noise level
   (estimated from the record itself), or after ``max_steps``; it says how much of the residual
   is left unexplained (the part above the noise level).

Held-out data: the last ``holdout`` fraction of the record (the model is fitted on the first
part and simulated over the whole record), or a second record (``validate``) simulated with its
own command. RMSE in metres.

The package, by concern:

- :mod:`~eha.explain.settings`: :class:`LoopSettings` and every constant of the loop and its
  null;
- :mod:`~eha.explain.results`: what a run reports (:class:`ExplainResult`) and its one
  serialisation (JSON, CSV, database rows, console table);
- :mod:`~eha.explain.decide`: the decision rule, pure functions on numbers;
- :mod:`~eha.explain.record`: the record, its start and its batches of LF runs;
- :mod:`~eha.explain.tracing`: the residual traced to the effects' signatures (b);
- :mod:`~eha.explain.problem`: :class:`Problem`, a record and what is fitted on it, built once
  per :func:`explain` call; :mod:`~eha.explain.fitting`: :class:`Fitter`, the fits and scores
  on a problem (the loop's, the healthy null's, the replicates' and the rival check's);
- :mod:`~eha.explain.loop`: :class:`ResidualLoop`, read top-down, and its parts
  :mod:`~eha.explain.rounds` (b-e) and :mod:`~eha.explain.final_check` (f);
- :mod:`~eha.explain.api`: :func:`explain`, its passes and :func:`healthy_null`;
- :mod:`~eha.explain.null`: the healthy null; :mod:`~eha.explain.leads`: leads for a residual
  no library effect explains; :mod:`~eha.explain.from_file`: the loop on measured files; :mod:`~eha.explain.outputs`: what a result writes.

The names below are re-exported for ``from eha.explain import ...``; a constant is read where
it is used, so a test that patches one patches the module that reads it.

``eha.explain`` is this package *and* the public API's function: calling the package,
``eha.explain(data, ...)``, runs :func:`explain` (docs/api.md). A package attribute of ``eha``
named ``explain`` is always the package (Python binds it on the first import of any
``eha.explain.*`` module), so the package itself is made callable rather than shadowed by the
function, which would break ``eha.explain.loop`` and every patch of ``eha.explain.*``.
"""

import sys
import types

from eha.explain.api import explain, healthy_null
from eha.explain.decide import (NOTHING_IMPROVED, Choice, better_pass, choose, edge_of_spread,
                                flow_gain_at_edge, keeps_effect, significance, trades_position,
                                unspecific)
from eha.explain.fitting import Fitter
from eha.explain.leads import LeadReport, residual_leads
from eha.explain.loop import ResidualLoop
from eha.explain.null import Null, NullError
from eha.explain.problem import Problem
from eha.explain.record import augmented_base, p12_objective_weight
from eha.explain.results import (Candidate, Dismissal, Evaluation, ExplainResult, Round,
                                 Step)
from eha.explain.settings import (ALTERNATIVE_MARGIN, CONFIRM_FRACTION, DEFAULT_FAULT_BOUNDS,
                                  DEFAULTS, FLOW_GAIN_EDGE, GLOBAL_METHODS,
                                  LEAST_SQUARES_FINISH, LOOK_AHEAD, MULTISTART,
                                  MULTISTART_PARAMS, P12_NOISE_FLOOR, POSITION_WORSENING,
                                  REVISITS, RIVAL_MARGIN, SECOND_PASS, SPECIFIC_GAIN,
                                  START_TOLERANCE, STRUCTURAL, SWAP_CANDIDATES, ExplainError,
                                  LoopSettings, parse_fit)
from eha.explain.tracing import SIGNALS, signatures, trace_residual
from eha.identification.measured import noise_level

__all__ = [
    # running the loop
    "explain", "healthy_null", "ResidualLoop", "Problem", "Fitter", "LoopSettings", "DEFAULTS",
    "ExplainError",
    "parse_fit", "augmented_base", "p12_objective_weight", "noise_level",
    # what it reports
    "ExplainResult", "Evaluation", "Candidate", "Step", "Dismissal", "Round", "LeadReport",
    "residual_leads", "Null", "NullError",
    # the decision rule
    "choose", "Choice", "NOTHING_IMPROVED", "significance", "keeps_effect", "unspecific",
    "trades_position", "edge_of_spread", "flow_gain_at_edge", "better_pass",
    # tracing
    "trace_residual", "signatures", "SIGNALS",
    # constants (eha.explain.settings)
    "DEFAULT_FAULT_BOUNDS", "MULTISTART_PARAMS", "MULTISTART", "GLOBAL_METHODS",
    "LEAST_SQUARES_FINISH", "START_TOLERANCE", "P12_NOISE_FLOOR", "ALTERNATIVE_MARGIN",
    "STRUCTURAL", "SPECIFIC_GAIN", "RIVAL_MARGIN", "LOOK_AHEAD", "CONFIRM_FRACTION",
    "POSITION_WORSENING", "SWAP_CANDIDATES", "REVISITS", "SECOND_PASS", "FLOW_GAIN_EDGE",
]


class _CallablePackage(types.ModuleType):
    """The type of the ``eha.explain`` package: calling it is :func:`explain`."""

    def __call__(self, *args, **kwargs):
        return self.api.explain(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
