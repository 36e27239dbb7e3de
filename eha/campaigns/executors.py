"""Executors: where a campaign's tasks run (a local spawn pool, a Dask cluster).

An :class:`Executor` runs a function over task payloads on its workers and yields the results
as they complete, with a bounded number in flight. Workers are set up once as they start
(:func:`warm_worker`: one numba thread each, exit with the parent, the warm-ups of the
campaign's job kinds, :func:`eha.campaigns.jobs.warm_up`), never per task.

This module imports nothing heavy at import time: spawn workers unpickle functions from it,
and :func:`_init_worker` must set ``NUMBA_NUM_THREADS`` before numba is first imported.
"""

from __future__ import annotations

import os
import socket
import time
from typing import Any, Callable, Iterable, Iterator, Sequence

from eha.campaigns.malloc import tune_malloc

#: Numba threads per worker process (one process per core already).
WORKER_NUMBA_THREADS = 1
#: After Ctrl-C or SIGTERM, how long the parent waits for its terminated workers to end [s].
ABORT_WAIT_S = 10.0


# =========================================================================== worker side
def _init_worker(kinds: tuple[str, ...] | None = None) -> None:
    """Pool-worker initialiser: one numba thread per process, exit when the parent dies, then
    :func:`warm_worker` of ``kinds``."""
    import signal

    os.environ["NUMBA_NUM_THREADS"] = str(WORKER_NUMBA_THREADS)
    # Ctrl-C goes to the whole terminal process group: the parent handles it (commits what is
    # finished, stops the pool); workers would only print tracebacks.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    warm_worker(kinds)


def _exit_with_parent() -> None:
    """Exit this worker as soon as its parent process is gone (killed with SIGKILL, say).

    An idle worker waits on the task queue, whose write end every worker also holds, so it
    would never see end-of-file and would block for good (and the resource tracker with it).
    A daemon thread waits on the parent's sentinel instead and ends the process; a run it
    interrupts is not recorded and is re-run by the next ``eha campaign run``.
    """
    import multiprocessing
    import threading
    from multiprocessing.connection import wait

    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:
        return

    def watch() -> None:
        wait([parent.sentinel])
        os._exit(1)

    threading.Thread(target=watch, name="eha-parent-watch", daemon=True).start()



def warm_worker(kinds: Sequence[str] | None = None) -> str:
    """Run the warm-ups of job kinds ``kinds`` (None: of every kind) in this process, once
    each (:func:`eha.campaigns.jobs.warm_up`; e.g. a tiny HF and LF run end to end, not
    recorded anywhere), so that imports happen once per worker instead of inside the first
    task and numba loads the cached kernels, after :func:`tune_malloc`. A kind not warmed here
    is warmed before its first job in the process. Returns ``host:pid``."""
    from eha.campaigns.jobs import warm_up

    tune_malloc()
    warm_up(kinds)
    return f"{socket.gethostname()}:{os.getpid()}"


# =========================================================================== executors
class Executor:
    """Runs a function over payloads on some workers; yields results as they complete.

    Subclasses implement :meth:`_submit` and :meth:`_wait_one`; at most ``in_flight`` tasks
    are outstanding so that a huge campaign does not sit in memory as futures.
    """

    workers: int = 1
    #: Tasks per worker a campaign of short chunks is sent as (several chunks per task, see
    #: :func:`eha.campaigns.runner.bundle_tasks`), or None: one chunk per task.
    tasks_per_worker: int | None = None

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        # Ctrl-C, SIGTERM or exit: what is finished is committed already (the runner's
        # ``finally``); the runs still in the workers are not, so stop them now rather than
        # wait for them.
        if exc_type is not None and not issubclass(exc_type, Exception):
            self.abort()
        self.close()

    def close(self) -> None:  # pragma: no cover - overridden
        pass

    def abort(self) -> None:
        """Stop the running jobs at once (their runs stay pending and are re-run)."""

    def warm_up(self, kinds: Sequence[str] | None = None) -> None:
        """Start the workers and run the warm-ups of job kinds ``kinds`` (None: every kind's)
        in each before timing or submitting jobs."""

    def map_unordered(self, fn: Callable, payloads: Iterable[Any]) -> Iterator[Any]:
        pending: set = set()
        in_flight = max(4, 4 * self.workers)
        it = iter(payloads)
        exhausted = False
        while True:
            while not exhausted and len(pending) < in_flight:
                try:
                    pending.add(self._submit(fn, next(it)))
                except StopIteration:
                    exhausted = True
            if not pending:
                return
            done, pending = self._wait(pending)
            for fut in done:
                yield fut.result()

    def _submit(self, fn, payload):  # pragma: no cover - overridden
        raise NotImplementedError

    def _wait(self, pending: set) -> tuple[set, set]:  # pragma: no cover - overridden
        raise NotImplementedError


