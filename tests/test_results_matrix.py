"""Every results folder opens in every reader (issue 61).

One results folder per command that writes one, each written by that command alone through
the real command line (small settings: 0.1-0.3 s records, a few actuators, tiny searches),
then every reader on it: ``eha report html``, ``eha query`` (every table, and one the folder
lacks), ``eha export`` of every table, ``eha report health`` and ``eha report thesis``. A
reader shows what the folder holds and names what it lacks: exit 0, or exit 2 with one line
naming what is missing; never a database error for a table nothing wrote, never the advice
to move a good database away. A last folder mixes the commands.

The folders of a campaign and of ``eha fdi`` are built in the quick loop; the others (``eha
design``, ``eha rul``, ``eha health calibrate`` + ``check``, ``eha design verify``, ``eha
explain``, an FDI campaign as ``eha reproduce`` runs it, and the mixed folder, which runs ``eha
fdi`` and ``eha design`` again) are ``slow``: each is a command line in its own process.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from helpers import SMALL_FLEET, invoke_eha, run_eha, small_campaign, write_campaign

#: Sections of ``eha report html`` each folder must show (at least).
SHOWN = {"campaign": {"campaigns"}, "fdi": {"fdi"}, "design": {"design"},
         "rul": {"fleet"}, "health": {"health"}, "verify": {"health"},
         "explain": {"explain"}, "fdi_campaign": {"identification"},
         "mix": {"campaigns", "fdi", "design"}}

#: A three-case FDI campaign named as the thesis' (what `eha reproduce` runs for `eha report
#: thesis`), 0.1 s, one seed, least squares.
FDI_CAMPAIGN = """
    name = "thesis-fdi"
    description = "one small case"
    kind = "fdi"
    [fdi]
    fit = ["BKL", "FDJ"]
    method = "lm"
    objective = "rmse"
    seeds = [0]
    t_end = 0.1
    [[fdi.cases]]
    case = 1
    command = "step_1mm"
    faults = { BKL = 1e-4, FDJ = 800 }
    bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
    pop = 4
    [[fdi.cases]]
    case = 2
    command = "chirp_1mm"
    faults = { BKL = 5e-5, FDJ = 1600 }
    bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
    pop = 4
    [[fdi.cases]]
    case = 3
    command = "mixed"
    faults = { BKL = 2e-4, FDJ = 400 }
    bounds = { BKL = [0, 1e-3], FDJ = [200, 4000] }
    pop = 4
