"""Runner: local spawn pool, metrics, resume, changed campaigns, worker set-up, Dask path."""

import json
import subprocess
import sys
import textwrap

import numpy as np
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from eha.cli import app
from eha.simulations.batch import worker_info
from eha.campaigns.executors import LocalPoolExecutor
from eha.campaigns.jobs import execute_job
from eha.campaigns.runner import run_campaign
from eha.models.run_metrics import lag, pair_metrics, settling_time
from eha.models.simulate import simulate
from eha.campaigns.query import query
from eha.campaigns.traces import read_trace

cli = CliRunner()

CAMPAIGN = textwrap.dedent("""
    name = "mini"
    models = ["hf", "lf"]
    commands = ["ramp", "mixed"]
    t_end = 0.08
    [faults]
    grid = {BKL = [1e-4, 5e-4], FDJ = [400.0]}
""")


def write(tmp_path, text=CAMPAIGN, name="mini.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_settling_time_and_lag_on_known_signals():
    t = np.arange(0, 1.0001, 1e-3)
    com = np.ones_like(t)
    xu = 1 - np.exp(-t / 0.05)
    assert settling_time(t, xu, com) == pytest.approx(-0.05 * np.log(0.02), abs=1.5e-3)
    assert settling_time(t, np.zeros_like(t), com) is None
    ramp = 0.01 * t
    assert lag(t, 0.01 * np.clip(t - 0.025, 0, None), ramp) == pytest.approx(0.025)
    assert lag(t, xu, com) is None  # constant command: no lag defined


def test_execute_job_records_a_failure_instead_of_raising(tmp_path):
    res = execute_job({"kind": "simulate", "spec": {"model": "hf"}, "run_key": "f" * 16,
                       "campaign": "x", "trace_file": str(tmp_path / "f.parquet"),
                       "trace_path": "traces/x/f.parquet"})
    assert res["status"] == "failed" and res["error"].startswith("KeyError")
    assert res["rows"] == {} and res["trace_path"] is None


@pytest.mark.slow
def test_campaign_run_rows_traces_metrics_and_resume(tmp_path):
    path = write(tmp_path)
    results = tmp_path / "results"
    s = run_campaign(path, results, workers=2, progress=False)
    assert (s.total, s.done, s.skipped, s.failed) == (8, 8, 0, 0)
    runs = query(results, "SELECT * FROM runs JOIN metrics USING (run_key) ORDER BY run_key")
    assert len(runs) == 8 and set(runs["status"]) == {"done"}
    assert runs["worker"].nunique() >= 1 and (runs["elapsed_s"] > 0).all()
    for _, r in runs.iterrows():
        file = results / r["trace_path"]
        assert file.name == f"{r['run_key']}.parquet" and file.parent.name == "mini"
        meta = json.loads(pq.read_schema(file).metadata[b"eha"])
        assert meta["run_key"] == r["run_key"] and meta["campaign"] == "mini"
        assert meta["model"] == r["model"] and meta["params"] == json.loads(r["faults"])
    # the recorded trace is the simulation of the recorded spec (seeded, reproducible)
    hf = runs[(runs["model"] == "hf") & (runs["command"] == "mixed")].iloc[0]
    again = simulate("hf", "mixed", json.loads(hf["faults"]), t_end=0.08, seed=int(hf["seed"]))
    np.testing.assert_array_equal(read_trace(results / hf["trace_path"]).xu, again.xu)
    # HF-vs-LF metrics: both runs of each case carry the RMSE between their traces
    for _, case in runs.groupby("case_key"):
        assert set(case["model"]) == {"hf", "lf"}
        tr = {m: read_trace(results / p) for m, p in zip(case["model"], case["trace_path"])}
        expected = pair_metrics(tr["hf"], tr["lf"])["rmse_xu_hf_lf"]
        assert case["rmse_xu_hf_lf"].tolist() == pytest.approx([expected, expected])
        assert expected > 0
    assert (runs["p12_abs_max"] > 0).all() and runs["lag"].notna().all()

    res = cli.invoke(app, ["plot", "mini", "--results", str(results)])
    assert res.exit_code == 0, res.output
    pngs = sorted(p.name for p in (results / "plots" / "mini").glob("*.png"))
    assert pngs == ["mixed_p12.png", "mixed_xu.png", "ramp_p12.png", "ramp_xu.png",
                    "rmse_hf_lf.png"]
    assert all((results / "plots" / "mini" / n).read_bytes()[:4] == b"\x89PNG" for n in pngs)
    res = cli.invoke(app, ["plot", "nope", "--results", str(results)])
    assert res.exit_code == 2 and "no finished runs" in res.output

    again = run_campaign(path, results, workers=2, progress=False)
    assert (again.done, again.skipped) == (0, 8)
    # a run whose trace disappeared is run again, and only that one
    (results / runs["trace_path"].iloc[3]).unlink()
    third = run_campaign(path, results, workers=1, progress=False)
    assert (third.done, third.skipped) == (1, 7)
    assert query(results, "SELECT count(*) AS n FROM runs")["n"][0] == 8


@pytest.mark.slow
def test_changed_campaign_is_reported_then_replaced(tmp_path):
    path = write(tmp_path)
    results = tmp_path / "results"
    res = cli.invoke(app, ["campaign", "run", str(path), "--results", str(results),
                           "--no-progress"])
    assert res.exit_code == 0, res.output
    path.write_text(CAMPAIGN.replace("FDJ = [400.0]", "FDJ = [800.0, 400.0]"))
    proc = subprocess.run([sys.executable, "-m", "eha", "campaign", "run", str(path),
                           "--results", str(results), "--no-progress"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "campaign 'mini'" in lines[0]
    assert "different definition" in lines[0] and "8 recorded runs, 16 planned, 8 in common" \
        in lines[0]
    assert query(results, "SELECT count(*) AS n FROM runs")["n"][0] == 8
    res = cli.invoke(app, ["campaign", "run", str(path), "--results", str(results), "--replace",
                           "--no-progress"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "discarded 0 runs" in res.output and "8 run now, 8 already done" in res.output
    runs = query(results, "SELECT count(*) AS n, count(DISTINCT run_key) AS k FROM runs")
    assert runs["n"][0] == runs["k"][0] == 16
    assert len(list((results / "traces" / "mini").glob("*.parquet"))) == 16
    # shrinking the grid discards the runs (rows and traces) it no longer has
    path.write_text(CAMPAIGN.replace("FDJ = [400.0]", "FDJ = [800.0]"))
    res = cli.invoke(app, ["campaign", "run", str(path), "--results", str(results), "--replace",
                           "--no-progress"], env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "discarded 8 runs" in res.output, res.output
    assert "0 run now, 8 already done" in res.output
    counts = query(results, "SELECT (SELECT count(*) FROM runs) AS r, "
                            "(SELECT count(*) FROM metrics) AS m, "
                            "(SELECT n_runs FROM campaigns) AS c")
    assert counts.iloc[0].tolist() == [8, 8, 8]
    assert len(list((results / "traces" / "mini").glob("*.parquet"))) == 8


@pytest.mark.slow
def test_pool_workers_use_one_numba_thread_and_the_kernel_cache():
    with LocalPoolExecutor(2) as ex:
        ex.warm_up()
        infos = [f.result() for f in [ex._pool.submit(worker_info) for _ in range(6)]]
    assert all(i["numba_threads"] == 1 for i in infos)
    assert all(i["cache_misses"] == 0 and i["cache_hits"] >= 2 for i in infos), infos


@pytest.mark.slow
def test_dask_scheduler_option_on_a_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    path = write(tmp_path)
    results = tmp_path / "results"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  protocol="tcp", host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        proc = subprocess.run([sys.executable, "-m", "eha", "campaign", "run", str(path),
                               "--results", str(results), "--scheduler",
                               cluster.scheduler_address, "--no-progress"],
                              capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    runs = query(results, "SELECT status, worker FROM runs")
    assert len(runs) == 8 and set(runs["status"]) == {"done"}
    # the jobs ran in the cluster (this process), not in the CLI process
    import os

    assert set(runs["worker"].str.split(":").str[1]) == {str(os.getpid())}
    metrics = query(results, "SELECT count(rmse_xu_hf_lf) AS n FROM metrics")
    assert metrics["n"][0] == 8
