"""What a new user met (issue 61, items 4-6 and the drift): output off a terminal, inputs
refused before anything is written, folders where files are expected, the campaign-name
rule, CSV out of ``eha simulate``, command files. Each test failed before its change."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import error_line, files_under, invoke_eha


def _record(path: Path, t_end: float = 0.2, nan_at: int | None = None) -> Path:
    """A measured record (HF, step_1mm, t,com,xu in SI) as CSV; a NaN at row ``nan_at``."""
    import eha
    from eha.campaigns.traces import write_table_file

    frame = eha.simulate("hf", "step_1mm", {}, t_end=t_end, seed=0).to_pandas()[
        ["t", "com", "xu"]]
    if nan_at is not None:
        frame.loc[nan_at, "xu"] = np.nan
    write_table_file(frame, path, "csv")
    return path


def _env_without_columns() -> dict:
    return {k: v for k, v in os.environ.items() if k != "COLUMNS"}


# ----------------------------------------------------------------------- off a terminal
@pytest.mark.slow   # a command line in its own process, piped
def test_output_to_a_pipe_is_not_cut_at_80_columns():
    """Without COLUMNS, to a pipe: rich took 80 columns and wrapped or cut every wider line
    ("(lm, \\nseed 0)", "estima…")."""
    proc = subprocess.run([sys.executable, "-m", "eha", "fdi", "--command", "step_1mm",
                           "--set", "FDJ=800", "--fit", "FDJ", "--method", "lm", "--t-end",
                           "0.1"], capture_output=True, text=True, env=_env_without_columns(),
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    last = [ln for ln in proc.stdout.splitlines() if "evaluations" in ln]
    assert len(last) == 1 and last[0].rstrip().endswith("seed 0)"), proc.stdout
    assert "…" not in proc.stdout


def test_explain_progress_off_a_terminal_is_lines_on_stderr(capsys, monkeypatch):
    """A spinner shows nothing off a terminal: the phases are lines (at most one per
    LINE_EVERY_S), none before the first LINE_EVERY_S (a quick error stays one line)."""
    import eha.cli.explain as E

    clock = [100.0]
    monkeypatch.setattr(E.time, "monotonic", lambda: clock[0])
    with E._progress_bar(True) as step:
        step("healthy null: actuator 1 of 30 done")          # at once: not printed
        clock[0] += E.LINE_EVERY_S
        step("healthy null: actuator 2 of 30 done")
        step("healthy null: actuator 3 of 30 done")          # too soon: not printed
        clock[0] += E.LINE_EVERY_S
        step("round 1: fitting the candidates")
    err = capsys.readouterr().err.splitlines()
    assert err == ["healthy null: actuator 2 of 30 done ...",
                   "round 1: fitting the candidates ..."]


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX pseudo-terminal")
def test_an_explain_error_on_a_terminal_has_no_empty_line_above_it(tmp_path):
    """On a terminal the spinner was stopped with a newline that rich then moved back over:
    an empty line above the error wherever the cursor does not move (a log of the terminal)."""
    import pty
    import select

    record = _record(tmp_path / "nan.csv", nan_at=5)
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "eha", "explain", str(record), "--results",
                             str(tmp_path / "r")], stdin=slave, stdout=slave, stderr=slave,
                            env={**os.environ, "COLUMNS": "200", "TERM": "xterm"})
    os.close(slave)
    out = b""
    while True:
        ready, _, _ = select.select([master], [], [], 120)
        if not ready:
            break
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the terminal's other end closed (the process ended)
            break
        if not chunk:
            break
        out += chunk
    proc.wait(timeout=60)
    os.close(master)
    assert proc.returncode == 2, out
    before = out[:out.index(b"error:")]
    assert b"\n" not in before, before[-200:]


# ----------------------------------------------------------------------- validation first
def test_a_nan_record_in_a_rul_manifest_is_refused_before_anything_is_written(tmp_path):
    records = tmp_path / "records"
    records.mkdir()
    _record(records / "a0.csv")
    _record(records / "a1.csv", nan_at=7)
    (tmp_path / "manifest.csv").write_text("actuator,cycle,record\nA,0,records/a0.csv\n"
                                           "A,100,records/a1.csv\n")
    results = tmp_path / "results"
    line = error_line(invoke_eha("rul", tmp_path / "manifest.csv", "--limit", "FDJ=1500",
                                 "--fit", "FDJ", "--results", results, "--no-progress",
                                 "--workers", "1"), 2)
    assert "line 3" in line and "cycle 100" in line and "not finite" in line
    assert not results.exists()


@pytest.mark.parametrize("args, said", [
    (lambda d: ["rul", d, "--limit", "FDJ=1500"], "a folder, not a manifest file"),
    (lambda d: ["simulate", "--command", d, "--out", d.parent / "x.parquet"],
     "a folder, not a command file"),
    (lambda d: ["fdi", "--command", d], "a folder, not a command file"),
    (lambda d: ["health", "calibrate", "--command", d, "--actuators", "5"],
     "a folder, not a command file"),
])
def test_a_folder_where_a_file_is_expected_says_it_is_a_folder(tmp_path, args, said):
    folder = tmp_path / "dir"
    folder.mkdir()
    before = files_under(tmp_path)
    line = error_line(invoke_eha(*args(folder), cwd=tmp_path), 2)
    assert said in line and "campaign name" not in line and "unknown command" not in line
    assert files_under(tmp_path) == before


def test_a_fleet_folder_given_to_rul_points_at_its_manifest(tmp_path):
    (tmp_path / "manifest.csv").write_text("actuator,cycle,record\n")
    line = error_line(invoke_eha("rul", tmp_path, "--limit", "FDJ=1500"), 2)
    assert "holds manifest.csv" in line


# ----------------------------------------------------------------------- campaign names
@pytest.mark.parametrize("name", [".", "..", "a/b", "..\\x", ".hidden", "", "x" * 81])
def test_the_campaign_name_rule_is_one_and_refuses_what_is_not_a_folder_name(name):
    from eha.campaigns.files import CampaignError, make_campaign, name_problem
    from eha.prognostics.fleet import FleetError, parse_fleet

    assert name_problem(name) is not None
    with pytest.raises(CampaignError, match="not a valid campaign name"):
        make_campaign(name, [])
    with pytest.raises(FleetError) as err:
        parse_fleet({"name": name, "actuators": 2, "limits": {"FDJ": 1500},
                     "faults": {"FDJ": {"initial": 200, "laws": ["linear"],
                                        "rate": {"median": 1.0, "sigma": 0.0}}}})
    assert "not a valid campaign name" in str(err.value)


def test_a_good_campaign_name_passes_everywhere():
    from eha.campaigns.files import make_campaign, name_problem

    assert name_problem("thesis-fdi.v2_x") is None
    assert make_campaign("thesis-fdi.v2_x", []).name == "thesis-fdi.v2_x"


# ----------------------------------------------------------------------- formats
def test_simulate_writes_csv_that_the_record_readers_take_back(tmp_path):
    out = tmp_path / "x.csv"
    proc = invoke_eha("simulate", "--command", "step_1mm", "--t-end", "0.1", "--out", out)
    assert proc.returncode == 0, proc.stderr
    from eha.identification.measured import load

    import pandas as pd

    frame = pd.read_csv(out)
    assert list(frame.columns)[:3] == ["t", "com", "xu"] and len(frame) == 101
    rec = load(out)
    assert np.allclose(rec.xu, frame["xu"].to_numpy(), rtol=0, atol=1e-12)
    line = error_line(invoke_eha("simulate", "--out", tmp_path / "x.mat"), 2)
    assert ".parquet, .csv" in line


def test_query_shows_null_not_nan_or_none(tmp_path):
    from helpers import small_campaign

    results = tmp_path / "results"
    assert invoke_eha("campaign", "run", small_campaign(tmp_path, 0.02), "--results", results,
                      "--workers", "1").returncode == 0
    out = invoke_eha("query", "DESCRIBE runs", "--results", results).stdout
    cells = {c.strip() for ln in out.splitlines() for c in ln.split("│")}
    assert "NULL" in cells and "nan" not in cells and "None" not in cells


# ----------------------------------------------------------------------- command files
def test_a_record_is_its_own_command_and_lasts_its_own_length(tmp_path):
    """A record's t and com columns are a command (``t,com,xu`` was refused: "header must be
    't,com'"), and a command file runs for its own length unless told otherwise (a 0.2-s
    command was simulated for 1 s, most of it at rest)."""
    import pandas as pd

    record = _record(tmp_path / "rec.csv", t_end=0.2)
    out = tmp_path / "again.csv"
    proc = invoke_eha("simulate", "--command", record, "--out", out)
    assert proc.returncode == 0, proc.stderr
    again, first = pd.read_csv(out), pd.read_csv(record)
    assert len(again) == len(first) == 201
    assert np.allclose(again["com"], first["com"], rtol=0, atol=1e-12)
    proc = invoke_eha("simulate", "--command", record, "--t-end", "0.3", "--out", out)
    assert proc.returncode == 0 and len(pd.read_csv(out)) == 301
    (tmp_path / "bad.csv").write_text("time,position\n0,0\n0.1,0\n")
    line = error_line(invoke_eha("simulate", "--command", tmp_path / "bad.csv", "--out", out),
                      2)
    assert "columns t and com" in line


def test_the_default_duration_of_a_command():
    from eha.models.commands import default_duration

    assert default_duration("chirp_1cm") == 1.0
    assert default_duration("chirp_1cm", 2.5) == 2.5


# ----------------------------------------------------------------------- design's words
def test_library_commands_beyond_the_users_limits_are_named():
    """`eha design --max-stroke 0.005 --duration 0.5` ranked its design against library
    commands beyond the limits given without saying so; they are compared cut to the limits
    (eha.design.library) and the line under the table says how, and which stay beyond."""
    from types import SimpleNamespace

    from eha.design.family import Limits
    from eha.design.headlines import beyond_limits, beyond_limits_lines
    from eha.design.library import cut_to_limits

    limits = Limits(0.5, 0.005, 0.1, 20.0)
    cuts = {n: cut_to_limits(n, limits) for n in ("chirp_1cm", "test")}
    result = SimpleNamespace(settings={"duration": 0.5, "library_cut": {
        n: {"scale": c.scale, "beyond": c.beyond} for n, c in cuts.items()}},
        library={"chirp_1cm": None})
    beyond = beyond_limits(result)
    assert beyond["chirp_1cm"] == f"scaled to x{cuts['chirp_1cm'].scale:.2f}"
    assert cuts["test"].beyond and beyond["test"].endswith(
        f"still beyond them ({cuts['test'].beyond}), not compared")
    result.library["test"] = None  # none fits: every one compared, said so
    assert beyond_limits(result)["test"].endswith("compared all the same")
    (line,) = beyond_limits_lines(result)
    assert line.startswith("library commands compared within your limits (each cut to 0.5 s)")
    within = SimpleNamespace(settings={"duration": 1.0, "library_cut": {
        "chirp_1cm": {"scale": 1.0, "beyond": None}}})
    assert beyond_limits_lines(within) == []


def test_the_verification_says_its_finding_first_in_units():
    """`eha design verify` printed a bare table in SI (BKL in m); it now starts with the
    finding per fault in the fault's display unit, the prediction beside it."""
    from eha.design.headlines import verification_headline
    from eha.design.verify import Verification

    def fault(md, top, lowest=False):
        return {"min_detectable": md, "at_lowest_level": lowest,
                "levels": [{"deviation": top, "p_detect": 1.0, "isolated": 1.0, "n": 3}]}

    fa = {"n": 20, "alarms": 1, "rate": 0.05, "upper_95": 0.2}
    # the campaign's order (library first) is not the order said: the design first
    v = Verification({"chirp_1cm": {"faults": {"BKL": fault(4e-5, 8e-5, True),
                                               "FDJ": fault(300.0, 391.0)},
                                    "false_alarms": fa},
                      "design-x": {"faults": {"BKL": fault(2e-5, 8e-5), "FDJ": fault(None, 391.0)},
                                   "false_alarms": fa}},
                     {"design": {"BKL": 1.5e-5, "FDJ": 97.7}}, {"library": ["chirp_1cm"]},
                     "verify-x", "results")
    lines = verification_headline(v)
    assert lines[0] == ("BKL detected (P_D >= 0.95) from a change of: the design: 20 µm "
                        "(predicted 15 µm); chirp_1cm: at most 40 µm")
    assert lines[1].startswith("FDJ detected") and "not detected up to 391 N (predicted " \
        "97.7 N)" in lines[1] and "chirp_1cm: 300 N" in lines[1]
    assert lines[2].startswith("false alarms on held-out healthy actuators: design-x: 1 of 20")
    assert "BKL m" in lines[2]


