"""Metrics of campaign runs (the ``metrics`` table), vectorised over the runs of a chunk.

Per run these cost as much as a short simulation when computed one run at a time (measured:
1.7 ms for a 0.2-s HF run that simulates in 1.1 ms; the lag search alone was 100-200 numpy
calls per run). :func:`batch_metrics` computes them for a whole chunk of equally long runs
on ``(runs, samples)`` arrays, the lag search in one numba call
(:func:`eha.models.metrics.lag_errors`); :func:`trace_metrics` is the same computation on one
run. Units are SI (cor in mA).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

#: Tolerance band of the settling time: fraction of the command's peak magnitude.
SETTLING_BAND = 0.02
#: Largest command-to-position lag searched [s].
MAX_LAG = 0.2
#: Columns of the ``metrics`` table computed per run, in the table's order.
RUN_METRICS = ("rmse_xu_com", "max_err_xu_com", "final_err_xu_com", "settling_time", "lag",
               "xu_min", "xu_max", "xs_abs_max", "p12_min", "p12_max", "p12_abs_max",
               "cor_abs_max")
#: HF-vs-LF columns of a case (both runs of the case get them).
PAIR_METRICS = ("rmse_xu_hf_lf", "max_err_xu_hf_lf", "rmse_p12_hf_lf")


def rmse(a, b) -> float:
    """Root-mean-square difference of two equally sampled signals."""
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def max_abs_error(a, b) -> float:
    """Largest absolute difference of two equally sampled signals."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


def _settling(t: np.ndarray, err: np.ndarray, com_peak: np.ndarray,
              band: float) -> np.ndarray:
    """Settling time [s] of each row of ``err = |xu - com|`` (NaN: never, or zero command)."""
    tol = band * com_peak
    outside = err > tol[:, None]
    n = err.shape[1]
    any_out = outside.any(axis=1)
    last = n - 1 - np.argmax(outside[:, ::-1], axis=1)  # last sample outside the band
    out = np.where(any_out, t[np.minimum(last + 1, n - 1)], t[0])
    return np.where((tol <= 0) | (any_out & (last == n - 1)), np.nan, out)


def _lag(t: np.ndarray, xu: np.ndarray, com: np.ndarray, max_lag: float) -> np.ndarray:
    """Shift [s] in ``[0, max_lag]`` of ``com`` best matching ``xu`` per row (least squares;
    NaN for a constant command or fewer than 3 samples)."""
    runs, n = xu.shape
    if n < 3:
        return np.full(runs, np.nan)
    # numba is imported here, not with this module: a spawn worker sets its thread count
    # before numba first loads (eha.campaigns.executors)
    from eha.models.metrics import lag_errors

    dt = float(t[1] - t[0])
    kmax = min(int(round(max_lag / dt)), n // 2)
    errs = np.empty((runs, kmax + 1))
    lag_errors(np.ascontiguousarray(xu, dtype=np.float64),
               np.ascontiguousarray(com, dtype=np.float64), kmax, errs)
    out = np.argmin(errs, axis=1) * dt
    return np.where(np.ptp(com, axis=1) == 0, np.nan, out)


def batch_metrics(t: np.ndarray, signals: Mapping[str, np.ndarray],
                  band: float = SETTLING_BAND, max_lag: float = MAX_LAG) -> dict[str, np.ndarray]:
    """Metrics of equally long runs.

    Parameters
    ----------
    t : float64 array (n,)
        Common time grid [s].
    signals : mapping
        ``xu``, ``com``, ``xs``, ``p12`` [m, m, m, Pa] and ``cor`` [mA], each a float64 array
        (runs, n).

    Returns
    -------
    dict
        :data:`RUN_METRICS` -> float64 array (runs,), NaN where undefined (stored as NULL).
    """
    xu, com = signals["xu"], signals["com"]
    diff = xu - com
    err = np.abs(diff)
    p12 = signals["p12"]
    return {
        "rmse_xu_com": np.sqrt(np.einsum("ij,ij->i", diff, diff) / diff.shape[1]),
        "max_err_xu_com": err.max(axis=1), "final_err_xu_com": diff[:, -1],
        "settling_time": _settling(t, err, np.abs(com).max(axis=1), band),
        "lag": _lag(t, xu, com, max_lag),
        "xu_min": xu.min(axis=1), "xu_max": xu.max(axis=1),
        "xs_abs_max": np.abs(signals["xs"]).max(axis=1),
        "p12_min": p12.min(axis=1), "p12_max": p12.max(axis=1),
        "p12_abs_max": np.abs(p12).max(axis=1),
        "cor_abs_max": np.abs(signals["cor"]).max(axis=1),
    }


def _none_if_nan(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


def settling_time(t, xu, com, band: float = SETTLING_BAND) -> float | None:
    """Time [s] from which ``|xu - com|`` stays within ``band * max|com|``; None if it never does
    (or the command is zero)."""
    t, xu, com = (np.asarray(a, dtype=float) for a in (t, xu, com))
    return _none_if_nan(_settling(t, np.abs(xu - com)[None], np.abs(com).max()[None], band)[0])


def lag(t, xu, com, max_lag: float = MAX_LAG) -> float | None:
    """Shift [s] in ``[0, max_lag]`` of ``com`` that best matches ``xu`` (least squares);
    None for a constant command."""
    t, xu, com = (np.asarray(a, dtype=float) for a in (t, xu, com))
    return _none_if_nan(_lag(t, xu[None], com[None], max_lag)[0])


def trace_metrics(trace) -> dict[str, float | None]:
    """Metrics of one run (a :class:`~eha.models.simulate.Trace`): the columns of the ``metrics``
    table, computed by :func:`batch_metrics` on a chunk of one."""
    sig = {n: np.asarray(trace[n])[None] for n in ("xu", "com", "xs", "p12", "cor")}
    out = batch_metrics(np.asarray(trace.t), sig)
    return {k: _none_if_nan(v[0]) if k in ("settling_time", "lag") else float(v[0])
            for k, v in out.items()}


def pair_metrics(hf, lf) -> dict[str, float | None]:
    """HF-vs-LF metrics of one case (same command, faults, seed, t_end).

    ``hf``, ``lf``: :class:`~eha.models.simulate.Trace` or mappings with ``"xu"`` and ``"p12"``.
    """
    out = {"rmse_xu_hf_lf": rmse(hf["xu"], lf["xu"]),
           "max_err_xu_hf_lf": max_abs_error(hf["xu"], lf["xu"]),
           "rmse_p12_hf_lf": rmse(hf["p12"], lf["p12"])}
    return {k: _none_if_nan(v) for k, v in out.items()}


def batch_pair_metrics(hf: Mapping[str, np.ndarray],
                       lf: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """:func:`pair_metrics` of many cases at once: ``xu``, ``p12`` arrays (cases, n) each."""
    dxu = hf["xu"] - lf["xu"]
    dp = hf["p12"] - lf["p12"]
    n = dxu.shape[1]
    return {"rmse_xu_hf_lf": np.sqrt(np.einsum("ij,ij->i", dxu, dxu) / n),
            "max_err_xu_hf_lf": np.abs(dxu).max(axis=1),
            "rmse_p12_hf_lf": np.sqrt(np.einsum("ij,ij->i", dp, dp) / n)}


def as_rows(values: Mapping[str, Any]) -> list[dict[str, float | None]]:
    """Column arrays -> one dict per run (NaN -> None)."""
    names = list(values)
    cols = [np.asarray(values[n], dtype=float) for n in names]
    return [{n: _none_if_nan(c[i]) for n, c in zip(names, cols)}
            for i in range(len(cols[0]) if cols else 0)]
