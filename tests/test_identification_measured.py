"""Measured-data input (docs/model.md §8): aliases, file types, validation messages, 1 kHz
resampling."""

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from eha.cli import app
from eha.identification.measured import (MIN_SAMPLES, MeasuredDataError, from_arrays, load,
                                         match_columns, synthetic_record)


def _frame(rate=1000.0, duration=0.3, t0=0.0, **rename):
    t = t0 + np.arange(int(round(duration * rate)) + 1) / rate
    df = pd.DataFrame({"t": t, "com": 2e-3 * np.sin(8 * t), "xu": 2e-3 * np.sin(8 * t - 0.1),
                       "p12": 1e6 * np.cos(8 * t)})
    return df.rename(columns=rename)


@pytest.mark.parametrize("suffix,kw", [(".csv", {}), (".tsv", {"sep": "\t"}),
                                       (".txt", {"sep": ";"}), (".txt", {"sep": " "})])
def test_text_files_with_aliases_and_units(tmp_path, suffix, kw):
    df = _frame(**{"t": "Time [s]", "com": "Command (m)", "xu": "position", "p12": "dP"})
    path = tmp_path / f"rec{suffix}"
    if kw.get("sep") == " ":
        df.columns = ["time", "cmd", "pos", "p12"]
    path.write_text("# exported by a test bench\n" + df.to_csv(index=False, **kw))
    rec = load(path)
    assert len(rec) == 301 and rec.t[1] == pytest.approx(1e-3)
    np.testing.assert_allclose(rec.xu, df.iloc[:, 2].to_numpy(), atol=1e-12)
    assert rec.p12 is not None and rec.xs is None
    assert rec.info["resampled"] is False


def test_parquet_and_resampling_from_other_rates(tmp_path):
    fast = _frame(rate=5000.0, duration=0.2, t0=12.5)   # starts at t = 12.5 s, 5 kHz
    fast.to_parquet(tmp_path / "fast.parquet")
    rec = load(tmp_path / "fast.parquet")
    assert len(rec) == 201 and rec.t[0] == 0.0 and rec.info["t0_s"] == 12.5
    assert rec.info["resampled"] and rec.info["period_s"] == pytest.approx(2e-4)
    np.testing.assert_allclose(rec.xu, 2e-3 * np.sin(8 * (rec.t + 12.5) - 0.1), atol=1e-9)
    slow = _frame(rate=250.0, duration=0.4)
    rec = from_arrays(slow.t, slow.com, slow.xu, source="slow")
    assert len(rec) == 401
    # linear interpolation of a smooth signal sampled at 250 Hz
    np.testing.assert_allclose(rec.xu, 2e-3 * np.sin(8 * rec.t - 0.1), atol=5e-7)  # h²/8·|f''|
    # the command keeps its own samples for the simulator
    assert rec.command.kind == "array" and rec.command.samples[0].size == slow.shape[0]


def _problems(**columns):
    with pytest.raises(MeasuredDataError) as info:
        from_arrays(**columns, source="rec.csv")
    return info.value.problems


def test_each_problem_is_one_clear_line():
    df = _frame()
    t, com, xu = df.t.to_numpy(), df.com.to_numpy(), df.xu.to_numpy()
    bad = xu.copy()
    bad[7] = np.nan
    bad[9] = np.inf
    (line,) = _problems(t=t, com=com, xu=bad)
    assert "column xu" in line and "2 value(s)" in line and "row 8" in line
    back = t.copy()
    back[20] = back[19]
    (line,) = _problems(t=back, com=com, xu=xu)
    assert "strictly increasing" in line and "row 21" in line
    gap = np.delete(t, np.arange(100, 110))
    (line,) = _problems(t=gap, com=np.delete(com, np.arange(100, 110)),
                        xu=np.delete(xu, np.arange(100, 110)))
    assert "irregular sampling" in line and "tolerance ±20 %" in line
    short = _problems(t=t[:10], com=com[:10], xu=xu[:10])
    assert f"at least {MIN_SAMPLES}" in short[0] and "at least 0.05 s" in short[1]
    (line,) = _problems(t=t, com=com, xu=xu * 1000)      # millimetres
    assert "[-0.2, 0.2] m" in line and "millimetres" in line
    (line,) = _problems(t=t, com=com, xu=xu, p12=np.full(t.size, 5e8))
    assert "column p12" in line and "Pa" in line
    lines = _problems(t=back, com=com * 1000, xu=bad)      # several problems, one line each
    assert len(lines) == 3
    assert _problems(t=t, com=com[:-1], xu=xu)[0].startswith("columns have different lengths")


