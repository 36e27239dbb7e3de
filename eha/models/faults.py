"""The health faults: every fact of a fault declared once, in one :class:`Fault` each.

A health fault is a degradation the monitoring (LF) model carries as one parameter and that
the health assessment, detection, intervals, prognostics, reports and the residual loop all
speak of. Its facts used to be spread over seven tables; they now derive from :data:`FAULTS`:

======================================  ================================================
derived table                           from
======================================  ================================================
``identification.problem.SEARCH_BOUNDS``  :attr:`Fault.thesis_bounds` or :attr:`Fault.bounds`
``explain.settings.DEFAULT_FAULT_BOUNDS``  :attr:`Fault.loop_bounds`
``identification.healthy.DISPERSION``     :attr:`Fault.scatter` (+ :data:`OTHER_SCATTER`)
``identification.intervals.MODEL_FORM``   :attr:`Fault.model_form`
``health.assessment`` bank                :attr:`Fault.role`, :attr:`Fault.bounds`,
                                          :attr:`Fault.healthy_std`, :attr:`Fault.direction`
``eha rul --fit`` default               :attr:`Fault.rul`
``models.units.display_unit``              :attr:`Fault.display` (else by the SI unit)
health-detection campaign levels          :attr:`Fault.levels`
======================================  ================================================

Every table of search bounds derives from :func:`search_bounds` (one :class:`Bounds` per
purpose: ``"assessment"``, ``"fdi"``, ``"loop"``); every display unit from
:func:`eha.models.units.display_unit`.

Adding a health fault on an existing LF parameter is one :func:`register` call (in this module
or in user code); :func:`registered` does it for the span of a ``with`` block (tests).

Examples
--------
>>> from eha.models.faults import FAULTS
>>> FAULTS["FDJ"].healthy, FAULTS["FDJ"].unit
(200.0, 'N')
>>> [f.name for f in FAULTS.values() if f.role == "core"]
['BKL', 'FDJ']
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping

from eha.models.bounds import Bounds
from eha.models.params import SPECS, ParameterError

#: Roles in the hypothesis bank: ``core`` faults are fitted in every hypothesis (the thesis'
#: two), each ``extra`` fault gets a hypothesis of its own.
ROLES = ("core", "extra")
#: Laws of a manufacturing scatter ``(law, a, b)``: ``uniform_rel`` nominal x U(1 - a, 1 + a);
#: ``normal`` N(a, b) clipped at 10 % of a; ``loguniform`` exp(U(ln a, ln b)).
SCATTER_LAWS = ("uniform_rel", "normal", "loguniform")
#: What a fault's search bounds are for (:func:`search_bounds`): the health assessment
#: (:attr:`Fault.bounds`), the thesis reproduction's identification ``eha fdi``
#: (:attr:`Fault.fdi_bounds`), the residual loop ``eha explain`` (:attr:`Fault.loop_bounds`).
PURPOSES = ("assessment", "fdi", "loop")
#: A model-form floor of a fault's interval: ``(relative, absolute [parameter unit])``.
Floor = tuple[float, float]


@dataclass(frozen=True)
class Fault:
    """One health fault (see the module docstring for what derives from each field).

    Attributes
    ----------
    name : str
        The LF parameter that carries it (``eha params``).
    description : str
        What degrades, in a few words.
    direction : int
        +1: degradation raises the parameter; -1: lowers it; 0: either way (an offset).
    bounds : (float, float)
        Search bounds of the health assessment [parameter unit].
    role : str
        ``"core"`` (fitted in every hypothesis of the bank) or ``"extra"`` (a hypothesis of
        its own).
    healthy_std : float
        Spread of the value among healthy actuators, what a hypothesis that holds the fault
        healthy says of it (the manufacturing scatter, or a small tolerance) [parameter unit].
    thesis_bounds : (float, float) or None
        Search bounds of the thesis reproduction's identification (``eha fdi``) where they
        differ from :attr:`bounds`.
    loop_bounds : (float, float) or None
        Search bounds of the residual loop (``eha explain``) when the fault is declared without
        bounds: wider than the thesis' chirp cases, for records of unknown actuators. None:
        :attr:`fdi_bounds`.
    scatter : (str, float, float) or None
        Manufacturing scatter of a healthy actuator (:data:`SCATTER_LAWS`); None: every healthy
        actuator has the nominal value.
    model_form : mapping of str to (float, float)
        Per LF base model (``plain``, ``calibrated``): the measured model-form floor
        ``(rel, abs)`` of the fault's interval (:mod:`eha.identification.intervals`).
    display : (str, float) or None
        Display unit and the factor from the SI value (``("µm", 1e6)``) where it is not the
        one :func:`eha.models.units.display_unit` gives by the SI unit; None: that one.
    levels : tuple of float
        Levels injected by the health-detection campaign (increasing severity).
    rul : bool
        Tracked by the remaining-useful-life prediction by default.
    effect : str or None
        The residual loop's effect (:mod:`eha.explain.effects`) that fits the same parameter.
        The effect searches wider bounds than :attr:`bounds`: the loop explains records of
        unknown actuators, the assessment a degradation of a known one.
    """

    name: str
    description: str
    direction: int
    bounds: tuple[float, float]
    role: str = "extra"
    healthy_std: float = 0.0
    thesis_bounds: tuple[float, float] | None = None
    loop_bounds: tuple[float, float] | None = None
    scatter: tuple[str, float, float] | None = None
    model_form: Mapping[str, Floor] = field(default_factory=dict)
    display: tuple[str, float] | None = None
    levels: tuple[float, ...] = ()
    rul: bool = False
    effect: str | None = None

    @property
    def healthy(self) -> float:
        """Value of a healthy actuator: the HF nominal [parameter unit]."""
        return SPECS[self.name].nominal

    @property
    def unit(self) -> str:
        """SI unit of the parameter (``eha params``)."""
        return SPECS[self.name].unit

    @property
    def display_unit(self) -> tuple[str, float]:
        """``(unit, factor)`` a person reads the fault in: :attr:`display`, else the one of
        its declared unit (:attr:`eha.models.params.ParamSpec.display`); what
        :func:`eha.models.units.display_unit` gives for the fault."""
        return self.display or SPECS[self.name].display

    @property
    def fdi_bounds(self) -> tuple[float, float]:
        """Search bounds of the thesis reproduction's identification."""
        return self.thesis_bounds or self.bounds

    def bounds_for(self, purpose: str) -> tuple[float, float]:
        """Search bounds for ``purpose`` (:data:`PURPOSES`)."""
        if purpose == "assessment":
            return self.bounds
        if purpose == "loop":
            return self.loop_bounds or self.fdi_bounds
        return self.fdi_bounds


