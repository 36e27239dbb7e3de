"""Simulation core: friction laws, play operator, kernels vs their pure-Python twins, physics.

Every tolerance says where it comes from.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from eha.models.commands import NOMINAL_COMMANDS, make_command
from eha.models import OUTPUTS
from eha.models.friction import (borello_velocity, borello_velocity_first_order,
                                 karnopp_velocity, karnopp_velocity_first_order, play)
from eha.models.hf import dither_samples, run_hf
from eha.models.lf import _lf_loop, run_lf
from eha.models.params import LF, resolve
from eha.models.simulate import command_on_grid, grid, simulate

DT_OVER_M = 1e-5 / 20.0  # nominal jack: DT / MJ


# ---------------------------------------------------------------- friction laws (docs/model.md §3)

@pytest.mark.parametrize("law", [borello_velocity, borello_velocity_first_order])
def test_borello_sticks_below_static_force(law):
    assert law(0.0, 399.0, 200.0, 400.0, DT_OVER_M) == 0.0
    assert law(0.0, -400.0, 200.0, 400.0, DT_OVER_M) == 0.0


def test_borello_breaks_away_above_static_force_against_dynamic_friction():
    # From rest, a force of 401 N > FS = 400 N accelerates the mass by (401 - 200)/m.
    v = borello_velocity(0.0, 401.0, 200.0, 400.0, DT_OVER_M)
    assert v == pytest.approx(201.0 * DT_OVER_M, rel=1e-12)
    v = borello_velocity(0.0, -401.0, 200.0, 400.0, DT_OVER_M)
    assert v == pytest.approx(-201.0 * DT_OVER_M, rel=1e-12)


def test_borello_moving_body_feels_dynamic_friction_and_stops_at_reversal():
    v = borello_velocity(1e-3, 0.0, 200.0, 400.0, DT_OVER_M)
    assert v == pytest.approx(1e-3 - 200.0 * DT_OVER_M, rel=1e-12)
    # A braking force large enough to reverse the velocity in one step leaves it stuck.
    assert borello_velocity(1e-5, -1e4, 200.0, 400.0, DT_OVER_M) == 0.0
    assert borello_velocity(-1e-5, 1e4, 200.0, 400.0, DT_OVER_M) == 0.0


def test_borello_first_order_keeps_moving_above_dynamic_force_and_stops_below():
    inv_c = 1.0 / 1000.0
    assert borello_velocity_first_order(1e-3, 300.0, 200.0, 400.0, inv_c) == pytest.approx(0.1)
    assert borello_velocity_first_order(1e-3, 150.0, 200.0, 400.0, inv_c) == 0.0
    assert borello_velocity_first_order(-1e-3, -300.0, 200.0, 400.0, inv_c) == pytest.approx(-0.1)


def test_karnopp_dead_band_sticks_and_outside_uses_velocity_sign():
    eps = 1e-5
    assert karnopp_velocity(5e-6, 300.0, 200.0, 400.0, eps, DT_OVER_M) == 0.0
    v = karnopp_velocity(5e-6, 500.0, 200.0, 400.0, eps, DT_OVER_M)
    assert v == pytest.approx(5e-6 + 300.0 * DT_OVER_M, rel=1e-12)
    # Outside the band friction opposes the velocity even if the force pushes the other way.
    v = karnopp_velocity(1e-3, -50.0, 200.0, 400.0, eps, DT_OVER_M)
    assert v == pytest.approx(1e-3 - 250.0 * DT_OVER_M, rel=1e-12)
    assert karnopp_velocity_first_order(0.0, 300.0, 200.0, 400.0, eps, 1e-3) == 0.0
    assert karnopp_velocity_first_order(1.0, 300.0, 200.0, 400.0, eps, 1e-3) == pytest.approx(0.1)


def test_jack_end_stop_holds_the_jack_while_pushed():
    # XJM = 2 mm below a 1 cm step: the jack must stop exactly there with zero velocity.
    tr = simulate("hf", "step_1cm", {"XJM": 2e-3}, t_end=0.2)
    assert tr["xj"].max() == pytest.approx(2e-3, abs=1e-15)
    assert np.all(tr["dxj"][tr["xj"] >= 2e-3] == 0.0)


def test_spool_end_stop_limits_the_spool():
    tr = simulate("hf", "step_1cm", t_end=0.1)
    assert np.abs(tr["xs"]).max() == pytest.approx(0.6e-3, abs=1e-15)


# ---------------------------------------------------------------- play operator

def test_play_operator_on_a_triangle_wave():
    # Input up 0 -> 1 then back down: output follows 0.1 behind, holds for 2*0.1 at reversal.
    h = 0.1
    x = np.concatenate([np.linspace(0, 1, 101), np.linspace(1, 0, 101)[1:]])
    y = np.empty_like(x)
    prev = 0.0
    for i, xi in enumerate(x):
        prev = play(xi, prev, h)
        y[i] = prev
    up = x[:101] >= h
    np.testing.assert_allclose(y[:101][up], x[:101][up] - h, atol=1e-12)
    assert np.all(y[:101][~up] == 0.0)
    down = x[101:]
    held = down >= 1.0 - 2 * h - 1e-12
    np.testing.assert_allclose(y[101:][held], 1.0 - h, atol=1e-12)
    np.testing.assert_allclose(y[101:][~held], down[~held] + h, atol=1e-12)
    assert np.all(np.abs(x - y) <= h + 1e-12)


def test_dithered_play_is_the_expected_play_of_a_noisy_input():
    """dithered_play against a Monte-Carlo mean of the play over 200 000 Gaussian draws (its
    definition, one step from a given output: agreement to 5 standard errors); it is the
    play as sigma -> 0 and passes the input through at zero width."""
    from eha.models.friction import dithered_play, play

    rng = np.random.default_rng(0)
    d = rng.normal(0.0, 1.0, 200_000)
    for x, y, h, sigma in [(0.0, 0.0, 0.2, 0.1), (0.25, 0.0, 0.2, 0.1), (-0.5, 0.1, 0.2, 0.3),
                           (1.0, 0.0, 0.05, 0.5)]:
        mc = np.array([play(x + sigma * di, y, h) for di in d[:20_000]])
        mc = np.concatenate([mc, np.clip(y, x + sigma * d[20_000:] - h,
                                         x + sigma * d[20_000:] + h)])
        assert dithered_play(x, y, h, sigma) == pytest.approx(
            mc.mean(), abs=5 * mc.std() / np.sqrt(mc.size) + 1e-12)
        assert dithered_play(x, y, h, 1e-9) == pytest.approx(play(x, y, h), abs=1e-8)
        assert dithered_play(x, y, 0.0, sigma) == pytest.approx(x, abs=1e-12)


@pytest.mark.parametrize("command", ["steps_1mm_like", "mixed"])
def test_lf_dithered_hysteresis_follows_the_hf_ensemble_mean(command):
    """The HF's dither (a fresh Gaussian current every 1 ms, 0.01 mA) acts on a 0.2 mA
    torque-motor hysteresis: one HF record differs from the mean of many (other dither
    seeds) by 1.2 µm RMS on these steps, 2.5 µm on `mixed`. The LF with the mean-field
    dithered play, at the HF's values (structure in), is within 2 µm of the mean of 16 HF
    records (whose own scatter is ~0.6 µm); with a plain play (dither_ma 0) it is more than 3x
    as far (measured: 1.23 and 0.74 µm vs 27.9 and 5.2 µm)."""
    from eha.models.commands import array_command

    if command == "steps_1mm_like":   # held 1 kHz steps within +-1 mm, as the FP bench's
        t = np.arange(1001) * 1e-3
        values = np.zeros_like(t)
        for start, level in [(120, 6e-4), (270, -4e-4), (410, 9e-4), (550, 1e-4),
                             (700, -8e-4), (840, 3e-4)]:
            values[start:] = level
        command = array_command(t, values, name="steps", hold="zoh")
    truth = {"BKL": 1e-4, "FDJ": 800.0, "His": 0.2}
    mean = np.mean([simulate("hf", command, truth, t_end=1.0, seed=s)["xu"]
                    for s in range(16)], axis=0)
    lf = {**truth, "orifice_law": 1.0, "SNF": 2513.0, "ZF": 0.6, "Clk": 1e-13}
    dithered = simulate("lf", command, lf, t_end=1.0)["xu"]
    plain = simulate("lf", command, {**lf, "dither_ma": 0.0}, t_end=1.0)["xu"]

    def rmse(a):
        return float(np.sqrt(np.mean((a - mean) ** 2)))

    assert rmse(dithered) < 2e-6
    assert rmse(plain) > 3 * rmse(dithered)


def test_output_backlash_is_a_dead_zone_of_width_bkl():
    bkl = 1e-3
    tr = simulate("hf", "sine", {"BKL": bkl}, t_end=0.4)
    gap = tr["xj"] - tr.xu
    assert np.abs(gap).max() == pytest.approx(bkl / 2, rel=1e-9)


# ---------------------------------------------------------------- kernels vs pure Python

def _short_run(model, command="chirp_1mm", overrides=None, t_end=0.01):
    p = resolve(model, overrides or {})
    spo, n_out, ts = grid(p, t_end)
    com = command_on_grid(command, ts)
    return p.to_array(), com, spo, np.empty((n_out, len(OUTPUTS))), p


# fastmath lets LLVM reassociate, so the twins agree to rounding, not bit for bit: 1e-9
# relative (plus 1e-15 absolute near zero) is ~1e6 ulps of slack over 1000 steps.
RTOL, ATOL = 1e-9, 1e-15


def test_hf_kernel_equals_its_py_func():
    vec, com, spo, out, p = _short_run("hf", "step_1cm", {"BKL": 2e-4, "His": 0.04,
                                                         "gioco": 1e-6, "GAI": 100.0})
    dith = dither_samples(0.01, out.shape[0] - 1, 3)
    out_py = out.copy()
    run_hf(vec, com, dith, spo, out)
    run_hf.py_func(vec, com, dith, spo, out_py)
    np.testing.assert_allclose(out, out_py, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("switches", [(False, False), (True, True)])
def test_lf_kernel_equals_its_py_func(switches):
    orifice, flapper = switches
    vec, com, spo, out, p = _short_run("lf", "step_1cm", {
        "BKL": 2e-4, "orifice_law": float(orifice), "SNF": 2513.0 if flapper else 0.0,
        "Clk": 1e-13, "FRC": 100.0, "Kaer": 1e4, "Ofs": 0.1, "His": 0.04})
    assert p.dither_ma > 0          # the hysteresis is dithered: both plays run
    out_py = out.copy()
    run_lf(vec, com, spo, out)
    _lf_loop.py_func(vec, com, spo, out_py, orifice, flapper)
    np.testing.assert_allclose(out, out_py, rtol=RTOL, atol=ATOL)


def _mixed_batch(n=13, t_end=0.2):
    """``n`` LF parameter rows with every structural switch setting and dithered hysteresis."""
    rng = np.random.default_rng(7)
    rows = []
    for j in range(n):
        p = resolve("lf", {"BKL": rng.uniform(0, 4e-4), "FDJ": rng.uniform(100, 3000),
                           "orifice_law": float(j % 2), "SNF": 2513.0 if j % 3 else 0.0,
                           "His": 0.05 if j % 4 == 0 else 0.0, "FRC": rng.uniform(0, 2000),
                           "Clk": 1e-13 * (j % 5)})
        rows.append(p.to_array())
    spo, n_out, ts = grid(p, t_end)
    return np.array(rows), command_on_grid("mixed", ts), spo, n_out


def test_lf_batch_equals_one_run_at_a_time():
    # the batch integrates its rows interleaved in groups (eha.models.lf._lf_group); each
    # row is the one-run kernel's, to rounding (fastmath may contract the two differently:
    # measured 3.5e-18 m on xu, 1e-15 relative), whatever the switches of the other rows
    from eha.models.lf import run_lf_batch

    rows, com, spo, n_out = _mixed_batch()
    out = np.empty((len(rows), n_out, len(OUTPUTS)))
    run_lf_batch(rows, com, spo, out)
    for j, row in enumerate(rows):
        one = np.empty((n_out, len(OUTPUTS)))
        run_lf(row, com, spo, one)
        np.testing.assert_allclose(out[j], one, rtol=RTOL, atol=ATOL)


def test_lf_batch_row_does_not_depend_on_its_group_or_the_threads():
    # bit for bit: a fit's objective values must not depend on the batch size or the cores
    import numba

    from eha.models.lf import batch_groups, run_lf_batch

    rows, com, spo, n_out = _mixed_batch()
    ref = np.empty((len(rows), n_out, len(OUTPUTS)))
    run_lf_batch(rows, com, spo, ref)
    assert len(batch_groups(rows, 2, 8)[1]) > 2          # several groups of several rows
    threads = numba.get_num_threads()
    try:
        # every thread of the pool, whatever the test process uses (one under xdist)
        for t in sorted({1, numba.config.NUMBA_NUM_THREADS}):
            numba.set_num_threads(t)
            for sub in (slice(0, 1), slice(4, 5), slice(0, 5), slice(3, 13)):
                out = np.empty((len(rows[sub]), n_out, len(OUTPUTS)))
                run_lf_batch(np.ascontiguousarray(rows[sub]), com, spo, out)
                assert np.array_equal(out, ref[sub])
    finally:
        numba.set_num_threads(threads)


def test_kernels_equal_a_fully_interpreted_run(tmp_path):
    # NUMBA_DISABLE_JIT runs every helper (friction, play) as plain Python too.
    code = (
        "import json, sys, numpy as np\n"
        "from eha.models.simulate import simulate\n"
        "out = {m: simulate(m, 'mixed', {'BKL': 1e-4, 'FDJ': 800}, t_end=0.005).data.tolist()"
        " for m in ('hf', 'lf')}\n"
        "json.dump(out, open(sys.argv[1], 'w'))\n")
    path = tmp_path / "interp.json"
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, env=env)
    interp = json.loads(path.read_text())
    for model in ("hf", "lf"):
        jit = simulate(model, "mixed", {"BKL": 1e-4, "FDJ": 800}, t_end=0.005).data
        np.testing.assert_allclose(jit, np.array(interp[model]), rtol=RTOL, atol=ATOL)


# ---------------------------------------------------------------- traces

def test_trace_has_spec_columns_and_1khz_samples(tmp_path):
    from eha.campaigns.traces import read_trace, write_trace

    tr = simulate("lf", "ramp", {"BKL": 1e-4}, t_end=1.0, seed=5)
    assert len(tr) == 1001
    assert list(tr.to_pandas().columns) == list(OUTPUTS)
    np.testing.assert_allclose(tr.t, np.arange(1001) * 1e-3, atol=1e-12)
    path = write_trace(tr, tmp_path / "a" / "run.parquet")
    back = read_trace(path)
    np.testing.assert_array_equal(back.data, tr.data)
    assert back.meta["params"] == {"BKL": 1e-4} and back.meta["seed"] == 5
    assert not list(path.parent.glob("*.tmp"))


def test_same_seed_same_hf_trace_other_seed_differs():
    a = simulate("hf", "chirp_1mm", t_end=0.3, seed=11)
    b = simulate("hf", "chirp_1mm", t_end=0.3, seed=11)
    c = simulate("hf", "chirp_1mm", t_end=0.3, seed=12)
    np.testing.assert_array_equal(a.data, b.data)
    assert np.abs(a["cor"] - c["cor"]).max() > 1e-4  # dither std is 0.01 mA


# ---------------------------------------------------------------- thesis facts (chapter 5)

@pytest.mark.parametrize("command", NOMINAL_COMMANDS)
def test_nominal_lf_matches_hf(command):
    # Issue 2: RMSE of xu below 2 % of the command peak (thesis: "almost indistinguishable").
    hf = simulate("hf", command)
    lf = simulate("lf", command)
    peak = np.abs(hf["com"]).max()
    assert np.sqrt(np.mean((hf.xu - lf.xu) ** 2)) < 0.02 * peak


def _settling_time(tr, band=0.02):
    target = tr["com"][-1]
    outside = np.nonzero(np.abs(tr.xu - target) > band * abs(target))[0]
    return tr.t[outside[-1] + 1]


def test_one_cm_step_saturates_spool_and_settles_later_than_one_mm():
    small = simulate("hf", "step_1mm", t_end=0.5)
    large = simulate("hf", "step_1cm", t_end=0.5)
    assert np.abs(large["xs"]).max() == pytest.approx(0.6e-3)  # at the end stop XSM
    assert np.abs(small["xs"]).max() < 0.6e-3
    assert _settling_time(large) > _settling_time(small) + 0.01


def test_p12_grows_in_proportion_to_jack_friction():
    # On a ramp the jack slides at constant speed, so AJ*P12 ≈ FDJ + CJ*v (force balance).
    p12 = {}
    for fdj in (800.0, 3200.0):
        tr = simulate("hf", "ramp", {"FDJ": fdj}, t_end=0.6)
        sliding = (tr.t > 0.3)
        p12[fdj] = np.median(tr["p12"][sliding])
        v = np.median(tr["dxj"][sliding])
        assert p12[fdj] * 8e-4 == pytest.approx(fdj + 50.0 * v, rel=0.05)
    assert p12[3200.0] / p12[800.0] == pytest.approx(4.0, rel=0.05)


def _delay_ms(tr, max_ms=150):
    """Delay of xu behind the command [ms]: the shift that best aligns them (least squares)."""
    c, x = tr["com"], tr.xu
    errs = [np.mean((x[k:] - c[:len(c) - k]) ** 2) for k in range(max_ms)]
    return int(np.argmin(errs))


def test_backlash_adds_lag_and_friction_adds_lag():
    # Thesis ch. 5: backlash makes the surface lag; raising FDJ adds a lag. On the 1 mm chirp
    # the nominal delay is ~7 ms; a 1 mm backlash (as wide as the command) must add >= 3 ms,
    # i.e. 3 samples, well above the 1-sample resolution of the measure.
    base = _delay_ms(simulate("hf", "chirp_1mm"))
    assert _delay_ms(simulate("hf", "chirp_1mm", {"BKL": 1e-3})) >= base + 3
    assert _delay_ms(simulate("hf", "chirp_1mm", {"FDJ": 6400})) >= base + 3


def test_chirp_jack_sticks_at_reversals():
    tr = simulate("hf", "chirp_1mm", {"FDJ": 800})
    com = tr["com"]
    reversals = np.nonzero(np.diff(np.sign(np.diff(com))) != 0)[0]
    stuck = tr["dxj"] == 0.0
    hits = sum(stuck[r:r + 40].any() for r in reversals if r + 40 < len(tr))
    assert hits >= 0.9 * len([r for r in reversals if r + 40 < len(tr)])


# ---------------------------------------------------------------- LF effects as data

def test_lf_orifice_law_and_leakage_bring_lf_closer_to_hf():
    hf = simulate("hf", "step_1cm")
    plain = simulate("lf", "step_1cm")
    aug = simulate("lf", "step_1cm", {"orifice_law": 1.0, "Clk": 1e-13, "SNF": 2513.0})
    err = lambda tr: np.sqrt(np.mean((tr.xu - hf.xu) ** 2))  # noqa: E731
    assert err(aug) < 0.5 * err(plain)


def test_lf_external_load_hinge_and_offset_move_the_equilibrium():
    base = simulate("lf", "step_1mm", t_end=0.5)
    load = simulate("lf", "step_1mm", {"FRC": 2000.0}, t_end=0.5)
    hinge = simulate("lf", "step_1mm", {"Kaer": 2e7}, t_end=0.5)
    offset = simulate("lf", "step_1mm", {"Ofs": 0.5}, t_end=0.5)
    assert load.xu[-1] < base.xu[-1] - 1e-6
    assert hinge.xu[-1] < base.xu[-1] - 1e-6
    # Offset current Ofs = 0.5 mA is cancelled by a position error of Ofs/GAP = 50 µm.
    assert offset.xu[-1] - base.xu[-1] == pytest.approx(0.5 / 1e4, rel=0.2)


def test_lf_sensor_effects_shape_the_recorded_position_only():
    base = simulate("lf", "ramp", t_end=0.3)
    biased = simulate("lf", "ramp", {"sensor_bias": 1e-4}, t_end=0.3)
    np.testing.assert_allclose(biased.xu - base.xu, 1e-4, atol=1e-15)
    np.testing.assert_array_equal(biased["xj"], base["xj"])


def test_lf_parameter_vector_order_matches_enum():
    p = resolve("lf", {"BKL": 3e-4, "FDJ": 999.0})
    vec = p.to_array()
    assert vec[LF.BKL] == 3e-4 and vec[LF.FDJ] == 999.0


# ---------------------------------------------------------------- commands

def test_mixed_command_is_the_eha_dat_formula():
    t = np.array([0.1, 0.3, 0.5, 0.65, 0.8])
    expected = [0.003, 0.009, 0.005 + 0.004 * np.sin(2 * np.pi / 0.35 * 0.2 + np.pi / 2),
                0.005 + 0.004 * np.sin(2 * np.pi / 0.35 * 0.35 + np.pi / 2),
                0.005 + 0.004 * np.sin(3 * np.pi / 0.35 * 0.15 + np.pi / 2)]
    np.testing.assert_allclose(make_command("mixed").sample(t), expected, rtol=1e-12)


def test_chirp_amplitude_falls_and_test_sequence_levels():
    c = make_command("chirp_1cm")
    t = np.linspace(0, 1, 100001)
    y = c.sample(t)
    assert np.abs(y[t < 0.5]).max() > np.abs(y[t > 0.5]).max()
    assert y[-1] == pytest.approx(0.0, abs=1e-15)
    s = make_command("test").sample(np.array([0.005, 0.1, 0.3, 0.5, 0.6]))
    np.testing.assert_allclose(s, [0.0, 3e-3, 0.0, 1e-3, 3e-3], atol=1e-15)


def test_command_parameters_override_and_validate():
    from eha.models.commands import CommandError, array_command

    assert make_command("step_1mm", A=2e-3).sample(np.array([1.0]))[0] == 2e-3
    with pytest.raises(CommandError, match="A=5 is out of range"):
        make_command("step_1mm", A=5)
    with pytest.raises(CommandError, match="unknown parameter 'B'"):
        make_command("step_1mm", B=1)
    with pytest.raises(CommandError, match="strictly increasing"):
        array_command(np.array([0.0, 0.0, 1.0]), np.zeros(3))
    with pytest.raises(CommandError, match="finite"):
        array_command(np.array([0.0, 0.5, 1.0]), np.array([0, np.nan, 0]))


# ---------------------------------------------------------------- parameters

def test_every_parameter_is_declared_with_unit_and_range_containing_its_nominal():
    from eha.models.params import PARAMETERS, fault_names

    for p in PARAMETERS:
        assert p.unit and p.lo <= p.nominal <= p.hi, p.name
        assert p.lo <= p.nominal_for("lf") <= p.hi, p.name
    assert set(fault_names()) == {"His", "GM", "Ofs", "gioco", "Kintas", "GP", "Clk", "FSS",
                                  "FDJ", "BKL"}


@pytest.mark.parametrize("overrides, message", [
    ({"BKL": 1.0}, "BKL=1 is out of range; allowed range [0, 0.1] m"),
    ({"FOO": 1.0}, "FOO: unknown parameter"),
    ({"fdj": 1.0}, "did you mean FDJ"),
    ({"FDJ": float("nan")}, "FDJ=nan is out of range"),
    ({"eps": 1e-5}, "eps: not a parameter of the HF model"),
    ({"XJ0": 0.5}, "XJ0=0.5 is out of range"),
])
def test_bad_parameters_are_rejected_in_one_line(overrides, message):
    from eha.models.params import ParameterError

    with pytest.raises(ParameterError) as info:
        resolve("hf", overrides)
    assert message in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("name", ["sine", "chirp_1mm", "chirp_1cm", "mixed", "test"])
def test_grid_recurrence_equals_direct_sin(name):
    # The rotation recurrence re-anchors every 64 samples: agreement to 1e-14 m (a few ulps of
    # the phase) over 10 s of 1e-5 s steps.
    t = np.arange(1_000_001) * 1e-5
    c = make_command(name)
    np.testing.assert_allclose(c.sample(t, uniform=True), c.sample(t), rtol=0, atol=1e-14)


@pytest.mark.parametrize("model", ["hf", "lf"])
def test_supply_pressure_law_sets_the_no_load_flow(model):
    """docs/model.md §2, the supply-pressure law: with the listing's XSS = PSR0/GP (XSSK 0)
    the no-load flow is GQ·XS·PSR/PSR0, so a 30 % lower supply slows the jack (on the step's
    rising edge the closed loop partly makes up for it: 21 % slower, measured; asserted: more
    than 15 %); with the text's XSS = PSR/GP (XSSK 1) the no-load flow is GQ·XS whatever the
    supply: the same peak speed within 3 % (no jack friction; the spool's dynamics are the
    same at both pressures)."""
    extra = {"orifice_law": 1.0} if model == "lf" else {}

    def peak_speed(**p):
        trace = simulate(model, "step", {**extra, "FDJ": 0.0, **p}, t_end=0.1, seed=0)
        return float(np.max(np.abs(trace["dxj"])))

    nominal = peak_speed()
    listing = peak_speed(PSR=1.4e7, XSSK=0.0)
    text = peak_speed(PSR=1.4e7, XSSK=1.0)
    assert listing / nominal < 0.85
    assert text / nominal == pytest.approx(1.0, rel=0.03)
