"""Records as users have them (issue 26, item 7): ``--columns SIGNAL=HEADER`` and ``--units``
of the commands that read a measured record, implemented in the loader
(:class:`eha.measured.RecordFile`, :func:`eha.measured.load`); and the CLI's one error
hierarchy (:mod:`eha.errors`)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from helpers import error_line, files_under, invoke_eha, run_eha

from eha.errors import EhaError, InputError
from eha.identification.measured import MeasuredDataError, RecordFile, load

USER_HEADER = {"t": "time_s", "com": "command_mm", "xu": "position_mm"}
COLUMNS = "t=time_s,com=command_mm,xu=position_mm"


def _record(path, header=USER_HEADER, scale=1e3, p12=None):
    """A 0.3 s, 1 kHz sine record; lengths multiplied by ``scale`` (1e3: millimetres)."""
    t = np.arange(301) * 1e-3
    com = 2e-3 * np.sin(2 * np.pi * 5 * t)
    frame = {header["t"]: t, header["com"]: com * scale, header["xu"]: 0.98 * com * scale}
    if p12 is not None:
        frame[p12] = 1e6 * np.cos(8 * t)
    pd.DataFrame(frame).to_csv(path, index=False)
    return path


# ----------------------------------------------------------------------------- the loader
def test_a_user_header_is_refused_without_columns_and_loads_with_them(tmp_path):
    path = _record(tmp_path / "rec.csv")
    with pytest.raises(MeasuredDataError) as err:
        load(path)
    assert any("column com: missing" in line and "`columns` com=HEADER" in line
               for line in err.value.lines())
    rec = load(path, columns=COLUMNS)          # the _mm suffix is the unit
    assert rec.com.max() == pytest.approx(2e-3, rel=1e-3)
    assert rec.xu.max() == pytest.approx(0.98 * 2e-3, rel=1e-3)
    same = load(RecordFile(path, {"t": "time_s", "com": "command_mm", "xu": "position_mm"}))
    np.testing.assert_array_equal(same.xu, rec.xu)


def test_units_apply_to_length_columns_without_a_unit_of_their_own(tmp_path):
    path = _record(tmp_path / "rec.csv", {"t": "t", "com": "cmd", "xu": "pos"})
    with pytest.raises(MeasuredDataError, match="millimetres.*`units` mm"):
        load(path)
    rec = load(path, units="mm")
    assert rec.xu.max() == pytest.approx(0.98 * 2e-3, rel=1e-3)
    um = _record(tmp_path / "um.csv", {"t": "t", "com": "cmd", "xu": "pos"}, scale=1e6)
    assert load(um, units="um").com.max() == pytest.approx(2e-3, rel=1e-3)
    # a unit in the header wins over --units
    marked = _record(tmp_path / "m.csv", {"t": "t", "com": "com [mm]", "xu": "xu [mm]"})
    assert load(marked, units="m").xu.max() == pytest.approx(0.98 * 2e-3, rel=1e-3)


def test_columns_map_any_header_and_leave_the_others_to_the_aliases(tmp_path):
    path = _record(tmp_path / "rec.csv", {"t": "t", "com": "setpoint", "xu": "LVDT 1"},
                   scale=1.0, p12="dP")
    rec = load(path, columns="xu=lvdt 1")      # case and spaces around are forgiven
    assert rec.p12 is not None and rec.xu.max() == pytest.approx(0.98 * 2e-3, rel=1e-3)


@pytest.mark.parametrize("kwargs, message", [
    ({"columns": "pos=position_mm"}, "`columns` pos=position_mm: unknown signal 'pos'"),
    ({"columns": "com=command_mm,xu=nope"}, "`columns` xu=nope: no column 'nope' in the file"),
    ({"columns": "com"}, "`columns` com=: no header"),
    ({"columns": "com=command_mm,com=position_mm"}, "com given twice"),
    ({"columns": "com=command_mm,xu=command_mm"}, "header 'command_mm' given for two signals"),
    ({"units": "inch"}, "`units` 'inch': allowed m, mm, um"),
])
def test_bad_columns_or_units_are_one_line_naming_the_option(tmp_path, kwargs, message):
    path = _record(tmp_path / "rec.csv")
    with pytest.raises(MeasuredDataError) as err:
        load(path, **{"columns": COLUMNS, **kwargs})
    assert any(message in line for line in err.value.lines()), err.value.lines()
    assert all("\n" not in line for line in err.value.lines())


# ----------------------------------------------------------------------------- the CLI
@pytest.mark.parametrize("command", [
    ["explain", "{rec}", "--results", "{res}", "--json", "{res}/x.json", "--no-progress"],
    ["fdi", "--data", "{rec}", "--json", "{res}/x.json"],
    ["health", "check", "{rec}", "--results", "{res}", "--json", "{res}/x.json",
     "--no-progress"],
])
@pytest.mark.parametrize("options, message", [
    (["--columns", "position=position_mm"], "--columns position=position_mm: unknown signal"),
    (["--columns", "t=time_s,com=command_mm,xu=pos"], "--columns xu=pos: no column 'pos'"),
    (["--columns", COLUMNS, "--units", "inch"], "--units 'inch': allowed m, mm, um"),
    ([], "column com: missing"),
])
def test_bad_columns_or_units_exit_2_in_one_line_and_write_nothing(tmp_path, command, options,
                                                                   message):
    rec = _record(tmp_path / "rec.csv")
    before = files_under(tmp_path)
    args = [a.format(rec=rec, res=tmp_path / "res") for a in command] + options
    proc = invoke_eha(*args)
    if not options:     # a missing column and a missing column: two lines, one a problem
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
    else:
        assert message in error_line(proc, 2)
    assert files_under(tmp_path) == before


def test_columns_and_units_need_a_record_in_fdi(tmp_path):
    line = error_line(invoke_eha("fdi", "--command", "ramp", "--units", "mm", "--json",
                                 tmp_path / "x.json"), 2)
    assert "only with --data" in line and not files_under(tmp_path)


def test_a_record_in_millimetres_loads_through_the_command_line(tmp_path):
    """Through the command line (in process): `eha fdi --data` on a time_s,command_mm,
    position_mm file with --columns identifies (least squares, one parameter: a second or
    two)."""
    rec = _record(tmp_path / "rec.csv")
    out = tmp_path / "fit.json"
    proc = invoke_eha("fdi", "--data", rec, "--columns", COLUMNS, "--fit", "FDJ", "--method",
                      "lm", "--json", out)
    assert proc.returncode == 0, proc.stderr
    assert "reference: " in proc.stdout and out.exists()
    proc = invoke_eha("fdi", "--data", rec, "--columns", "t=time_s,signal=command_mm", "--json",
                      tmp_path / "y.json")
    assert "unknown signal 'signal'" in error_line(proc, 2)
    assert not (tmp_path / "y.json").exists()


# ----------------------------------------------------------------------------- the errors
def test_the_library_errors_derive_from_one_hierarchy():
    from eha.campaigns.files import CampaignError
    from eha.campaigns.runner import CampaignChanged
    from eha.campaigns.store import StoreError, StoreWriteError
    from eha.models.commands import CommandError
    from eha.health.detection import DetectionError
    from eha.explain.settings import ExplainError
    from eha.identification.problem import FDIError
    from eha.prognostics.fleet import FleetError
    from eha.prognostics.manifest import ManifestError
    from eha.models.params import ParameterError
    from eha.prognostics.degradation import PrognosticsError
    from eha.reports.html import ReportError

    for cls in (CampaignError, CampaignChanged, CommandError, DetectionError, ExplainError,
                FDIError, FleetError, ManifestError, MeasuredDataError, ParameterError,
                PrognosticsError, ReportError):
        assert issubclass(cls, InputError) and issubclass(cls, ValueError), cls
    assert issubclass(StoreError, EhaError) and issubclass(StoreError, RuntimeError)
    assert StoreError.exit_code == 2 and StoreWriteError.exit_code == 1
    err = CampaignError(["a: 1: allowed [0, 0.5]", "b: missing"])
    assert err.lines() == ["a: 1: allowed [0, 0.5]", "b: missing"] and err.exit_code == 2
    rec = MeasuredDataError("r.csv", ["column t: missing", "column xu: missing"])
    assert rec.lines() == ["r.csv: column t: missing", "r.csv: column xu: missing"]
    assert str(rec) == "r.csv: column t: missing; column xu: missing"


def test_loop_settings_are_checked_in_one_place():
    """`eha explain` builds a LoopSettings: its problems are the CLI's lines."""
    from eha.explain.settings import ExplainError, LoopSettings

    with pytest.raises(ExplainError) as err:
        LoopSettings(min_gain=float("nan"), alpha=1.5)
    assert err.value.lines() == ["`min_gain` nan: allowed range [0, 1]",
                                 "`alpha` 1.5: allowed range (0, 1)"]
    assert LoopSettings().problems() == []


