"""Parameter sets of the HF (detailed) and LF (monitoring) models: units, nominal values, ranges.

Every parameter is declared once, in :data:`PARAMETERS`, with its unit, nominal value, allowed
range and the models that use it (docs/model.md §1; values from the thesis' EHA_Dat.m). The frozen
dataclasses :class:`HFParams` and :class:`LFParams` are generated from that table, so the field
order of each dataclass is also the order of the float64 vector the numba kernels receive
(:meth:`ModelParams.to_array`), and :data:`HF` / :data:`LF` are ``IntEnum`` indices into it.

Loading from TOML or the command line goes through :func:`resolve`, the one place where names
and ranges are validated.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Iterable, Mapping
from eha.errors import InputError

MODELS = ("hf", "lf")


class ParameterError(InputError):
    """A parameter name or value that the models do not accept (message is one line)."""


@dataclass(frozen=True)
class ParamSpec:
    """Declaration of one model parameter.

    Attributes
    ----------
    name : str
        Name as in EHA_Dat.m (LF copies drop the ``m`` suffix: ``BKL`` sets ``BKLm``).
    unit : str
        SI unit (currents in mA, as in the thesis).
    nominal : float
        Nominal value in the HF model.
    lo, hi : float
        Allowed closed range.
    description : str
        One-line meaning.
    models : tuple of str
        Models that use it (``"hf"``, ``"lf"``).
    lf_nominal : float or None
        Nominal value in the LF model when it differs (effects that are off in LF).
    fault : bool
        One of the ten fault parameters of EHA_Dat.m's check list (docs/model.md §1).
    """

    name: str
    unit: str
    nominal: float
    lo: float
    hi: float
    description: str
    models: tuple[str, ...] = MODELS
    lf_nominal: float | None = None
    fault: bool = False

    def nominal_for(self, model: str) -> float:
        if model == "lf" and self.lf_nominal is not None:
            return self.lf_nominal
        return self.nominal

    def range_text(self) -> str:
        return f"[{self.lo:g}, {self.hi:g}] {self.unit}".rstrip()

    @property
    def display(self) -> tuple[str, float]:
        """``(unit, factor)`` people read the parameter in, from its declared unit
        (:data:`DISPLAY_OF_UNIT`; ``value_shown = factor * value``). Read it through
        :func:`eha.models.units.display_unit`, which also honours a health fault's own."""
        if self.name in KEEP_DISPLAY:
            return self.unit, 1.0
        return DISPLAY_OF_UNIT.get(self.unit, (self.unit, 1.0))


#: Declared (SI) unit -> (display unit, factor from the declared unit): positions and lengths
#: µm, pressures MPa, delays ms, dimensionless ``""`` (:attr:`ParamSpec.display`).
DISPLAY_OF_UNIT: dict[str, tuple[str, float]] = {
    "m": ("µm", 1e6),
    "Pa": ("MPa", 1e-6),
    "s": ("ms", 1e3),
    "-": ("", 1.0),
    "N*s/m": ("N·s/m", 1.0),
    "m^3/(Pa*s)": ("m³/(Pa·s)", 1.0),
    "m^2/s": ("m²/s", 1.0),
    "m^2": ("m²", 1.0),
}
#: Parameters shown in their declared unit for another reason: the integration step stays in
#: seconds (a model setting, not a measured quantity).
KEEP_DISPLAY = frozenset({"DT"})


_HF = ("hf",)
_LF = ("lf",)
_B = MODELS