"""


def _ok(*args):
    """The command in its own process: a folder holds only the tables its command's modules
    declare (in one process, every table declared so far is created in each database)."""
    proc = run_eha(*map(str, args))
    assert proc.returncode == 0, (args, proc.stdout, proc.stderr)
    return proc


def _campaign(results: Path, work: Path, get) -> None:
    _ok("campaign", "run", small_campaign(work, 0.05), "--results", results, "--workers", 1)


def _fdi(results: Path, work: Path, get=None) -> None:
    _ok("fdi", "--command", "step_1mm", "--set", "FDJ=800", "--fit", "FDJ", "--method", "lm",
        "--t-end", 0.1, "--results", results)


def _design(results: Path, work: Path, get=None) -> Path:
    _ok("design", "--faults", "FDJ", "--generations", 1, "--population", 4, "--actuators", 1,
        "--duration", 0.3, "--out", work / "design", "--name", "design", "--results", results)
    return work / "design" / "design.json"


def _fleet(work: Path) -> Path:
    """The small fleet's records (``eha fleet simulate``, outside any results folder), one
    simulation for the module: the rul and health folders both read them (``work`` is a
    folder's own work folder; the fleet is beside them)."""
    work = work.parent
    if not (work / "fleet" / "manifest.csv").is_file():
        (work / "fleet.toml").write_text(SMALL_FLEET)
        _ok("fleet", "simulate", work / "fleet.toml", "--out", work / "fleet", "--no-progress",
            "--workers", 1)
    return work / "fleet"


def _rul(results: Path, work: Path, get) -> None:
    fleet = _fleet(work)
    proc = _ok("rul", fleet / "manifest.csv", "--limit", "FDJ=1500", "--fit", "FDJ",
               "--results", results, "--no-progress", "--workers", 1)
    assert "RUL median [cycles]" in proc.stdout        # the unit of the manifest's cycles


def _health(results: Path, work: Path, get) -> None:
    fleet = _fleet(work)
    cal = work / "calibration.json"
    _ok("health", "calibrate", "--command", "chirp_1cm", "--t-end", 0.3, "--actuators", 5,
        "--out", cal, "--results", results, "--workers", 1, "--no-progress")
    record = sorted((fleet / "records").rglob("*.csv"))[0]
    _ok("health", "check", record, "--calibration", cal, "--results", results)


def _verify(results: Path, work: Path, get) -> None:
    # the design the "design" folder's command wrote (its JSON is outside that folder's
    # database; verify writes only into its own folder)
    get("design")
    design = work.parent / "design-work" / "design" / "design.json"
    proc = _ok("design", "verify", design, "--healthy", 6, "--calibration", 5, "--per-level",
               1, "--library", "step_1mm", "--results", results, "--workers", 1,
               "--no-progress")
    # the finding first, in the fault's unit (it printed a bare SI table)
    assert proc.stdout.startswith("FDJ detected (P_D >= 0.95) from a change of: the design: ")
    assert " N" in proc.stdout.splitlines()[0]


def _explain(results: Path, work: Path, get) -> None:
    record = work / "record.parquet"
    _ok("simulate", "--command", "step_1mm", "--t-end", 0.3, "--set", "FDJ=800", "--out", record)
    # the smallest search that still adds a step (the readers' claim needs a folder that
    # `eha explain` wrote, with a step in explain_steps, not the loop's full search): the
    # null of 5 healthy actuators, one candidate effect, no replicates (14 s, not 45-70 s)
    proc = _ok("explain", record, "--fit", "FDJ", "--pop", 4, "--null-actuators", 5,
               "--effects", "flapper_dynamics", "--candidates", 1, "--max-steps", 1,
               "--interval-replicates", 0, "--rival-replicates", 0, "--results", results)
    assert "flapper_dynamics" in proc.stdout, proc.stdout
    # off a terminal no spinner is drawn: stderr holds plain lines only, phases (" ...", at
    # most one per LINE_EVERY_S, so how many depends on the machine's speed; their timing is
    # tested in test_cli_frictions) and warnings
    assert "\x1b[" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert all(line.endswith(" ...") or line.startswith("warning: ")
               for line in proc.stderr.splitlines()), proc.stderr


def _fdi_campaign(results: Path, work: Path, get) -> None:
    _ok("campaign", "run", write_campaign(work, FDI_CAMPAIGN, "thesis-fdi.toml"), "--results",
        results, "--workers", 1)


def _mix(results: Path, work: Path, get) -> None:
    """The campaign folder (a copy: its database records its traces by relative path), then
    ``eha fdi`` and ``eha design`` into it: the three commands' tables in one folder, with
    one campaign run less than running all three here."""
    shutil.copytree(get("campaign"), results)
    for build in (_fdi, _design):
        build(results, work)


BUILDERS = {"campaign": _campaign, "fdi": _fdi, "design": _design, "rul": _rul,
            "health": _health, "verify": _verify, "explain": _explain,
            "fdi_campaign": _fdi_campaign, "mix": _mix}
QUICK = ("campaign", "fdi")


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """``{command: results folder}``, each built on first use (a test of a folder builds it)."""
    work = tmp_path_factory.mktemp("matrix")
    made: dict[str, Path] = {}

    def get(name: str) -> Path:
        if name not in made:
            results = work / name
            (work / f"{name}-work").mkdir(exist_ok=True)
            BUILDERS[name](results, work / f"{name}-work", get)
            made[name] = results
        return made[name]
    return get


def _no_database_error(proc) -> None:
    text = proc.stdout + proc.stderr
    assert "Traceback" not in text, text
    assert "Catalog Error" not in text and "does not exist" not in text, text
    assert "move it away" not in text and "damaged" not in text, text


def _one_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def _tables(results: Path) -> list[str]:
    from eha.campaigns.query import tables

    return [t for t in tables(results) if t != "traces"]


def _params(names):
    return [pytest.param(n, marks=() if n in QUICK else pytest.mark.slow) for n in names]


@pytest.mark.parametrize("name", _params(BUILDERS))
def test_the_html_report_shows_what_the_folder_holds_and_names_the_rest(folders, name,
                                                                        tmp_path):
    results = folders(name)
    out = tmp_path / "report.html"
    proc = invoke_eha("report", "html", "--results", results, "--out", out)
    _no_database_error(proc)
    assert proc.returncode == 0, proc.stderr
    text = out.read_text(encoding="utf-8")
    from eha.reports.html import SECTIONS

    shown = {sid for sid in SECTIONS if f'<section id="{sid}"' in text}
    assert SHOWN[name] <= shown, (name, shown)
    for sid in SHOWN[name]:  # every section it shows has a figure
        section = text.split(f'<section id="{sid}"')[1].split("</section>")[0]
        assert 'class="plot"' in section, (name, sid)
    absent = set(SECTIONS) - shown
    assert absent and "Not in this report" in text         # what it lacks, by name
    from eha.reports.html import FILLED_BY

    for sid in absent:
        assert FILLED_BY[sid].split(",")[0].split(" ...")[0] in text.replace("&#x27;", "'")


@pytest.mark.parametrize("name", _params(BUILDERS))
def test_query_and_export_of_every_table_and_of_one_it_lacks(folders, name, tmp_path):
    results = folders(name)
    tables = _tables(results)
    assert {"runs", "campaigns"} <= set(tables)
    for table in tables:
        proc = invoke_eha("query", f'SELECT count(*) AS n FROM "{table}"', "--results",
                          results, "--format", "csv")
        assert proc.returncode == 0, (table, proc.stderr)
        csv = tmp_path / f"{table}.csv"
        proc = invoke_eha("export", table, "--csv", csv, "--results", results)
        assert proc.returncode == 0 and csv.is_file(), (table, proc.stderr)
    proc = invoke_eha("query", "DESCRIBE runs", "--results", results)
    assert proc.returncode == 0 and "nan" not in proc.stdout.split()
    from eha.campaigns.jobs import TABLE_GROUP, _entry_points

    lacking = next(t for t in _entry_points(TABLE_GROUP) if t not in tables)
    for args in (["query", f"SELECT * FROM {lacking}"], ["export", lacking, "--csv",
                                                          tmp_path / "x.csv"]):
        proc = invoke_eha(*args, "--results", results)
        assert proc.returncode == 2
        line = _one_line(proc)
        assert lacking in line and "nothing has" in line and "move it away" not in line


@pytest.mark.parametrize("name", _params(BUILDERS))
def test_report_health_and_thesis_say_what_is_missing(folders, name, tmp_path):
    results = folders(name)
    for args in (["report", "health"], ["report", "thesis"]):
        proc = invoke_eha(*args, "--results", results, "--out", tmp_path / args[1])
        _no_database_error(proc)
        if args[1] == "thesis" and name == "fdi_campaign":
            assert proc.returncode == 0, proc.stderr
            assert (tmp_path / "thesis" / "fdi_table.csv").is_file()
            continue
        assert proc.returncode == 2, (args, proc.stdout, proc.stderr)
        line = _one_line(proc)
        assert ("no detection campaign" in line if args[1] == "health"
                else "no FDI results" in line), line
    if name == "verify":  # its campaign is a detection campaign, named in the message
        proc = invoke_eha("report", "health", "--results", results, "--out", tmp_path / "h")
        campaign = _one_line(proc).split("there: ")[1].split(")")[0]
        proc = invoke_eha("report", "health", "--campaign", campaign, "--results", results,
                          "--out", tmp_path / "h")
        assert proc.returncode == 0, proc.stderr
        assert (tmp_path / "h" / "detection.csv").is_file()


def test_a_missing_table_is_never_called_a_damaged_database():
    """The guard's line for DuckDB's "Table ... does not exist" (an unexpected reader):
    the table is named, the database said to be intact, no advice to move it away."""
    import duckdb

    from eha.cli.guard import _unexpected

    con = duckdb.connect()
    try:
        con.execute("SELECT * FROM metrics")
    except duckdb.Error as exc:
        line = _unexpected(exc)
    assert "metrics" in line and "intact" in line and "move it away" not in line
    damaged = duckdb.IOException("IO Error: Corrupt database file: checksum mismatch")
    assert "move it away" in _unexpected(damaged)


def test_a_report_reader_that_meets_a_missing_table_leaves_its_section_out(folders, tmp_path,
                                                                          monkeypatch):
    """A section whose reader meets a table the database lacks (a folder an older version
    wrote) is named as absent with the table, and the rest of the report is written."""
    from eha.reports.html import build_report
    from eha.reports.html import data as D

    results = tmp_path / "results"          # a copy of the fdi folder: the report is untouched
    shutil.copytree(folders("fdi"), results)

    def old_reader(con):
        return con.execute("SELECT * FROM some_table_never_written").df()

    monkeypatch.setattr(D, "read_designs", old_reader)
    res = build_report(results, tmp_path / "r.html")
    text = (tmp_path / "r.html").read_text(encoding="utf-8")
    assert res.sections == ["fdi"]
    assert "some_table_never_written" in text


def test_an_empty_folder_and_a_folder_of_other_files_stay_one_line(tmp_path):
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    for folder in (tmp_path / "other", tmp_path / "none"):
        proc = invoke_eha("report", "html", "--results", folder, "--out", tmp_path / "r.html")
        assert proc.returncode == 2 and "eha" in _one_line(proc)
    shutil.rmtree(tmp_path / "other")


def test_fdi_rows_are_what_the_command_printed(folders):
    """``eha fdi --results``: one row, in SI, whose values are the JSON output's (the same fit
    run again replaces its row, never duplicates it)."""
    import json

    from eha.campaigns.query import query

    results = folders("fdi")
    fdi = query(results, "SELECT * FROM fdi_runs")
    assert len(fdi) == 1
    est = json.loads(fdi["estimates"].iloc[0])
    assert set(est) == {"FDJ"} and 200 <= est["FDJ"] <= 4000
    assert json.loads(fdi["truth"].iloc[0]) == {"FDJ": 800.0}
    _fdi(results, results.parent)
    assert len(query(results, "SELECT * FROM fdi_runs")) == 1


@pytest.mark.slow   # the design folder is built in the full suite
def test_design_rows_are_what_the_command_printed(folders):
    """``eha design --results``: one row, in SI, whose values are the JSON output's."""
    import json

    from eha.campaigns.query import query

    design = query(folders("design"), "SELECT * FROM design_runs")
    assert len(design) == 1
    doc = json.loads(Path(design["json_file"].iloc[0]).read_text())
    targets = json.loads(design["targets"].iloc[0])
    assert targets["FDJ"]["min_detectable"] == doc["targets"]["FDJ"]["min_detectable"]
    assert design["duration"].iloc[0] == pytest.approx(0.3)
    assert Path(design["command_file"].iloc[0]).is_file()


@pytest.mark.slow
@pytest.mark.parametrize("name", list(BUILDERS))
def test_each_folders_report_opens_in_headless_chromium(folders, name, tmp_path):
    """The report of each folder in a browser: no console error, no request but the file,
    every figure drawn (tests/browser.py; skipped where Chromium is missing, but in CI)."""
    from browser import check_page

    out = tmp_path / "report.html"
    proc = invoke_eha("report", "html", "--results", folders(name), "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert check_page(out, tmp_path)["plots"] >= 1
