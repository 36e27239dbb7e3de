"""The one error hierarchy of the library.

Every error the library anticipates derives from :class:`EhaError`: its text is written for
the user (one line per problem, naming the field, the value and what is allowed), so the
command line prints it as it is, one ``error:`` line per problem, and exits with the error's
:attr:`~EhaError.exit_code` (docs/reliability.md): 2 for bad input (:class:`InputError`:
an option, a campaign or fleet file, a measured record; nothing was written), 1 for a failure
of the machine (a database that cannot be written).

The domain modules keep their own classes (``eha.models.params.ParameterError``,
``eha.identification.measured.MeasuredDataError``, ``eha.campaigns.store.StoreError``, ...) where they are
defined; they derive from these. Each input error is also a ``ValueError`` (and the store's
errors a ``RuntimeError``), as they were before this hierarchy, so that existing ``except``
clauses keep working.
"""

from __future__ import annotations

from typing import Iterable

#: Exit status of bad input (an option, a file, a record): nothing was written.
BAD_INPUT = 2
#: Exit status of a failure of the machine or of the program.
FAILURE = 1


class EhaError(Exception):
    """An error the library anticipated; its message is for the user.

    :meth:`lines` gives the message one problem a line; :attr:`exit_code` is what the command
    line exits with (1: a failure, not the input's fault).
    """

    exit_code = FAILURE

    def lines(self) -> list[str]:
        """The message, one problem a line (never empty)."""
        lines = [line for line in str(self).splitlines() if line.strip()]
        return lines or [type(self).__name__]


class InputError(EhaError, ValueError):
    """Bad input: one or more problems, each ``"field: value: allowed ..."``.

    Parameters
    ----------
    problems : str or iterable of str
        One problem, or one line per problem.
    source : str, optional
        What the problems are in (a file name): each line starts with it.
    message : str, optional
        The exception's text (default: the lines joined by ``"; "``, one line).
    """

    exit_code = BAD_INPUT

    def __init__(self, problems: str | Iterable[str] = (), source: str | None = None,
                 message: str | None = None):
        self.problems = [problems] if isinstance(problems, str) else [str(p) for p in problems]
        self.source = None if source is None else str(source)
        super().__init__(message if message is not None else "; ".join(self.lines()))

    def lines(self) -> list[str]:
        if not self.problems:
            return super().lines()
        prefix = f"{self.source}: " if self.source else ""
        return [prefix + line for problem in self.problems
                for line in (problem.splitlines() or [problem])]


__all__ = ["EhaError", "InputError", "BAD_INPUT", "FAILURE"]
