"""Exit codes as docs/reliability.md states them (issue 43): one table, case -> code, each
case run through the command line. 2: bad input or a results folder that cannot be used as
given (missing, locked); 1: a failure of the machine or of a file (a full disk, a damaged
trace or database)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys

import pytest
from helpers import Inline, error_line, invoke_eha, small_campaign

import report_data
from eha.campaigns.runner import run_campaign


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("codes")
    small_campaign(root, 0.05)
    assert run_campaign(root / "small.toml", root / "results", executor=Inline(),
                        progress=False).failed == 0
    report_data.build(root / "report")
    return root


def damaged_trace(root, tmp):
    shutil.copytree(root / "results", tmp / "r")
    chunk = next((tmp / "r" / "traces" / "small").glob("*.parquet"))
    with open(chunk, "r+b") as fh:
        fh.seek(chunk.stat().st_size // 2)
        fh.write(b"\x00" * 16)
    return ["query", "SELECT avg(xu) FROM traces", "--results", tmp / "r"]


def damaged_database(root, tmp):
    shutil.copytree(root / "results", tmp / "r")
    db = tmp / "r" / "eha.duckdb"
    with open(db, "r+b") as fh:
        # its second half, whatever block the metrics landed in (16 kB at the middle missed
        # them once the database also held schema_migrations)
        fh.seek(db.stat().st_size // 2)
        fh.write(os.urandom(db.stat().st_size - db.stat().st_size // 2))
    return ["query", "SELECT * FROM metrics", "--results", tmp / "r"]


def truth_file(text: bytes):
    def case(root, tmp):
        (tmp / "truth.csv").write_bytes(text)
        return ["report", "html", "--results", root / "report", "--out", tmp / "r.html",
                "--truth", tmp / "truth.csv"]
    return case


#: (case, arguments (a function of the fixture's folder and a fresh folder), exit code,
#: words of the one error line)
CASES = [
    ("option out of range", lambda r, t: ["campaign", "run", r / "small.toml", "--workers",
                                          "0"], 2, "--workers"),
    ("query that writes", lambda r, t: ["query", "SET threads = 1", "--results",
                                        r / "results"], 2, "refused"),
    ("query of a folder without database", lambda r, t: ["query", "SELECT 1", "--results", t],
     2, "no result database"),
    ("report thesis of a folder without database",
     lambda r, t: ["report", "thesis", "--results", t], 2, "no result database"),
    ("report html of a folder without database",
     lambda r, t: ["report", "html", "--results", t, "--out", t / "r.html"], 2, "results"),
    ("query of a damaged trace", damaged_trace, 1, "eha campaign verify --repair"),
    ("query of a damaged database", damaged_database, 1, "damaged"),
    ("report html --truth not UTF-8", truth_file(b"actuator,eol\nA1,\xff\xfe\n"), 2,
     "not UTF-8"),
    ("report html --truth of other actuators", truth_file(b"actuator,eol\nZ9,100\n"), 2,
     "no end of life"),
]


@pytest.mark.parametrize("case, args, code, words", CASES, ids=[c[0] for c in CASES])
def test_exit_code_of_each_case(folders, tmp_path, case, args, code, words):
    line = error_line(invoke_eha(*args(folders, tmp_path)), code)
    assert words in line, line


def test_a_locked_database_is_2_for_every_reader(folders, tmp_path):
    """query, export and report html alike (report html said 1)."""
    results = folders / "results"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import duckdb, sys, time; c = duckdb.connect(sys.argv[1]); "
         "print('locked', flush=True); time.sleep(60)", str(results / "eha.duckdb")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        for args in (["query", "SELECT 1"], ["export", "runs", "--csv", tmp_path / "r.csv"],
                     ["report", "html", "--out", tmp_path / "r.html"],
                     ["campaign", "verify"]):
            assert "locked by another process" in error_line(
                invoke_eha(*args, "--results", results), 2)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()


def test_export_on_a_full_disk_is_1_naming_the_file(folders, tmp_path):
    """It was 2 with DuckDB's raw JSON. RLIMIT_FSIZE stands in for the full disk."""
    import resource

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    out = tmp_path / "traces.csv"
    proc = subprocess.run([sys.executable, "-m", "eha", "export", "traces", "--csv", str(out),
                           "--results", str(folders / "results")], capture_output=True,
                          text=True, preexec_fn=small_disk, timeout=120)
    line = error_line(proc, 1)
    assert f"{out}: could not be written (File too large)" in line and "{" not in line
    assert not out.exists() and list(tmp_path.iterdir()) == []
