"""What a new user trips on (issue 42, item 4): each small CLI answer that was unhelpful or
wrong, and the listings readable at 80 columns. Each test failed before the change."""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from helpers import error_line, files_under, invoke_eha, run_eha, write_campaign


def test_a_mistyped_parameter_gets_a_suggestion(tmp_path):
    line = error_line(invoke_eha("simulate", "--set", "BLK=1e-4", "--out",
                                 tmp_path / "x.parquet"), 2)
    assert "BLK: unknown parameter (did you mean BKL?)" in line
    assert not files_under(tmp_path)


def test_a_folder_given_as_a_record_says_it_is_a_folder(tmp_path):
    (tmp_path / "records").mkdir()
    line = error_line(invoke_eha("fdi", "--data", tmp_path / "records"), 2)
    assert "a folder, not a record file" in line and "file not found" not in line


def test_query_without_a_database_here_names_the_results_option(tmp_path):
    line = error_line(invoke_eha("query", "SELECT 1", cwd=tmp_path), 2)
    assert "no result database yet" in line and "--results" in line


@pytest.mark.parametrize("args", [["explain", "--help"], ["params"], ["--help"]])
def test_a_closed_pipe_ends_quietly_with_the_conventional_status(args):
    """``eha explain --help | head``: the reader went away; no "Broken pipe" line, exit 141
    (128 + SIGPIPE, what a shell reports for ``yes | head``), not 1."""
    proc = subprocess.Popen([sys.executable, "-m", "eha", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env={**os.environ, "COLUMNS": "80"})
    proc.stdout.close()             # before the command writes: every write meets EPIPE
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141 and err == "", err


def test_campaign_validate_never_shows_none(tmp_path):
    camp = write_campaign(tmp_path, """
        models = ["lf"]
        commands = ["step_1mm"]
        """)
    proc = invoke_eha("campaign", "validate", camp)
    assert proc.returncode == 2 and "None" not in proc.stderr
    assert "name: missing; required" in proc.stderr


def test_campaign_plan_counts_the_runs_done_and_says_durations_plainly(tmp_path):
    from eha.campaigns.files import load_campaign, plan
    from eha.campaigns.runner import run_campaign
    from helpers import Inline

    camp = write_campaign(tmp_path, """
        name = "tiny"
        models = ["lf"]
        commands = ["step_1mm"]
        seeds = [0]
        t_end = 0.05
        [faults]
        nominal = true
        """)
    results = tmp_path / "results"
    before = invoke_eha("campaign", "plan", camp, "--results", results)
    assert before.returncode == 0, before.stderr
    assert "already done" not in before.stdout
    assert not re.search(r"\d\.\d s\b", before.stdout), before.stdout    # not "2.0 s"
    run_campaign(load_campaign(camp), results=results, executor=Inline())
    info = plan(load_campaign(camp), 2, results)
    assert info["done"] == info["jobs"] == 1 and info["estimated_s"] == 0.0
    after = invoke_eha("campaign", "plan", camp, "--results", results)
    assert "already done in" in after.stdout and "1 of 1 runs" in after.stdout
    assert "nothing left to run" in after.stdout


def test_duration_text():
    from eha.models.units import duration

    assert [duration(s) for s in (0.4, 8.2, 25, 250, 1502.0, 3900)] == \
        ["0.4 s", "8 s", "25 s", "4 min 10 s", "25 min", "1 h 05 min"]


def test_health_check_with_a_missing_calibration_says_how_to_make_one(tmp_path):
    rec = tmp_path / "r.csv"
    rec.write_text("t,com,xu\n" + "\n".join(f"{i / 1000},0,0" for i in range(300)) + "\n")
    line = error_line(invoke_eha("health", "check", rec, "--calibration",
                                 tmp_path / "cal.json"), 2)
    assert "no such file" in line and "eha health calibrate" in line


def test_commands_lists_presets_and_kinds_apart():
    out = run_eha("commands", env={"COLUMNS": "80"}).stdout
    presets, kinds = out.split("kinds (", 1)
    assert presets.lstrip().startswith("presets")
    assert "chirp_1cm" in presets and "chirp_1cm" not in kinds
    assert "A0=0.001 m [0, 0.2]" in kinds
    assert max(map(len, out.splitlines())) <= 80


def test_params_at_80_columns_is_one_line_of_facts_and_the_description_whole():
    from eha.models.params import PARAMETERS

    out = run_eha("params", env={"COLUMNS": "80"}).stdout
    lines = out.splitlines()
    assert max(map(len, lines)) <= 80
    assert len(lines) <= 2.5 * len(PARAMETERS)          # was 224 lines, a word a line
    text = " ".join(out.split())
    for p in PARAMETERS:
        assert " ".join(p.description.split()) in text, p.name


def test_no_help_text_loses_a_bracketed_unit_to_markup():
    """typer renders help through rich, which takes "[s]" or "[mm]" for a style tag and drops
    it ("Record length , 0.2 to 10."): no help text may hold one."""
    import typer

    from eha.cli import app

    tag = re.compile(r"(?<!\\)\[[a-z#/@][^\[]*?\]")

    def walk(cmd, path):
        yield path, cmd
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, path + [name])

    found = [(path, p.name, m.group(0))
             for path, cmd in walk(typer.main.get_command(app), [])
             for p in cmd.params for m in tag.finditer(getattr(p, "help", "") or "")]
    assert not found, found
    out = run_eha("health", "calibrate", "--help", env={"COLUMNS": "100"}).stdout
    assert "Record length in s, 0.2 to 10 (default: a command file" in " ".join(
        out.replace("│", " ").split())


