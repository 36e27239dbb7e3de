"""Predicted detectability and separability of targets on one command (docs/design.md).

For each target ``f`` the *truth* ``s_f`` is the change of the recorded signals per unit of
the parameter (an HF secant from a healthy actuator, the same dither on both runs), whitened by
each signal's sensor noise. The check fits the LF model's column of ``f`` together with its
nuisance parameters ``N`` (the core faults, and for a core fault the bank's best-fitting
one-more-fault hypothesis; for an effect also the flow gain); by Frisch-Waugh its
least-squares estimate moves along ``v = (I - P_N) c_f`` (``c_f`` the LF column) and

    estimate error = u'(e + d) / |v|,   u = v / |v|,   gain = u' s_f / |v|,

with ``e`` the white sensor noise (unit variance once whitened) and ``d`` a healthy actuator's
departure from nominal: manufacturing scatter (a secant column per scattered parameter times
its std, :data:`eha.identification.healthy.DISPERSION`), the dither (two reruns with other
seeds) and the check's LF model-form error (its mean square times its correlation time). The
healthy spread of the estimate is ``sigma = sqrt(1 + model form + sum (u'd)^2) / |v|``, the
OLS (sandwich) variance of the estimator the check really runs, not the Fisher bound of an
ideal one. With the health check's union bound and the check's own model-form floor, the
minimum detectable size at ``P_D`` is

    MDS_f = (z(1 - alpha/m) * sqrt(sigma^2 + floor^2) + z(P_D) * sigma) / gain.

Telling ``f`` from a rival ``g``: on ``f``'s truth, the residual ``g``'s best refit leaves
beyond ``f``'s own; the size of ``f`` at which it stands out by the same margin is its
*separable size* (kept absolute, and as a multiple of MDS_f: <= 2 told apart at twice the
detectable size).

Robust to the actuator's own scatter: every number is the worst over the design's actuators
(the nominal one and scattered ones).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Mapping, Sequence

import numpy as np

from eha.design.targets import SIGNALS, Target, nuisance_params
from eha.identification.healthy import DISPERSION, draw_actuator
from eha.identification.intervals import FLAG_RATIO, LOOP_MODEL_FORM, MODEL_FORM
from eha.identification.problem import CALIBRATED_LF
from eha.models import OUTPUTS
from eha.models.commands import Command
from eha.models.faults import FAULTS, core_faults, extra_faults
from eha.models.params import SPECS
from eha.models.simulate import simulate_hf_batch, simulate_lf_rows

#: Probability of detection the minimum detectable size is stated at.
P_DETECT = 0.95
#: Seeds of the design's scattered actuators (apart from the fleets' seeds 0..1e6 that
#: calibrations and verifications draw).
DESIGN_SEED0 = 1_000_000
#: Largest healthy model-form residual of the check's LF model on a usable command, in noise
#: stds (the identification's flag, :data:`eha.identification.intervals.FLAG_RATIO`).
FOLLOW_RATIO = FLAG_RATIO
#: Relative step of the flow gain's secant.
GQ_STEP = 0.02


@dataclass
class Prediction:
    """Predicted detectability of every target on one command (worst over the actuators).

    Attributes
    ----------
    mds : dict
        Target name -> minimum detectable deviation [parameter unit] (inf: no signature).
    sigma : dict
        Target name -> healthy std of its estimate [parameter unit].
    separable : dict
        ``separable[f][g]``: the size at which ``f`` is told from ``g``, as a multiple of
        ``mds[f]`` (inf: ``g`` mimics ``f`` completely).
    footprint : dict
        Target name -> RMS change of the position at its probe [m] (what it does to the
        record), beside ``noise`` for the "why not".
    """

    mds: dict[str, float]
    sigma: dict[str, float]
    separable: dict[str, dict[str, float]]
    footprint: dict[str, float]
    probes: dict[str, float] = field(default_factory=dict)
    model_form: float = 0.0
    separable_at: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def followed(self) -> bool:
        """Can the check's LF model follow the command? Its healthy model-form residual,
        once the core faults took what they can, is at most :data:`FOLLOW_RATIO` times the
        noise (beyond it the check's fit is flagged, and the measured campaign detects
        nothing: the 5 Hz sine)."""
        return self.model_form <= FOLLOW_RATIO

    def separable_size(self, f: str, g: str) -> float:
        """The deviation of ``f`` at which it is told from ``g`` [``f``'s unit]."""
        return self.separable_at[f][g]

    def detectable(self, target: Target) -> bool:
        return math.isfinite(self.mds[target.name]) and self.mds[target.name] <= target.limit


def scatter_columns() -> list[tuple[str, float]]:
    """``(parameter, std)`` of every scattered parameter of a healthy actuator."""
    out = []
    for name, (law, a, b) in DISPERSION.items():
        nominal = SPECS[name].nominal
        if law == "uniform_rel":
            std = abs(nominal) * a / math.sqrt(3.0)
        elif law == "normal":
            std = b
        else:  # log-uniform on [a, b]
            la, lb = math.log(a), math.log(b)
            m1 = (b - a) / (lb - la)
            m2 = (b * b - a * a) / (2.0 * (lb - la))
            std = math.sqrt(max(m2 - m1 * m1, 0.0))
        if std > 0:
            out.append((name, std))
    return out


def actuators(count: int) -> list[dict[str, float]]:
    """The design's actuators: the nominal one, then ``count - 1`` scattered ones."""
    return [{}] + [draw_actuator(DESIGN_SEED0 + k) for k in range(1, count)]


def _hf_runs(targets: Sequence[Target], actuator: Mapping[str, float], seed: int):
    """The HF runs of one actuator: ``(role, name, step, params, seed)``; the truth of each
    target, the healthy scatter of each scattered parameter (one std) and two dither
    reruns."""
    base = dict(actuator)

    def moved(param: str, step: float) -> dict[str, float]:
        return {**base, param: base.get(param, SPECS[param].nominal) + step}

    runs = [("base", "", 1.0, base, seed)]
    runs += [("target", t.name, t.probe, moved(t.param, t.probe), seed) for t in targets]
    runs += [("scatter", p, std, moved(p, std), seed) for p, std in scatter_columns()]
    runs += [("dither", str(k), 1.0, base, seed + 7919 * k) for k in (1, 2)]
    return runs


def _lf_columns(command: Command, targets: Sequence[Target], t_end: float, base: Mapping,
                signals, noise, decimate) -> tuple[np.ndarray, dict]:
    """The check's LF model on the command: its whitened output and, per fitted parameter
    (each target's, the nuisances', every health fault for the bank's hypotheses), its
    whitened secant column per unit parameter."""
    names = {t.param: t.probe for t in targets}
    for p in dict.fromkeys([n for t in targets for n in nuisance_params(t.kind)] +
                           (list(FAULTS) if any(t.kind == "fault" for t in targets) else [])):
        names.setdefault(p, _nuisance_step(p))
    params = [dict(base)] + [{**base, p: base.get(p, SPECS[p].nominal_for("lf")) + step}
                             for p, step in names.items()]
    y = whiten(simulate_lf_rows(params, command, t_end), signals, noise, decimate)
    return y[0], {p: (y[i + 1] - y[0]) / step for i, (p, step) in enumerate(names.items())}


def _hypotheses(target: Target) -> list[tuple[str, ...]]:
    """The nuisance sets under which ``target`` may be estimated: its check's nuisances; for a
    core fault of the health bank also each one-more-fault hypothesis (the bank's estimate is
    the best-fitting hypothesis', which absorbs what it can of a healthy actuator's scatter,
    :func:`_best_fitting`:
    measured, the H0 estimate of FDJ scatters 70 N over healthy actuators on chirp_1cm, 98 %
    correlated with their flow gain, which the motor-gain hypothesis absorbs)."""
    base = tuple(p for p in nuisance_params(target.kind) if p != target.param)
    if target.kind != "fault" or FAULTS[target.param].role != "core":
        return [base]
    return [base] + [base + (g,) for g in extra_faults()]


def _best_fitting(hypotheses: list[tuple[str, ...]], col: Mapping, spread: np.ndarray
                  ) -> tuple[str, ...]:
    """The hypothesis whose fit leaves the least of a healthy actuator's departures."""
    if len(hypotheses) == 1:
        return hypotheses[0]

    def left(hyp: tuple[str, ...]) -> float:
        basis = _orth([col[p] for p in hyp])
        rest = spread if basis is None else spread - basis @ (basis.T @ spread)
        return float(np.sum(rest ** 2))

    return min(hypotheses, key=left)


def _nuisance_step(param: str) -> float:
    if param in FAULTS:
        f = FAULTS[param]
        mid = f.levels[len(f.levels) // 2] if f.levels else f.bounds[1]
        return mid - f.healthy
    return GQ_STEP * SPECS[param].nominal


def whiten(out: np.ndarray, signals: Sequence[str], noise: Mapping[str, float],
           decimate: int) -> np.ndarray:
    """Recorded signals of runs ``out`` (shape ``(n, n_out, len(OUTPUTS))``) as one whitened
    vector per run: each signal after its first sample, every ``decimate``-th sample, divided
    by its noise std."""
    parts = [out[:, 1::decimate, OUTPUTS.index(s)] / noise[s] for s in signals]
    return np.concatenate(parts, axis=1)


def _orth(columns: list[np.ndarray]) -> np.ndarray | None:
    if not columns:
        return None
    u, sv, _ = np.linalg.svd(np.stack(columns, axis=1), full_matrices=False)
    keep = sv > 1e-9 * max(float(sv[0]), 1e-300)
    return u[:, keep] if np.any(keep) else None


def integrated_time(r: np.ndarray) -> float:
    """Integrated autocorrelation time of ``r`` [samples]: ``1 + 2 sum rho_k`` up to the first
    negative autocorrelation (at least 1, at most a tenth of the samples)."""
    r = r - r.mean()
    var = float(np.dot(r, r))
    if not var > 0:
        return 1.0
    n = r.size
    f = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[: n // 10] / var
    negative = np.flatnonzero(acf[1:] < 0)
    stop = int(negative[0]) + 1 if negative.size else acf.size
    return float(max(1.0, 1.0 + 2.0 * np.sum(acf[1:stop])))


def _model_form_variance(model_form: np.ndarray, basis: np.ndarray | None) -> float:
    """What the check's LF model-form error (healthy HF minus LF, whitened) adds to the
    variance along any signature: its mean square per sample times its integrated
    autocorrelation time, once the fitted parameters took what they can. Why this form: the
    bank weighs a hypothesis by BIC on ``n / tau`` effective samples of the residual, so a
    fault's gain must stand out against ``tau * (1 + q)`` instead of the white noise's 1 (q the
    model-form error's mean square per sample in noise units)."""
    r = model_form if basis is None else model_form - basis @ (basis.T @ model_form)
    return float(np.mean(r ** 2)) * integrated_time(r)


def predict(command: Command, targets: Sequence[Target], t_end: float,
            signals: Sequence[str] = ("xu",), noise: Mapping[str, float] | None = None,
            alpha: float = 0.01, n_actuators: int = 3, decimate: int = 1,
            pairs: Sequence[tuple[str, str]] | None = None,
            lf_base: Mapping[str, float] | None = None,
            setting: Mapping[str, float] | None = None) -> Prediction:
    """Predicted minimum detectable sizes and separable sizes of ``targets`` on ``command``.

    Parameters
    ----------
    t_end : float
        Record length [s].
    signals : sequence of str
        Recorded signals (:data:`eha.design.targets.SIGNALS`).
    noise : mapping, optional
        White-noise std of each signal (default :data:`SIGNALS`' defaults) [signal unit].
    alpha : float
        False-alarm probability of one check, split over the faults it tests (union bound).
    n_actuators : int
        The nominal actuator and ``n_actuators - 1`` scattered ones; the worst counts.
    decimate : int
        Keep every ``decimate``-th sample of the 1 kHz record (the recorded sampling).
    pairs : sequence of (str, str), optional
        Which separable sizes to compute (default every ordered pair of targets).
    lf_base : mapping, optional
        The check's LF model (default the calibrated LF): its model-form error on the command
        (HF minus LF, healthy) counts as one more departure along each signature, so a command
        the LF cannot follow (the rate or the spool saturated) predicts no better than it
        checks.
    setting : mapping, optional
        Parameters of the test set-up on every actuator and in the check's LF model, e.g. a
        test load ``{"FRC": 2000.0}`` [N].
    """
    noise = {s: SIGNALS[s][1] for s in signals} | dict(noise or {})
    setting = dict(setting or {})
    acts = [{**a, **setting} for a in actuators(n_actuators)]
    plan = [(k, r) for k, a in enumerate(acts) for r in _hf_runs(targets, a, DESIGN_SEED0 + k)]
    out = simulate_hf_batch([r[3] for _, r in plan], command, t_end, [r[4] for _, r in plan])
    y = whiten(out, signals, noise, decimate)
    y_lf, lf = _lf_columns(command, targets, t_end,
                           {**(CALIBRATED_LF if lf_base is None else lf_base), **setting},
                           signals, noise, decimate)
    xu = out[:, 1::decimate, OUTPUTS.index("xu")]
    if pairs is None:
        pairs = [(f.name, g.name) for f in targets for g in targets if f.name != g.name]
    found = Prediction({t.name: 0.0 for t in targets}, {t.name: 0.0 for t in targets},
                       {f: {} for f, _ in pairs}, {t.name: 0.0 for t in targets},
                       {t.name: t.probe for t in targets})
    for k in range(len(acts)):
        rows = [(i, r) for i, (kk, r) in enumerate(plan) if kk == k]
        i0 = rows[0][0]
        truth = {r[1]: (y[i] - y[i0]) / r[2] for i, r in rows if r[0] == "target"}
        spread = np.stack([y[i] - y[i0] for i, r in rows if r[0] == "scatter"] +
                          # two draws of one random departure: their mean square
                          [(y[i] - y[i0]) / 2.0 for i, r in rows if r[0] == "dither"], axis=1)
        for i, r in rows:
            if r[0] == "target":
                foot = float(np.sqrt(np.mean((xu[i] - xu[i0]) ** 2)))
                found.footprint[r[1]] = max(found.footprint[r[1]], foot)
        _actuator(found, targets, pairs, truth, lf, spread, y[i0] - y_lf, alpha)
    found.separable_at = {f: dict(row) for f, row in found.separable.items()}
    found.separable = {f: {g: (v / found.mds[f] if 0 < found.mds[f] < math.inf else math.inf)
                           for g, v in row.items()} for f, row in found.separable.items()}
    return found


def _actuator(found: Prediction, targets: Sequence[Target], pairs, truth: Mapping,
              lf: Mapping, spread: np.ndarray, model_form: np.ndarray, alpha: float) -> None:
    """Fold one actuator's detectable and separable sizes into ``found`` (the worst)."""
    z = NormalDist().inv_cdf
    m = {"fault": len(FAULTS), "effect": max(1, len(targets))}
    core = _orth([lf[p] for p in core_faults() if p in lf])
    left = model_form if core is None else model_form - core @ (core.T @ model_form)
    found.model_form = max(found.model_form, float(np.sqrt(np.mean(left ** 2))))
    by_name = {t.name: t for t in targets}
    for t in targets:
        hyp = _best_fitting(_hypotheses(t), lf, spread)
        basis = _orth([lf[p] for p in hyp])
        size, sd = _detectable(lf[t.param], truth[t.name], basis, spread,
                               _model_form_variance(model_form, basis), _floor(t),
                               z(1.0 - alpha / m[t.kind]), z(P_DETECT))
        found.mds[t.name] = max(found.mds[t.name], size)
        found.sigma[t.name] = max(found.sigma[t.name], sd)
    c = z(1.0 - alpha / m["fault"]) + z(P_DETECT)
    for f, g in pairs:
        tf, tg = by_name[f], by_name[g]
        nuis = [lf[p] for p in nuisance_params(tf.kind) if p not in (tf.param, tg.param)]
        size = _separable(truth[f], _orth(nuis + [lf[tf.param]]), _orth(nuis + [lf[tg.param]]),
                          spread, model_form, c)
        found.separable[f][g] = max(found.separable[f].get(g, 0.0), size)


def _floor(target: Target) -> float:
    """The check's own model-form floor on the target's std at its probe (the calibrated
    LF's :data:`eha.identification.intervals.MODEL_FORM` for a fault, the loop's relative
    floor for an effect): every healthy check's interval carries it, and the thresholds
    add it to the fleet's spread."""
    value = abs(target.healthy + target.probe)
    if target.kind == "fault":
        form = MODEL_FORM.get("calibrated", {}).get(target.param)
        return 0.0 if form is None else math.hypot(form.rel * value, form.abs)
    return LOOP_MODEL_FORM.rel * value


def _detectable(column: np.ndarray, truth: np.ndarray, basis, spread, mf_var: float,
                floor: float, z_alarm: float, z_detect: float) -> tuple[float, float]:
    """``(size, sigma)`` of one target: the check fits the LF ``column`` beside ``basis``; a
    healthy actuator's estimate scatters by ``sigma`` (noise, scatter, dither, model form),
    the threshold is ``z_alarm * sqrt(sigma^2 + floor^2)``, and a true deviation ``a`` (the
    HF ``truth`` per unit) moves the estimate by ``gain * a``."""
    v = column if basis is None else column - basis @ (basis.T @ column)
    norm = float(np.linalg.norm(v))
    if not norm > 0:
        return math.inf, math.inf
    u = v / norm
    sigma = math.sqrt(1.0 + mf_var + float(np.sum((u @ spread) ** 2))) / norm
    gain = float(u @ truth) / norm
    if not gain > 0:
        return math.inf, sigma
    return (z_alarm * math.hypot(sigma, floor) + z_detect * sigma) / gain, sigma


def _separable(truth: np.ndarray, own, rival, spread, model_form, c: float) -> float:
    """Size of a true deviation (HF ``truth`` per unit) at which the rival hypothesis' best
    refit (``rival`` basis) leaves more residual than its own hypothesis (``own``) by ``c``
    healthy stds along that residual (inf: the rival fits it as well)."""
    def rest(basis, x):
        return x if basis is None else x - basis @ (basis.T @ x)

    r_rival, r_own = rest(rival, truth), rest(own, truth)
    excess = float(r_rival @ r_rival - r_own @ r_own)
    if not excess > 0:
        return math.inf
    u = r_rival / float(np.linalg.norm(r_rival))
    var = 1.0 + _model_form_variance(model_form, rival) + float(np.sum((u @ spread) ** 2))
    return c * math.sqrt(var) / math.sqrt(excess)


__all__ = ["Prediction", "predict", "scatter_columns", "actuators", "whiten", "P_DETECT"]