#: Every parameter of both models, in kernel-vector order.
PARAMETERS: tuple[ParamSpec, ...] = (
    # simulation
    ParamSpec("DT", "s", 1e-5, 1e-7, 1e-4, "fixed integration step"),
    # controller
    ParamSpec("GAP", "mA/m", 1e4, 0.0, 1e7, "proportional gain"),
    ParamSpec("GAI", "mA/(m*s)", 0.0, 0.0, 1e8, "integral gain", _HF),
    ParamSpec("GAD", "mA*s/m", 0.0, 0.0, 1e3, "derivative gain", _HF),
    ParamSpec("ErIM", "m*s", 1e-3, 0.0, 1.0, "integrator saturation", _HF),
    ParamSpec("GAS", "mA*s/m", 0.0, 0.0, 1e5, "jack-velocity feedback gain", _HF),
    # torque motor
    ParamSpec("CorM", "mA", 10.0, 0.1, 100.0, "current saturation"),
    ParamSpec("His", "mA", 0.0, 0.0, 5.0, "magnetic hysteresis half-width", _B, fault=True),
    ParamSpec("Ofs", "mA", 0.0, -10.0, 10.0, "offset current", _B, fault=True),
    ParamSpec("GM", "N/mA", 0.01, 0.0, 0.1, "motor gain (demagnetisation lowers it)", fault=True),
    ParamSpec("dither_ma", "mA", 0.01, 0.0, 10.0,
              "dither std, ZOH Gaussian every 1 ms (reconstruction; 0 = off); LF: its "
              "expected effect on the hysteresis (mean-field dithered play)", _B),
    # first stage
    ParamSpec("KF", "N/m", 40.0, 1.0, 1e4, "flapper spring stiffness"),
    ParamSpec("KSF", "N/m", 160.0, 1.0, 1e4, "feedback spring stiffness"),
    ParamSpec("SNF", "rad/s", 2513.0, 0.0, 1e5,
              "flapper natural frequency (LF: 0 = static first stage, flapper_dynamics off)",
              _B, lf_nominal=0.0),
    ParamSpec("ZF", "-", 0.6, 0.01, 10.0, "flapper damping ratio"),
    ParamSpec("XFM", "m", 1e-4, 1e-6, 1e-2, "flapper end stop"),
    ParamSpec("gioco", "m", 0.0, 0.0, 1e-3, "feedback-spring ball backlash half-width",
              fault=True),
    # second stage
    ParamSpec("ASV", "m^2", 0.7e-4, 1e-6, 1e-2, "spool area"),
    ParamSpec("CSV", "N*s/m", 1000.0, 0.0, 1e6, "spool viscous coefficient"),
    ParamSpec("GPF", "Pa/m", 1e11, 1e6, 1e14, "first-stage pressure gain"),
    ParamSpec("GQF", "m^2/s", 0.014, 1e-5, 10.0, "first-stage flow gain"),
    ParamSpec("XSM", "m", 0.6e-3, 1e-5, 1e-2, "spool end stop"),
    ParamSpec("Kintas", "-", 0.0, 0.0, 1.0, "first-stage filter clogging (0 healthy, 1 jammed)",
              fault=True),
    ParamSpec("FSS", "N", 7.0, 0.0, 1e4, "spool static friction (ASV*GPF*XFM/100)", fault=True),
    ParamSpec("FSDS", "-", 1.2, 1.0, 10.0, "spool static/dynamic friction ratio"),
    ParamSpec("q_xs", "m", 0.0, 0.0, 1e-3, "spool-position quantizer step (0 = off)", _HF),
    # fluid
    ParamSpec("PSR", "Pa", 2e7, 1e5, 1e8, "supply-return pressure"),
    ParamSpec("PSR0", "Pa", 2e7, 1e5, 1e8, "pressure at which GP and GQ are defined"),
    ParamSpec("XSSK", "-", 0.0, 0.0, 1.0,
              "supply-pressure law: spool saturation opening XSS = PSR0/GP*(PSR/PSR0)^XSSK "
              "(0: the thesis' listing, flow at no load in proportion to PSR; 1: its text, "
              "XSS = PSR/GP, flow independent of PSR; 0.5: an orifice's sqrt(PSR))"),
    ParamSpec("PRV", "Pa", 1e6, 0.0, 1e7, "return (tank) pressure"),
    ParamSpec("PVap", "Pa", 1e3, 0.0, 1e6, "oil vapour pressure"),
    ParamSpec("GP", "Pa/m", 1e11, 1e6, 1e14, "valve pressure gain", fault=True),
    ParamSpec("GQ", "m^2/s", 0.2, 1e-4, 100.0, "valve flow gain"),
    ParamSpec("Clk", "m^3/(Pa*s)", 1e-13, 0.0, 1e-9, "leakage coefficient (LF: leakage effect)",
              _B, lf_nominal=0.0, fault=True),
    ParamSpec("orifice_law", "-", 1.0, 0.0, 1.0,
              "1 = nonlinear orifice P12 law of HF, 0 = linear LF law", _LF, lf_nominal=0.0),
    # loads
    ParamSpec("FRC", "N", 0.0, -1e6, 1e6, "constant external load"),
    ParamSpec("FRR", "N/s", 0.0, -1e7, 1e7, "external load ramp", _HF),
    ParamSpec("FR_time", "s", 0.0, 0.0, 1e4, "external load start time", _HF),
    ParamSpec("FRSA", "N", 0.0, 0.0, 1e6, "sinusoidal load amplitude", _HF),
    ParamSpec("FRSF", "rad/s", 0.0, 0.0, 1e5, "sinusoidal load frequency", _HF),
    ParamSpec("Kaer", "N/m", 0.0, 0.0, 1e8, "hinge-moment stiffness (0.25*AJ*PSR/XJM when on)"),
    # jack
    ParamSpec("AJ", "m^2", 8e-4, 1e-6, 1.0, "jack area"),
    ParamSpec("CJ", "N*s/m", 50.0, 0.0, 1e7, "jack viscous coefficient"),
    ParamSpec("MJ", "kg", 20.0, 1e-3, 1e5, "jack mass"),
    ParamSpec("XJM", "m", 0.2, 1e-4, 10.0, "jack end stop"),
    ParamSpec("XJ0", "m", 0.0, -10.0, 10.0, "initial jack position"),
    ParamSpec("FDJ", "N", 200.0, 0.0, 1e6, "jack dynamic friction", fault=True),
    ParamSpec("FSD", "-", 2.0, 1.0, 10.0, "jack static/dynamic friction ratio (FSJ = FSD*FDJ)"),
    ParamSpec("BKL", "m", 0.0, 0.0, 0.1, "jack-surface backlash, total width", fault=True),
    ParamSpec("eps", "m/s", 1e-5, 1e-9, 1e-2, "Karnopp velocity dead band", _LF),
    # measurement (applied to the recorded xu only, never to the feedback)
    ParamSpec("sensor_bias", "m", 0.0, -0.1, 0.1, "bias of the recorded position"),
    ParamSpec("sensor_gain", "-", 1.0, 0.5, 2.0, "gain of the recorded position"),
    ParamSpec("sensor_delay", "s", 0.0, 0.0, 0.1, "transport delay of the recorded position"),
)

