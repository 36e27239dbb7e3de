"""Fault limits from performance requirements (``eha limits``), by HF simulation.

A requirement names the *failure* condition of a performance metric on a command::

    METRIC(COMMAND) OP VALUE          OP is > or >= or < or <=

e.g. ``"lag(mixed) > 0.02"`` (the tracking lag on the mixed command exceeds 20 ms) or
``"spool_saturation(chirp_1cm) > 0"`` (the spool reaches its end stop on chirp_1cm). The
command is a preset or kind of ``eha commands`` (kind parameters as in
``chirp(A0=0.005,f1=2)``). Metrics (SI units) are those of the campaign ``metrics`` table
(:func:`eha.models.run_metrics.trace_metrics`):

``lag`` [s], ``rmse_xu_com`` [m], ``max_err_xu_com`` [m], ``final_err_xu_com`` [m],
``settling_time`` [s], ``xs_abs_max`` [m], ``p12_abs_max`` [Pa], ``cor_abs_max`` [mA],
``xu_min``, ``xu_max`` [m], ``p12_min``, ``p12_max`` [Pa]

and ``spool_saturation`` [-], the share of the samples where |xs| >= 99.9 % of the spool end
stop XSM.

:func:`derive_limit` finds the smallest value of one fault (between ``lo``, where the
requirement holds, and ``hi``, where it fails) at which the failure condition becomes true, by
bisection on HF runs (other parameters nominal or ``base``; HF dither seed ``seed``). The
metric must change monotonically with the fault over [lo, hi] for the answer to be the
limit; the result lists every evaluated point so that this can be checked.
"""

from __future__ import annotations

import math
import operator
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from eha.prognostics.degradation import PrognosticsError

METRICS = ("lag", "rmse_xu_com", "max_err_xu_com", "final_err_xu_com", "settling_time",
           "xs_abs_max", "p12_abs_max", "cor_abs_max", "xu_min", "xu_max", "p12_min",
           "p12_max", "spool_saturation")
_OPS = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}
_REQ = re.compile(r"^\s*([A-Za-z_0-9]+)\s*\(\s*([A-Za-z_0-9]+)\s*(?:\((.*?)\))?\s*\)\s*"
                  r"(>=|<=|>|<)\s*([-+0-9.eE]+)\s*$")


@dataclass(frozen=True)
class Requirement:
    """A parsed failure condition ``metric(command) op value``."""

    metric: str
    command: str
    command_set: dict
    op: str
    value: float
    text: str

    def failed(self, metric_value: float | None) -> bool:
        """Whether a metric value violates the requirement (None, e.g. no lag: no)."""
        if metric_value is None or not math.isfinite(metric_value):
            return False
        return bool(_OPS[self.op](metric_value, self.value))


def parse_requirement(text: str) -> Requirement:
    """Parse ``METRIC(COMMAND) OP VALUE``; raises :class:`PrognosticsError` (one line)."""
    from eha.models.commands import CommandError, make_command

    m = _REQ.match(text or "")
    if not m:
        raise PrognosticsError(f"`requirement` {text!r}: expected METRIC(COMMAND) OP VALUE, e.g. "
                               "'lag(mixed) > 0.02' or 'spool_saturation(chirp_1cm) > 0'")
    metric, cmd, args, op, value = m.groups()
    if metric not in METRICS:
        raise PrognosticsError(f"`requirement` {text!r}: unknown metric {metric!r}; allowed: "
                               f"{', '.join(METRICS)}")
    sets: dict[str, float] = {}
    for part in filter(None, (a.strip() for a in (args or "").split(","))):
        k, sep, v = part.partition("=")
        try:
            sets[k.strip()] = float(v)
        except ValueError:
            raise PrognosticsError(f"`requirement` {text!r}: command parameter {part!r}: "
                                   "expected NAME=NUMBER") from None
    try:
        make_command(cmd, **sets)
    except CommandError as exc:
        raise PrognosticsError(f"`requirement` {text!r}: {exc}") from None
    try:
        val = float(value)
    except ValueError:
        raise PrognosticsError(f"`requirement` {text!r}: {value!r} is not a number") from None
    return Requirement(metric, cmd, sets, op, val, text.strip())


