"""glibc's malloc thresholds in a worker (:func:`tune_malloc`): run by the executors' warm-up
and by every task (:mod:`eha.campaigns.jobs`), so it lives apart from both."""

from __future__ import annotations

#: glibc malloc thresholds set in every worker [bytes] (:func:`tune_malloc`): allocations up
#: to 32 MiB come from the heap, which keeps up to 64 MiB of free memory at its top (glibc's
#: own dynamic maxima).
MALLOC_MMAP_THRESHOLD = 32 << 20
MALLOC_TRIM_THRESHOLD = 64 << 20

_malloc_tuned = False


def tune_malloc() -> bool:
    """Fix glibc's malloc thresholds in this worker (:data:`MALLOC_MMAP_THRESHOLD`,
    :data:`MALLOC_TRIM_THRESHOLD`); once per process, a no-op elsewhere than glibc. Returns
    whether they are set.

    Dask's nanny starts every worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (its
    ``distributed.nanny.pre-spawn-environ``; a ``LocalCluster`` also leaves it in the parent's
    environment, so pool workers spawned after one inherit it). Any such variable turns off
    glibc's dynamic mmap threshold: every array over 128 kB (a 1-s run's command on the step
    grid is 0.8 MB) is then mmap-ed and unmapped on each run, about 1100 page faults per 1-s HF
    run, and ``simulate()`` took 6.5 ms of CPU instead of 3.6 ms (measured, docs/scaling.md).
    """
    global _malloc_tuned
    if _malloc_tuned:
        return True
    import ctypes
    import platform

    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        # M_MMAP_THRESHOLD = -3, M_TRIM_THRESHOLD = -1 (malloc.h); mallopt returns 1 on success
        _malloc_tuned = bool(libc.mallopt(-3, MALLOC_MMAP_THRESHOLD)
                             and libc.mallopt(-1, MALLOC_TRIM_THRESHOLD))
    except (OSError, AttributeError):  # pragma: no cover - no such libc
        return False
    return _malloc_tuned


__all__ = ["MALLOC_MMAP_THRESHOLD", "MALLOC_TRIM_THRESHOLD", "tune_malloc"]