SPECS: dict[str, ParamSpec] = {p.name: p for p in PARAMETERS}


def specs_for(model: str) -> tuple[ParamSpec, ...]:
    """Parameter declarations of ``model`` ("hf" or "lf"), in kernel-vector order."""
    _check_model(model)
    return tuple(p for p in PARAMETERS if model in p.models)


def _check_model(model: str) -> None:
    if model not in MODELS:
        raise ParameterError(f"model: unknown model {model!r}; allowed: hf, lf")


class ModelParams:
    """Mixin of the generated parameter dataclasses."""

    model: str = ""

    def to_array(self):
        """Float64 vector in kernel order (index it with :data:`HF` or :data:`LF`)."""
        import numpy as np

        return np.array([getattr(self, f.name) for f in dataclasses.fields(self)],
                        dtype=np.float64)

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def replace(self, **overrides: float) -> "ModelParams":
        """A copy with ``overrides`` applied, validated like :func:`resolve`."""
        return resolve(self.model, overrides, base=self)


def _make_dataclass(model: str) -> type:
    specs = specs_for(model)
    doc_lines = [f"Parameters of the {model.upper()} model (frozen; SI units, currents in mA).",
                 "", "Attributes", "----------"]
    for p in specs:
        doc_lines += [f"{p.name} : float", f"    {p.description} [{p.unit}], "
                      f"nominal {p.nominal_for(model):g}, range {p.range_text()}"]
    cls = dataclasses.make_dataclass(
        f"{model.upper()}Params",
        [(p.name, float, dataclasses.field(default=p.nominal_for(model))) for p in specs],
        bases=(ModelParams,),
        frozen=True,
        namespace={"model": model},
    )
    cls.__doc__ = "\n".join(doc_lines)
    cls.__module__ = __name__
    return cls


HFParams = _make_dataclass("hf")
LFParams = _make_dataclass("lf")

#: Index of each HF parameter in the kernel vector (``p[HF.GAP]``).
HF = IntEnum("HF", [(p.name, i) for i, p in enumerate(specs_for("hf"))], module=__name__)
#: Index of each LF parameter in the kernel vector (``p[LF.GAP]``).
LF = IntEnum("LF", [(p.name, i) for i, p in enumerate(specs_for("lf"))], module=__name__)

_CLASSES = {"hf": HFParams, "lf": LFParams}


def parse_name_value(text: str, option: str = "item", form: str = "VALUE"
                     ) -> tuple[str, float | tuple[float, float] | None]:
    """The one parser of ``NAME=VALUE`` and ``NAME=LO:HI`` command-line items.

    Parameters
    ----------
    text : str
        ``"BKL=1e-4"`` (``form="VALUE"``), ``"BKL=0:1e-3"`` (``form="LO:HI"``), or, with
        ``form="[LO:HI]"``, also a bare ``"BKL"`` (value None: the caller's default).
    option : str
        Named in the message of a malformed item.

    Returns
    -------
    (name, value)
        ``value`` is a float, a ``(lo, hi)`` tuple, or None.

    Raises
    ------
    ParameterError
        One line naming the option or the parameter and the expected form.
    """
    name, sep, value = text.partition("=")
    name = name.strip()
    if not name or (not sep and form != "[LO:HI]"):
        example = "BKL=1e-4" if form == "VALUE" else "BKL=0:1.25e-3"
        raise ParameterError(f"{option} {text!r}: expected NAME={form.strip('[]')}, for "
                             f"example {example}")
    if not sep:
        return name, None
    if form == "VALUE":
        try:
            return name, float(value)
        except ValueError:
            raise ParameterError(f"{name}: value {value.strip()!r} is not a number") from None
    lo, colon, hi = value.partition(":")
    try:
        if not colon:
            raise ValueError
        return name, (float(lo), float(hi))
    except ValueError:
        raise ParameterError(f"{option} {text!r}: expected NAME=LO:HI, for example "
                             "BKL=0:1.25e-3") from None


