"""Command files (`t,com` CSV, eha design's output) wherever a command is named, named by their
content in run keys; bad files one line, exit 2, nothing written."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import error_line, invoke_eha
from eha.models.commands import (CommandError, command_label, load_command_file, make_command,
                                 pin_command, write_command_file)


def _file(path, com=None, t_end=0.5):
    t = np.round(np.arange(0.0, t_end + 5e-4, 1e-3), 6)
    com = 2e-3 * np.sin(2 * np.pi * 3 * t) if com is None else com
    return write_command_file(path, t, com, {"made_by": "test"})


def test_a_command_file_round_trips_and_is_named_by_its_content(tmp_path):
    path = _file(tmp_path / "probe.csv")
    cmd = make_command(str(path))
    t = np.array([0.0, 0.1, 0.25, 2.0])
    assert np.allclose(cmd.sample(t), [0.0, 2e-3 * np.sin(0.6 * np.pi),
                                       2e-3 * np.sin(1.5 * np.pi), cmd.samples[1][-1]])
    pinned = pin_command(str(path))
    assert pinned.startswith(str(path.resolve())) and "#sha=" in pinned
    assert command_label(str(path)) == cmd.name and cmd.name.startswith("probe-")
    assert make_command(pinned).name == cmd.name
    _file(path, com=np.zeros(501))                     # the same file, another command
    assert pin_command(str(path)) != pinned
    with pytest.raises(CommandError, match="changed since it was pinned"):
        make_command(pinned)


@pytest.mark.parametrize("text, message", [
    ("t,com\n0,0\n0.1,0\n0.1,1e-3\n", "data row 3: t must increase strictly"),
    ("t,com\n0,0\n0.1,nan\n", "data row 2: not a finite number"),
    ("t,com\n0,0\n0.1,0.5\n", "data row 2: com = 0.5 m is beyond the stroke; allowed range "
                              "[-0.2, 0.2] m"),
    ("t,com\n0.2,0\n0.3,0\n", "t must start at 0 s"),
    ("time,x\n0,0\n1,0\n", "header with the columns t and com"),
    ("t,com\n0,0\n", "at least 2 samples"),
    ("t,com\n0,0\n0.1,abc\n", "data row 2: expected 2 numbers"),
])
def test_a_bad_command_file_is_one_line(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(CommandError, match=message.replace("[", r"\[")):
        load_command_file(str(path))


def test_a_command_file_works_in_simulate_and_a_bad_one_exits_2(tmp_path):
    path = _file(tmp_path / "probe.csv")
    out = tmp_path / "sim.parquet"
    proc = invoke_eha("simulate", "--command", path, "--t-end", "0.5", "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert out.exists()
    bad = tmp_path / "bad.csv"
    bad.write_text("t,com\n0,0\n0.1,0.5\n")
    out2 = tmp_path / "sim2.parquet"
    proc = invoke_eha("simulate", "--command", bad, "--out", out2)
    assert "beyond the stroke" in error_line(proc, 2) and not out2.exists()
    proc = invoke_eha("simulate", "--command", tmp_path, "--out", out2)   # a folder: a name
    assert proc.returncode == 2 and not out2.exists()
    proc = invoke_eha("simulate", "--command", path, "--set", "BKL=1e-4", "--out", out2,
                      "--t-end", "0.2")
    assert proc.returncode == 0


def test_campaign_and_health_jobs_key_a_command_file_by_content(tmp_path):
    from eha.campaigns.files import build_campaign
    from eha.health.detection import health_jobs

    path = _file(tmp_path / "probe.csv")
    table = {"name": "cf", "models": ["lf"], "commands": [str(path)], "t_end": 0.5,
             "faults": {"nominal": True}}
    first = build_campaign(table).jobs[0].run_key
    problems: list[str] = []
    jobs = health_jobs({"commands": [str(path)], "actuators": 1}, problems)
    assert not problems and jobs[0]["columns"]["command"] == command_label(str(path))
    assert "#sha=" in jobs[0]["spec"]["command"]
    _file(path, com=np.zeros(501))
    assert build_campaign(table).jobs[0].run_key != first