class _MainHidden:
    """Hide ``__main__`` from multiprocessing while workers are spawned.

    A spawned worker normally re-imports the parent's main script (the ``eha`` entry point,
    a notebook kernel, a script without an ``if __name__ == "__main__"`` guard, or fails for
    ``python - < script``). The pool only runs functions of importable modules (this package's
    and the job kinds'), so the workers need nothing from ``__main__``: skipping it starts them
    faster and from anywhere.
    """

    def __enter__(self):
        import sys

        self.main = sys.modules.get("__main__")
        self.saved = {k: getattr(self.main, k) for k in ("__spec__", "__file__")
                      if self.main is not None and hasattr(self.main, k)}
        if self.main is not None:
            self.main.__spec__ = None
            if "__file__" in self.saved:
                del self.main.__file__
        return self

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            setattr(self.main, k, v)


class LocalPoolExecutor(Executor):
    """A pool of ``workers`` spawned processes (one numba thread each).

    All workers are started by :meth:`warm_up` (the runner calls it before the first job,
    with the campaign's job kinds); the pool is made then, or at the first task.
    """

    def __init__(self, workers: int = 2):
        self.workers = max(1, int(workers))
        self._made = None

    @property
    def _pool(self):
        return self._make(())  # a task before any warm-up: each kind warms at its first job

    def _make(self, kinds: Sequence[str] | None = None):
        """The process pool, made on first use: its workers warm up ``kinds`` as they start."""
        if self._made is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self._made = ProcessPoolExecutor(
                self.workers, mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
                initargs=(None if kinds is None else tuple(kinds),))
        return self._made

    def warm_up(self, kinds: Sequence[str] | None = None) -> None:
        # Every worker runs the initialiser (warm_worker) as it starts; these no-op tasks only
        # make all of them start now. A pool already made warms another campaign's kinds
        # before each kind's first job instead (eha.campaigns.jobs.execute_task).
        self._make(kinds)
        if getattr(self, "_warm", False):
            return
        self._warm = True
        # One task per worker, submitted back to back: each submit spawns a process (none is
        # idle yet), so every worker starts here, inside _MainHidden.
        with _MainHidden():
            futs = [self._pool.submit(time.sleep, 0.02) for _ in range(self.workers)]
        for f in futs:
            f.result()

    def _submit(self, fn, payload):
        return self._pool.submit(fn, payload)

    def _wait(self, pending):
        from concurrent.futures import FIRST_COMPLETED, wait

        done, rest = wait(pending, return_when=FIRST_COMPLETED)
        return set(done), set(rest)

    def close(self) -> None:
        # The workers exit on their own once told to; the parent goes on meanwhile.
        if self._made is not None:
            self._made.shutdown(wait=False, cancel_futures=True)

    def abort(self) -> None:
        from multiprocessing.connection import wait

        if self._made is None:
            return
        procs = list((getattr(self._made, "_processes", None) or {}).values())
        for proc in procs:
            try:
                proc.terminate()
            except (OSError, ValueError, AttributeError):  # already gone
                pass
        # A worker stopped while it sends a result leaves half a message in the result pipe:
        # the pool's manager thread then waits for the rest for good, and so does the exit of
        # the interpreter, which joins that thread (CPython 3.11; a SIGTERM test hung so in
        # CI). Once the workers are gone, the parent's own write end is the pipe's last:
        # closing it gives the thread end-of-file, it marks the pool broken and ends.
        try:
            sentinels = [p.sentinel for p in procs]
        except (ValueError, AttributeError):  # pragma: no cover - a process not started
            return
        deadline = time.monotonic() + ABORT_WAIT_S
        while sentinels and time.monotonic() < deadline:
            gone = wait(sentinels, timeout=max(0.0, deadline - time.monotonic()))
            sentinels = [s for s in sentinels if s not in gone]
        writer = getattr(getattr(self._made, "_result_queue", None), "_writer", None)
        if procs and not sentinels and writer is not None:
            try:
                writer.close()
            except OSError:  # pragma: no cover - closed already
                pass