# ----------------------------------------------------------------------- units
def test_a_derived_limit_is_printed_with_its_unit_and_nominal():
    """`eha limits` printed "FDJ limit ...: 6000.78" with no unit."""
    proc = invoke_eha("limits", "--fault", "FDJ", "--require", "lag(mixed) > 0.02", "--lo",
                      "200", "--hi", "20000", "--tol", "0.05", "--t-end", "0.5")
    assert proc.returncode == 0, proc.stderr
    line = proc.stdout.strip().splitlines()[0]
    value = float(line.split("': ")[1].split(" N")[0])
    assert f"{value:g} N, {100 * (value - 200) / 200:+.0f} % of its nominal 200 N" in line
    assert "bracket [200, 20000] N" in line


def test_a_pair_named_and_read_from_around_is_one_pair(tmp_path):
    """`eha design --separate external_load,offset --around f01.json` printed the pair's
    separation block twice: once named, once read from the explain JSON."""
    import json

    from eha.cli.design import _around

    doc = {"steps": [{"effect": "external_load", "params": {"FRC": 800.0}}],
           "not_excluded": [{"effect": "offset", "value": -0.009}]}
    path = tmp_path / "f01.json"
    path.write_text(json.dumps(doc))
    for named in ([("external_load", "offset")], [("offset", "external_load")], []):
        pairs = list(named)
        values = _around(path, pairs)
        assert len(pairs) == 1, pairs
        assert values == {"external_load": 800.0, "offset": -0.009}