@pytest.mark.slow   # eha fdi in its own process
def test_fdi_table_has_units_and_states_the_sign_of_its_error():
    proc = run_eha("fdi", "--command", "chirp_1cm", "--set", "BKL=1e-4", "--set", "FDJ=800",
                   "--t-end", "0.3", env={"COLUMNS": "80"})
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert max(map(len, lines)) <= 80 and "…" not in proc.stdout
    header = next(line for line in lines if "param" in line)
    assert "unit" in header and "error %" in header
    bkl = next(line for line in lines if line.strip().startswith("BKL"))
    assert bkl.split()[1] == "µm" and bkl.split()[4] == "100"         # 1e-4 m shown in µm
    assert "error % = (injected - identified) / injected" in " ".join(proc.stdout.split())


def test_explain_steps_table_is_whole_at_80_columns():
    """The steps table of f01's run (structure, a load, the flapper) at 80 columns: no name or
    value cut to "orifice_…" / "BKL=0.00…", parameters in display units, structure marked."""
    import numpy as np
    from rich.console import Console

    from eha.cli.explain import _steps_table
    from eha.explain.results import Evaluation, ExplainResult, Step
    from eha.models.params import LFParams

    p = LFParams().replace(FRC=829.4, SNF=4911.0, ZF=1.177, orifice_law=1.0)
    ev = lambda r: Evaluation(p, np.zeros(3), r, 1.3 * r, 1.1 * r)  # noqa: E731
    steps = [Step("orifice_law", {}, 21.5e-6, 22.5e-6, 17.2e-6, 19.1e-6, 29e-6, 29e-6, {}, {},
                  0, 0),
             Step("external_load", {"FRC": 800.0}, 22.5e-6, 1.68e-6, 19.1e-6, 1.66e-6, 29e-6,
                  1.73e-6, {}, {}, 0, 0),
             Step("flapper_dynamics", {"SNF": 1.0, "ZF": 1.0}, 1.68e-6, 1.03e-6, 1.66e-6,
                  0.987e-6, 1.73e-6, 1.12e-6, {}, {}, 0, 0)]
    res = ExplainResult(
        source="f01.csv", fit_bounds={}, faults_before={"BKL": 2.2e-8, "FDJ": 1084.0},
        faults_after={}, before=ev(21.5e-6), after=ev(1.03e-6), steps=steps, rounds=[],
        noise_rmse=1.09e-6, stop_reason="", holdout="", t=np.zeros(3), measured=np.zeros(3),
        settings={}, seconds=0.0)
    console = Console(width=80, record=True, file=open(os.devnull, "w"))
    console.print(_steps_table(res))
    text = console.export_text()
    assert "…" not in text and max(map(len, text.splitlines())) <= 80
    for word in ("orifice_law", "external_load", "flapper_dynamics", "FRC 829 N",
                 "SNF 4911 rad/s", "(structure)", "BKL 0.022 µm", "FDJ 1084 N"):
        assert word in " ".join(text.split()), (word, text)


def test_one_display_unit_per_quantity():
    """Positions and lengths in µm, forces N, currents mA, pressures MPa, from the parameter
    table; a fault's label, a report's number column and a heat-map cell in one format."""
    from eha.models.units import display_unit, plain, show
    from eha.reports.html.figures import _sig3
    from eha.reports.html.page import fmt_num
    from eha.reports.plots import fault_text

    assert display_unit("BKL") == ("µm", 1e6) and display_unit("sensor_bias")[0] == "µm"
    assert display_unit("FRC")[0] == "N" and display_unit("Ofs")[0] == "mA"
    assert display_unit("PSR") == ("MPa", 1e-6) and display_unit("Kintas")[0] == ""
    assert show("Kintas", 0.0741) == "0.0741"                  # was "0.0741 - in Kintas"
    assert fault_text({"BKL": 1e-4, "FDJ": 800.0}) == "BKL 100 µm, FDJ 800 N"   # was mm
    assert [fmt_num(3)(v) for v in (158.2, 1720.0)] == ["158", "1720"]   # was 1.72e+03
    assert list(_sig3(__import__("numpy").log10([158.2, 1720.0]))) == ["158", "1720"]
    assert plain(2.5e7) == "2.5e+07"
