"""Effect library (docs/model.md §6): registry, switching on/off, every effect changes the LF
output."""

import numpy as np
import pytest

from eha.explain.effects import (EFFECTS, Effect, effects_on, get, missing_requirements, register,
                                 switch_on_with_requirements)
from eha.models.params import SPECS, LFParams, ParameterError
from eha.models.simulate import simulate

SPEC_NAMES = ("orifice_law", "leakage", "external_load", "hinge_moment", "offset", "hysteresis",
              "motor_gain", "clogging", "supply_pressure", "flapper_dynamics",
              "viscous_friction", "sensor_bias", "sensor_gain", "delay")


def test_registry_holds_the_14_spec_effects_in_order():
    assert tuple(EFFECTS) == SPEC_NAMES


@pytest.mark.parametrize("name", SPEC_NAMES)
def test_effect_is_off_in_nominal_lf_and_switches_on_and_off(name):
    effect = EFFECTS[name]
    nominal = LFParams()
    assert not effect.is_on(nominal)
    on = effect.switch_on(nominal)
    assert effect.is_on(on) and effects_on(on) == [name]
    assert effect.switch_off(on) == nominal
    for param, (lo, hi) in effect.bounds.items():
        assert SPECS[param].lo <= lo < hi <= SPECS[param].hi
        assert lo <= effect.probe[param] <= hi


@pytest.mark.parametrize("name", SPEC_NAMES)
def test_every_effect_changes_the_lf_output(name):
    # the 'test' command has steps (saturation), a ramp and a sine: every effect shows
    # (with the effects it requires on: the supply pressure acts through the orifice law)
    base = LFParams().replace(BKL=1e-4, FDJ=800.0)
    for required in EFFECTS[name].requires:
        base = EFFECTS[required].switch_on(base)
    off = simulate("lf", "test", base, t_end=0.6).xu
    on = simulate("lf", "test", EFFECTS[name].switch_on(base), t_end=0.6).xu
    assert np.sqrt(np.mean((on - off) ** 2)) > 1e-7


def test_supply_pressure_requires_the_orifice_law():
    """With the linear P12 law the supply pressure is only P12's clamp: a 20 % drop leaves a
    `chirp_1cm` run (P12 far from the clamp) unchanged, which is why the residual loop tries it
    with the orifice law (``requires``); with the law on, the same drop moves the position."""
    effect = EFFECTS["supply_pressure"]
    assert effect.requires == ("orifice_law",)
    base = LFParams().replace(BKL=1e-4, FDJ=800.0, FRC=2000.0)
    assert missing_requirements(effect, base) == ["orifice_law"]
    low = effect.switch_on(base, {"PSR": 1.6e7})
    linear = [simulate("lf", "chirp_1cm", p, t_end=0.5).xu for p in (base, low)]
    assert np.max(np.abs(linear[1] - linear[0])) < 1e-9
    on = switch_on_with_requirements(effect, base)
    assert on.orifice_law == 1.0 and on.PSR == effect.probe["PSR"]
    assert missing_requirements(effect, on) == []
    law = base.replace(orifice_law=1.0)
    runs = [simulate("lf", "chirp_1cm", p, t_end=0.5).xu
            for p in (law, effect.switch_on(law, {"PSR": 1.6e7}))]
    assert np.sqrt(np.mean((runs[1] - runs[0]) ** 2)) > 1e-6
    assert all(not EFFECTS[n].requires for n in EFFECTS if n != "supply_pressure")


def test_switch_on_with_values_and_bad_values():
    p = EFFECTS["external_load"].switch_on(LFParams(), {"FRC": 1234.0})
    assert p.FRC == 1234.0
    with pytest.raises(ParameterError, match="GM"):
        EFFECTS["external_load"].switch_on(LFParams(), {"GM": 0.1})
    with pytest.raises(ParameterError, match="out of range"):
        EFFECTS["offset"].switch_on(LFParams(), {"Ofs": 50.0})


def test_get_and_register_validate_names():
    assert [e.name for e in get("offset, delay")] == ["offset", "delay"]
    with pytest.raises(ParameterError, match="unknown"):
        get("wind")
    with pytest.raises(ParameterError, match="not an LF parameter"):
        register(Effect("bad", "uses an HF-only parameter", bounds={"GAI": (0.0, 1.0)}))
    with pytest.raises(ParameterError, match="requires wind"):
        register(Effect("bad", "needs an unknown effect", bounds={"Ofs": (-1.0, 1.0)},
                        requires=("wind",)))
    with pytest.raises(ParameterError, match="registered twice"):
        register(Effect("offset", "again", bounds={"Ofs": (-1.0, 1.0)}))
    assert "bad" not in EFFECTS


def test_shift_is_the_distance_of_the_effect_parameter_from_off():
    """The statistic the loop tests against its healthy null: the fitted parameter's distance
    from its off value, in its unit; nan for a switch or a two-parameter effect."""
    import math

    from eha.explain.effects import EFFECTS
    from eha.models.params import LFParams

    leak, psr = EFFECTS["leakage"], EFFECTS["supply_pressure"]
    assert leak.shift_at(LFParams().replace(Clk=5e-12)) == pytest.approx(5e-12)
    drop = LFParams().PSR - 1.3e7
    assert psr.shift_at(LFParams().replace(PSR=1.3e7)) == pytest.approx(drop)
    assert psr.shift_at(LFParams()) == 0.0
    assert math.isnan(EFFECTS["orifice_law"].shift_at(LFParams()))
    assert math.isnan(EFFECTS["flapper_dynamics"].shift_at(LFParams()))
