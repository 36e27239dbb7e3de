"""kill -9 of the whole process group at several moments, then resume: real subprocesses, real
DuckDB file, real Parquet; the end state must equal an uninterrupted run's."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from eha.campaigns.query import query
from eha.campaigns.store import StoreError

CAMPAIGN = textwrap.dedent("""
    name = "killme"
    models = ["hf", "lf"]
    commands = ["ramp", "mixed"]
    t_end = 0.5
    [params]
    DT = 1e-6          # 10x the nominal steps: runs long enough to be killed in the middle
    [faults]
    grid = {BKL = [1e-4, 2e-4, 5e-4, 1e-3], FDJ = [400.0, 800.0, 1600.0, 3200.0, 6400.0]}
""")
TOTAL = 80


def start(campaign, results):
    # A new session is a new process group: the parent, its spawn workers and the
    # multiprocessing resource tracker all get the SIGKILL together.
    return subprocess.Popen([sys.executable, "-m", "eha", "campaign", "run", str(campaign),
                             "--results", str(results), "--workers", "2", "--no-progress"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def kill_group(proc):
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.time() + 10
    while time.time() < deadline:  # the workers are gone too
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    raise AssertionError("processes of the killed group are still alive")


def n_traces(results):
    folder = results / "traces" / "killme"
    return len(list(folder.glob("*.parquet"))) if folder.is_dir() else 0


def wait_for(cond, proc, timeout=60):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if cond() or proc.poll() is not None:
            return
        time.sleep(0.01)


def done_count(results):
    try:
        return int(query(results, "SELECT count(*) AS n FROM runs WHERE status = 'done'")["n"][0])
    except StoreError:  # killed before the database or its tables existed
        return 0


def state(results):
    runs = query(results, "SELECT * FROM runs JOIN metrics USING (run_key) ORDER BY run_key")
    return runs.drop(columns=["worker", "queued_at", "started_at", "finished_at", "sim_s",
                              "elapsed_s", "trace_mtime"])


@pytest.mark.slow
def test_kill_minus_9_at_any_moment_then_resume_equals_uninterrupted(tmp_path):
    campaign = tmp_path / "killme.toml"
    campaign.write_text(CAMPAIGN)
    reference = tmp_path / "reference"
    ref = subprocess.run([sys.executable, "-m", "eha", "campaign", "run", str(campaign),
                          "--results", str(reference), "--no-progress"],
                         capture_output=True, text=True, timeout=300)
    assert ref.returncode == 0, ref.stderr

    results = tmp_path / "results"
    moments = [
        lambda: (results / "eha.duckdb").exists(),  # while starting: DB open, pool spawning
        lambda: n_traces(results) >= 1,             # first traces being written
        lambda: n_traces(results) >= 30,            # in the thick of it
    ]
    done_after_kill = []
    for moment in moments:
        proc = start(campaign, results)
        wait_for(moment, proc)
        if proc.poll() is not None:
            raise AssertionError(f"the run finished before it could be killed (exit "
                                 f"{proc.returncode}): {proc.stderr.read().decode()[-2000:]}")
        kill_group(proc)
        done_after_kill.append(done_count(results))
    assert min(done_after_kill) < TOTAL, done_after_kill  # the kills did interrupt the work

    final = subprocess.run([sys.executable, "-m", "eha", "campaign", "run", str(campaign),
                            "--results", str(results), "--no-progress"],
                           capture_output=True, text=True, timeout=300)
    assert final.returncode == 0, final.stderr

    got, want = state(results), state(reference)
    assert len(got) == TOTAL and got["run_key"].is_unique
    assert set(got["status"]) == {"done"}
    assert got.equals(want), "resumed results differ from the uninterrupted run"
    counts = query(results, """SELECT (SELECT count(*) FROM runs) AS runs,
                                      (SELECT count(DISTINCT run_key) FROM runs) AS keys,
                                      (SELECT count(*) FROM metrics) AS metrics,
                                      (SELECT count(*) FROM campaigns) AS campaigns,
                                      (SELECT count(DISTINCT run_key) FROM traces) AS traces""")
    assert counts.iloc[0].tolist() == [TOTAL, TOTAL, TOTAL, 1, TOTAL]
    files = sorted(p.relative_to(results) for p in results.rglob("*") if p.is_file())
    ref_files = sorted(p.relative_to(reference) for p in reference.rglob("*") if p.is_file())
    assert files == ref_files  # no temporary file, no WAL, no stray trace
    assert not [p for p in files if p.name.endswith((".tmp", ".wal"))]
