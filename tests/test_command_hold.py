"""Measured commands held between samples (a digital controller) or interpolated:
``--command-hold zoh|linear|auto`` of eha explain and eha fdi --data."""

import json

import numpy as np
import pytest

from eha.models.commands import array_command, as_command
from eha.identification.measured import detect_hold, from_arrays, load, synthetic_record

from helpers import error_line, invoke_eha

GRID = np.arange(1001) * 1e-3


def step_sequence(seed=0, n_steps=6, amplitude=5e-3):
    """Random steps at sample instants, held between them (a controller's output)."""
    rng = np.random.default_rng(seed)
    values = np.zeros(GRID.size)
    for k in np.sort(rng.choice(np.arange(50, 950), n_steps, replace=False)):
        values[k:] = rng.uniform(-amplitude, amplitude)
    return values


def test_a_held_command_steps_at_its_sample_instant_and_a_linear_one_a_sample_early():
    t = np.array([0.0, 1e-3, 2e-3, 3e-3])
    v = np.array([0.0, 0.0, 1.0, 1.0])
    fine = np.arange(31) * 1e-4          # an integration grid 10x finer
    held = array_command(t, v, hold="zoh").sample(fine)
    linear = array_command(t, v).sample(fine)
    # held: 0 up to 2 ms, 1 from 2 ms on (k*1e-4 rounding must not move the step)
    assert np.all(held[fine < 2e-3 - 1e-9] == 0.0) and np.all(held[fine >= 2e-3 - 1e-9] == 1.0)
    # linear: already half-way at 1.5 ms
    assert linear[15] == pytest.approx(0.5)


@pytest.mark.parametrize("values, expected", [
    (step_sequence(), "zoh"),
    (as_command("test").sample(GRID), "zoh"),            # steps between flat runs
    (as_command("sine").sample(GRID), "linear"),          # changes at every sample
    (as_command("chirp_1cm").sample(GRID), "linear"),
    (as_command("ramp").sample(GRID), "linear"),
    (as_command("step_1cm").sample(GRID), "linear"),      # constant: nothing to tell
    (np.sin(2 * np.pi * 5 * GRID)[(np.arange(GRID.size) // 4) * 4], "zoh"),  # 250 Hz DAC
])
def test_auto_detects_a_held_command(values, expected):
    assert detect_hold(values)[0] == expected


def test_the_reading_records_how_the_command_was_rebuilt():
    values = step_sequence(1)
    xu = np.zeros_like(values)
    auto = from_arrays(GRID, values, xu, source="r")
    assert auto.info["command_hold"] == "zoh" and "held" in auto.info["command_hold_reason"]
    forced = from_arrays(GRID, values, xu, source="r", command_hold="linear")
    assert forced.info["command_hold"] == "linear" and forced.command.hold == "linear"


def test_a_synthetic_record_is_driven_the_way_it_is_read_back(tmp_path):
    cmd = array_command(GRID, step_sequence(2), name="steps")
    df = synthetic_record(cmd, {"BKL": 1e-4}, t_end=1.0, noise=0.0, seed=0)
    df.to_csv(tmp_path / "r.csv", index=False)
    rec = load(tmp_path / "r.csv")
    from eha.models.simulate import simulate

    again = simulate("hf", rec.command, {"BKL": 1e-4}, t_end=1.0, seed=0)
    assert rec.command.hold == "zoh"
    np.testing.assert_allclose(again.xu, rec.xu, atol=1e-12)


@pytest.mark.parametrize("args", [
    ["explain", "{rec}", "--command-hold", "cubic", "--results", "{res}"],
    ["fdi", "--data", "{rec}", "--command-hold", "hold", "--json", "{res}/f.json"],
    ["fdi", "--command", "sine", "--command-hold", "zoh", "--json", "{res}/f.json"]])
def test_a_bad_command_hold_is_one_line_and_exit_2(tmp_path, args):
    rec = tmp_path / "r.csv"
    synthetic_record("sine", {}, t_end=0.2, noise=1e-6).to_csv(rec, index=False)
    line = error_line(invoke_eha(*[a.format(rec=rec, res=tmp_path / "res") for a in args]), 2)
    assert "--command-hold" in line
    assert not (tmp_path / "res").exists()


@pytest.mark.slow   # two GA identifications
def test_fdi_on_a_held_record_fits_better_read_held_and_says_so(tmp_path):
    cmd = array_command(GRID, step_sequence(3), name="steps")
    rec = tmp_path / "r.csv"
    synthetic_record(cmd, {"BKL": 1e-4, "FDJ": 800.0}, t_end=1.0, noise=1e-6,
                     seed=1).to_csv(rec, index=False)
    out = {}
    for hold in ("zoh", "linear"):
        proc = invoke_eha("fdi", "--data", str(rec), "--command-hold", hold, "--json",
                          str(tmp_path / f"{hold}.json"))
        assert proc.returncode == 0, proc.stderr
        out[hold] = json.loads((tmp_path / f"{hold}.json").read_text())
    assert out["zoh"]["command_hold"] == "zoh" and out["linear"]["command_hold"] == "linear"
    # driven a sample early at every step, the linear reading fits worse
    assert out["zoh"]["objective"] < 0.8 * out["linear"]["objective"]
