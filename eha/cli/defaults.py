"""The CLI options' defaults, read from the library when an option is parsed: the CLI does not
retype them, and ``eha --help`` / ``eha query`` do not pay for importing the numerical modules
(each function imports its module when called: plain imports, no ``importlib``)."""

from __future__ import annotations

import inspect
from typing import Any, Callable


def _parameter_default(function: Callable[..., Any], parameter: str) -> Any:
    return inspect.signature(function).parameters[parameter].default


def fit_faults() -> str:
    """``eha fdi`` / ``eha explain --fit``: the declared faults (identification's default)."""
    from eha.identification.problem import DEFAULT_FIT

    return ",".join(DEFAULT_FIT)


def fit_method() -> str:
    from eha.identification.problem import DEFAULT_METHOD

    return DEFAULT_METHOD


def interval_level() -> float:
    from eha.identification.problem import DEFAULT_LEVEL

    return DEFAULT_LEVEL


def fdi_population() -> int:
    from eha.identification.fdi import identify_source

    return _parameter_default(identify_source, "pop")


def health_alpha() -> float:
    from eha.health.detection import DEFAULT_ALPHA

    return DEFAULT_ALPHA


def noise_p12() -> float:
    """``--noise-p12`` of ``eha design`` and ``eha health calibrate``: the load-pressure
    sensor noise the checks assume [Pa]."""
    from eha.health.assessment import DEFAULT_NOISE_P12

    return DEFAULT_NOISE_P12


def rul_faults() -> str:
    from eha.models import faults

    return ",".join(faults.rul_faults())


def loop_setting(name: str, cast: Callable[[Any], Any] = float) -> Callable[[], Any]:
    """A default of :data:`eha.explain.settings.DEFAULTS` (the residual loop's settings)."""
    def default() -> Any:
        from eha.explain.settings import DEFAULTS

        return cast(DEFAULTS[name])

    default.__name__ = f"loop_setting_{name}"
    return default