#: The registry: LF parameter name -> :class:`Fault`, in the order of the hypothesis bank.
FAULTS: dict[str, Fault] = {}

#: Manufacturing scatter of parameters that are not health faults (the healthy fleet).
OTHER_SCATTER: dict[str, tuple[str, float, float]] = {
    "GP": ("uniform_rel", 0.03, 0.0), "GQ": ("uniform_rel", 0.03, 0.0),
    "CJ": ("uniform_rel", 0.03, 0.0), "MJ": ("uniform_rel", 0.03, 0.0)}
#: The order the healthy fleet draws its scatter in (an actuator is one random stream, so the
#: order fixes which actuator a seed gives; kept from the first fleets so that seeds give the
#: same actuators). A scattered parameter not listed is drawn after these, in registry order.
SCATTER_DRAW_ORDER = ("GP", "GQ", "CJ", "MJ", "FSS", "GM", "FDJ", "Clk")


def _problems(fault: Fault) -> list[str]:
    spec = SPECS.get(fault.name)
    if spec is None or "lf" not in spec.models:
        return [f"fault {fault.name}: not an LF parameter (eha params)"]
    out = []
    if fault.role not in ROLES:
        out.append(f"fault {fault.name}: role {fault.role!r}; allowed {', '.join(ROLES)}")
    if fault.direction not in (-1, 0, 1):
        out.append(f"fault {fault.name}: direction {fault.direction!r}; allowed -1, 0, 1")
    for what, (lo, hi) in (("bounds", fault.bounds), ("thesis_bounds", fault.fdi_bounds),
                           ("loop_bounds", fault.bounds_for("loop"))):
        if not (spec.lo <= lo < hi <= spec.hi):
            out.append(f"fault {fault.name}: {what} [{lo:g}, {hi:g}] must lie inside "
                       f"{spec.range_text()}")
    if fault.scatter is not None and fault.scatter[0] not in SCATTER_LAWS:
        out.append(f"fault {fault.name}: scatter law {fault.scatter[0]!r}; allowed "
                   f"{', '.join(SCATTER_LAWS)}")
    if not (math.isfinite(fault.healthy_std) and fault.healthy_std >= 0):
        out.append(f"fault {fault.name}: healthy_std must be >= 0")
    for v in fault.levels:
        if not spec.lo <= v <= spec.hi:
            out.append(f"fault {fault.name}: level {v:g} outside {spec.range_text()}")
    return out