class DaskExecutor(Executor):
    """Jobs on a Dask distributed cluster (``scheduler``: ``tcp://HOST:PORT`` or a Client).

    Workers must see the results folder at the same absolute path (shared file system) and
    have ``eha`` installed; see docs/scaling.md.

    A Dask task costs the scheduler and the client 2-5 ms of CPU (the local pool's about
    0.1 ms), on a ``LocalCluster`` taken from the cores the workers use: short chunks go in
    bundles of about four tasks per worker (2000 runs of 0.2 s on 2 workers: 8 tasks instead
    of 64, Dask / pool 1.05 instead of 1.32; the pool itself is slower with bundles, 1.23
    against 1.12 s, as the parent then commits in fewer, later batches).
    """

    tasks_per_worker = 4

    def __init__(self, scheduler: Any):
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - depends on the install
            raise RuntimeError("`scheduler` needs Dask: pip install 'eha[dask]'") from None
        if isinstance(scheduler, Client):
            self.client, self._own = scheduler, False
        else:
            try:
                self.client, self._own = Client(scheduler, timeout="10s"), True
            except (OSError, TimeoutError, ValueError, TypeError) as exc:
                raise RuntimeError(f"`scheduler` {scheduler}: cannot connect "
                                   f"({type(exc).__name__}: {exc})") from None
        self.workers = max(1, sum(w.get("nthreads", 1) for w in
                                  self.client.scheduler_info()["workers"].values()))

    def warm_up(self, kinds: Sequence[str] | None = None) -> None:
        # once per worker and kind (the pool's workers also warm up once): a campaign reusing
        # this executor only warms the workers that joined since, or its kinds not yet warmed
        want = None if kinds is None else frozenset(kinds)  # None: every kind
        warmed: dict = getattr(self, "_warmed", {})  # worker -> kinds warmed (None: every)

        def done(w) -> bool:
            had = warmed.get(w, frozenset())
            return had is None or (want is not None and want <= had)

        new = [w for w in self.client.scheduler_info()["workers"] if not done(w)]
        if new:
            self.client.run(warm_worker, None if want is None else sorted(want), workers=new)
        for w in new:
            warmed[w] = None if want is None else warmed.get(w, frozenset()) | want
        self._warmed = warmed

    def _submit(self, fn, payload):
        return self.client.submit(fn, payload, pure=False)

    def _wait(self, pending):
        from distributed import wait

        res = wait(list(pending), return_when="FIRST_COMPLETED")
        return set(res.done), set(res.not_done)

    def close(self) -> None:
        if self._own:
            self.client.close()


def check_scheduler(address: str) -> str:
    """Refuse a ``--scheduler`` that is not a Dask address (``tcp://HOST:PORT``) before any
    work starts; returns it.

    Raises
    ------
    eha.errors.InputError
        One line naming the option and the expected form (a ``ValueError``).
    """
    import re

    from eha.errors import InputError

    ok = re.fullmatch(r"(?:(?:tcp|tls|ucx|ws|wss)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                      r":(\d{1,5})", address.strip())
    if not ok or not 0 < int(ok.group(1)) < 65536:
        raise InputError(f"`scheduler` {address!r}: not a scheduler address; expected "
                         "tcp://HOST:PORT (PORT in [1, 65535])")
    return address


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Refuse a ``--scheduler`` (``tcp://HOST:PORT``) that no one answers at, before any
    work starts (the results folder and its database are not created): a TCP connection to
    its host and port, closed at once.

    Raises
    ------
    RuntimeError
        One line naming the address and the reason (connection refused, timed out, unknown
        host).
    """
    import re
    import socket

    found = re.fullmatch(r"(?:\w+://)?\[?([^\]]+?)\]?:(\d+)", address.strip())
    if found is None:
        return  # check_scheduler's to refuse
    try:
        socket.create_connection((found.group(1), int(found.group(2))), timeout=timeout).close()
    except OSError as exc:
        raise RuntimeError(f"cannot reach the Dask scheduler at {address} "
                           f"({exc.strerror or exc}); nothing was created") from None


def make_executor(workers: int = 2, scheduler: Any = None) -> Executor:
    """The local spawn pool, or a :class:`DaskExecutor` when ``scheduler`` is given."""
    if scheduler is not None:
        return DaskExecutor(scheduler)
    return LocalPoolExecutor(workers)


__all__ = ["Executor", "LocalPoolExecutor", "DaskExecutor", "make_executor", "check_scheduler",
           "check_reachable",
           "warm_worker", "tune_malloc", "WORKER_NUMBA_THREADS"]