def test_missing_columns_and_files(tmp_path):
    mapping, problems = match_columns(["time", "position", "Position"])
    assert any("given twice" in p for p in problems)
    assert any(p.startswith("column com: missing") for p in problems)
    (tmp_path / "a.csv").write_text("time,foo\n0,1\n")
    with pytest.raises(MeasuredDataError, match="column com: missing.*column xu: missing"):
        load(tmp_path / "a.csv")
    with pytest.raises(MeasuredDataError, match="file not found"):
        load(tmp_path / "none.csv")
    (tmp_path / "a.xlsx").write_text("x")
    with pytest.raises(MeasuredDataError, match="unsupported file type"):
        load(tmp_path / "a.xlsx")
    (tmp_path / "text.csv").write_text("t,com,xu\n" + "0,0,abc\n" * 60)
    with pytest.raises(MeasuredDataError, match="not finite numbers"):
        load(tmp_path / "text.csv")


def test_synthetic_record_is_self_consistent(tmp_path):
    df = synthetic_record("step_1mm", {"FRC": 1000.0}, t_end=0.1, noise=1e-6, seed=3)
    again = synthetic_record("step_1mm", {"FRC": 1000.0}, t_end=0.1, noise=1e-6, seed=3)
    pd.testing.assert_frame_equal(df, again)
    assert list(df.columns) == ["t", "com", "xu", "p12", "xs"] and len(df) == 101
    df.to_csv(tmp_path / "s.csv", index=False)
    rec = load(tmp_path / "s.csv")
    np.testing.assert_allclose(rec.xu, df.xu.to_numpy())



def test_synthetic_positions_are_the_records_positions_in_one_batch(monkeypatch):
    """The change calibration's batch of HF runs: each row is exactly what the record of the
    same parameters and seed holds (bit for bit), across batches and on a held command."""
    from eha.identification import synthetic
    from eha.identification.synthetic import synthetic_positions

    monkeypatch.setattr(synthetic, "BATCH_RUNS", 2)          # three batches for five runs
    runs = [({}, 0), ({"BKL": 2e-5}, 7), ({"FDJ": 400.0}, 2**30 + 3), ({"GM": 0.01}, 4),
            ({"Ofs": 0.01}, 5)]
    for command in ("chirp_1cm", "step_1mm"):
        xs = synthetic_positions(command, [hf for hf, _ in runs], 0.2, 1e-6,
                                 [s for _, s in runs])
        assert xs.shape == (5, 201)
        for row, (hf, seed) in zip(xs, runs):
            want = synthetic_record(command, hf, t_end=0.2, noise=1e-6, seed=seed)["xu"]
            assert np.array_equal(row, want.to_numpy())

def test_cli_rejects_bad_data_and_writes_nothing(tmp_path):
    df = _frame()
    df.loc[5, "t"] = df.loc[4, "t"]
    df["xu"] *= 1000
    path = tmp_path / "bad.csv"
    df.to_csv(path, index=False)
    out, js, res = tmp_path / "out", tmp_path / "r.json", tmp_path / "results"
    result = CliRunner().invoke(app, ["explain", str(path), "--json", str(js), "--out", str(out),
                                      "--results", str(res), "--no-progress"])
    assert result.exit_code == 2
    lines = [ln for ln in result.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 2 and "strictly increasing" in lines[0] and "millimetres" in lines[1]
    assert not out.exists() and not js.exists() and not res.exists()
    result = CliRunner().invoke(app, ["explain", str(path), "--holdout", "0.2", "--validate",
                                      str(path), "--no-progress"])
    assert result.exit_code == 2 and "exclude each other" in result.output