# ----------------------------------------------------------------------------- eha rul
RUL_COLUMNS = "t=time_s,com=command_mm,xu=lvdt"


def _rul_manifests(folder):
    """One actuator whose friction grows (FDJ 300, 700, 1100 N at cycles 0, 100, 200), its
    records twice: canonical (t, com, xu in m) and as a logger writes them (time_s, command_mm,
    lvdt in mm: the position's header declares no unit). The two hold the same numbers: the
    canonical file is the user's read back and scaled, as the loader does."""
    from eha.identification.measured import synthetic_record

    rows = {"canonical": [], "user": []}
    for i, (cycle, fdj) in enumerate([(0, 300.0), (100, 700.0), (200, 1100.0)]):
        run = synthetic_record("chirp_1cm", {"FDJ": fdj}, t_end=0.3, noise=1e-6, seed=i)
        pd.DataFrame({"time_s": run["t"], "command_mm": 1e3 * run["com"],
                      "lvdt": 1e3 * run["xu"]}).to_csv(folder / f"u{i}.csv", index=False)
        back = pd.read_csv(folder / f"u{i}.csv")
        pd.DataFrame({"t": back["time_s"], "com": 1e-3 * back["command_mm"],
                      "xu": 1e-3 * back["lvdt"]}).to_csv(folder / f"c{i}.csv", index=False)
        rows["canonical"].append(f"A1,{cycle},c{i}.csv")
        rows["user"].append(f"A1,{cycle},u{i}.csv")
    for name, lines in rows.items():
        (folder / f"{name}.csv").write_text("\n".join(["actuator,cycle,record", *lines]) + "\n")
    return folder / "canonical.csv", folder / "user.csv"


