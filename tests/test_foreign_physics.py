"""The test-only foreign-physics records (tests/foreign_physics.py): with the switches off they
are eha's own HF records; with each switch on they differ visibly.

The visibility check uses the ``mixed`` command: in 1 s it travels to 9 mm and back in both
directions, so the cubic spring (which grows with xj^3) and the asymmetric gain (which needs
currents of both signs) both show; ``chirp_1cm`` reaches only 5 mm in its first second (its
amplitude falls linearly), where the default cubic spring changes xu by ~6 µm RMS only.
"""

from __future__ import annotations

import numpy as np
import pytest

from eha.models.simulate import simulate
from foreign_physics import FOREIGN_EFFECTS, foreign_record, simulate_foreign


def rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


@pytest.mark.parametrize("command,params", [("mixed", None), ("test", {"FRC": 500.0,
                                                                       "BKL": 2e-5})])
def test_switches_off_reproduce_simulate_hf(command, params):
    a = simulate_foreign(command, {}, params, t_end=0.4, seed=3)
    b = simulate("hf", command, params, t_end=0.4, seed=3)
    assert a.data.shape == b.data.shape
    # not bit-identical: with fastmath the extra branches change the compiled arithmetic at
    # rounding level (1e-18 m); positions must agree to 1e-12 m, the rest relatively
    for name in ("t", "com", "xu", "xj", "xs", "xf"):
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-12, err_msg=name)
    for name in ("dxj", "p12", "cor"):
        scale = float(np.max(np.abs(b[name]))) or 1.0
        np.testing.assert_allclose(a[name], b[name], rtol=0, atol=1e-12 * scale, err_msg=name)


def test_foreign_record_is_synthetic_record_when_off():
    from eha.identification.measured import synthetic_record

    for command in ("mixed", "test"):  # a smooth command and a stepping (held) one
        ours = foreign_record(command, "none", 0.0, t_end=0.5, seed=1)
        theirs = synthetic_record(command, t_end=0.5, seed=1)
        assert list(ours.columns) == list(theirs.columns) == ["t", "com", "xu", "p12", "xs"]
        np.testing.assert_allclose(ours.xu, theirs.xu, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours.p12, theirs.p12, rtol=0,
                                   atol=1e-12 * np.max(np.abs(theirs.p12)))


@pytest.mark.parametrize("effect", list(FOREIGN_EFFECTS))
def test_each_switch_is_clearly_visible(effect):
    magnitude = FOREIGN_EFFECTS[effect][2]
    plain = foreign_record("mixed", "none", 0.0, noise=0.0)
    foreign = foreign_record("mixed", effect, magnitude, noise=0.0)
    # measured (docs in the module): cubic_spring 40, asymmetric_gain 83, spool_overlap 33 µm
    assert rmse(foreign.xu, plain.xu) > 10e-6
    # zero magnitude is the plain record
    np.testing.assert_array_equal(foreign_record("mixed", effect, 0.0, noise=0.0).xu, plain.xu)


def test_unknown_effect():
    with pytest.raises(ValueError, match="unknown"):
        foreign_record("mixed", "quadratic_spring", 1.0)
