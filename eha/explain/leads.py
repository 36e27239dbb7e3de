"""Leads for a residual no library effect explains: its relation to candidate signal features.

When the residual of the best library model (:mod:`eha.explain.effects`) is still well above the
measurement noise, ``eha explain`` says so and gives the user a lead: which simple functions
of the model's signals the residual follows, e.g. ``unexplained residual 12.3 µm (8.1× noise),
correlated with position_cubed (61 % of it), velocity_sign (9 %)``. A cubic position term points
at a non-linear spring or load, ``velocity_sign`` at dry friction the model lacks,
``command_steps`` at unmodelled fast dynamics after command jumps.

The relation is a sparse linear regression of the residual on the ~12 features of
:data:`FEATURES`, by sequentially thresholded least squares (STLSQ, the sparse regression of
SINDy, Brunton, Proctor & Kutz, PNAS 2016): fit all features, zero the coefficients below a
threshold, refit the rest, repeat until the selection no longer changes.

Why hand-written rather than PySINDy: PySINDy's STLSQ is built to regress *derivatives* of a
state on a library of its functions and brings scikit-learn with it; here the target is a
residual [m] and the library is a dozen columns, so the whole method is a few small
least-squares solves (~100 lines of numpy), deterministic, with the two things PySINDy does
not give: each term's share of the residual (drop-one R²) and coefficients in physical units.

Conventions (see :func:`sparse_regression`):

- columns and the residual are scaled to unit RMS, *not centred*: ``constant`` is a candidate
  like the others, so a residual's mean is a lead of its own (a sensor bias), and R² is the
  fraction of the residual's mean square, the quantity its RMSE reports;
- a term's share is what the sparse model loses without it (refitted): shares of correlated
  terms need not add up to R²;
- at most ``max_terms`` terms are kept, and none that explains less than ``min_share``: the
  weakest (smallest share) is removed and the rest refitted until both hold. This also resolves
  exact collinearity (``tracking_error = command - position``): a term the others reproduce
  exactly has share 0.

No I/O; nothing random.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from eha.errors import InputError

#: Candidate features, in column order: name -> meaning. Signals are the model's (LF) position
#: x [m] and jack velocity v [m/s], the command c [m] and the load pressure P12 [Pa].
FEATURES: dict[str, str] = {
    "position": "model position x",
    "velocity": "model jack velocity v",
    "velocity_sign": "sign(v), 0 within the dead zone |v| <= VELOCITY_DEAD_ZONE (dry friction)",
    "p12": "load pressure P12",
    "position_abs_position": "x*|x| (a quadratic, odd load or stiffness)",
    "position_cubed": "x^3 (a cubic spring or load)",
    "velocity_abs_velocity": "v*|v| (quadratic damping, turbulent flow)",
    "command": "position command c",
    "tracking_error": "c - x",
    "command_steps": "sum over command jumps of sign(jump)*exp(-(t - t_jump)/STEP_TAU)",
    "position_sign": "sign(x) (a force or bias that depends on the side of the stroke)",
    "constant": "1 (a bias)",
}
#: Unit of each feature (a coefficient's unit is m per this unit).
FEATURE_UNITS: dict[str, str] = {
    "position": "m", "velocity": "m/s", "velocity_sign": "-", "p12": "Pa",
    "position_abs_position": "m^2", "position_cubed": "m^3", "velocity_abs_velocity": "m^2/s^2",
    "command": "m", "tracking_error": "m", "command_steps": "-", "position_sign": "-",
    "constant": "-",
}
#: |v| below which sign(v) is 0 [m/s]: the LF jack creeps at µm/s near a held position, and
#: its sign there is not the direction of a motion (a 1 cm chirp at 0.1 Hz peaks at 6 mm/s).
VELOCITY_DEAD_ZONE = 1e-4
#: Decay time of the command-step feature [s]: the actuator's closed-loop response time.
STEP_TAU = 0.02
#: A command jump: a one-sample change larger than STEP_FACTOR times the mean change of the
#: STEP_WINDOW samples on each side (a ramp or a chirp changes about as much every sample; a
#: logged step stands out), and at least STEP_FLOOR [m] (a held command's quantisation).
STEP_FACTOR = 10.0
STEP_WINDOW = 10
STEP_FLOOR = 1e-6
#: Default STLSQ threshold on a coefficient of the unit-RMS problem (a term below it would
#: carry at most (0.05)^2 = 0.25 % of the residual's mean square on its own).
THRESHOLD = 0.05
#: Default smallest share of the residual a kept term must explain (drop-one R²).
MIN_SHARE = 0.01
#: The sparse model must explain at least this share of the residual for the residual to be
#: called "correlated with" its terms (:attr:`LeadReport.leads`).
LEAD_SHARE = 0.10


class LeadsError(InputError):
    """Bad input to the residual leads (one line)."""


def _sign(x: np.ndarray, dead_zone: float = 0.0) -> np.ndarray:
    return np.where(x > dead_zone, 1.0, np.where(x < -dead_zone, -1.0, 0.0))


def command_steps(t: np.ndarray, command: np.ndarray, tau: float = STEP_TAU) -> np.ndarray:
    """The command-step feature: ``sum_j sign(jump_j)*exp(-(t - t_j)/tau)`` for ``t >= t_j``.

    Parameters
    ----------
    t : float64 array
        Time [s], increasing.
    command : float64 array
        Position command [m] at ``t``.
    tau : float
        Decay time [s].

    Returns
    -------
    float64 array, same length; zeros when the command has no jump (see :data:`STEP_FACTOR`).
    Consecutive jump samples (a step logged across two samples) are one jump, at the first.
    """
    t = np.asarray(t, dtype=np.float64)
    command = np.asarray(command, dtype=np.float64)
    d = np.abs(np.diff(command))
    if d.size == 0:
        return np.zeros_like(t)
    # mean |change| of the STEP_WINDOW samples on each side, the sample itself left out (a
    # step must not hide itself), from a cumulative sum: O(n) for hour-long records
    c = np.concatenate(([0.0], np.cumsum(d)))
    k = np.arange(d.size)
    lo = np.maximum(k - STEP_WINDOW, 0)
    hi = np.minimum(k + STEP_WINDOW + 1, d.size)
    local = (c[hi] - c[lo] - d) / np.maximum(hi - lo - 1, 1)
    jump = (d > STEP_FACTOR * local) & (d >= STEP_FLOOR)
    out = np.zeros_like(t)
    if not jump.any():
        return out
    dc = np.diff(command)
    # each group of consecutive jump samples: its total change, at the group's first sample
    opens = jump & ~np.concatenate(([False], jump[:-1]))
    first = np.flatnonzero(opens)
    group_id = np.cumsum(opens) - 1
    total = np.bincount(group_id[jump], weights=dc[jump], minlength=first.size)
    starts = first + 1  # the sample where the command has its new value
    # exact piecewise decay: between jumps j and j+1 the feature is S_j*exp(-(t - t_j)/tau)
    level = 0.0
    for j, (s, tot) in enumerate(zip(starts, total)):
        if j:
            level *= math.exp(-(t[s] - t[starts[j - 1]]) / tau)
        level += math.copysign(1.0, tot) if tot != 0.0 else 0.0
        end = starts[j + 1] if j + 1 < starts.size else t.size
        out[s:end] = level * np.exp(-(t[s:end] - t[s]) / tau)
    return out


def _as_signal(name: str, values, n: int | None) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1:
        raise LeadsError(f"residual leads: {name} must be 1-D, got shape {a.shape}")
    if n is not None and a.size != n:
        raise LeadsError(f"residual leads: {name} has {a.size} samples, t has {n}")
    if not np.all(np.isfinite(a)):
        raise LeadsError(f"residual leads: {name} has a non-finite value (NaN or inf)")
    return a


def feature_matrix(t, command, position, velocity, p12, *,
                   velocity_dead_zone: float = VELOCITY_DEAD_ZONE,
                   tau: float = STEP_TAU) -> tuple[list[str], np.ndarray]:
    """The candidate features of :data:`FEATURES` on the record's grid.

    Parameters
    ----------
    t : float64 array
        Time [s] (the 1 kHz grid of the record).
    command : float64 array
        Position command [m].
    position : float64 array
        Model position x [m].
    velocity : float64 array
        Model jack velocity v [m/s].
    p12 : float64 array or None
        Load pressure [Pa]; None leaves the feature out.
    velocity_dead_zone : float
        |v| [m/s] below which ``velocity_sign`` is 0.
    tau : float
        Decay time [s] of ``command_steps``.

    Returns
    -------
    names : list of str
        Feature names, in :data:`FEATURES` order, without the features of zero variance (a
        command without jumps has no ``command_steps``; a stroke on one side no
        ``position_sign``); ``constant`` is always there.
    X : float64 array, shape (n, len(names))
        The features, in their units (:data:`FEATURE_UNITS`).
    """
    t = _as_signal("t", t, None)
    n = t.size
    c = _as_signal("command", command, n)
    x = _as_signal("position", position, n)
    v = _as_signal("velocity", velocity, n)
    cols = {
        "position": x,
        "velocity": v,
        "velocity_sign": _sign(v, velocity_dead_zone),
        "p12": None if p12 is None else _as_signal("p12", p12, n),
        "position_abs_position": x * np.abs(x),
        "position_cubed": x ** 3,
        "velocity_abs_velocity": v * np.abs(v),
        "command": c,
        "tracking_error": c - x,
        "command_steps": command_steps(t, c, tau),
        "position_sign": _sign(x),
        "constant": np.ones(n),
    }
    names = []
    for name, col in cols.items():
        if col is None:
            continue
        # zero variance relative to the column's size (a constant column is the constant's
        # duplicate; an all-zero one explains nothing)
        if name != "constant" and np.std(col) <= 1e-12 * max(float(np.max(np.abs(col))), 1e-300):
            continue
        names.append(name)
    X = np.column_stack([cols[n_] for n_ in names]) if names else np.empty((n, 0))
    return names, X


@dataclass(frozen=True)
class Lead:
    """One term of the sparse model of the residual.

    Attributes
    ----------
    feature : str
        Feature name (:data:`FEATURES`).
    coefficient : float
        Residual per unit of the feature [m per :data:`FEATURE_UNITS` unit].
    share : float
        Fraction of the residual's mean square the term explains: R² of the sparse model minus
        R² of the model refitted without it (0..1).
    """

    feature: str
    coefficient: float
    share: float

    @property
    def unit(self) -> str:
        """Unit of :attr:`coefficient`."""
        u = FEATURE_UNITS.get(self.feature, "?")
        return "m" if u == "-" else f"m/({u})" if "/" in u else f"m/{u}"


@dataclass(frozen=True)
class SparseFit:
    """Result of :func:`sparse_regression`.

    Attributes
    ----------
    terms : tuple of Lead
        Selected terms, largest share first.
    r2 : float
        Fraction of the residual's mean square the sparse model explains (0..1).
    correlations : dict of str to float
        Pearson correlation of the residual with every feature but ``constant`` (with which it
        is undefined), selected or not, in column order.
    """

    terms: tuple[Lead, ...]
    r2: float
    correlations: dict[str, float] = field(default_factory=dict)


def _r2(G: np.ndarray, b: np.ndarray, idx: Sequence[int]) -> tuple[float, np.ndarray]:
    """R² and coefficients of the least-squares fit on columns ``idx`` (unit-RMS problem:
    ``G = X'X/n``, ``b = X'y/n``, ``y'y/n = 1``); min-norm where the columns are dependent."""
    idx = list(idx)
    if not idx:
        return 0.0, np.zeros(0)
    xi = np.linalg.lstsq(G[np.ix_(idx, idx)], b[idx], rcond=1e-12)[0]
    return float(min(max(b[idx] @ xi, 0.0), 1.0)), xi


def sparse_regression(residual, X, names: Sequence[str], threshold: float = THRESHOLD,
                      max_terms: int = 3, min_share: float = MIN_SHARE) -> SparseFit:
    """Sparse linear model of a residual on candidate features (STLSQ).

    Parameters
    ----------
    residual : float64 array, shape (n,)
        Residual [m] (measured minus model position).
    X : float64 array, shape (n, p)
        Features in their units (:func:`feature_matrix`).
    names : sequence of str
        Column names of ``X``.
    threshold : float
        STLSQ threshold on the coefficients of the unit-RMS problem (columns and residual
        scaled to RMS 1): a term below it is dropped and the rest refitted.
    max_terms : int
        Most terms kept.
    min_share : float
        Smallest share of the residual's mean square a kept term must explain.

    Returns
    -------
    SparseFit
        Terms with de-standardised coefficients [m per feature unit] and drop-one shares, the
        sparse model's R², and the Pearson correlation with every feature.

    Notes
    -----
    All fits use the p x p Gram matrix of the scaled columns (one pass over the data), so the
    cost is O(n p²) for any number of refits. Columns of zero RMS are never selected.
    """
    y = _as_signal("residual", residual, None)
    X = np.asarray(X, dtype=np.float64)
    names = list(names)
    if X.ndim != 2 or X.shape[0] != y.size or X.shape[1] != len(names):
        raise LeadsError(f"residual leads: X has shape {X.shape}, expected ({y.size}, "
                         f"{len(names)})")
    n, p = X.shape
    correlations = {}
    y_c = y - y.mean()
    y_sd = float(np.sqrt(np.mean(y_c ** 2)))
    for j, name in enumerate(names):
        if name == "constant":
            continue
        col = X[:, j] - X[:, j].mean()
        sd = float(np.sqrt(np.mean(col ** 2)))
        correlations[name] = float(np.mean(col * y_c) / (sd * y_sd)) if sd > 0 and y_sd > 0 \
            else 0.0
    y_rms = float(np.sqrt(np.mean(y ** 2))) if n else 0.0
    scale = np.sqrt(np.mean(X ** 2, axis=0)) if n else np.zeros(p)
    usable = [j for j in range(p) if scale[j] > 0.0]
    if y_rms == 0.0 or not usable:
        return SparseFit((), 0.0, correlations)
    Xs = X[:, usable] / scale[usable]
    G = Xs.T @ Xs / n
    b = Xs.T @ (y / y_rms) / n

    def stlsq(active: list[int]) -> list[int]:
        # the STLSQ iteration: threshold, refit, until the selection is stable
        while active:
            xi = _r2(G, b, active)[1]
            keep = [a for a, c in zip(active, xi) if abs(c) >= threshold]
            if keep == active:
                break
            active = keep
        return active

    def shares(active: list[int]) -> tuple[float, list[float]]:
        full = _r2(G, b, active)[0]
        return full, [full - _r2(G, b, [a for a in active if a != k])[0] for k in active]

    active = stlsq(list(range(len(usable))))
    while active:
        full, sh = shares(active)
        if len(active) <= max_terms and min(sh) >= min_share:
            break
        xi = _r2(G, b, active)[1]
        # the weakest term goes: smallest share, then smallest coefficient, then the later
        # column (the simpler features come first in FEATURES); deterministic
        weakest = min(range(len(active)), key=lambda i: (sh[i], abs(xi[i]), -active[i]))
        active = stlsq(active[:weakest] + active[weakest + 1:])
    if not active:
        return SparseFit((), 0.0, correlations)
    full, sh = shares(active)
    xi = _r2(G, b, active)[1]
    terms = [Lead(names[usable[a]], float(c * y_rms / scale[usable[a]]), float(max(s, 0.0)))
             for a, c, s in zip(active, xi, sh)]
    terms.sort(key=lambda L: -L.share)
    return SparseFit(tuple(terms), full, correlations)


@dataclass(frozen=True)
class LeadReport:
    """What is known about a residual the library cannot explain.

    Attributes
    ----------
    rmse : float
        RMSE of the residual [m].
    noise_rmse : float
        Measurement-noise level [m] (0 when not known).
    ratio : float
        ``rmse/noise_rmse`` (inf when the noise level is not known).
    terms : tuple of Lead
        The sparse model's terms, largest share first (:func:`sparse_regression`).
    r2 : float
        Fraction of the residual's mean square the sparse model explains.
    correlations : dict of str to float
        Pearson correlation of the residual with every feature but ``constant``.
    """

    rmse: float
    noise_rmse: float
    ratio: float
    terms: tuple[Lead, ...]
    r2: float
    correlations: dict[str, float] = field(default_factory=dict)

    @property
    def leads(self) -> tuple[Lead, ...]:
        """The terms worth naming: all of them when the sparse model explains at least
        :data:`LEAD_SHARE` of the residual, else none (a model of a few percent of the residual
        is not a lead). The model's R² decides, not the largest share: correlated terms (the
        velocity, its sign and the tracking error of a lagging loop) can together explain 90 %
        while each one's drop-one share is small."""
        if self.terms and self.r2 >= LEAD_SHARE:
            return self.terms
        return ()

    def describe(self) -> str:
        """One line, e.g. ``unexplained residual 12.3 µm (8.1× noise), correlated with
        position_cubed (61 % of it), velocity_sign (9 %)``.

        When the shares do not add up to the model's R² (correlated terms) by 5 points or
        more, ``; together 91 %`` follows."""
        if self.noise_rmse > 0.0 and math.isfinite(self.ratio):
            level = f"{_fmt(self.ratio)}× noise"
        else:
            level = "noise level not known"
        text = f"unexplained residual {_fmt(1e6 * self.rmse)} µm ({level})"
        leads = self.leads
        if not leads:
            return text + ", not correlated with any candidate feature"
        parts = [f"{L.feature} ({100.0 * L.share:.0f} %{' of it' if i == 0 else ''})"
                 for i, L in enumerate(leads)]
        text += ", correlated with " + ", ".join(parts)
        if len(leads) > 1 and abs(self.r2 - sum(L.share for L in leads)) >= 0.05:
            text += f"; together {100.0 * self.r2:.0f} %"
        return text

    def to_json(self) -> dict:
        """Plain types for a JSON report: lengths in m, shares and R² as fractions; ``ratio``
        is None when the noise level is not known."""
        return {
            "rmse": float(self.rmse),
            "noise_rmse": float(self.noise_rmse),
            "ratio": float(self.ratio) if math.isfinite(self.ratio) else None,
            "r2": float(self.r2),
            "terms": [{"feature": L.feature, "coefficient": float(L.coefficient),
                       "unit": L.unit, "share": float(L.share)} for L in self.terms],
            "leads": [L.feature for L in self.leads],
            "correlations": {k: float(v) for k, v in self.correlations.items()},
            "text": self.describe(),
        }


def _fmt(x: float) -> str:
    """3 significant digits without an exponent (12.3, 0.512, 1234)."""
    if x >= 100.0:
        return f"{x:.0f}"
    return f"{x:.3g}" if x >= 0.001 else f"{x:.1g}"


def residual_leads(residual, t, command, position, velocity, p12, noise_rmse: float,
                   threshold: float = THRESHOLD, max_terms: int = 3,
                   min_share: float = MIN_SHARE) -> LeadReport:
    """Leads for a residual: its size against the noise, and its sparse model on the features.

    Parameters
    ----------
    residual : float64 array
        Measured minus model position [m] on the record's grid.
    t, command, position, velocity, p12
        As :func:`feature_matrix` (s, m, m, m/s, Pa; ``p12`` may be None).
    noise_rmse : float
        Measurement-noise level [m]; 0 when not known.
    threshold, max_terms, min_share
        As :func:`sparse_regression`.

    Returns
    -------
    LeadReport
    """
    names, X = feature_matrix(t, command, position, velocity, p12)
    r = _as_signal("residual", residual, X.shape[0])
    fit = sparse_regression(r, X, names, threshold=threshold, max_terms=max_terms,
                            min_share=min_share)
    rmse = float(np.sqrt(np.mean(r ** 2))) if r.size else 0.0
    noise = float(noise_rmse) if noise_rmse is not None and math.isfinite(noise_rmse) else 0.0
    ratio = rmse / noise if noise > 0.0 else math.inf
    return LeadReport(rmse, max(noise, 0.0), ratio, fit.terms, fit.r2, fit.correlations)


__all__ = ["FEATURES", "FEATURE_UNITS", "Lead", "LeadReport", "LeadsError", "SparseFit",
           "command_steps", "feature_matrix", "residual_leads", "sparse_regression"]