def register(fault: Fault) -> Fault:
    """Add ``fault`` to :data:`FAULTS`; a bad declaration raises :class:`ParameterError`."""
    problems = _problems(fault)
    if fault.name in FAULTS:
        problems.append(f"fault {fault.name}: registered twice")
    if problems:
        raise ParameterError(problems[0])
    FAULTS[fault.name] = fault
    return fault


@contextlib.contextmanager
def registered(fault: Fault) -> Iterator[Fault]:
    """:func:`register` ``fault`` for the span of a ``with`` block, then remove it."""
    register(fault)
    try:
        yield fault
    finally:
        FAULTS.pop(fault.name, None)


class Derived(Mapping):
    """A read-only mapping computed from :data:`FAULTS` at every access, so that a table
    derived from the registry (``SEARCH_BOUNDS``, ``DISPERSION``, ...) never goes stale when a
    fault is registered later."""

    def __init__(self, compute: Callable[[], Mapping[str, Any]], name: str = ""):
        self._compute, self._name = compute, name

    def __getitem__(self, key: str) -> Any:
        return self._compute()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._compute())

    def __len__(self) -> int:
        return len(self._compute())

    def __repr__(self) -> str:
        return f"{self._name or 'Derived'}({dict(self._compute())!r})"


def core_faults() -> tuple[str, ...]:
    """Faults fitted in every hypothesis of the bank."""
    return tuple(f.name for f in FAULTS.values() if f.role == "core")


def extra_faults() -> tuple[str, ...]:
    """Faults that each get a hypothesis of their own."""
    return tuple(f.name for f in FAULTS.values() if f.role == "extra")


def search_bounds(names=None, purpose: str = "fdi", declared: bool = False) -> Bounds:
    """Search bounds for ``purpose`` (:data:`PURPOSES`) of ``names`` (default: every fault).

    A name that is not a fault gets its parameter's allowed range (``eha params``);
    ``declared=True`` keeps only the faults that declare bounds of their own for ``purpose``
    (for the loop, those with :attr:`Fault.loop_bounds`; every fault has assessment and fdi
    bounds).

    Raises
    ------
    ParameterError
        ``purpose`` unknown, or a name that is no parameter.
    """
    if purpose not in PURPOSES:
        raise ParameterError(f"`purpose` {purpose!r}: allowed {', '.join(PURPOSES)}")
    pool = list(FAULTS if names is None else names)
    if declared:
        pool = [n for n in pool if n in FAULTS
                and (purpose != "loop" or FAULTS[n].loop_bounds is not None)]
    out = Bounds()
    for name in pool:
        if name in FAULTS:
            out[name] = FAULTS[name].bounds_for(purpose)
        elif name in SPECS:
            out[name] = (SPECS[name].lo, SPECS[name].hi)
        else:
            raise ParameterError(f"fit {name}: unknown parameter (see `eha params --model lf`)")
    return out


def dispersion() -> dict[str, tuple[str, float, float]]:
    """Manufacturing scatter of a healthy actuator, in its draw order
    (:data:`SCATTER_DRAW_ORDER`)."""
    laws = {**OTHER_SCATTER, **{f.name: f.scatter for f in FAULTS.values() if f.scatter}}
    order = [n for n in SCATTER_DRAW_ORDER if n in laws]
    order += [n for n in laws if n not in order]
    return {n: laws[n] for n in order}


