"""The change check's calibration: thresholds from simulated healthy pairs, the HF gain of
each fault's estimate, and the judgement of one record difference.

A healthy pair is one actuator of the healthy fleet (manufacturing scatter,
:func:`eha.identification.healthy.draw_actuator`) recorded twice on the same command: the
earlier record with its own noise and dither, the later one on another test day (the
nuisances of :mod:`eha.health.change`, drawn uniformly within their half-widths) with other
noise and dither. Per fault the threshold is the normal tolerance bound of probability
``alpha / m`` with confidence :data:`TOLERANCE_CONFIDENCE` (the mean and std estimated from
the pairs; two-sided for the offset): the probability that a healthy pair raises any alarm is at most
``alpha`` (union bound). The std is split into a white-noise part, scaled at a check by the
two records' own noise (:func:`eha.identification.measured.noise_level`), and the rest
(nuisances, dither), kept: a noisier record gets a wider threshold instead of false alarms.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from eha.health.change import (NUISANCES, GainCurve, Signatures, check_nuisances,
                               draw_test_day, probe)
from eha.health.change_runs import (GAIN_ACTUATORS, LATER_SEED_SHIFT, _faulted, _gains,
                                    _positions, _record, later_seed, sign_of)
from eha.identification.healthy import DetectionError, built_calibration, draw_actuator
from eha.models.faults import FAULTS

#: Version of the change calibration's file format.
CHANGE_FORMAT = 1
#: Fewest healthy pairs a calibration is made from.
MIN_PAIRS = 5
#: Most healthy pairs of a calibration.
MAX_PAIRS = 10000
#: Healthy pairs simulated in one batch of parallel HF runs (progress is said after each).
PAIRS_A_BATCH = 32

@dataclass(frozen=True)
class ChangeCalibration:
    """Thresholds of the change check for one command, record length and model version."""

    command: str
    command_sig: str
    t_end: float
    model_version: str
    alpha: float
    level: float
    noise: float
    nuisances: dict[str, float]
    pairs: int
    seed: int
    #: per fault: mean, std, noise_var (the noise part of the variance at the calibration's
    #: noise), other_var, noise_factor, threshold (the margin over the mean at the
    #: calibration's noise), two_sided, n
    faults: dict[str, dict[str, Any]]
    #: per fault: :class:`eha.health.change.GainCurve` as a dict
    gains: dict[str, dict[str, list]]
    #: per fault: the earlier records against the nominal LF (mean, std, threshold): is a
    #: baseline itself unlike the healthy fleet?
    screen: dict[str, dict[str, float]]
    #: the model the signatures come from (``hf`` or ``lf``)
    signatures: str = "hf"
    #: the healthy pairs' variance over the model's (median over the faults): what the
    #: model's Gaussian noise leaves out (the dither), for the isolation's likelihood ratios
    excess: float = 1.0
    false_alarms: dict[str, Any] = field(default_factory=dict)
    created_at: str = ""
    format: int = CHANGE_FORMAT
    reference: str = "baseline"
    #: the fault levels the healthy pairs and the signatures are at [fault units] (empty:
    #: healthy; :func:`check_operating_point`)
    operating_point: dict[str, float] = field(default_factory=dict)
    #: per fault ``f`` and other fault ``g``: ``g``'s change estimated beside a free change of
    #: ``f`` on the healthy pairs (mean, std, other_var, noise_factor, tail, n, two_sided) and
    #: ``leak``: its mean and std when only ``f`` changed, by ``f``'s size (the two-fault
    #: reading's bias from ``f``'s nonlinear response; :func:`judge_second`)
    second: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)

    def save(self, path: str | Path) -> Path:
        from eha.outputs import write_json

        return write_json(Path(path), asdict(self), indent=2)

    def gain(self, name: str) -> GainCurve:
        g = self.gains[name]
        return GainCurve(tuple(g["sizes"]), tuple(g["gains"]), tuple(g["spread"]))


def load_change_calibration(path: str | Path) -> ChangeCalibration:
    """Read a change calibration; one-line :class:`DetectionError` on any problem (a fleet
    calibration given to the change check says so)."""
    path = Path(path)
    if path.is_dir():
        raise DetectionError(f"`calibration` {path}: a folder, not a calibration file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DetectionError(f"`calibration` {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise DetectionError(f"`calibration` {path}: not a calibration file "
                             f"({type(exc).__name__})") from None
    if isinstance(data, dict) and data.get("reference", "fleet") == "fleet" and \
            "thresholds" in data:
        raise DetectionError(f"`calibration` {path}: a fleet calibration; the check against a "
                             "baseline record needs one made with eha health calibrate "
                             "--baseline")
    required = {"format", "model_version", "command", "command_sig", "t_end", "faults",
                "gains", "screen"}
    if not isinstance(data, dict) or data.get("format") != CHANGE_FORMAT or \
            data.get("reference") != "baseline" or not required <= set(data):
        raise DetectionError(f"`calibration` {path}: not a change calibration of format "
                             f"{CHANGE_FORMAT} (make one with eha health calibrate --baseline)")
    return built_calibration(ChangeCalibration, data, path,
                             "eha health calibrate --baseline")


# --------------------------------------------------------------------------------------------
# judging one difference


#: Confidence of the thresholds' tolerance bound: with this probability over the draw of
#: the calibration's healthy pairs, a healthy pair alarms in a fault with probability at most
#: its share of alpha (a prediction bound holds the rate only on average over calibrations:
#: measured 3 of 200 held-out pairs at alpha 0.01 on chirp_1cm and mixed, docs/health.md).
TOLERANCE_CONFIDENCE = 0.9


def tolerance_factor(n: int, p: float, confidence: float = TOLERANCE_CONFIDENCE) -> float:
    """``k`` of the one-sided normal tolerance bound ``mean + k * std`` from ``n`` samples
    that a new value exceeds with probability at most ``p``, with ``confidence``
    (the noncentral t: ``k = t'_confidence(n - 1, z_(1-p) sqrt(n)) / sqrt(n)``)."""
    from scipy.stats import nct, norm

    return float(nct.ppf(confidence, n - 1, norm.ppf(1.0 - p) * math.sqrt(n)) / math.sqrt(n))


def tail_factor(values: np.ndarray, p: float) -> float:
    """How much heavier than normal the healthy pairs' tail is at probability ``p``: the
    Cornish-Fisher quantile over the normal one, from the sample skewness and excess kurtosis
    each shrunk by one standard error towards 0 (the evidence beyond a normal sample's own
    scatter), never below 1. Why: on commands with steps (``test``) the jack friction's
    estimate has excess kurtosis 2.9 and skewness 0.9 over 400 healthy pairs, and a normal
    bound let 11 of 200 held-out pairs alarm at alpha 0.01 (docs/health.md)."""
    from scipy.stats import kurtosis, norm, skew

    n = values.size
    if n < 8:
        return 1.0
    g1, g2 = float(skew(values)), float(kurtosis(values))
    s1 = math.copysign(max(abs(g1) - math.sqrt(6.0 / n), 0.0), g1)
    s2 = max(g2 - math.sqrt(24.0 / n), 0.0)
    z = float(norm.ppf(1.0 - p))
    cf = (z + (z * z - 1) * s1 / 6 + (z ** 3 - 3 * z) * s2 / 24
          - (2 * z ** 3 - 5 * z) * s1 * s1 / 36)
    return max(cf / z, 1.0)


def judge(cal: ChangeCalibration, sig: Signatures, r: np.ndarray, noise2: float,
          level: float | None = None) -> dict[str, dict[str, Any]]:
    """:func:`judge_estimates` of the record difference ``r`` [m] (its linear estimates,
    :meth:`Signatures.estimate`)."""
    out = judge_estimates(cal, sig.faults, sig.estimate(r), noise2, level, sig.blind)
    # the generalized likelihood ratio of each fault alone (the model's variance at the
    # record's noise, widened by the pairs' measured excess over the model: the dither)
    for i, name in enumerate(sig.faults):
        if name in out:
            # the faults whose signatures differ less than the two models disagree on either
            out[name]["alike"] = [g for j, g in enumerate(sig.faults) if j != i and
                                  sig.separation[i, j] <= max(sig.shape_doubt[i],
                                                              sig.shape_doubt[j])]
            d = out[name]["statistic"]
            out[name]["glr"] = float(d * d * sig.info[i] * sig.noise2
                                     / max(noise2, 1e-30) / cal.excess)
    return out


def judge_estimates(cal: ChangeCalibration, names: Sequence[str], est: np.ndarray,
                    noise2: float, level: float | None = None, blind: Sequence[str] = ()
                    ) -> dict[str, dict[str, Any]]:
    """Each fault's change, interval, statistic, threshold and alarm from the linear
    estimates ``est`` of a record difference whose two records' noise variances sum to
    ``noise2`` [m^2].

    The statistic of fault ``f`` is its linear estimate in the direction of degradation, less
    the healthy pairs' mean; its threshold the calibration's tolerance bound with the white
    noise part of the std at ``noise2``. The change is the estimate read back through the
    fault's HF gain curve; its interval at ``level`` (default the calibration's) the
    estimate's spread (Student's t) mapped the same way, widened by the gain's spread over
    actuators.
    """
    level = cal.level if level is None else float(level)
    out = {}
    m = len(cal.faults)
    for i, name in enumerate(names):
        f = cal.faults.get(name)
        if f is None:
            continue
        n = int(f["n"])
        sd = math.sqrt(max(f["other_var"] + f["noise_factor"] * noise2, 1e-300))
        scale = sd * math.sqrt(1.0 + 1.0 / n)
        two = bool(f["two_sided"])
        s = sign_of(name)
        d = s * float(est[i]) - f["mean"]                 # the change in the estimate's units
        stat = abs(d) if two else d
        margin = tolerance_factor(n, cal.alpha / m / (2.0 if two else 1.0)) * sd * \
            f.get("tail", 1.0)
        curve = cal.gain(name)
        change, lo, hi, open_end = change_interval(curve, s, d, scale, n, level)
        out[name] = {"change": change, "interval": [lo, hi], "open_ended": open_end,
                     "statistic": stat, "threshold": margin, "z": stat / scale,
                     "degraded": bool(stat > margin), "alarm_change": curve.invert(s * margin, s),
                     "blind": name in blind}
    return out


def change_interval(curve: GainCurve, sign: float, d: float, scale: float, n: int,
                    level: float, relative: float = 0.0) -> tuple[float, float, float, bool]:
    """A fault's change and its interval at ``level`` from its linear statistic ``d`` (the
    estimate in the direction of degradation, less the healthy pairs' mean) whose spread over
    healthy pairs is ``scale`` (``n`` pairs: Student's t with n - 1 degrees of freedom): both
    ends read back through the fault's HF gain curve, widened by the gain's spread over
    actuators and by a further ``relative`` error of the change (added in quadrature: a
    reading beside another grown fault, :func:`eha.health.change_runs._interactions`).
    Returns ``(change, low, high, open_ended)``; beyond the response's growing range the
    interval is open on its far side."""
    from scipy.stats import t as student

    change = curve.invert(sign * d, sign)
    qi = float(student.ppf(0.5 + level / 2.0, n - 1))
    lo_e, hi_e = sign * (d - qi * scale), sign * (d + qi * scale)
    lo, hi = sorted((curve.invert(lo_e, sign), curve.invert(hi_e, sign)))
    extra = qi * math.hypot(curve.relative_spread(change), relative) * abs(change)
    lo, hi = lo - extra, hi + extra
    open_end = curve.beyond(hi_e if sign > 0 else lo_e, sign)
    if open_end:
        lo, hi = (lo, math.inf) if sign > 0 else (-math.inf, hi)
    return change, lo, hi, open_end


#: How much smaller (in the log-likelihood ratio, 2 ln LR) a fault's fit of the difference may
#: be than the best one's and still be kept among the faults the change is isolated to: the
#: 95 % point of chi-square with one degree of freedom (the records cannot tell them apart).
AMBIGUITY_MARGIN = 3.84


def isolate_group(judged: Mapping[str, Mapping[str, Any]],
                  margin: float = AMBIGUITY_MARGIN) -> list[str]:
    """The faults a degraded difference is isolated to, best first: the alarming fault with
    the largest generalized likelihood ratio (``glr``), the alarming faults within ``margin``
    of it, and those whose signatures differ from its less than the HF and LF models of one
    actuator disagree on either's shape (``alike``: a separation finer than the models' own
    is not evidence); ``[]`` when nothing alarms. More than one: faults the records do not
    tell apart (on ``chirp_1cm`` the jack friction and the leakage, the clogging and the
    spool friction)."""
    alarmed = sorted(((v.get("glr", v["z"] ** 2), n) for n, v in judged.items()
                      if v["degraded"]), reverse=True)
    if not alarmed:
        return []
    best, first = alarmed[0]
    alike = judged[first].get("alike", ())
    return [n for g, n in alarmed if g >= best - margin or n in alike]


def isolate(judged: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The fault a degraded difference is isolated to: among the alarming faults, the one
    whose statistic is the most standard deviations beyond its healthy mean (the generalized
    likelihood ratio of one fault under the check's Gaussian model); ``[]`` when nothing
    alarms."""
    alarmed = [(v["z"], n) for n, v in judged.items() if v["degraded"]]
    return [max(alarmed)[1]] if alarmed else []


# --------------------------------------------------------------------------------------------
# calibration


def _prediction_bound(values: np.ndarray, alpha: float, two: bool) -> float:
    """The margin over the mean of :func:`tolerance_factor`'s bound from ``values``, widened
    by their :func:`tail_factor` (of ``|values - mean|``'s sign-free tail for two-sided)."""
    n = values.size
    p = alpha / (2.0 if two else 1.0)
    return tolerance_factor(n, p) * float(values.std(ddof=1)) * _tail(values, p, two)


def _tail(values: np.ndarray, p: float, two: bool) -> float:
    if two:   # both tails: the heavier one
        return max(tail_factor(values, p), tail_factor(-values, p))
    return tail_factor(values, p)


def check_operating_point(at: Mapping[str, float] | None) -> dict[str, float]:
    """Fault levels of an operating point, each a known fault within its parameter's range.

    Raises
    ------
    DetectionError
        An unknown fault or a value outside its range, one line naming it.
    """
    from eha.models.params import SPECS

    out = {}
    for name, value in (at or {}).items():
        if name not in FAULTS:
            raise DetectionError(f"`at` {name}: unknown fault; allowed {', '.join(FAULTS)}")
        spec = SPECS[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value) or not spec.lo <= value <= spec.hi:
            raise DetectionError(f"`at` {name}={value!r}: allowed range [{spec.lo:g}, "
                                 f"{spec.hi:g}] {spec.unit}".rstrip())
        out[name] = float(value)
    return out


def _check_settings(actuators, alpha, level, noise, t_end) -> None:
    """One line per setting outside its range (:class:`DetectionError`)."""
    problems = []
    if isinstance(actuators, bool) or not isinstance(actuators, int) or \
            not MIN_PAIRS <= actuators <= MAX_PAIRS:
        problems.append(f"`actuators` {actuators!r}: allowed range [{MIN_PAIRS}, {MAX_PAIRS}] "
                        "(healthy pairs)")
    if not 0 < alpha < 1:
        problems.append(f"`alpha` {alpha!r}: allowed range (0, 1)")
    if not 0 < level < 1:
        problems.append(f"`level` {level!r}: allowed range (0, 1)")
    if not (isinstance(noise, (int, float)) and 0 < noise <= 1e-3):
        problems.append(f"`noise` {noise!r}: allowed range (0, 0.001] m")
    if not 0.2 <= t_end <= 10:
        problems.append(f"`t_end` {t_end!r}: allowed range [0.2, 10] s")
    if problems:
        raise DetectionError(problems)


def calibrate_change(command: str = "chirp_1cm", actuators: int = 30, seed: int = 0,
                     t_end: float = 1.0, noise: float = 1e-6, alpha: float = 0.01,
                     level: float = 0.9, nuisances: Mapping[str, float] | None = None,
                     model: str = "hf", gains: bool = True,
                     on_progress: Callable[[str], None] | None = None,
                     at: Mapping[str, float] | None = None
                     ) -> tuple[ChangeCalibration, dict[str, Any]]:
    """Calibrate the change check on ``actuators`` simulated healthy pairs.

    ``at``: the operating point, fault levels the baseline already has (e.g. its fleet
    identification): every pair's actuator carries them and the signatures are taken there
    (a fault's signature at a degraded point can be nearly orthogonal to the healthy one's,
    :class:`eha.health.change.Signatures`). ``gains=False`` skips the HF gain curves (every gain 1: a design's search, which ranks
    commands and needs no sizes read back). Returns the calibration and the pairs' figures (``estimates``: one row per pair, the
    faults' linear estimates; ``screen``: the earlier records against the nominal LF).

    Raises
    ------
    DetectionError
        A setting outside its range (one line naming it).
    """
    from eha.identification.healthy import command_signature
    from eha.identification.measured import noise_level
    from eha.models.commands import CommandError, as_command
    from eha.models.simulate import MODEL_VERSION

    _check_settings(actuators, alpha, level, noise, t_end)
    widths = check_nuisances(nuisances)
    at = check_operating_point(at)
    try:
        cmd = as_command(command)
    except (CommandError, ValueError) as exc:
        raise DetectionError(f"`command`: {exc}") from None
    first = _record(cmd, {**draw_actuator(seed), **at}, t_end, noise, seed)
    pairs = []
    for k0 in range(0, actuators, PAIRS_A_BATCH):
        runs = []
        for s in range(seed + k0, seed + min(k0 + PAIRS_A_BATCH, actuators)):
            hf = {**draw_actuator(s), **at}
            runs += [(hf, s), (draw_test_day(hf, widths, s), later_seed(s))]
        xs = _positions(cmd, runs, t_end, noise)
        pairs += list(zip(xs[0::2], xs[1::2]))
        if on_progress:
            on_progress(f"{len(pairs)} of {actuators} healthy pairs")
    # the records' own command, as a reader of them rebuilds it (the check does the same)
    sig = Signatures(first.command, t_end, noise, widths, model=model, shapes=gains, at=at)
    names = sig.faults
    est = [sig.estimate(b - a) for a, b in pairs]
    screen = [sig.estimate(a - sig.y0) for a, _ in pairs]
    noise2 = [noise_level(a) ** 2 + noise_level(b) ** 2 for a, b in pairs]
    est, screen, noise2 = np.array(est), np.array(screen), np.array(noise2)
    faults, screened = {}, {}
    m = len(names)
    for i, name in enumerate(names):
        s = sign_of(name)
        d = s * est[:, i]
        two = FAULTS[name].direction == 0
        var = float(d.var(ddof=1))
        noise_var = float(sig.noise_factor[i] * noise2.mean())
        faults[name] = {"mean": float(d.mean()), "std": math.sqrt(var),
                        "noise_var": noise_var, "other_var": max(var - noise_var, 0.0),
                        "noise_factor": float(sig.noise_factor[i]),
                        "threshold": _prediction_bound(d, alpha / m, two),
                        "tail": _tail(d, alpha / m / (2.0 if two else 1.0), two),
                        "two_sided": two, "n": int(d.size)}
        sd = s * screen[:, i]
        screened[name] = {"mean": float(sd.mean()), "std": float(sd.std(ddof=1)),
                          "threshold": _prediction_bound(sd, alpha / m, two), "two_sided": two}
    second = _second_pairs(sig, np.array([b - a for a, b in pairs]), noise2, alpha)
    if on_progress:
        on_progress("the HF gain of each fault")
    # without ``gains`` (a design's search) every estimate reads at the LF slope
    if gains:
        gains, leaks = _gains(cmd, sig, widths, actuators, seed, t_end, noise, at)
        for f, per in leaks.items():
            for g, leak in per.items():
                if g in second.get(f, {}):
                    second[f][g].update(leak)
    else:
        gains = {n: {"sizes": [probe(n)], "gains": [1.0], "spread": [0.0]} for n in names}
        second = {}         # without the leaks, no second fault is judged
    cal = ChangeCalibration(
        command=str(command), command_sig=command_signature(first.com), t_end=float(t_end),
        model_version=MODEL_VERSION, alpha=float(alpha), level=float(level),
        noise=float(noise), nuisances=widths, pairs=int(actuators), seed=int(seed),
        faults=faults, gains=gains, screen=screened, signatures=model,
        operating_point=at, second=second, excess=float(max(np.median([faults[n]["std"] ** 2 * sig.info[i]
                                    for i, n in enumerate(names) if sig.info[i] > 0]), 1.0)),
        created_at=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    alarms = [any(v["degraded"] for v in judge_estimates(cal, names, e, n2).values())
              for e, n2 in zip(est, noise2)]
    cal = ChangeCalibration(**{**asdict(cal), "false_alarms": {
        "in_sample": int(sum(alarms)), "n": int(actuators),
        "loo": _leave_one_out(est, noise2, sig, cal)}})
    return cal, {"estimates": est, "screen": screen, "noise2": noise2, "names": names}


def _leave_one_out(est: np.ndarray, noise2: np.ndarray, sig: Signatures,
                   cal: ChangeCalibration) -> dict[str, Any]:
    """Each healthy pair judged against thresholds set without it: alarms out of sample."""
    names = sig.faults
    m, n = len(names), est.shape[0]
    alarms = 0
    for j in range(n):
        keep = np.arange(n) != j
        hit = False
        for i, name in enumerate(names):
            d = sign_of(name) * est[keep, i]
            two = cal.faults[name]["two_sided"]
            thr = _prediction_bound(d, cal.alpha / m, two)
            x = sign_of(name) * est[j, i] - d.mean()
            hit |= (abs(x) if two else x) > thr
        alarms += int(hit)
    return {"alarms": alarms, "n": n}


def _second_pairs(sig: Signatures, diffs: np.ndarray, noise2: np.ndarray, alpha: float
                  ) -> dict[str, dict[str, dict[str, Any]]]:
    """Per fault ``f`` and other fault ``g``, the healthy pairs' figures of ``g``'s change
    estimated beside a free change of ``f`` (:meth:`Signatures.conditional`)."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    for i, f in enumerate(sig.faults):
        cond = sig.conditional(i)
        est = diffs @ cond.T
        out[f] = {}
        for j, g in enumerate(sig.faults):
            factor = float(cond[j] @ cond[j])
            if j == i or factor <= 0:
                continue
            d = sign_of(g) * est[:, j]
            two = FAULTS[g].direction == 0
            var = float(d.var(ddof=1))
            out[f][g] = {"mean": float(d.mean()), "std": math.sqrt(var),
                         "other_var": max(var - factor * float(noise2.mean()), 0.0),
                         "noise_factor": factor, "two_sided": two, "n": int(d.size),
                         "tail": float(_tail(d, alpha / len(sig.faults) / (2.0 if two else 1.0),
                                             two))}
    return out


__all__ = ["CHANGE_FORMAT", "ChangeCalibration", "load_change_calibration", "calibrate_change",
           "judge", "judge_estimates", "change_interval", "check_operating_point", "isolate", "isolate_group", "tail_factor",
           "tolerance_factor",
           "AMBIGUITY_MARGIN", "later_seed", "sign_of", "MIN_PAIRS", "NUISANCES"]
