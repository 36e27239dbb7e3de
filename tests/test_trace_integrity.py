"""Damage inside a trace chunk is caught (issue 43): a checksum of every trace file's bytes
is recorded with its runs; the resume hashes every file and redoes the runs of a damaged
one; a query or an export over ``traces`` names the damaged file and the one command that
repairs it; ``eha campaign verify`` checks a results folder without running anything."""

from __future__ import annotations

import os
import shutil
import textwrap

import pytest
from helpers import Inline, error_line, invoke_eha

from eha.campaigns.query import query
from eha.campaigns.runner import run_campaign

CAMPAIGN = textwrap.dedent("""
    name = "dmg"
    models = ["hf", "lf"]
    commands = ["ramp", "step_1mm"]
    seeds = [0, 1, 2, 3, 4, 5, 6, 7]
    t_end = 0.05
    signals = ["t", "com", "xu", "xj", "xs", "p12", "cor"]
    [faults]
    nominal = true
    single = {BKL = [1e-4, 5e-4, 1e-3]}
""")   # 128 runs: 2 per chunk file

#: The audit's 24 trials: at 10, 20, ..., 80 % of the file, bit 0 or bit 7 of one byte
#: flipped, or 16 bytes overwritten; the size is kept.
TRIALS = [(pct, how) for pct in range(10, 90, 10) for how in ("bit0", "bit7", "16 bytes")]


def state(results):
    runs = query(results, "SELECT * FROM runs JOIN metrics USING (run_key) ORDER BY run_key")
    return runs.drop(columns=["worker", "queued_at", "started_at", "finished_at", "sim_s",
                              "elapsed_s", "trace_mtime"])


def traces(results):
    return query(results, "SELECT * FROM traces ORDER BY run_key, t")


@pytest.fixture(scope="module")
def undamaged(tmp_path_factory):
    root = tmp_path_factory.mktemp("dmg")
    (root / "dmg.toml").write_text(CAMPAIGN)
    s = run_campaign(root / "dmg.toml", root / "results", executor=Inline(), progress=False)
    assert (s.done, s.failed) == (128, 0)
    results = root / "results"
    return root / "dmg.toml", results, state(results), traces(results)


def damage(path, pct: int, how: str) -> None:
    size = path.stat().st_size
    at = size * pct // 100
    with open(path, "r+b") as fh:
        fh.seek(at)
        if how == "16 bytes":
            old = fh.read(16)
            new = bytes((b + 0x5A) & 0xFF for b in old)  # every byte differs
            fh.seek(at)
            fh.write(new)
        else:
            b = fh.read(1)[0] ^ (1 if how == "bit0" else 0x80)
            fh.seek(at)
            fh.write(bytes([b]))
    assert path.stat().st_size == size


def copy(undamaged, tmp_path):
    camp, results, *_ = undamaged
    shutil.copytree(results, tmp_path / "results")
    return camp, tmp_path / "results"


#: The quick loop's trials: each kind of damage twice, at six depths into the file; the full
#: suite runs the other 18 of the 24 as well.
QUICK_TRIALS = TRIALS[::4]


@pytest.mark.parametrize("trials", [
    pytest.param(QUICK_TRIALS, id="6"),
    pytest.param([t for t in TRIALS if t not in QUICK_TRIALS], id="18", marks=pytest.mark.slow)])
def test_the_24_damage_trials_are_named_by_a_query_and_redone_by_the_resume(undamaged,
                                                                            tmp_path, trials):
    camp, results = copy(undamaged, tmp_path)
    _, _, before, before_traces = undamaged
    chunks = sorted(before["trace_path"].unique())
    named = redone = 0
    for i, (pct, how) in enumerate(trials):
        victim = chunks[i % len(chunks)]
        in_it = int((before["trace_path"] == victim).sum())
        damage(results / victim, pct, how)
        proc = invoke_eha("query", "SELECT count(*), avg(xj) FROM traces",
                          "--results", results)
        line = error_line(proc, 1)
        named += (os.path.basename(victim) in line
                  and "eha campaign verify --repair" in line)
        s = run_campaign(camp, results, executor=Inline(), progress=False)
        redone += (s.done, s.skipped) == (in_it, 128 - in_it)
        assert state(results).equals(before), (pct, how)
    assert (named, redone) == (len(trials), len(trials))
    assert traces(results).equals(before_traces)


def test_export_of_traces_names_the_damaged_file_and_writes_nothing(undamaged, tmp_path):
    _, results = copy(undamaged, tmp_path)
    victim = sorted((results / "traces" / "dmg").glob("*.parquet"))[3]
    damage(victim, 50, "bit0")
    out = tmp_path / "t.csv"
    line = error_line(invoke_eha("export", "traces", "--csv", out, "--results", results), 1)
    assert victim.name in line and "eha campaign verify --repair" in line
    assert not out.exists() and list(tmp_path.glob(".t.csv*")) == []
    # the tables without traces are still read
    assert invoke_eha("query", "SELECT count(*) FROM runs", "--results", results).returncode == 0


def test_campaign_verify_checks_without_running_and_its_repair_repairs(undamaged, tmp_path):
    _, results = copy(undamaged, tmp_path)
    _, _, before, before_traces = undamaged
    ok = invoke_eha("campaign", "verify", "--results", results)
    assert ok.returncode == 0 and "64 trace files of 128 runs checked, 0 damaged" in ok.stdout
    files = sorted((results / "traces" / "dmg").glob("*.parquet"))
    damage(files[0], 30, "16 bytes")
    st = os.stat(files[1])
    damage(files[1], 70, "bit7")
    os.utime(files[1], ns=(st.st_atime_ns, st.st_mtime_ns))  # time put back: hashing sees it
    db = (results / "eha.duckdb").read_bytes()
    proc = invoke_eha("campaign", "verify", "--results", results)
    assert proc.returncode == 1 and "2 damaged" in proc.stdout
    assert files[0].name in proc.stderr and files[1].name in proc.stderr
    assert "eha campaign verify --repair" in proc.stderr.splitlines()[-1]
    assert (results / "eha.duckdb").read_bytes() == db       # nothing written
    proc = invoke_eha("campaign", "verify", "--repair", "--results", results)
    assert proc.returncode == 0, proc.stderr
    assert "dmg: 4 runs of its damaged trace files run again" in proc.stdout
    assert state(results).equals(before) and traces(results).equals(before_traces)
    again = invoke_eha("campaign", "verify", "--results", results)
    assert again.returncode == 0 and "0 damaged" in again.stdout


def test_a_copy_that_changed_the_times_is_hashed_once_then_restamped(undamaged, tmp_path):
    camp, results = copy(undamaged, tmp_path)
    for f in (results / "traces" / "dmg").glob("*.parquet"):
        os.utime(f, ns=(1, 1))
    from eha.campaigns.integrity import check_files, recorded_files
    from eha.campaigns.store import ResultStore

    with ResultStore(results) as db:
        files = recorded_files(db.con)
        assert check_files(results, files, full=False).hashed == 64
        assert len(db.verify_traces("dmg")[0]) == 128       # restamps
        assert check_files(results, recorded_files(db.con), full=False).hashed == 0
