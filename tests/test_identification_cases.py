"""FDI through the campaign runner and DuckDB, the thesis report, and the `eha fdi` CLI.

Real parts: a spawn worker pool, a DuckDB file, Parquet traces, subprocesses for the CLI.
Records are short (t_end = 0.3 s) to keep the file within a few tens of seconds.
"""

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from eha.campaigns.files import CampaignError, load_campaign
from eha.reports.thesis import thesis_report
from eha.campaigns.runner import run_campaign
from eha.campaigns.query import query
from helpers import invoke_eha
from eha.campaigns.store import StoreError

CAMPAIGN = """
name = "fdi-test"
kind = "fdi"
description = "two thesis cases on a short record"

[fdi]
seeds = [0, 1]
t_end = 0.3

[[fdi.cases]]
case = 9
command = "chirp_1cm"
faults = { BKL = 2e-4, FDJ = 200 }
bounds = { BKL = [0, 1.25e-3], FDJ = [200, 4000] }
thesis = { BKL = 2.02e-4, FDJ = 200, err_BKL_pct = -0.78, err_FDJ_pct = 0, mean_err_pct = 0.39 }

[[fdi.cases]]
case = 12
command = "chirp_1cm"
faults = { BKL = 1e-4, FDJ = 800 }
bounds = { BKL = [0, 1.5e-3], FDJ = [200, 900] }
pop = 40
thesis = { BKL = 1.06e-4, FDJ = 832.5374, err_BKL_pct = -5.93, err_FDJ_pct = -4.067, mean_err_pct = 5.0, seconds = 4873 }
"""


