"""Numba kernel of the run metrics (:mod:`eha.models.run_metrics`): the lag search.

The lag of a run is the shift of the command that best matches the position, searched over
up to 200 shifts; as numpy calls that was 100-200 calls per run (1.7 ms per 0.2-s run, more
than its simulation). This loop does every shift of every run of a chunk in one call.
"""

from numba import njit


@njit(cache=True)
def lag_errors(xu, com, kmax, errs):
    """Mean squared error of ``xu[r, k:]`` against ``com[r, :n-k]`` for every run ``r`` and
    shift ``k`` in ``0..kmax`` (samples), into ``errs[r, k]`` [m^2].

    Parameters
    ----------
    xu, com : float64 arrays (runs, n)
        Position and command [m].
    kmax : int
        Largest shift [samples], at most n - 1.
    errs : float64 array (runs, kmax + 1)
        Output.
    """
    runs, n = xu.shape
    for r in range(runs):
        for k in range(kmax + 1):
            s = 0.0
            for i in range(n - k):
                d = xu[r, i + k] - com[r, i]
                s += d * d
            errs[r, k] = s / (n - k)
