"""The one guard of the command line: signals, exit codes and one-line errors.

Every command runs inside :class:`GuardedGroup`: SIGTERM unwinds like Ctrl-C (exit 143),
Ctrl-C exits 130, an error the library anticipated (:class:`eha.errors.EhaError`) is printed
one ``error:`` line per problem and exits with its code (2 for bad input), and any other
exception becomes one ``error:`` line and exit 1 (``--debug`` shows the traceback). No Python
traceback reaches a user (docs/reliability.md).
"""

from __future__ import annotations

import os
import re
import signal
import sys
from contextlib import contextmanager
from typing import Callable, Iterator

import typer
from rich.console import Console
from rich.markup import escape
from typer.core import TyperGroup

from eha.errors import BAD_INPUT, FAILURE, EhaError



def _on_broken_pipe(self) -> None:
    """Rich's reaction to a closed standard output (``eha params | head``), with the
    conventional status: stdout discarded (the interpreter's final flush must not fail
    again), exit :data:`PIPE_CLOSED`, nothing printed. Rich (and typer's help, which prints
    through rich) would exit 1."""
    discard_stdout()
    raise SystemExit(PIPE_CLOSED)


Console.on_broken_pipe = _on_broken_pipe

#: Width of standard output off a terminal (a file, a pipe) when ``COLUMNS`` sets none: rich
#: would take 80 and cut every wider table ("estima…"); there is no screen to fit.
WIDTH_OFF_TERMINAL = 1000


class _Output(Console):
    """Rich's console, as wide as :data:`WIDTH_OFF_TERMINAL` when its file is not a terminal
    and neither ``COLUMNS`` nor a width was given (a terminal, or ``COLUMNS``, as rich
    measures them)."""

    @property
    def size(self):
        size = Console.size.fget(self)
        if self._width is None and not self.is_terminal and \
                not str(self._environ.get("COLUMNS", "")).isdigit():
            return size._replace(width=WIDTH_OFF_TERMINAL)
        return size

    @size.setter
    def size(self, new_size) -> None:
        Console.size.fset(self, new_size)


#: Standard output: text, never console markup (issue 43: an actuator id ``x[/]`` or ``[bold]``
#: in a name is data, printed as it is, in tables too); whole off a terminal (issue 61).
console = _Output(markup=False)
err_console = Console(stderr=True)

# The option parser's exceptions: click's, or the copy of click that typer >= 0.20 vendors.
_CLICK = sys.modules[typer.BadParameter.__module__]
_NO_ARGS = getattr(_CLICK, "NoArgsIsHelpError", ())
#: Exit status after SIGTERM (128 + 15, what a shell reports for a terminated process).
TERMINATED = 143
#: Exit status after Ctrl-C (128 + SIGINT).
INTERRUPTED = 130
#: Exit status when the reader of standard output closed it early (``eha params | head``):
#: 128 + SIGPIPE, what a shell reports for a process a closed pipe ended; nothing is printed.
PIPE_CLOSED = 141
#: ``--debug`` (or EHA_DEBUG=1): unexpected errors show their traceback.
STATE = {"debug": bool(os.environ.get("EHA_DEBUG"))}

_TERMINATED_LINE = "terminated (SIGTERM); outputs are written only when complete"
_INTERRUPTED_LINE = "interrupted (Ctrl-C); outputs are written only when complete"

__all__ = ["BAD_INPUT", "FAILURE", "TERMINATED", "INTERRUPTED", "PIPE_CLOSED", "GuardedGroup", "Terminated",
           "console", "err_console", "error_line", "fail", "fail_lines", "warn", "resumable",
           "discard_stdout", "stdout_failed", "keywords_as", "as_flags"]

