"""Transactions of the result database that a signal cannot cut in half.

Ctrl-C or SIGTERM raised inside a DuckDB statement comes back as DuckDB's own error ("Query
interrupted"; after an interrupted COMMIT even the ROLLBACK fails), so the store's writes and
the schema's migrations hold the signals until their statement or transaction has ended
(:func:`signals_held`, :func:`transaction`). This module imports nothing of eha.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM while the block runs; their handlers run right after it.

    Run inside a DuckDB statement, a handler that raises interrupts the statement itself and
    DuckDB reports its own error ("Query interrupted"; after an interrupted COMMIT even the
    ROLLBACK fails) instead of the signal. Only handlers set in Python are held (the default
    SIGTERM still ends the process: the write-ahead log keeps the file whole).
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # handlers only run in the main thread, between its statements
        return
    held: list[int] = []
    previous = {}
    for signum in (signal.SIGINT, signal.SIGTERM):
        if callable(signal.getsignal(signum)):
            previous[signum] = signal.signal(signum, lambda n, _frame: held.append(n))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(held):
            previous[signum](signum, None)


@contextmanager
def transaction(con) -> Iterator[None]:
    """One transaction on ``con``, committed or rolled back whole, with Ctrl-C and SIGTERM
    held until it has ended (:func:`signals_held`; a commit of runs takes milliseconds)."""
    with signals_held():
        con.execute("BEGIN")
        try:
            yield
            con.execute("COMMIT")
        except BaseException:
            try:
                con.execute("ROLLBACK")
            except Exception:  # the transaction ended already (a failed COMMIT)
                pass
            raise


__all__ = ["signals_held", "transaction"]