@pytest.mark.slow
def test_rul_reads_the_records_with_columns_and_units_like_canonical_ones(tmp_path):
    """`eha rul --columns --units` in a real process: the manifest of time_s,command_mm,lvdt
    records in millimetres gives the RUL of the same records with canonical headers in SI
    (the options travel with each record's job to the worker that reads it)."""
    import json

    canonical, user = _rul_manifests(tmp_path)
    common = ["--limit", "FDJ=1500", "--fit", "FDJ", "--results", tmp_path / "res",
              "--workers", "1", "--no-progress"]
    proc = run_eha("rul", canonical, *common, "--json", tmp_path / "c.json", timeout=600)
    assert proc.returncode == 0, proc.stderr
    proc = run_eha("rul", user, *common, "--json", tmp_path / "u.json", "--columns",
                   RUL_COLUMNS, "--units", "mm", timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "3 records assessed now" in proc.stdout
    ref = json.loads((tmp_path / "c.json").read_text())
    out = json.loads((tmp_path / "u.json").read_text())
    assert out["columns"] == {"t": "time_s", "com": "command_mm", "xu": "lvdt"}
    assert out["units"] == "mm" and "columns" not in ref
    got, want = out["actuators"]["A1"]["predictions"], ref["actuators"]["A1"]["predictions"]
    assert [p["cycle"] for p in got] == [p["cycle"] for p in want] == [0.0, 100.0, 200.0]
    assert want[-1]["rul"] is not None and want[-1]["driver"] == "FDJ"   # not None == None
    for a, b in zip(got, want):
        assert a["estimates"]["FDJ"] == pytest.approx(b["estimates"]["FDJ"], rel=1e-9)
        for key in ("rul", "rul_lo", "rul_hi"):
            assert a[key] == (None if b[key] is None else pytest.approx(b[key], rel=1e-9))
    assert abs(want[-1]["rul"] - 100.0) < 60.0     # FDJ reaches 1500 N near cycle 300


@pytest.mark.parametrize("options, message", [
    (["--columns", "position=lvdt"], "--columns position=lvdt: unknown signal 'position'; "
                                     "allowed: t, com, xu, p12, xs"),
    (["--columns", RUL_COLUMNS, "--units", "inch"], "--units 'inch': allowed m, mm, um"),
])
def test_rul_bad_columns_or_units_exit_2_in_one_line_and_write_nothing(tmp_path, options,
                                                                         message):
    for i in range(3):
        _record(tmp_path / f"u{i}.csv")
    manifest = tmp_path / "m.csv"
    manifest.write_text("actuator,cycle,record\n" + "".join(f"A1,{100 * i},u{i}.csv\n"
                                                            for i in range(3)))
    before = files_under(tmp_path)
    proc = invoke_eha("rul", manifest, "--limit", "FDJ=1500", "--results", tmp_path / "res",
                      "--json", tmp_path / "rul.json", "--no-progress", *options)
    line = error_line(proc, 2)
    assert line == f"error: {message}" or line.startswith(f"error: {message} "), line
    assert files_under(tmp_path) == before and not (tmp_path / "res").exists()
