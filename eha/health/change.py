"""The change check's estimator: a record judged against the same actuator's own earlier record.

Why
---
The fleet check (:mod:`eha.health.detection`) compares one record with a simulated healthy
fleet, so it cannot see a fault smaller than the fleet's manufacturing scatter plus the LF
model's model-form error (docs/design.md: backlash 5.7 µm, jack friction 96 N, motor gain
9.7e-4 N/mA on every command). Two records of one actuator on one command share its scatter
and the model-form error; what differs between them is the sensor noise, the servo valve's
dither, the test day (the nuisances, :data:`NUISANCES`) and a fault's growth.

The statistic (docs/health.md, "The change check")
-------------------------------------------------
``r = later - earlier`` (the recorded positions on the same 1 kHz grid) is modelled as

    r = sum_f S_f a_f + N n + e

with ``S_f`` the LF model's change of the position per unit of fault ``f`` (its signature, at
the calibrated LF base, a step :data:`PROBE` in the direction of degradation), ``N`` the
nuisances' signatures with random sizes ``n`` (uniform on their stated ranges: variances
``D``), ``e`` white noise of both records. Each fault's change is estimated on its own by
generalized least squares with ``Sigma = s^2 I + N D N^T``::

    a_f = S_f^T Sigma^-1 r / (S_f^T Sigma^-1 S_f)

the best linear unbiased estimate of a lone fault with the test-day differences as random
effects: a nuisance with a signature of its own is fitted out in proportion to how large it
can be, and one that looks like the fault (a flow-gain change like a motor-gain loss) widens
that fault's spread instead of raising false alarms. Its threshold comes from simulated
healthy pairs (:mod:`eha.health.change_calibration`); the change in fault units from the HF
gain measured there (:class:`GainCurve`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from eha.models.faults import FAULTS

#: Step of each fault's LF signature, in the direction of degradation [fault unit]: about the
#: change the check is built to see (a signature is a slope; the gain curve corrects the
#: response of larger changes, :class:`GainCurve`).
PROBE: dict[str, float] = {"BKL": 5e-6, "FDJ": 50.0, "GM": -5e-4, "Kintas": 0.1,
                           "Clk": 5e-13, "Ofs": 0.01, "FSS": 5.0}
#: Sizes, in multiples of :data:`PROBE`, at which a calibration measures the HF gain: a factor
#: sqrt(2) apart (a factor 2 left a clogging of 0.58 read as 0.49 on ``chirp_1cm``, between
#: knots where the response grows 5-fold, and its interval missed it in 9 of 9).
GAIN_SIZES = (0.25, 0.35, 0.5, 0.71, 1.0, 1.41, 2.0, 2.83, 4.0, 5.66, 8.0, 11.3, 16.0)


@dataclass(frozen=True)
class Nuisance:
    """One difference between two test days that is not a fault.

    Attributes
    ----------
    name : str
        The model parameter that carries it (``eha params``).
    law : str
        ``"rel"``: the later record's value is the earlier one's times U(1 - w, 1 + w);
        ``"abs"``: plus U(-w, w) [parameter unit].
    width : float
        The default half-width ``w``.
    why : str
        What makes it differ between two test days.
    """

    name: str
    law: str
    width: float
    why: str


#: The test-day differences a healthy pair's two records carry by default (issue 60: each
#: settable, ``eha health calibrate --baseline --nuisance NAME=WIDTH``).
NUISANCES: dict[str, Nuisance] = {n.name: n for n in (
    Nuisance("CJ", "rel", 0.05, "viscous friction: oil temperature"),
    Nuisance("FDJ", "rel", 0.05, "jack (seal) friction: oil temperature"),
    Nuisance("GQ", "rel", 0.01, "valve flow gain: oil density and viscosity"),
    Nuisance("PSR", "rel", 0.02, "supply pressure"),
    Nuisance("Ofs", "abs", 0.002, "valve null drift [mA]"),
)}
#: Largest half-width accepted for each law (a relative one of 50 % is no longer the same
#: actuator; an absolute one in the parameter's unit: the offset's allowed range).
MAX_WIDTH = {"rel": 0.5, "abs": 1.0}


def check_nuisances(widths: Mapping[str, float] | None) -> dict[str, float]:
    """The half-widths of every nuisance: the defaults with ``widths`` over them.

    Raises
    ------
    eha.identification.healthy.DetectionError
        An unknown nuisance or a width outside its range, one line naming it.
    """
    from eha.identification.healthy import DetectionError

    out = {n: v.width for n, v in NUISANCES.items()}
    for name, w in (widths or {}).items():
        if name not in NUISANCES:
            raise DetectionError(f"`nuisance` {name}: unknown; allowed "
                                 f"{', '.join(NUISANCES)}")
        hi = MAX_WIDTH[NUISANCES[name].law]
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not math.isfinite(w) \
                or not 0 <= w <= hi:
            unit = "relative" if NUISANCES[name].law == "rel" else "mA"
            raise DetectionError(f"`nuisance` {name}={w!r}: allowed range [0, {hi:g}] "
                                 f"({unit} half-width)")
        out[name] = float(w)
    return out


def draw_test_day(hf: Mapping[str, float], widths: Mapping[str, float], seed: int
                  ) -> dict[str, float]:
    """The actuator ``hf`` on another test day: each nuisance drawn uniformly within its
    half-width (reproducible from ``seed``)."""
    from eha.models.params import SPECS

    rng = np.random.default_rng([8191, int(seed)])
    out = dict(hf)
    for name, nz in NUISANCES.items():
        u = float(rng.uniform(-1.0, 1.0))        # drawn always: the streams stay aligned
        w = widths.get(name, 0.0)
        value = float(hf.get(name, SPECS[name].nominal))
        out[name] = value * (1.0 + w * u) if nz.law == "rel" else value + w * u
    return out


def _unit_rows(x: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(x, axis=1)
    return x / np.where(norm > 0, norm, 1.0)[:, None]


def probe(name: str) -> float:
    """The signature step of fault ``name`` (:data:`PROBE`; a fault registered later: a
    quarter of its first detection level's change, in its direction)."""
    if name in PROBE:
        return PROBE[name]
    f = FAULTS[name]
    if f.levels:
        return (f.levels[0] - f.healthy) / 4.0
    width = f.bounds[1] - f.bounds[0]
    return (1 if f.direction >= 0 else -1) * 0.01 * width


class Signatures:
    """The signatures of the faults and the nuisances on one command, and the generalized
    least-squares weights of each fault's change (see the module docstring).

    Parameters
    ----------
    command : Command or str
        The records' command (a record's own: :attr:`MeasuredData.command`).
    t_end : float
        Record length [s].
    noise : float
        Sensor-noise std of one record [m] the weights assume (the calibration's).
    widths : mapping
        Nuisance half-widths (:func:`check_nuisances`).
    faults : sequence of str
        The faults (default every one of :data:`eha.models.faults.FAULTS`).
    model : {"hf", "lf"}
        The model the signatures come from (HF: both runs with the same dither, so that it
        cancels; LF: the calibrated LF base).
    shapes : bool
        Also take the other model's signatures, for :attr:`shape_doubt` (the isolation);
        without, ``shape_doubt`` is 0.
    at : mapping, optional
        The operating point: fault levels of the baseline [fault units] (default healthy).
        A fault's signature depends on where the actuator already is: on ``chirp_1cm`` the
        backlash's at 20 µm of backlash, or at 500 N of jack friction, is nearly orthogonal
        (sin^2 0.86-0.89) to its signature at the healthy point.
    """

    def __init__(self, command, t_end: float, noise: float, widths: Mapping[str, float],
                 faults: Sequence[str] | None = None, model: str = "hf",
                 shapes: bool = True, at: Mapping[str, float] | None = None):
        from eha.identification.problem import BASE_MODELS
        from eha.models import OUTPUTS
        from eha.models.params import SPECS
        from eha.models.simulate import simulate_hf_batch, simulate_lf_rows

        self.faults = tuple(faults or FAULTS)
        self.model = model
        at = {k: float(v) for k, v in (at or {}).items()}
        base = {**(dict(BASE_MODELS["calibrated"]) if model == "lf" else {}), **at}
        steps = [(n, probe(n)) for n in self.faults]
        nz = []
        for name, spec in NUISANCES.items():
            nominal = float(base.get(name, SPECS[name].nominal))
            # a relative nuisance's step and spread on the nominal value (Ofs: absolute)
            unit = nominal if spec.law == "rel" else 1.0
            step = 0.01 * unit if spec.law == "rel" else 0.001
            var = (widths.get(name, 0.0) * unit) ** 2 / 3.0       # uniform on +-w
            if var > 0 and step != 0:
                nz.append((name, step, var))
        rows = [base] + [{**base, n: float(base.get(n, FAULTS[n].healthy)) + s}
                         for n, s in steps]
        rows += [{**base, n: float(base.get(n, SPECS[n].nominal)) + s} for n, s, _ in nz]
        if model == "lf":
            y = simulate_lf_rows(rows, command, t_end)[:, :, OUTPUTS.index("xu")]
        else:   # the HF model, every run with the same dither (its effect cancels)
            y = simulate_hf_batch(rows, command, t_end, [0] * len(rows))[:, :, OUTPUTS.index("xu")]
        y0 = y[0]
        self.S = np.stack([(y[1 + i] - y0) / s for i, (_, s) in enumerate(steps)])
        # the other model's signatures: how much two models of one actuator disagree on the
        # shape of each fault's response (the isolation cannot trust a finer separation;
        # without ``shapes``, a design's search, none)
        other = {**(dict(BASE_MODELS["calibrated"]) if model != "lf" else {}), **at}
        So = self.S
        if shapes:
            yo = simulate_lf_rows([other] + [{**other, n: float(other.get(n, FAULTS[n].healthy))
                                              + s} for n, s in steps], command, t_end
                                  )[:, :, OUTPUTS.index("xu")]
            So = np.stack([(yo[1 + i] - yo[0]) / s for i, (_, s) in enumerate(steps)])
        unit = _unit_rows(self.S)
        #: Per pair of faults, sin^2 of the angle between their signatures.
        self.separation = 1.0 - np.clip(unit @ unit.T, -1.0, 1.0) ** 2
        #: Per fault, sin^2 of the angle between its HF and LF signatures.
        self.shape_doubt = 1.0 - np.clip(np.einsum("ij,ij->i", unit, _unit_rows(So)),
                                         -1.0, 1.0) ** 2
        m = len(steps)
        self.nuisances = tuple(n for n, _, _ in nz)
        N = np.stack([(y[1 + m + j] - y0) / s for j, (_, s, _) in enumerate(nz)]) if nz \
            else np.zeros((0, y0.size))
        D = np.array([v for _, _, v in nz])
        self.y0 = y0
        s2 = 2.0 * max(float(noise), 1e-9) ** 2          # two records' noise
        # Sigma^-1 S_f by Woodbury: (S - N (s2 D^-1 + N N^T)^-1 N S) / s2
        if len(D):
            inner = np.linalg.inv(np.diag(s2 / D) + N @ N.T)
            sinv_s = (self.S - (self.S @ N.T) @ inner @ N) / s2
        else:
            sinv_s = self.S / s2
        info = np.einsum("ij,ij->i", self.S, sinv_s)         # S_f^T Sigma^-1 S_f
        self._sinv_s = sinv_s
        self._gram = self.S @ sinv_s.T                          # S_f^T Sigma^-1 S_g
        ok = info > 0
        self.W = np.where(ok[:, None], sinv_s / np.where(ok, info, 1.0)[:, None], 0.0)
        #: Per fault ``S_f^T Sigma^-1 S_f`` [1/fault unit^2]: the inverse variance of its
        #: estimate under the model (the generalized likelihood ratio of a change ``a`` is
        #: ``a^2 info``).
        self.info = np.where(ok, info, 0.0)
        self.noise2 = s2
        #: Per fault, the estimate's variance per unit of white-noise variance of r.
        self.noise_factor = np.einsum("ij,ij->i", self.W, self.W)
        #: Faults the command does not move at all (a zero signature): never detected.
        self.blind = tuple(n for n, good in zip(self.faults, ok) if not good)

    def conditional(self, first: int) -> np.ndarray:
        """Per fault ``g``, the weights of its change estimated jointly with fault ``first``
        (whose size is left free): ``g``'s change beside a change of ``first`` (row
        ``first`` is zero). The generalized least squares of the two-fault model."""
        G, X = self._gram, self._sinv_s
        out = np.zeros_like(X)
        gii = G[first, first]
        for g in range(len(self.faults)):
            det = gii * G[g, g] - G[first, g] ** 2
            if g != first and det > 1e-12 * max(gii * G[g, g], 1e-300):
                out[g] = (gii * X[g] - G[first, g] * X[first]) / det
        return out

    def conditional_info(self, first: int) -> np.ndarray:
        """Per fault ``g``, the inverse variance of its change estimated jointly with fault
        ``first`` (:meth:`conditional`) under the model [1/fault unit^2]: the two-fault
        generalized likelihood ratio of a change ``a`` of ``g`` is ``a^2`` times it."""
        G = self._gram
        gii = G[first, first]
        det = gii * np.diag(G) - G[first] ** 2
        out = np.where(det > 1e-12 * np.maximum(gii * np.diag(G), 1e-300), det, 0.0) / gii
        out[first] = 0.0
        return out

    def estimate(self, r: np.ndarray) -> np.ndarray:
        """Each fault's linear change estimate from a record difference ``r`` [m]
        (fault units at the probe's slope)."""
        r = np.asarray(r, dtype=np.float64)
        if r.size != self.W.shape[1]:
            raise ValueError(f"difference of {r.size} samples; the signatures have "
                             f"{self.W.shape[1]}")
        return self.W @ r


@dataclass(frozen=True)
class GainCurve:
    """How the linear estimate of a fault responds to the fault's true change in HF records:
    ``estimate = gain(size) * size``, measured at ``sizes`` (signed, in the direction of
    degradation) over the calibration's actuators. Between sizes the estimate is interpolated
    linearly (through 0); beyond the largest, the last gain holds."""

    sizes: tuple[float, ...]
    gains: tuple[float, ...]
    spread: tuple[float, ...]            # std of the gain over the actuators

    def estimate_at(self, size: float) -> float:
        """The expected linear estimate of a change ``size``: linear from 0 to the first
        knot, a power law between knots (the response of a growing fault bends), the top's
        secant beyond."""
        xs, ys = self._knots()
        s = abs(size)
        if s >= xs[-1]:
            return math.copysign(ys[-1] * s / xs[-1], size)
        k = int(np.searchsorted(xs, s, side="right"))        # xs[k-1] <= s < xs[k]
        x1, x2, y1, y2 = xs[k - 1], xs[k], ys[k - 1], ys[k]
        if x1 <= 0 or y1 <= 0 or y2 <= 0:
            return math.copysign(float(np.interp(s, xs, ys)), size)
        p = math.log(y2 / y1) / math.log(x2 / x1)
        return math.copysign(float(y1 * (s / x1) ** p), size)

    def _knots(self) -> tuple[np.ndarray, np.ndarray]:
        """The response up to the largest size where it still grows (by 2 % or more from the
        knot below): beyond it the estimate no longer tells the size (a clogging filter near
        jammed, a motor gain at a fifth of nominal)."""
        xs = np.array([0.0] + [abs(s) for s in self.sizes])
        ys = np.array([0.0] + [g * abs(s) for s, g in zip(self.sizes, self.gains)])
        top = 1
        while top + 1 < xs.size and ys[top + 1] >= 1.02 * ys[top] and ys[top] > 0:
            top += 1
        return xs[:top + 1], ys[:top + 1]

    def top(self) -> tuple[float, float]:
        """``(size, estimate)`` at the end of the response's growing range."""
        xs, ys = self._knots()
        return float(xs[-1]), float(ys[-1])

    def beyond(self, estimate: float, sign: float) -> bool:
        """Is ``estimate`` beyond the growing range (the size only bounded below)?"""
        _, y_top = self.top()
        return bool(y_top > 0 and estimate * sign > y_top)

    def invert(self, estimate: float, sign: float) -> float:
        """The change whose expected estimate is ``estimate`` (``sign``: the direction of
        degradation of the fault's sizes; an estimate against it is read at the first gain,
        one beyond the growing range at the top's secant gain: a lower bound of the size,
        :meth:`beyond`)."""
        xs, ys = self._knots()
        e = estimate * sign
        if e <= 0 or ys[-1] <= 0:
            g = self.gains[0] if self.gains and self.gains[0] > 0 else 1.0
            return float(estimate / g)
        if e >= ys[-1]:
            return float(sign * e * xs[-1] / ys[-1])
        k = int(np.searchsorted(ys, e, side="right"))        # ys[k-1] <= e < ys[k]
        x1, x2, y1, y2 = xs[k - 1], xs[k], ys[k - 1], ys[k]
        if x1 <= 0 or y1 <= 0 or y2 <= y1:
            return sign * float(np.interp(e, ys, xs))
        p = math.log(y2 / y1) / math.log(x2 / x1)            # the power law between knots
        return float(sign * x1 * (e / y1) ** (1.0 / p))

    def relative_spread(self, size: float) -> float:
        """The gain's relative spread over actuators near ``size`` (interpolated)."""
        xs = np.array([abs(s) for s in self.sizes])
        rel = np.array([sd / g if g > 0 else 0.0 for sd, g in zip(self.spread, self.gains)])
        return float(np.interp(abs(size), xs, rel))

    def to_dict(self) -> dict:
        return {"sizes": list(self.sizes), "gains": list(self.gains),
                "spread": list(self.spread)}


__all__ = ["PROBE", "GAIN_SIZES", "Nuisance", "NUISANCES", "check_nuisances",
           "draw_test_day", "probe", "Signatures", "GainCurve"]
