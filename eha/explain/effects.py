"""Missing-effect library of the residual loop (docs/model.md §6): physics the LF model may lack.

Every effect is one registered :class:`Effect`: a stable name (used in reports and JSON), the LF
parameters it fits with their search bounds, the parameters it merely switches (``orifice_law``),
a probe value used to compute its signature, and a one-line description. The LF kernel already
carries every effect parameter with a neutral "off" value (:mod:`eha.models.params`), so switching
an effect on is setting parameters on an :class:`~eha.models.params.LFParams`; any combination runs
in the one compiled kernel.

Adding an effect is one :func:`register` call in this module (or in user code).

Examples
--------
>>> from eha.explain.effects import EFFECTS
>>> from eha.models.params import LFParams
>>> p = EFFECTS["external_load"].switch_on(LFParams(), {"FRC": 500.0})
>>> p.FRC
500.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

from eha.models.params import SPECS, LFParams, ParameterError, resolve


@dataclass(frozen=True)
class Effect:
    """One missing effect of the library (docs/model.md §6).

    Attributes
    ----------
    name : str
        Stable name (docs/model.md §6), e.g. ``"external_load"``.
    description : str
        What it adds to the LF model, in one line.
    bounds : mapping of str to (float, float)
        LF parameters that are fitted when the effect is on, with their search bounds (in the
        parameter's unit). Empty for a pure switch (``orifice_law``).
    switch : mapping of str to float
        LF parameters set (not fitted) when the effect is on, e.g. ``{"orifice_law": 1.0}``.
    probe : mapping of str to float
        "On" values used for the signature (the secant sensitivity of xu between the off and the
        probe value); a typical, clearly visible but small magnitude of the effect.
    requires : tuple of str
        Effects without which this one does not act on the LF model: with the linear P12 law
        the supply pressure only bounds P12, so ``supply_pressure`` requires ``orifice_law``.
        The residual loop tries such an effect together with the requirements the model
        lacks.
    other_starts : tuple of mappings
        Further values the loop's local test also starts from (on top of the probe), for a
        parameter that sets another's sensitivity by orders of magnitude: the supply
        pressure's law (``XSSK``), whose two ends are the thesis' two laws; from the probe's
        end alone least squares stays in that law's basin.
    statistic : str
        The parameter a size of the effect is stated in (:attr:`tested`: injected by the
        benchmarks, named in the report), when the effect fits more than one (the supply
        pressure, not its law); default: the one fitted parameter. Unless ``footprint``, the
        healthy null tests its distance from off (:meth:`shift`).
    footprint : bool
        The healthy null also tests the effect's *footprint* on the record: the RMS change of
        the simulated position when the effect is switched off in the fitted model
        (:meth:`eha.explain.record.Record.footprint`, m), beside the tested parameter's shift
        (:attr:`shift_key`); the effect passes the gate when either passes its threshold,
        each one of the union bound's statistics.
        For an effect whose parameters trade so that no one of them is identified on every
        command: with the supply pressure's law near the text's (``XSSK`` 1) the pressure
        ``PSR`` only bounds P12, so on a record that never reaches that bound a healthy fit
        moves it by megapascals at no cost (healthy shifts up to 1.7-8.8 MPa), which hid a
        real 4 MPa drop; its footprint stays under 2 µm there (docs/explain.md).
    """

    name: str
    description: str
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    switch: Mapping[str, float] = field(default_factory=dict)
    probe: Mapping[str, float] = field(default_factory=dict)
    requires: tuple[str, ...] = ()
    other_starts: tuple[Mapping[str, float], ...] = ()
    statistic: str = ""
    footprint: bool = False

    @property
    def params(self) -> tuple[str, ...]:
        """Fitted LF parameters (the degrees of freedom the effect adds)."""
        return tuple(self.bounds)

    @property
    def off(self) -> dict[str, float]:
        """The neutral value of every parameter the effect touches (LF nominal)."""
        nominal = LFParams()
        return {n: getattr(nominal, n) for n in (*self.bounds, *self.switch)}

    def units(self) -> dict[str, str]:
        return {n: SPECS[n].unit for n in self.bounds}

    @property
    def shift_key(self) -> str | None:
        """For an effect tested by its footprint, the null's key of its second statistic,
        the tested parameter's shift (``"supply_pressure.PSR"``); else None."""
        return f"{self.name}.{self.tested}" if self.footprint else None

    @property
    def statistic_unit(self) -> str:
        """Unit of the statistic the healthy null tests: m for a footprint, else the tested
        parameter's."""
        return "m" if self.footprint else self.units()[self.tested]

    def switch_on(self, base: LFParams, values: Mapping[str, float] | None = None) -> LFParams:
        """``base`` with the effect on: the switches set, fitted parameters at ``values``.

        Parameters without a value take the probe value (or stay as in ``base`` when the effect
        has no probe for them).
        """
        values = dict(values or {})
        unknown = set(values) - set(self.bounds)
        if unknown:
            raise ParameterError(f"effect {self.name}: {sorted(unknown)[0]} is not one of its "
                                 f"parameters ({', '.join(self.params) or 'none'})")
        overrides = dict(self.switch)
        for name in self.bounds:
            if name in values:
                overrides[name] = values[name]
            elif name in self.probe:
                overrides[name] = self.probe[name]
        return resolve("lf", overrides, base=base)

    def switch_off(self, base: LFParams) -> LFParams:
        """``base`` with every parameter of the effect back at its off value."""
        return resolve("lf", self.off, base=base)

    @property
    def tested(self) -> str | None:
        """The parameter the healthy null tests (:attr:`statistic`, or the one fitted
        parameter); None for an effect of several parameters without one (the flapper
        dynamics) or of none."""
        if self.statistic:
            return self.statistic
        return next(iter(self.bounds)) if len(self.bounds) == 1 else None

    def shift(self, values: Mapping[str, float]) -> float:
        """How far the tested parameter (:attr:`tested`) in ``values`` is from its off value
        (its unit): the statistic the residual loop tests against the healthy null
        (:mod:`eha.explain.null`). An effect without one (the flapper dynamics): nan."""
        name = self.tested
        if name is None:
            return math.nan
        return abs(float(values[name]) - self.off[name])

    def shift_at(self, params: LFParams) -> float:
        """:meth:`shift` of the effect's parameter in ``params``."""
        return self.shift({n: getattr(params, n) for n in self.params})

    def is_on(self, params: LFParams) -> bool:
        return any(getattr(params, n) != v for n, v in self.off.items())


def missing_requirements(effect: Effect, params: LFParams) -> list[str]:
    """The effects ``effect`` requires (:attr:`Effect.requires`) that are off in ``params``."""
    return [name for name in effect.requires if not EFFECTS[name].is_on(params)]


def switch_on_with_requirements(effect: Effect, params: LFParams) -> LFParams:
    """``params`` with ``effect`` on at its probe values, and the effects it requires on."""
    for name in missing_requirements(effect, params):
        params = EFFECTS[name].switch_on(params)
    return effect.switch_on(params)


#: The registry, in the order of docs/model.md §6: stable name -> :class:`Effect`.
EFFECTS: dict[str, Effect] = {}


def register(effect: Effect) -> Effect:
    """Add ``effect`` to :data:`EFFECTS` (its parameters must be LF parameters)."""
    for name in (*effect.bounds, *effect.switch, *effect.probe,
                 *(n for start in effect.other_starts for n in start)):
        spec = SPECS.get(name)
        if spec is None or "lf" not in spec.models:
            raise ParameterError(f"effect {effect.name}: {name} is not an LF parameter")
    for name in effect.requires:
        if name not in EFFECTS:
            raise ParameterError(f"effect {effect.name}: requires {name}, not a registered "
                                 f"effect")
    if effect.statistic and effect.statistic not in effect.bounds:
        raise ParameterError(f"effect {effect.name}: statistic {effect.statistic} is not one of "
                             f"its fitted parameters")
    for name, (lo, hi) in effect.bounds.items():
        spec = SPECS[name]
        if not (spec.lo <= lo < hi <= spec.hi):
            raise ParameterError(f"effect {effect.name}: bounds of {name} [{lo:g}, {hi:g}] must "
                                 f"lie inside {spec.range_text()}")
    if effect.name in EFFECTS:
        raise ParameterError(f"effect {effect.name}: registered twice")
    EFFECTS[effect.name] = effect
    return effect


def get(names: str | Iterable[str]) -> list[Effect]:
    """Effects by name (a comma-separated string or an iterable); unknown names raise."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    out = []
    for name in names:
        if name not in EFFECTS:
            raise ParameterError(f"effect {name!r}: unknown; allowed: {', '.join(EFFECTS)}")
        out.append(EFFECTS[name])
    return out


# -- the library (docs/model.md §6). Bounds are search ranges for a real actuator of the
# thesis' size:
#    AJ*PSR = 16 kN maximum jack force, GAP = 1e4 mA/m, 1 kHz position records.
register(Effect("orifice_law", "HF's nonlinear orifice P12 law (uses PSR, XSS) instead of the "
                "linear one", switch={"orifice_law": 1.0}))
register(Effect("leakage", "leakage between the chambers in the P12 law",
                bounds={"Clk": (0.0, 2e-11)}, probe={"Clk": 1e-12}))
register(Effect("external_load", "constant load force on the jack",
                bounds={"FRC": (-8000.0, 8000.0)}, probe={"FRC": 500.0}))
register(Effect("hinge_moment", "load proportional to the jack position (aerodynamic hinge "
                "moment)", bounds={"Kaer": (0.0, 1e6)}, probe={"Kaer": 5e4}))
register(Effect("offset", "torque-motor offset current",
                bounds={"Ofs": (-2.0, 2.0)}, probe={"Ofs": 0.1}))
register(Effect("hysteresis", "play-type magnetic hysteresis on the motor current (dithered: "
                "the expected play under the dither_ma dither, docs/model.md section 6)",
                bounds={"His": (0.0, 1.0)}, probe={"His": 0.05}))
register(Effect("motor_gain", "torque-motor gain change (demagnetisation)",
                bounds={"GM": (0.002, 0.02)}, probe={"GM": 0.009}))
register(Effect("clogging", "first-stage filter clogging: lower first-stage pressure gain",
                bounds={"Kintas": (0.0, 0.95)}, probe={"Kintas": 0.3}))
register(Effect("supply_pressure", "supply-pressure change (and its law, XSSK)",
                bounds={"PSR": (5e6, 3e7), "XSSK": (0.0, 1.0)},
                probe={"PSR": 1.8e7, "XSSK": 0.0}, requires=("orifice_law",),
                other_starts=({"XSSK": 1.0},), statistic="PSR", footprint=True))
register(Effect("flapper_dynamics", "second-order first stage (flapper inertia and damping) "
                "instead of a static one", bounds={"SNF": (300.0, 2e4), "ZF": (0.1, 2.0)},
                probe={"SNF": 2513.0, "ZF": 0.6}))
register(Effect("viscous_friction", "jack viscous friction coefficient",
                bounds={"CJ": (0.0, 2e4)}, probe={"CJ": 1000.0}))
register(Effect("sensor_bias", "measured position = XU + bias",
                bounds={"sensor_bias": (-5e-3, 5e-3)}, probe={"sensor_bias": 1e-5}))
register(Effect("sensor_gain", "measured position = gain*XU",
                bounds={"sensor_gain": (0.8, 1.25)}, probe={"sensor_gain": 1.01}))
register(Effect("delay", "transport delay of the measured position",
                bounds={"sensor_delay": (0.0, 0.02)}, probe={"sensor_delay": 2e-3}))


#: Effects that may only help together, so the residual loop also tries them as one candidate:
#: on step-rich commands the HF's orifice law and flapper dynamics each explain little alone
#: (measured on the 'test' command: 72 µm -> 58 / 30 µm alone, 3.9 µm together).
COMBINATIONS: tuple[tuple[str, ...], ...] = (("orifice_law", "flapper_dynamics"),)


def effects_on(params: LFParams) -> list[str]:
    """Names of the effects that ``params`` switches on (differs from their off values)."""
    return [e.name for e in EFFECTS.values() if e.is_on(params)]


__all__ = ["Effect", "EFFECTS", "COMBINATIONS", "register", "get", "effects_on",
           "missing_requirements", "switch_on_with_requirements"]