#: How the library names one of its keyword arguments in an error or a note: in backticks
#: (`holdout`). The command line shows the flag that sets it (``--holdout``): see
#: :func:`as_flags`.
KEYWORD = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*)`")


def keywords_as(**flags: str) -> Callable:
    """Declare, on a command function, the flags of library keywords that its options do not
    name alike: ``@keywords_as(fixed="--set", null="--healthy")`` (the library's ``fixed`` is
    this command's ``--set``). Options named as the keyword (``holdout`` -> ``--holdout``)
    need no declaration."""
    def mark(function: Callable) -> Callable:
        function.keyword_flags = dict(flags)
        return function
    return mark


def _command_flags(command) -> dict[str, str]:
    """``{keyword: flag}`` of one command: its options' names, then its declared aliases."""
    flags = {}
    for param in getattr(command, "params", ()):
        longs = [o for o in getattr(param, "opts", ()) if o.startswith("--")]
        if longs and param.name:
            flags[param.name] = longs[0]
    callback = getattr(command, "callback", None)
    flags.update(getattr(getattr(callback, "__wrapped__", callback), "keyword_flags", {}))
    return flags


def _leaf_command(group, args: list[str]):
    """The command a command line runs: down the groups by the first word that names a
    subcommand (``eha health check ...`` -> ``check``)."""
    command = group
    for word in args:
        commands = getattr(command, "commands", None)
        if commands is None:
            break
        if word.startswith("-"):
            continue
        if word not in commands:
            break
        command = commands[word]
    return command


def as_flags(message: str) -> str:
    """A library text as the command line says it: each backticked keyword of the running
    command becomes its flag (`holdout` -> --holdout); other backticked words stay as they
    are."""
    flags = STATE.get("flags") or {}
    return KEYWORD.sub(lambda m: flags.get(m.group(1), m.group(0)), message)



class Terminated(KeyboardInterrupt):
    """SIGTERM received: unwinds like Ctrl-C (every ``finally`` commits what is finished)."""


#: The signals received by this process's guard (SIGINT, SIGTERM), in order.
_RECEIVED: list[int] = []


def _on_sigterm(signum, frame):  # pragma: no cover - exercised by subprocess tests
    _RECEIVED.append(signal.SIGTERM)
    raise Terminated()


def _on_sigint(signum, frame):  # pragma: no cover - exercised by subprocess tests
    _RECEIVED.append(signal.SIGINT)
    raise KeyboardInterrupt()


def _handle_signals() -> dict:
    """Turn SIGTERM into :class:`Terminated` and Ctrl-C into KeyboardInterrupt, both noted in
    :data:`_RECEIVED`; returns the previous handlers (empty when they cannot be set: not the
    main thread, e.g. an embedding application). A SIGINT that is ignored (a job started in
    the background) stays ignored."""
    previous = {}
    try:
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _on_sigterm)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            previous[signal.SIGINT] = signal.signal(signal.SIGINT, _on_sigint)
    except ValueError:
        pass
    return previous


def _restore(previous: dict) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def _signal_line() -> tuple[str, int] | None:
    """After Ctrl-C or SIGTERM, any error is its consequence: a library that runs the
    signal's handler inside its own code may report the interruption as its own error (DuckDB:
    "Query interrupted"). The line and exit status of the last signal received, else None."""
    if not _RECEIVED:
        return None
    if _RECEIVED[-1] == signal.SIGTERM:
        return _TERMINATED_LINE, TERMINATED
    return _INTERRUPTED_LINE, INTERRUPTED


def _report_known(exc: Exception, args=None) -> int | None:
    """Print the line(s) of an error whose cause is known and return the exit status: one
    that followed Ctrl-C or SIGTERM (:func:`_signal_line`), or one the library anticipated
    (:class:`EhaError`: its own words, one line a problem). None for any other error."""
    signalled = _signal_line()
    if signalled is not None:
        _traceback(args)
        error_line(signalled[0])
        return signalled[1]
    if isinstance(exc, EhaError):
        for line in exc.lines():
            error_line(line)
        return exc.exit_code
    return None


def error_line(message: str) -> None:
    """``error: message`` on stderr, as text (escaped: "[fdi]", "[0, 0.1] m" are not markup)."""
    err_console.print(f"[bold red]error:[/] {escape(as_flags(message))}", highlight=False,
                      soft_wrap=True)


def warn(message: str, prefix: str = "warning") -> None:
    """``warning: message`` (or another ``prefix``) on stderr, as text."""
    err_console.print(f"{prefix}: {escape(as_flags(message))}", highlight=False,
                      soft_wrap=True)


def fail(message: str, code: int = BAD_INPUT) -> None:
    """Print one line to stderr and exit with ``code``.

    Called from a command's ``except KeyboardInterrupt`` with code 130 while the interrupt is
    SIGTERM (:class:`Terminated`), it says so and exits 143, as the guard does."""
    if code == INTERRUPTED and isinstance(sys.exc_info()[1], Terminated):
        code = TERMINATED
        message = message.replace("interrupted", "terminated (SIGTERM)", 1)
    error_line(message)
    raise typer.Exit(code)


def fail_lines(lines: list[str], code: int = BAD_INPUT) -> None:
    """One ``error:`` line per problem, then exit with ``code``."""
    for line in lines:
        error_line(line)
    raise typer.Exit(code)


@contextmanager
def resumable(kept: str) -> Iterator[None]:
    """Ctrl-C (or SIGTERM) inside: ``interrupted; KEPT`` and exit 130 (143 for SIGTERM)."""
    try:
        yield
    except KeyboardInterrupt:
        fail(f"interrupted; {kept}", INTERRUPTED)


def _unexpected(exc: BaseException) -> str:
    """One line for an exception no command anticipated (class 1 of docs/reliability.md)."""
    import errno

    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, OSError):
        # no file name: a stream (standard output, a pipe) failed
        what = exc.filename or "writing the output"
        reason = exc.strerror or first or type(exc).__name__
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return f"{what}: {reason}; free some space and run the same command again"
        return f"{what}: {reason}"
    if isinstance(exc, UnicodeDecodeError):
        return f"input is not UTF-8 text ({first})"
    if isinstance(exc, MemoryError):
        return "out of memory; make the input smaller (shorter t_end, fewer runs)"
    if any("duckdb" in cls.__module__ for cls in type(exc).__mro__):
        if "Catalog Error" in first or type(exc).__name__ == "CatalogException":
            # a table nothing has written yet: the file is whole, never to be thrown away
            return (f"results database: {first} (nothing has written that table to this "
                    "results folder yet; its other results are intact)")
        if any(w in first for w in ("Corrupt", "checksum", "not a valid DuckDB")):
            return (f"results database: {first}; the file is damaged: move it away and run "
                    "the campaign again")
        return f"results database: {first}"
    return (f"internal error ({type(exc).__name__}: {first}); run again with --debug for "
            "the traceback")


def stdout_failed() -> bool:
    """Flush stdout; True (and stdout discarded) when it cannot be written (a full disk, a
    closed pipe)."""
    try:
        sys.stdout.flush()
        return False
    except (OSError, ValueError):
        STATE["pipe_closed"] = stdout_closed()
        discard_stdout()
        return True


def stdout_closed() -> bool:
    """Has the reader of standard output gone (a pipe whose other end is closed: ``| head``)?
    False when it cannot be told (not a file descriptor: an in-process caller)."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


def _pipe_closed(exc: BaseException) -> bool:
    """An error from writing to a standard output whose reader has gone."""
    import errno

    return isinstance(exc, OSError) and exc.errno == errno.EPIPE and stdout_closed()


def discard_stdout() -> None:
    """After a failed write to stdout: point fd 1 at /dev/null so that the interpreter's
    final flush of the unwritten rest does not fail a second time (with a traceback)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def _traceback(args=None) -> None:
    if STATE["debug"] or "--debug" in (args if args is not None else sys.argv):
        import traceback

        traceback.print_exc()


class GuardedGroup(TyperGroup):
    """The top-level command group: the one guard of the CLI (see the module docstring).
    Usage errors of the option parser (a value outside an option's range) are one line too,
    exit 2."""

    def invoke(self, ctx):
        previous = _handle_signals()
        try:
            return super().invoke(ctx)
        except (typer.Exit, typer.Abort, _CLICK.ClickException):
            raise
        except Terminated:
            error_line(_TERMINATED_LINE)
            raise typer.Exit(TERMINATED)
        except KeyboardInterrupt:
            error_line(_INTERRUPTED_LINE)
            raise typer.Exit(INTERRUPTED)
        except Exception as exc:
            if _pipe_closed(exc):       # `eha params | head`: the reader has what it wanted
                discard_stdout()
                raise typer.Exit(PIPE_CLOSED)
            code = _report_known(exc)
            if code is not None:
                raise typer.Exit(code)
            _traceback()
            if isinstance(exc, RecursionError):  # a hostile JSON or TOML: 100 000 nested [
                error_line("an input file is nested too deeply to be read (JSON or TOML "
                           "arrays or tables inside each other)")
                raise typer.Exit(BAD_INPUT)
            if isinstance(exc, OSError) and stdout_failed():
                if STATE.get("pipe_closed"):
                    raise typer.Exit(PIPE_CLOSED)
                exc = OSError(exc.errno, exc.strerror, "standard output")
            error_line(_unexpected(exc))
            raise typer.Exit(FAILURE)
        finally:
            _restore(previous)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        if not standalone_mode:
            return super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                                standalone_mode=False, **extra)
        _RECEIVED.clear()  # a new command line (in-process callers run several)
        STATE.pop("pipe_closed", None)
        # the running command's flags, for the library's keywords in its errors (as_flags)
        STATE["flags"] = _command_flags(_leaf_command(self, list(
            sys.argv[1:] if args is None else args)))
        previous = _handle_signals()  # from here on: parsing reads defaults from the library
        try:
            rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                              standalone_mode=False, **extra)
        except _NO_ARGS as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except SystemExit as exc:   # typer ends a closed pipe (`--help | head`) with exit 1
            if exc.code == FAILURE and (stdout_closed() or STATE.get("pipe_closed")):
                sys.exit(PIPE_CLOSED)
            raise
        except _CLICK.ClickException as exc:
            where = f"{exc.ctx.command_path}: " if getattr(exc, "ctx", None) else ""
            error_line(where + exc.format_message().replace("\n", " "))
            sys.exit(exc.exit_code)
        except typer.Abort:
            error_line("aborted")
            sys.exit(FAILURE)
        except Terminated:  # while the arguments were parsed, before invoke
            error_line(_TERMINATED_LINE)
            sys.exit(TERMINATED)
        except KeyboardInterrupt:
            error_line(_INTERRUPTED_LINE)
            sys.exit(INTERRUPTED)
        except Exception as exc:  # e.g. a default read from the library failed to import
            code = _report_known(exc, args)
            if code is not None:
                sys.exit(code)
            _traceback(args)
            error_line(_unexpected(exc))
            sys.exit(FAILURE)
        finally:
            _restore(previous)
        if stdout_failed():  # e.g. `eha params > /dev/full`: say so, not at the final flush
            if STATE.get("pipe_closed"):
                sys.exit(PIPE_CLOSED)
            error_line("the output could not be written to standard output")
            sys.exit(FAILURE)
        sys.exit(rv if isinstance(rv, int) else 0)
