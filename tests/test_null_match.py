"""A user's healthy null must match the record (issue 43): healthy records of another
command, length, sampling or noise class are refused with one line naming the healthy
record and the field, before any fit; matching ones pass."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import error_line, files_under, invoke_eha

from eha.explain import DEFAULT_FAULT_BOUNDS, LoopSettings
from eha.explain.null import NullError, record_mismatch, records_null
from eha.identification.measured import load


def write(path, t_end=1.0, rate=1000.0, command="chirp", noise=2e-6, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(t_end * rate)) + 1) / rate
    if command == "chirp":
        com = 1e-2 * np.sin(2 * np.pi * (1 + 4 * t) * t)
    else:
        com = np.where(t >= 0.1, 1e-3, 0.0)
    xu = np.concatenate([[0.0] * 5, com[:-5]]) + rng.normal(0, noise, t.size)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("t,com,xu\n" + "\n".join(f"{a:.6f},{b:.9g},{c:.9g}"
                                              for a, b, c in zip(t, com, xu)) + "\n")
    return path


@pytest.mark.parametrize("kw, field", [
    ({"command": "step"}, "command differs"),
    ({"t_end": 0.6}, "length 0.6 s, the record 1 s"),
    ({"rate": 250.0}, "sampling 250 Hz, the record 1000 Hz"),
    ({"rate": 2000.0}, "sampling 2000 Hz, the record 1000 Hz"),
    ({"noise": 2e-5}, "noise"),
])
def test_a_healthy_folder_unlike_the_record_is_refused_naming_record_and_field(tmp_path, kw,
                                                                               field):
    record = load(write(tmp_path / "rec.csv"))
    for k in range(5):
        write(tmp_path / "h" / f"h{k}.csv", seed=k + 1, **kw)
    with pytest.raises(NullError, match=field) as info:
        records_null(tmp_path / "h", DEFAULT_FAULT_BOUNDS, ["offset"], LoopSettings(),
                     record=record)
    assert "h0.csv" in str(info.value) and "rec.csv" in str(info.value)


def test_one_second_records_are_not_the_null_of_a_long_record(tmp_path):
    record = load(write(tmp_path / "long.csv", t_end=20.0))
    healthy = load(write(tmp_path / "h.csv", t_end=1.0))
    assert record_mismatch(healthy, record).startswith("length 1 s, the record 20 s")


def test_records_of_the_same_test_match(tmp_path):
    record = load(write(tmp_path / "rec.csv"))
    for k in range(3):
        assert record_mismatch(load(write(tmp_path / f"h{k}.csv", seed=k + 1,
                                          noise=(1.5e-6, 2e-6, 3e-6)[k])), record) is None


def test_cli_refuses_a_mismatched_healthy_folder_before_any_work(tmp_path):
    rec = write(tmp_path / "rec.csv")
    for k in range(5):
        write(tmp_path / "h" / f"h{k}.csv", seed=k + 1, command="step")
    before = files_under(tmp_path)
    line = error_line(invoke_eha("explain", rec, "--healthy", tmp_path / "h", "--results",
                                 tmp_path / "res", "--no-progress"), 2)
    assert "--healthy" in line and "h0.csv" in line and "command differs" in line
    assert "rec.csv" in line
    assert files_under(tmp_path) == before
