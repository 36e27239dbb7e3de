"""eha: model-based prognostics of flapper-nozzle servo-valve electro-hydraulic actuators.

One package per concern; data flows one way (``tests/test_layering.py`` checks the imports):

- :mod:`eha.campaigns`: the infrastructure below the domain: campaign files, job registry,
  runner, executors, traces, the result store and queries. It imports nothing of the domain;
  every layer may use it.
- :mod:`eha.models`: parameters, commands, the numba kernels, ``simulate``, the run metrics.
- :mod:`eha.simulations`: the ``simulate`` job kind (its part of a campaign file, chunks,
  worker, ``metrics`` table, HF-vs-LF pairs).
- :mod:`eha.identification`: fit LF parameters to a record with intervals; measured records;
  the healthy reference; the thesis' identification cases.
- :mod:`eha.explain`: the residual loop (which physics the LF model lacks).
- :mod:`eha.health`: assessment, detection and monitoring of one actuator.
- :mod:`eha.prognostics`: degradation trends, RUL, prognostic metrics, limits, fleets.
- :mod:`eha.reports`: the thesis report, simulation figures, the HTML report.
- :mod:`eha.cli`: the command line (``eha``), above everything.

Flat modules that stay flat: :mod:`eha.trace` (the recorded columns and a run's
:class:`~eha.trace.Trace`: the models and the campaign infrastructure share them),
:mod:`eha.figures` (matplotlib without a display and saving a
PNG: the one helper every layer's figures use, so it sits below them all) and
:mod:`eha.docgen` (writes ``docs/cli.md`` from the command line; tooling of :mod:`eha.cli`).
Importing ``eha`` or one of its packages imports nothing else: a job kind's worker loads only
the module of its kind.

The public API (``docs/api.md``, one example each): what a notebook calls, importable from
``eha`` itself. Each name is loaded on first use (module ``__getattr__``, PEP 562, with plain
``from ... import``), so ``import eha`` stays cheap and loads neither numba nor DuckDB:

- :func:`simulate`: run the HF or LF model on a command;
- :func:`load`, :func:`synthetic_record`: a measured record (a file; one made by the simulator);
- :func:`identify`: fit LF parameters to a position trace; :func:`identify_source`: the same on
  a measured record file or an HF reference (``eha fdi``);
- :func:`explain`: the residual loop on a record (``eha explain``): the package
  :mod:`eha.explain`, callable as :func:`eha.explain.api.explain`;
- :func:`assess_record` (:func:`assess` on arrays): health assessment of a record (``eha health
  assess``);
- :func:`run_rul`: assessments, RUL predictions and metrics of a manifest of checks (``eha rul``);
- :func:`run_campaign`: run or resume a campaign file into a results folder;
- :func:`query`, :func:`tables`: read a results folder's database (read-only, a DataFrame);
  :func:`connect`: a DuckDB connection to it (pass ``read_only=True``).
"""

__version__ = "0.1.0"

__all__ = ["simulate", "load", "synthetic_record", "identify", "identify_source", "explain",
           "assess", "assess_record", "run_rul", "run_campaign", "query", "tables", "connect",
           "__version__"]

#: False at run time (``typing`` is not imported: ``import eha`` stays cheap); type checkers
#: and IDEs read the imports below, at run time :func:`__getattr__` loads each name.
TYPE_CHECKING = False
if TYPE_CHECKING:
    from eha.campaigns.query import query, tables
    from eha.campaigns.runner import run_campaign
    from eha.campaigns.store import connect
    from eha.health.assessment import assess, assess_record
    from eha.identification.fdi import identify, identify_source
    from eha.identification.measured import load, synthetic_record
    from eha.models.simulate import simulate
    from eha.prognostics.jobs import run_rul


def __getattr__(name: str):
    """Load a public name on first use (PEP 562); plain imports, no ``importlib``."""
    if name == "simulate":
        from eha.models.simulate import simulate as value
    elif name == "load":
        from eha.identification.measured import load as value
    elif name == "synthetic_record":
        from eha.identification.synthetic import synthetic_record as value
    elif name == "identify":
        from eha.identification.fdi import identify as value
    elif name == "identify_source":
        from eha.identification.fdi import identify_source as value
    elif name == "explain":
        # the package, callable as eha.explain.api.explain (see eha/explain/__init__.py);
        # importing it binds eha.explain
        import eha.explain.api  # noqa: F401
        return globals()["explain"]
    elif name == "assess":
        from eha.health.assessment import assess as value
    elif name == "assess_record":
        from eha.health.assessment import assess_record as value
    elif name == "run_rul":
        from eha.prognostics.jobs import run_rul as value
    elif name == "run_campaign":
        from eha.campaigns.runner import run_campaign as value
    elif name == "query":
        from eha.campaigns.query import query as value
    elif name == "tables":
        from eha.campaigns.query import tables as value
    elif name == "connect":
        from eha.campaigns.store import connect as value
    else:
        raise AttributeError(f"module 'eha' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