def test_the_fdi_plot_names_no_signal_the_record_lacks(tmp_path, monkeypatch):
    """The fdi plot's P12 and spool legends listed "MEASURED" for a record of t,com,xu."""
    import eha.reports.plots as P
    from eha.identification.fdi import identify_source

    run = identify_source(data=_record(tmp_path / "r.csv"), fit=["FDJ"], method="lm")
    figs = []
    monkeypatch.setattr(P, "_save", lambda fig, path, dpi=110: figs.append(fig) or Path(path))
    P.plot_traces([run.reference, run.fitted], tmp_path / "fit.png")
    axes = figs[0].axes
    by_label = {ax.get_ylabel(): [t.get_text() for t in (ax.get_legend().get_texts()
                                                         if ax.get_legend() else [])]
                for ax in axes}
    for panel in ("P12 [bar]", "spool xs [mm]"):
        assert by_label[panel] and not any("MEASURED" in t for t in by_label[panel]), by_label
    assert any("MEASURED" in t for t in by_label["position [mm]"])


def test_an_interval_that_is_the_search_bounds_is_said_why():
    """The report showed the thesis cases 1-2's search bounds as their 90 % interval and did
    not say why."""
    from types import SimpleNamespace

    from eha.reports.html.sections import _bounds_note

    def row(case, iv, flagged):
        return SimpleNamespace(case=case, intervals={"BKL": iv}, flagged=flagged,
                               bounds={"BKL": [0.0, 5e-3]})

    rows = [row(1, (0.0, 5e-3), True), row(2, (0.0, 5e-3), False), row(3, (1e-4, 2e-4), False)]
    note = _bounds_note(rows, ["BKL"])
    assert "cases 1, 2 the 90 % interval is the search bounds" in note
    assert "flagged on case 1:" in note and "3" not in note.split("search bounds")[0]
    assert _bounds_note(rows[2:], ["BKL"]) == ""


def test_the_explain_spinner_counts_fits_without_1_steps():
    import eha.cli.explain as E

    texts = [getattr(c, "text_format", "") for c in E._progress_bar(True).bar.columns]
    assert "[dim]fits done: {task.completed}" in texts
    assert not any("} steps" in t for t in texts)


def test_the_explain_table_says_what_its_symbols_are():
    """The steps table named SNF, ZF, GQ and "(structure)" without saying what they are."""
    from types import SimpleNamespace

    from eha.cli.explain import _symbols

    steps = [SimpleNamespace(effect="flapper_dynamics")]
    res = SimpleNamespace(faults_before={"FDJ": 586.0, "GQ": 0.198}, steps=steps,
                          final_params=lambda s: {"SNF": 2568.0, "ZF": 0.61})
    line = _symbols(res)
    assert line.startswith("symbols: FDJ jack dynamic friction; GQ valve flow gain; SNF "
                           "flapper natural frequency; ZF flapper damping ratio")
    assert "(structure): what the LF model lacks on any actuator" in line