def model_form_floors() -> dict[str, dict[str, Floor]]:
    """Per LF base model, the model-form floor ``(rel, abs)`` of each fault that has one."""
    out: dict[str, dict[str, Floor]] = {}
    for f in FAULTS.values():
        for base, floor in f.model_form.items():
            out.setdefault(base, {})[f.name] = floor
    return out


def rul_faults() -> tuple[str, ...]:
    """Faults the remaining-useful-life prediction tracks by default."""
    return tuple(f.name for f in FAULTS.values() if f.rul)


def detection_levels(names=None) -> dict[str, list[float]]:
    """The health-detection campaign's levels of ``names`` (default every fault)."""
    return {n: list(FAULTS[n].levels) for n in (names or FAULTS) if FAULTS[n].levels}


# -- the seven health faults of the thesis' LF model (docs/health.md). Model-form floors:
# the plain LF reads FDJ 3.8-4.8 % high on chirp records at an RMSE near the noise (dense scan,
# docs/fdi.md) and BKL up to 2 %: floors that cover that bias at 90 %. The calibrated LF's
# floors: `python validation/intervals.py --calibrate` (60 calibration records, chirp_1cm
# and mixed): the floors of smallest median width that bring the coverage to 90 % (GM and Ofs
# need none; no floor helps Clk, whose leakage the chirp record cannot tell from friction).
# The loop's bounds of BKL and FDJ: wider than the thesis' chirp cases, for records of unknown
# actuators (eha explain --fit BKL,FDJ).
register(Fault("BKL", "jack-surface backlash", +1, (0.0, 1.25e-3), role="core",
               loop_bounds=(0.0, 2e-3),
               model_form={"plain": (0.02, 2e-6), "calibrated": (0.001, 1.5e-6)},
               levels=(5e-6, 2e-5, 1e-4), rul=True))
# FDJ from 50 N in the assessment: a healthy actuator's friction scatters below the thesis'
# 200 N bound
register(Fault("FDJ", "jack dynamic friction", +1, (50.0, 4000.0), role="core",
               thesis_bounds=(200.0, 4000.0), loop_bounds=(0.0, 8000.0),
               scatter=("normal", 200.0, 20.0),
               model_form={"plain": (0.035, 0.0), "calibrated": (0.0, 5.0)},
               levels=(250.0, 300.0, 400.0), rul=True))
# GM is tracked by the RUL prediction with the thesis' two: it is both a fault
# (demagnetisation) and the actuator's largest manufacturing dispersion; left fixed at nominal,
# a unit whose motor gain is 3 % off had its FDJ identified 10-26 % off (fleet-demo,
# docs/prognostics.md); fitted, within 3 %.
register(Fault("GM", "torque-motor gain, demagnetisation", -1, (0.003, 0.012), healthy_std=6e-5,
               scatter=("uniform_rel", 0.01, 0.0), levels=(0.0095, 0.009, 0.008), rul=True,
               effect="motor_gain"))
register(Fault("Kintas", "first-stage filter clogging", +1, (0.0, 0.9), healthy_std=0.005,
               model_form={"calibrated": (0.0, 0.05)}, levels=(0.1, 0.3, 0.6),
               effect="clogging"))
register(Fault("Clk", "internal leakage", +1, (0.0, 5e-12), healthy_std=2e-14,
               scatter=("loguniform", 0.7e-13, 1.4e-13), levels=(5e-13, 1.5e-12, 4e-12),
               effect="leakage"))
register(Fault("Ofs", "torque-motor offset current", 0, (-1.0, 1.0), healthy_std=0.003,
               levels=(0.01, 0.05, 0.2), effect="offset"))
register(Fault("FSS", "spool static friction", +1, (0.0, 60.0), healthy_std=0.12,
               scatter=("uniform_rel", 0.03, 0.0), model_form={"calibrated": (0.0, 0.5)},
               levels=(10.0, 20.0, 40.0)))


__all__ = ["Fault", "FAULTS", "Bounds", "Floor", "Derived", "ROLES", "PURPOSES", "SCATTER_LAWS",
           "OTHER_SCATTER", "SCATTER_DRAW_ORDER",
           "register", "registered", "core_faults", "extra_faults", "search_bounds",
           "dispersion", "model_form_floors", "rul_faults", "detection_levels"]