def _eha(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "eha", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def campaign_results(tmp_path_factory):
    root = tmp_path_factory.mktemp("fdi")
    path = root / "fdi-test.toml"
    path.write_text(CAMPAIGN)
    results = root / "results"
    first = run_campaign(path, results, workers=1, progress=False)
    second = run_campaign(path, results, workers=1, progress=False)
    return path, results, first, second


@pytest.mark.slow
def test_campaign_runs_into_fdi_results(campaign_results):
    path, results, first, second = campaign_results
    assert first.total == 4 and first.done == 4 and first.failed == 0
    assert second.skipped == 4 and second.done == 0          # resume: nothing re-run
    rows = query(results, "SELECT f.*, r.kind, r.status, r.trace_path FROM fdi_results f "
                          "JOIN runs r USING (run_key) ORDER BY f.case_id, f.seed")
    assert len(rows) == 4                                       # no duplicate rows
    assert list(rows["case_id"]) == [9, 9, 12, 12] and list(rows["seed"]) == [0, 1, 0, 1]
    assert set(rows["kind"]) == {"fdi"} and set(rows["status"]) == {"done"}
    assert set(rows["method"]) == {"ga+ps"} and set(rows["objective_name"]) == {"rmse"}
    for r in rows.itertuples():
        errors = json.loads(r.errors_pct)
        assert r.mean_err_pct == pytest.approx((abs(errors["BKL"]) + abs(errors["FDJ"])) / 2)
        assert r.err_bkl_pct == pytest.approx(100 * (r.bkl_true - r.bkl_est) / r.bkl_true)
        bounds = json.loads(r.bounds)
        assert bounds["FDJ"][0] <= r.fdj_est <= bounds["FDJ"][1]
        assert r.evaluations > 0 and r.seconds > 0 and r.objective > 0
        assert (results / r.trace_path).exists()                # the identified LF trace
        # HF vs plain LF on a 0.3 s record: BKL within 5 %, FDJ within 10 % (docs/fdi.md)
        assert abs(r.err_bkl_pct) < 5 and abs(r.err_fdj_pct) < 10


@pytest.mark.slow
def test_same_seed_same_row_in_a_fresh_database(campaign_results, tmp_path):
    path, results, *_ = campaign_results
    again = tmp_path / "again"
    run_campaign(path, again, workers=1, progress=False)
    cols = "case_id, seed, bkl_est, fdj_est, objective, evaluations"
    a = query(results, f"SELECT {cols} FROM fdi_results ORDER BY case_id, seed")
    b = query(again, f"SELECT {cols} FROM fdi_results ORDER BY case_id, seed")
    pd.testing.assert_frame_equal(a, b)


@pytest.mark.slow
def test_thesis_report_files(campaign_results, tmp_path):
    _, results, *_ = campaign_results
    paths = thesis_report(results, tmp_path / "report", campaign="fdi-test")
    table = pd.read_csv(paths["table"])
    for col in ("case", "mean_err_pct", "thesis_mean_err_pct", "seconds", "thesis_seconds",
                "bkl_in", "fdj_out", "err_bkl_pct", "mean_err_pct_min", "mean_err_pct_max"):
        assert col in table.columns
    assert list(table["case"]) == [9, 12] and list(table["seeds"]) == [2, 2]
    assert table.loc[1, "thesis_seconds"] == 4873 and table.loc[1, "thesis_mean_err_pct"] == 5.0
    assert paths["plot"].stat().st_size > 10_000
    assert sorted(p.name for p in paths["cases"].iterdir()) == ["case_09.png", "case_12.png"]
    text = paths["summary"].read_text()
    assert "| 12 |" in text and "mean_error.png" in text


def test_report_without_results_is_a_clear_error(tmp_path):
    with pytest.raises(StoreError, match="no result database"):
        thesis_report(tmp_path / "none")
    proc = invoke_eha("report", "thesis", "--results", tmp_path / "none")
    assert proc.returncode == 2 and "no result database" in proc.stderr   # as eha query


def test_bad_fdi_section_rejected_before_running(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CAMPAIGN.replace("FDJ = [200, 900]", "FDJ = [900, 200]"))
    with pytest.raises(CampaignError, match=r"fdi.cases\[1\].*FDJ.*below"):
        load_campaign(bad)
    assert not (tmp_path / "results").exists()


def test_thesis_campaign_file_expands_to_60_jobs():
    camp = load_campaign(Path(__file__).resolve().parents[1] / "campaigns" / "thesis-fdi.toml")
    assert len(camp.jobs) == 60 and {j.kind for j in camp.jobs} == {"fdi"}
    assert len({j.run_key for j in camp.jobs}) == 60


@pytest.mark.slow
def test_cli_fdi_against_hf_and_bad_input(tmp_path):
    out = tmp_path / "fit.json"
    proc = _eha("fdi", "--command", "chirp_1cm", "--set", "BKL=5e-4", "--set", "FDJ=200",
                "--t-end", "0.3", "--seed", "1", "--json", str(out))
    assert proc.returncode == 0, proc.stderr
    res = json.loads(out.read_text())
    assert res["truth"] == {"BKL": 5e-4, "FDJ": 200.0} and res["method"] == "ga+ps"
    assert res["estimates"]["BKL"] == pytest.approx(5e-4, rel=0.02)
    assert "mean error" in proc.stdout

    bad = tmp_path / "bad.json"
    proc = _eha("fdi", "--command", "chirp_1cm", "--bounds", "FDJ=900:100", "--json", str(bad))
    assert proc.returncode == 2 and not bad.exists()
    assert proc.stderr.count("\n") == 1 and "FDJ" in proc.stderr and "below" in proc.stderr


@pytest.mark.slow
def test_cli_fdi_against_a_measured_csv(tmp_path):
    from eha.models.simulate import simulate

    frame = simulate("hf", "chirp_1cm", {"BKL": 2e-4, "FDJ": 200.0}, t_end=0.3).to_pandas()
    good = tmp_path / "rec.csv"
    frame[["t", "com", "xu"]].to_csv(good, index=False)
    proc = _eha("fdi", "--data", str(good), "--fit", "BKL", "--json", str(tmp_path / "m.json"))
    assert proc.returncode == 0, proc.stderr
    res = json.loads((tmp_path / "m.json").read_text())
    assert res["truth"] is None and res["estimates"]["BKL"] == pytest.approx(2e-4, rel=0.05)

    broken = tmp_path / "broken.csv"
    frame[["t", "com"]].to_csv(broken, index=False)
    proc = _eha("fdi", "--data", str(broken))
    assert proc.returncode == 2 and "xu" in proc.stderr and "missing" in proc.stderr