def metric_of(req: Requirement, fault: str, value: float, base: Mapping[str, float],
              seed: int = 0, t_end: float = 1.0) -> float | None:
    """The requirement's metric on an HF run with ``fault = value``."""
    from eha.models.commands import make_command
    from eha.models.params import resolve
    from eha.models.run_metrics import trace_metrics
    from eha.models.simulate import simulate

    params = {**base, fault: value}
    tr = simulate("hf", make_command(req.command, **req.command_set), params, t_end=t_end,
                  seed=seed)
    if not np.all(np.isfinite(tr.data)):
        return math.nan
    if req.metric == "spool_saturation":
        xsm = resolve("hf", params).as_dict()["XSM"]
        return float(np.mean(np.abs(tr["xs"]) >= 0.999 * xsm))
    return trace_metrics(tr)[req.metric]


@dataclass
class LimitResult:
    """Outcome of :func:`derive_limit`: ``limit`` [fault unit] and every evaluated point."""

    fault: str
    requirement: str
    limit: float
    lo: float
    hi: float
    tol: float
    seed: int
    points: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"fault": self.fault, "requirement": self.requirement, "limit": self.limit,
                "bracket": [self.lo, self.hi], "tol": self.tol, "seed": self.seed,
                "points": self.points}


def derive_limit(fault: str, requirement: str, lo: float, hi: float,
                 base: Mapping[str, float] | None = None, tol: float = 1e-3, seed: int = 0,
                 t_end: float = 1.0, max_iter: int = 60) -> LimitResult:
    """Smallest ``fault`` value in [lo, hi] at which ``requirement`` fails (bisection).

    Parameters
    ----------
    fault : str
        HF parameter (e.g. ``"FDJ"`` [N], ``"BKL"`` [m]).
    requirement : str
        Failure condition ``METRIC(COMMAND) OP VALUE`` (module docstring).
    lo, hi : float
        Bracket [fault unit]: the requirement must hold at ``lo`` and fail at ``hi``.
    base : mapping, optional
        Other HF parameters held fixed.
    tol : float
        Stop when the bracket is narrower than ``tol·(hi − lo)``.
    seed : int
        HF dither seed (the same for every run).
    t_end : float
        Simulated time [s].

    Raises
    ------
    PrognosticsError
        Bad fault, bracket or requirement, or a bracket that does not bracket.
    """
    from eha.models.params import ParameterError, check_value

    req = parse_requirement(requirement)
    try:
        lo = check_value(fault, lo, "hf")
        hi = check_value(fault, hi, "hf")
        for k, v in (base or {}).items():
            check_value(k, v, "hf")
    except ParameterError as exc:
        raise PrognosticsError(str(exc)) from None
    if not lo < hi:
        raise PrognosticsError(f"`lo` {lo:g} must be below `hi` {hi:g}")
    if not 0 < tol < 0.5:
        raise PrognosticsError(f"`tol` {tol:g}: allowed range (0, 0.5)")
    base = dict(base or {})
    points: list[dict[str, Any]] = []

    def evaluate(x: float) -> bool:
        m = metric_of(req, fault, x, base, seed, t_end)
        bad = req.failed(m)
        points.append({fault: x, req.metric: m, "failed": bad})
        return bad

    if evaluate(lo):
        raise PrognosticsError(f"the requirement already fails at `lo` {fault}={lo:g} "
                               f"({req.metric} = {points[-1][req.metric]!r}); lower `lo`")
    if not evaluate(hi):
        raise PrognosticsError(f"the requirement still holds at `hi` {fault}={hi:g} "
                               f"({req.metric} = {points[-1][req.metric]!r}); raise `hi`")
    a, b = lo, hi
    width = tol * (hi - lo)
    for _ in range(max_iter):
        if b - a <= width:
            break
        mid = 0.5 * (a + b)
        if evaluate(mid):
            b = mid
        else:
            a = mid
    points.sort(key=lambda p: p[fault])
    return LimitResult(fault, req.text, float(b), float(lo), float(hi), float(tol), int(seed),
                       points)


__all__ = ["Requirement", "parse_requirement", "derive_limit", "LimitResult", "METRICS"]
