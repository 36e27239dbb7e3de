"""Hardening (issue 12), classes 1, 4, 5 and 6 of docs/reliability.md: hostile but realistic
inputs end in one ``error:`` line naming the field and its allowed range, a non-zero exit, and
nothing written. Real files, the real command line in subprocesses."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pandas as pd
import pytest

from helpers import (close, error_line, files_under, invoke_eha,
                      write_campaign)
from eha.identification.measured import load

ROOT_IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def record_csv(path, t_scale=1.0, x_scale=1.0, header=("t", "com", "xu")):
    """A 0.2 s, 1 kHz record (a 5 Hz sine) written with the given units/scales."""
    t = np.arange(201) * 1e-3
    com = 2e-3 * np.sin(2 * np.pi * 5 * t)
    xu = 0.98 * com
    pd.DataFrame({header[0]: t * t_scale, header[1]: com * x_scale,
                  header[2]: xu * x_scale}).to_csv(path, index=False)
    return path


# =========================================================================== class 1: guard
GUARD_SCRIPT = textwrap.dedent('''
    import sys
    import typer
    from eha.cli import app

    @app.command("boom")
    def boom():
        """Fails the way an unanticipated bug would. Example: eha boom"""
        raise RuntimeError("broken [fdi] section, allowed range [0, 1] m")

    def no_default():
        raise ImportError("the module of this default is missing")

    @app.command("parse")
    def parse(x: int = typer.Option(..., "--x", default_factory=no_default)):
        """Fails while its options are parsed. Example: eha parse"""

    @app.command("term")
    def term():
        """A command with its own Ctrl-C message gets SIGTERM. Example: eha term"""
        import os, signal, time
        from eha.cli import fail

        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except KeyboardInterrupt:
            fail("interrupted; finished records are kept", 130)

    app(prog_name="eha")
''')


def test_guard_turns_an_unexpected_exception_into_one_line_and_exit_1():
    proc = subprocess.run([sys.executable, "-c", GUARD_SCRIPT, "boom"], capture_output=True,
                          text=True)
    line = error_line(proc, 1)
    # the brackets are text, not console markup that would swallow "[fdi]"
    assert "broken [fdi] section, allowed range [0, 1] m" in line
    assert "--debug" in line


def test_guard_covers_the_parsing_of_options():
    proc = subprocess.run([sys.executable, "-c", GUARD_SCRIPT, "parse"], capture_output=True,
                          text=True)
    line = error_line(proc, 1)
    assert "ImportError: the module of this default is missing" in line


def test_sigterm_in_a_commands_own_ctrl_c_handler_exits_143():
    proc = subprocess.run([sys.executable, "-c", GUARD_SCRIPT, "term"], capture_output=True,
                          text=True, timeout=60)
    assert error_line(proc, 143) == "error: terminated (SIGTERM); finished records are kept"


def test_guard_debug_shows_the_traceback():
    proc = subprocess.run([sys.executable, "-c", GUARD_SCRIPT, "--debug", "boom"],
                          capture_output=True, text=True)
    assert proc.returncode == 1
    assert "Traceback (most recent call last)" in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("error: internal error")


def test_option_parser_errors_are_one_line_naming_the_option(tmp_path):
    line = error_line(invoke_eha("campaign", "run", tmp_path / "x.toml", "--workers", "0"), 2)
    assert "--workers" in line and "1" in line
    assert not files_under(tmp_path)


def test_campaign_file_that_is_not_utf8_text(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b'name = "caf\xe9"\nmodels = ["hf"]\n')
    line = error_line(invoke_eha("campaign", "validate", bad), 2)
    assert "not UTF-8 text" in line and str(bad) in line


@pytest.mark.parametrize("args", [
    ["simulate", "--t-end", "0.01", "--seed", "-1"],
    ["simulate", "--t-end", "0.01", "--seed", str(2**32)],
    ["fdi", "--command", "ramp", "--seed", "-1"],
])
def test_seed_out_of_range(tmp_path, args):
    out = tmp_path / "o" / "t.parquet"
    extra = ["--out", out] if args[0] == "simulate" else ["--json", tmp_path / "o" / "r.json"]
    line = error_line(invoke_eha(*args, *extra), 2)
    assert "--seed" in line and "allowed range [0, 4294967295]" in line
    assert not files_under(tmp_path)


def test_unsupported_plot_suffix_is_refused_before_the_trace_is_written(tmp_path):
    out = tmp_path / "t.parquet"
    line = error_line(invoke_eha("simulate", "--t-end", "0.01", "--out", out, "--plot",
                              tmp_path / "t.gif"), 2)
    assert "--plot" in line and "'.gif'" in line and ".png" in line
    assert not out.exists() and not files_under(tmp_path)


def test_scheduler_that_is_not_an_address(tmp_path):
    camp = write_campaign(tmp_path, 'name = "s"\nmodels = ["lf"]\ncommands = ["ramp"]\n'
                                    't_end = 0.01\n')
    results = tmp_path / "results"
    line = error_line(invoke_eha("campaign", "run", camp, "--results", results, "--scheduler",
                              "not an address"), 2)
    assert "--scheduler" in line and "tcp://HOST:PORT" in line
    assert not results.exists()


@pytest.mark.parametrize("command", [
    lambda f, d: ["simulate", "--t-end", "0.01", "--out", f / "x.parquet"],
    lambda f, d: ["fdi", "--command", "ramp", "--json", f / "x.json"],
    lambda f, d: ["explain", d, "--results", f],
    lambda f, d: ["explain", d, "--json", f / "x.json"],
    lambda f, d: ["campaign", "run", d, "--results", f],
    lambda f, d: ["export", "runs", "--csv", f / "x.csv"],
    lambda f, d: ["reproduce", "--results", f],
    lambda f, d: ["fleet", "simulate", d, "--out", f / "fleet"],
    lambda f, d: ["limits", "--fault", "FDJ", "--require", "lag(mixed) > 0.02", "--lo", "200",
                  "--hi", "2000", "--json", f / "x.json"],
    lambda f, d: ["rul", d, "--limit", "BKL=5e-4", "--json", f / "x.json"],
    lambda f, d: ["rul", d, "--limit", "BKL=5e-4", "--plots", f / "p"],
    lambda f, d: ["report", "html", "--results", d.parent, "--out", f / "report.html"],
])
def test_output_path_under_a_file_is_refused_before_any_work(tmp_path, command):
    blocker = tmp_path / "F"
    blocker.write_text("a file, not a folder")
    data = record_csv(tmp_path / "rec.csv")
    before = files_under(tmp_path)
    line = error_line(invoke_eha(*command(blocker, data), cwd=tmp_path), 2)
    assert str(blocker) in line and ("not a folder" in line or "is a file" in line)
    assert files_under(tmp_path) == before and blocker.read_text() == "a file, not a folder"


@pytest.fixture
def read_only_dir(tmp_path):
    """A folder nobody may write into: mode 0555, or (for root, whom modes do not stop) a
    read-only tmpfs mounted there; skipped where neither is possible."""
    ro = tmp_path / "ro"
    ro.mkdir()
    if not ROOT_IS_ROOT:
        if os.name == "nt":
            pytest.skip("POSIX permissions")
        ro.chmod(0o555)
        yield ro
        ro.chmod(0o755)
        return
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(ro)],
                             capture_output=True)
    if mounted.returncode != 0:
        pytest.skip("running as root without a read-only mount")
    try:
        yield ro
    finally:
        subprocess.run(["umount", str(ro)], capture_output=True)


@pytest.mark.parametrize("command", [
    lambda ro, d: ["export", "runs", "--csv", ro / "x.csv"],
    lambda ro, d: ["plot", "c", "--out", ro / "plots"],
    lambda ro, d: ["explain", d, "--out", ro / "e"],
    lambda ro, d: ["simulate", "--t-end", "0.01", "--out", ro / "x.parquet"],
])
def test_read_only_folder_is_refused_before_any_work(tmp_path, read_only_dir, command):
    data = record_csv(tmp_path / "rec.csv")
    line = error_line(invoke_eha(*command(read_only_dir, data)), 2)
    assert "not writable" in line and not files_under(read_only_dir)


# =========================================================================== class 4: units
def test_header_units_are_honoured(tmp_path):
    si = load(record_csv(tmp_path / "si.csv"))
    mm = load(record_csv(tmp_path / "mm.csv", x_scale=1e3,
                         header=("t [s]", "com [mm]", "xu (mm)")))
    ms = load(record_csv(tmp_path / "ms.csv", t_scale=1e3, x_scale=1e6,
                         header=("time [ms]", "com [um]", "xu [µm]")))
    for rec in (mm, ms):
        close(rec.t, si.t, abs=1e-12)
        close(rec.xu, si.xu, rel=1e-9, abs=1e-15)
        close(rec.com, si.com, rel=1e-9, abs=1e-15)


def test_unknown_header_unit_is_refused(tmp_path):
    path = record_csv(tmp_path / "v.csv", header=("t", "com", "xu [V]"))
    proc = invoke_eha("explain", path, "--results", tmp_path / "r", "--no-progress")
    line = error_line(proc, 2)
    assert "column xu" in line and "'V'" in line and "allowed: m, cm, mm" in line
    assert not (tmp_path / "r").exists()


def test_time_in_milliseconds_without_a_unit_is_refused(tmp_path):
    """t in ms read as seconds: a 200-s record at 1 Hz, which the models cannot resolve
    (it used to run for minutes in gigabytes)."""
    path = record_csv(tmp_path / "ms.csv", t_scale=1e3)
    proc = invoke_eha("explain", path, "--results", tmp_path / "r", "--no-progress")
    line = error_line(proc, 2)
    assert "sampling period 1 s" in line and "at most 0.01 s" in line and "t [ms]" in line
    assert not (tmp_path / "r").exists()


def test_every_separator_reads_the_same_record(tmp_path):
    """The sniffer (comma, semicolon, tab, aligned spaces, # comments) in front of pandas' C
    parser: each layout of one record loads to the same arrays."""
    frame = pd.read_csv(record_csv(tmp_path / "rec.csv"))
    (tmp_path / "semi.csv").write_text(frame.to_csv(index=False, sep=";"))
    (tmp_path / "tab.tsv").write_text("# logged by the rig\n" + frame.to_csv(index=False,
                                                                           sep="\t"))
    (tmp_path / "aligned.txt").write_text(frame.to_string(index=False))
    ref = load(tmp_path / "rec.csv")
    for name in ("semi.csv", "tab.tsv", "aligned.txt"):
        got = load(tmp_path / name)
        close(got.xu, ref.xu, rel=1e-5, abs=1e-12, what=name)
        close(got.t, ref.t, abs=1e-12, what=name)


# =========================================================================== class 5: campaigns
def huge_grid(n):
    values = ", ".join(f"{x:.6g}" for x in np.linspace(1e-5, 1e-3, n))
    forces = ", ".join(f"{x:.6g}" for x in np.linspace(100, 4000, n))
    return f'''
        name = "huge"
        models = ["hf", "lf"]
        commands = ["ramp", "mixed"]
        [faults]
        grid = {{BKL = [{values}], FDJ = [{forces}]}}
    '''


def test_job_limit_is_checked_before_expansion(tmp_path):
    """A 10^7-run grid (2 models x 2 commands x 1581^2 fault sets) is refused in seconds."""
    camp = write_campaign(tmp_path, huge_grid(1581))
    proc = invoke_eha("campaign", "validate", camp)
    line = error_line(proc, 2)
    assert "expands to up to 9998248 jobs; the limit is 200000" in line


def test_validation_of_a_long_run_allocates_no_step_grid(tmp_path):
    """t_end = 3600 s at DT = 1e-5 s is 3.6e8 steps: validating it used to take 5.7 GB."""
    camp = write_campaign(tmp_path, '''
        name = "long"
        models = ["hf", "lf"]
        commands = ["ramp"]
        t_end = 3600
    ''')
    code = (f"import resource; from eha.campaigns.files import load_campaign; "
            f"c = load_campaign({str(camp)!r}); "
            f"print(len(c.jobs), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout.split()
    jobs, peak_kb = int(out[0]), int(out[1])
    if sys.platform == "darwin":
        peak_kb //= 1024  # bytes there
    assert jobs == 2 and peak_kb < 1_000_000, peak_kb


def test_validation_uses_the_campaigns_own_dt(tmp_path):
    """At the nominal DT 3600 s is allowed; at the campaign's DT = 1e-6 s of the HF runs it is
    3.6e9 steps per run (about 58 GB), refused before anything runs."""
    camp = write_campaign(tmp_path, '''
        name = "fine"
        models = ["hf", "lf"]
        commands = ["ramp"]
        t_end = 3600
        [params.hf]
        DT = 1e-6
    ''')
    line = error_line(invoke_eha("campaign", "validate", camp), 2)
    assert "DT=1e-06" in line and "(HF)" in line and "at most 4e+08" in line


@pytest.mark.parametrize("name", ["..", ".", ".hidden", "-x"])
def test_campaign_name_that_would_leave_the_traces_folder(tmp_path, name):
    camp = write_campaign(tmp_path, f'name = "{name}"\nmodels = ["lf"]\ncommands = ["ramp"]\n'
                                    "t_end = 0.01\n")
    results = tmp_path / "results"
    line = error_line(invoke_eha("campaign", "run", camp, "--results", results), 2)
    assert f"name: {name!r} is not a valid campaign name" in line
    assert "starting with a letter or digit" in line and not results.exists()


def test_two_points_with_one_name_are_refused(tmp_path):
    camp = write_campaign(tmp_path, '''
        name = "pts"
        models = ["lf"]
        commands = ["ramp"]
        t_end = 0.01
        [faults]
        points = [{name = "worn", BKL = 1e-4}, {name = "new", BKL = 0.0},
                  {name = "worn", BKL = 5e-4}]
    ''')
    line = error_line(invoke_eha("campaign", "validate", camp), 2)
    assert "faults.points[2].name: 'worn' is also the name of faults.points[0]" in line


def test_every_problem_of_an_fdi_section_is_reported(tmp_path):
    camp = write_campaign(tmp_path, '''
        name = "fdibad"
        kind = "fdi"
        [fdi]
        method = "nope"
        seeds = [-1]
        [[fdi.cases]]
        command = "ramp"
        bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
        pop = 2
        [[fdi.cases]]
        command = "ramp"
        bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
        [[fdi.cases]]
        command = "nosuch"
        bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
    ''')
    proc = invoke_eha("campaign", "validate", camp)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert all(line.startswith("error: fdi: fdi.") for line in lines), lines
    text = "\n".join(lines)
    assert "fdi.method 'nope'" in text and "fdi.seeds" in text
    assert "fdi.cases[0]: pop=2" in text and "fdi.cases[2]: command" in text
    assert len(lines) == 4


def test_messages_with_brackets_keep_them(tmp_path):
    camp = write_campaign(tmp_path, 'name = "b"\nmodels = ["lf"]\ncommands = ["ramp"]\n'
                                    "t_end = 0.01\nfdi = 3\n[faults]\ngrid = {BKL = [5.0]}\n")
    proc = invoke_eha("campaign", "validate", camp)
    assert proc.returncode == 2
    assert "must be a table ([fdi])" in proc.stderr
    assert "allowed range [0, 0.1] m" in proc.stderr


# =========================================================================== class 6: options
@pytest.mark.parametrize("args, message", [
    (["--candidates", "-1"], "--candidates -1: allowed range [0, ...]"),
    (["--max-steps", "-1"], "--max-steps -1: allowed range [0, ...]"),
    (["--min-gain", "nan"], "--min-gain nan: allowed range [0, 1]"),
    (["--min-gain", "-0.5"], "--min-gain -0.5: allowed range [0, 1]"),
    (["--p12-weight", "-1"], "--p12-weight -1.0: allowed range [0, 100]"),
    (["--p12-weight", "nan"], "--p12-weight nan: allowed range [0, 100]"),
    (["--method", "lm"], "--method lm: the loop's refits search globally; allowed ga, ga+ps"),
    (["--fit", "BKL,BKL"], "--fit BKL,BKL: BKL given twice"),
    (["--fit", "BKL=0:1e-3,FDJ,BKL"], "BKL given twice"),
    (["--prior", "PRIOR"], "expected the --json of an earlier eha explain (key 'steps'"),
])
def test_explain_option_ranges(tmp_path, args, message):
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"estimates": {"BKL": 1e-4}, "objective": 1e-6}))
    data = record_csv(tmp_path / "rec.csv")
    args = [str(prior) if a == "PRIOR" else a for a in args]
    before = files_under(tmp_path)
    line = error_line(invoke_eha("explain", data, "--results", tmp_path / "r", "--no-progress",
                              *args), 2)
    assert message in line
    assert files_under(tmp_path) == before


def test_fdi_fit_named_twice(tmp_path):
    line = error_line(invoke_eha("fdi", "--command", "ramp", "--fit", "BKL,FDJ,BKL", "--json",
                              tmp_path / "r.json"), 2)
    assert "--fit BKL,FDJ,BKL: BKL given twice" in line and not files_under(tmp_path)


def test_one_name_value_parser():
    from eha.models.params import ParameterError, parse_assignment, parse_name_value

    assert parse_assignment(" BKL =1e-4") == ("BKL", 1e-4)
    assert parse_name_value("BKL=0:1e-3", "--bounds", "LO:HI") == ("BKL", (0.0, 1e-3))
    assert parse_name_value("FDJ", "--fit", "[LO:HI]") == ("FDJ", None)
    for text, form, message in [("BKL", "VALUE", "--x 'BKL': expected NAME=VALUE"),
                                ("FDJ=abc", "VALUE", "FDJ: value 'abc' is not a number"),
                                ("BKL=1", "LO:HI", "--x 'BKL=1': expected NAME=LO:HI"),
                                ("=1:2", "[LO:HI]", "expected NAME=LO:HI")]:
        with pytest.raises(ParameterError, match=message):
            parse_name_value(text, "--x", form)
