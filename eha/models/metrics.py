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

    Eight shifts are summed side by side (eight independent sums in one pass over the
    samples), each still in sample order, so every value is bit for bit the plain loop's
    (tests/test_chunks.py) at a third of its time: one sum alone waits on each addition.

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
        x = xu[r]
        c = com[r]
        k = 0
        while k + 7 <= kmax:
            s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
            m = n - k - 7          # samples that all eight shifts have
            for i in range(m):
                ci = c[i]
                d0 = x[i + k] - ci
                d1 = x[i + k + 1] - ci
                d2 = x[i + k + 2] - ci
                d3 = x[i + k + 3] - ci
                d4 = x[i + k + 4] - ci
                d5 = x[i + k + 5] - ci
                d6 = x[i + k + 6] - ci
                d7 = x[i + k + 7] - ci
                s0 += d0 * d0
                s1 += d1 * d1
                s2 += d2 * d2
                s3 += d3 * d3
                s4 += d4 * d4
                s5 += d5 * d5
                s6 += d6 * d6
                s7 += d7 * d7
            sums = (s0, s1, s2, s3, s4, s5, s6, s7)
            for j in range(8):     # the samples left to the smaller shifts
                s = sums[j]
                for i in range(m, n - k - j):
                    d = x[i + k + j] - c[i]
                    s += d * d
                errs[r, k + j] = s / (n - k - j)
            k += 8
        for k in range(k, kmax + 1):
            s = 0.0
            for i in range(n - k):
                d = x[i + k] - c[i]
                s += d * d
            errs[r, k] = s / (n - k)