def parse_assignment(text: str, option: str = "item") -> tuple[str, float]:
    """Parse ``NAME=VALUE`` (e.g. ``BKL=1e-4``) into a name and a float; an error names
    ``option`` (the command line passes its flag, ``--set``)."""
    name, value = parse_name_value(text, option, "VALUE")
    return name, value


def parse_assignments(items: Iterable[str], option: str = "item") -> dict[str, float]:
    """Parse several ``NAME=VALUE`` strings; a repeated name is an error (naming
    ``option``, as :func:`parse_assignment`)."""
    out: dict[str, float] = {}
    for item in items:
        name, value = parse_assignment(item, option)
        if name in out:
            raise ParameterError(f"{name}: set twice")
        out[name] = value
    return out


def check_value(name: str, value: Any, model: str | None = None) -> float:
    """Validate one parameter value; return it as float.

    Raises
    ------
    ParameterError
        Unknown name (for ``model`` when given), non-numeric, non-finite or out-of-range value.
    """
    spec = SPECS.get(name)
    if spec is None:
        import difflib

        close = [n for n in SPECS if n.lower() == name.lower()] or difflib.get_close_matches(
            name, SPECS, n=1, cutoff=0.6) or difflib.get_close_matches(
            name.upper(), [n.upper() for n in SPECS], n=1, cutoff=0.6)
        close = [next(n for n in SPECS if n.upper() == c.upper()) for c in close]
        hint = f" (did you mean {close[0]}?)" if close else " (see `eha params`)"
        raise ParameterError(f"{name}: unknown parameter{hint}")
    if model is not None and model not in spec.models:
        raise ParameterError(f"{name}: not a parameter of the {model.upper()} model "
                             f"(used by {', '.join(m.upper() for m in spec.models)})")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{name}: value {value!r} is not a number; allowed range "
                             f"{spec.range_text()}")
    value = float(value)
    if not math.isfinite(value) or not (spec.lo <= value <= spec.hi):
        raise ParameterError(f"{name}={value:g} is out of range; allowed range {spec.range_text()}")
    return value


def resolve(model: str, overrides: Mapping[str, Any] | None = None,
            base: ModelParams | None = None) -> ModelParams:
    """Build the parameter set of ``model`` from nominal values (or ``base``) and overrides.

    This is the single validation point for parameters coming from TOML, the CLI or the API.

    Parameters
    ----------
    model : {"hf", "lf"}
    overrides : mapping of name to value, optional
        Names as in :data:`PARAMETERS`; values in the declared units.
    base : ModelParams, optional
        Starting set instead of the nominal one.
    """
    _check_model(model)
    values = dict(overrides or {})
    checked = {name: check_value(name, v, model) for name, v in values.items()}
    cls = _CLASSES[model]
    start = base if base is not None else cls()
    params = dataclasses.replace(start, **checked)
    _check_consistency(params)
    return params


def _check_consistency(p: ModelParams) -> None:
    if abs(p.XJ0) > p.XJM:
        raise ParameterError(f"XJ0={p.XJ0:g} is out of range; allowed range "
                             f"[{-p.XJM:g}, {p.XJM:g}] m (within the jack end stops XJM)")
    if p.model == "lf" and p.orifice_law not in (0.0, 1.0):
        raise ParameterError(f"orifice_law={p.orifice_law:g} is out of range; allowed 0 or 1")
    steps = 1e-3 / p.DT
    if abs(steps - round(steps)) > 1e-6 * steps:
        raise ParameterError(f"DT={p.DT:g}: the 1 ms output step must be a whole number of DT; "
                             f"allowed range [1e-07, 0.0001] s dividing 1e-3")


def fault_names() -> tuple[str, ...]:
    """The ten fault parameters of EHA_Dat.m's check list (FSJ enters through FDJ)."""
    return tuple(p.name for p in PARAMETERS if p.fault)
