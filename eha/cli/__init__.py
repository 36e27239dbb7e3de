"""Command-line interface: a thin typer layer. A command parses its options, builds the
library's settings object, calls one library function and renders its result; errors the
library anticipates (:class:`eha.errors.EhaError`) are printed by the one guard, one line a
problem, exit 2 for bad input (docs/reliability.md).

- :mod:`eha.cli.guard`: signals, exit codes, one-line errors (:class:`GuardedGroup`);
- :mod:`eha.cli.options`: shared options, defaults read from the library, output checks;
- one module per group: :mod:`~eha.cli.models` (simulate, params, commands),
  :mod:`~eha.cli.campaign` (campaign, query, export, plot), :mod:`~eha.cli.identify` (fdi),
  :mod:`~eha.cli.explain`, :mod:`~eha.cli.report` (report, reproduce),
  :mod:`~eha.cli.health`, :mod:`~eha.cli.prognostics` (fleet, rul, limits);
- :mod:`eha.cli.app`: the application, its commands in order.

No module here imports the simulation stack (numba kernels) at import time: ``eha query``
and ``eha --help`` start without it; each command imports what it calls.
"""

from eha.cli.app import app, main
from eha.cli.guard import BAD_INPUT, INTERRUPTED, TERMINATED, Terminated, fail

__all__ = ["app", "main", "fail", "BAD_INPUT", "INTERRUPTED", "TERMINATED", "Terminated"]
