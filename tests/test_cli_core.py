"""CLI of the simulation core: simulate, params, commands (typer's runner, real files)."""

import subprocess
import sys

import pytest

from helpers import invoke_eha
from typer.testing import CliRunner

from eha.cli import app
from eha.campaigns.traces import read_trace

runner = CliRunner()


@pytest.mark.parametrize("model", ["hf", "lf"])
@pytest.mark.parametrize("command", ["step_1mm", "step_1cm", "ramp", "sine", "chirp_1mm",
                                     "chirp_1cm", "mixed", "test"])
def test_simulate_runs_every_preset_on_both_models(tmp_path, model, command):
    out = tmp_path / "t.parquet"
    res = runner.invoke(app, ["simulate", "--model", model, "--command", command, "--t-end",
                              "0.05", "--set", "BKL=1e-4", "--out", str(out)])
    assert res.exit_code == 0, res.output
    tr = read_trace(out)
    assert len(tr) == 51 and tr.meta["command"]["name"] == command


def test_simulate_writes_plot(tmp_path):
    png = tmp_path / "p.png"
    res = runner.invoke(app, ["simulate", "--command", "chirp_1mm", "--t-end", "0.1", "--out",
                              str(tmp_path / "t.parquet"), "--plot", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, message", [
    (["--set", "BKL=1"], "BKL=1 is out of range; allowed range [0, 0.1] m"),
    (["--set", "NOPE=1"], "NOPE: unknown parameter"),
    (["--set", "BKL"], "expected NAME=VALUE"),
    (["--set", "FDJ=abc"], "FDJ: value 'abc' is not a number"),
    (["--command", "square"], "unknown command 'square'"),
    (["--model", "mf"], "unknown model 'mf'"),
    (["--t-end", "0"], "t_end=0 is out of range"),
    (["--model", "lf", "--set", "GAI=0.1"], "GAI: not a parameter of the LF model"),
])
def test_simulate_bad_input_fails_in_one_line_and_writes_nothing(tmp_path, args, message):
    # in this process (typer's runner); the real process is checked once below
    out = tmp_path / "t.parquet"
    proc = invoke_eha("simulate", "--out", str(out), *args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr
    assert not out.exists() and not list(tmp_path.iterdir())


def test_bad_input_in_a_real_process_is_one_line_without_a_traceback(tmp_path):
    out = tmp_path / "t.parquet"
    proc = subprocess.run([sys.executable, "-m", "eha", "simulate", "--out", str(out),
                           "--set", "BKL=1"], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "BKL=1 is out of range; allowed range [0, 0.1] m" in lines[0], \
        lines
    assert not list(tmp_path.iterdir())


def test_params_and_commands_list_everything():
    res = runner.invoke(app, ["params"], env={"COLUMNS": "250"})
    assert res.exit_code == 0
    for name in ("BKL", "FDJ", "GAP", "Clk", "orifice_law"):
        assert name in res.output
    res = runner.invoke(app, ["commands"], env={"COLUMNS": "250"})
    assert res.exit_code == 0
    for name in ("step_1mm", "chirp_1cm", "mixed", "test"):
        assert name in res.output


def test_every_command_has_help_with_an_example():
    res = runner.invoke(app, ["--help"], env={"COLUMNS": "200"})
    names = [line.split()[1] for line in res.output.splitlines()
             if line.startswith("│ ") and line[2] != " "  # not a wrapped description
             and len(line.split()) > 2 and line.split()[1].isalpha()]
    assert "simulate" in names
    for name in names:
        sub = runner.invoke(app, [name, "--help"], env={"COLUMNS": "200"})
        assert sub.exit_code == 0
        assert "Example" in sub.output, name
