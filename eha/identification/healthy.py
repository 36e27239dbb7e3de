"""The healthy reference: what a healthy actuator and a healthy statistic look like.

Shared by detection (:mod:`eha.health.detection`: fleets, thresholds, calibrations) and the
residual loop's null (:mod:`eha.explain.null`), so that the loop does not import the health
layer above it: the manufacturing dispersion of a healthy actuator (:func:`draw_actuator`),
the threshold a healthy statistic exceeds with a given probability (:func:`tail_threshold`)
and the signature of a command (:func:`command_signature`).
"""

from __future__ import annotations

import hashlib
import math
from statistics import NormalDist
from typing import Any, Mapping, Sequence

import numpy as np

from eha.errors import InputError
from eha.models.faults import Derived, dispersion as _dispersion
from eha.models.params import SPECS

#: Manufacturing dispersion of a healthy actuator: name -> (law, a, b), in draw order; declared
#: with each fault (:attr:`eha.models.faults.Fault.scatter`) and in
#: :data:`eha.models.faults.OTHER_SCATTER` for the other parameters.
#: ``uniform_rel``: nominal x U(1 - a, 1 + a); ``normal``: N(a, b) (clipped at 10 %);
#: ``loguniform``: exp(U(ln a, ln b)).
DISPERSION: Mapping[str, tuple[str, float, float]] = Derived(_dispersion, "DISPERSION")


class DetectionError(InputError):
    """Bad input of detection (calibration file, fleet section, thresholds); one-line
    message."""


def draw_actuator(seed: int, dispersion: Mapping[str, tuple[str, float, float]] = DISPERSION
                  ) -> dict[str, float]:
    """HF parameters of one healthy actuator (reproducible from ``seed``)."""
    rng = np.random.default_rng([7919, seed])
    out = {}
    for name, (law, a, b) in dispersion.items():
        nominal = SPECS[name].nominal
        if law == "uniform_rel":
            out[name] = nominal * float(rng.uniform(1.0 - a, 1.0 + a))
        elif law == "normal":
            out[name] = float(max(0.1 * a, rng.normal(a, b)))
        elif law == "loguniform":
            out[name] = float(math.exp(rng.uniform(math.log(a), math.log(b))))
        else:
            raise DetectionError(f"dispersion {name}: unknown law {law!r}")
    return out


def command_signature(com: np.ndarray) -> str:
    """Hash of a command sampled at 1 kHz (rounded to 0.1 µm): which command a calibration
    belongs to."""
    q = np.round(np.asarray(com, dtype=np.float64) / 1e-7).astype(np.int64)
    return hashlib.sha256(q.tobytes()).hexdigest()[:16]


def built_calibration(cls, data: Mapping[str, Any], path, remake: str):
    """``cls(**data)`` of a calibration file's content, refused in one line when made for
    another model version (``remake``: the command that makes one again) or with unexpected
    keys (shared by the fleet and the change check's calibrations)."""
    from eha.models.simulate import MODEL_VERSION

    if data.get("model_version") != MODEL_VERSION:
        raise DetectionError(f"`calibration` {path}: made for model version "
                             f"{data.get('model_version')!r}, this is {MODEL_VERSION!r}; "
                             f"calibrate again ({remake})")
    try:
        return cls(**data)
    except TypeError as exc:
        raise DetectionError(f"`calibration` {path}: unexpected content ({exc})") from None


def upper_bound(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided Clopper-Pearson upper bound of a rate from ``k`` events in ``n`` trials (a
    false-alarm rate measured on held-out healthy records)."""
    from scipy.stats import beta

    return 1.0 if k >= n else float(beta.ppf(confidence, k + 1, n - k))


def tail_threshold(values: Sequence[float], alpha: float, spread: float = 0.0
                   ) -> tuple[float, dict[str, float]]:
    """The value a healthy statistic exceeds with probability ``alpha``: the one hypothesis
    test of ``eha health`` and of the residual loop (:mod:`eha.explain.null`).

    ``values`` are the statistic on healthy records. Its spread has two parts: the healthy
    records' dispersion, measured (``std``), and ``spread``, what one record's estimate
    scatters by that a small sample can under-sample (a check's measurement uncertainty, an
    optimizer's resolution). The threshold is ``mean + z·scale``, ``scale = sqrt(std² +
    spread²)``, with ``z`` the normal quantile of ``1 - alpha``: a normal tail, because the
    1e-3 quantiles it needs cannot be read from tens of records. Callers testing ``m``
    statistics at once pass ``alpha / m`` (union bound).

    Returns
    -------
    threshold : float
    summary : dict
        ``mean``, ``std``, ``spread``, ``scale``, ``n`` and ``max`` of the statistic.
    """
    if not 0 < alpha < 1:
        raise DetectionError(f"alpha={alpha!r}: allowed range (0, 1)")
    d = np.asarray(values, dtype=np.float64)
    d = d[np.isfinite(d)]
    if d.size < 2:
        raise DetectionError(f"{d.size} healthy values; a threshold needs at least 2")
    mean, std = float(d.mean()), float(d.std(ddof=1))
    scale = math.sqrt(std * std + spread * spread)
    z = NormalDist().inv_cdf(1.0 - alpha)
    return mean + z * scale, {"mean": mean, "std": std, "spread": float(spread),
                              "scale": scale, "n": int(d.size), "max": float(d.max())}
