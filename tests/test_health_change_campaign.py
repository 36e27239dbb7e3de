"""Health campaigns of the change check (``[health] baseline = true``,
eha.health.change_campaign and change_performance): each actuator a pair of records, the
injected level a change in the later one, the pairs' linear estimates in a real DuckDB
(``health_changes``), ``eha report health`` on them; bad sections (one line each)."""

from __future__ import annotations

import csv
import json
import textwrap

import pandas as pd
import pytest

from helpers import Inline, error_line, files_under, invoke_eha
from eha.campaigns.query import query
from eha.campaigns.runner import run_campaign
from eha.health.change import draw_test_day
from eha.health.detection import health_jobs
from eha.identification.healthy import draw_actuator

CAMPAIGN = textwrap.dedent("""\
    name = "change-small"
    kind = "health"
    [health]
    command = "chirp_1cm"
    t_end = 0.3
    healthy_actuators = 8
    actuators = 2
    seed = 0
    baseline = true
    nuisances = { GQ = 0.005 }
    faults = { BKL = [2e-5], GM = [-3e-3] }
    """)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """12 pairs of 0.3-s chirp_1cm records, run in this process (a few seconds)."""
    root = tmp_path_factory.mktemp("change-campaign")
    (root / "c.toml").write_text(CAMPAIGN)
    summary = run_campaign(root / "c.toml", root / "results", executor=Inline(), progress=False)
    assert summary.done == 12 and summary.failed == 0
    return root / "results"


def test_baseline_section_makes_pairs_with_changes():
    problems: list[str] = []
    jobs = health_jobs({"command": "chirp_1cm", "actuators": 1, "healthy_actuators": 2,
                        "baseline": True, "faults": ["BKL"]}, problems)
    assert problems == []
    assert {j["kind"] for j in jobs} == {"health_change"}
    groups = [j["spec"]["group"] for j in jobs]
    # healthy pairs, then the fault by name: 1, 2 and 4 times its signature step of 5 µm
    assert groups == ["healthy", "healthy", "BKL=5e-06", "BKL=1e-05", "BKL=2e-05"]
    assert [j["spec"]["change"] for j in jobs[2:]] == pytest.approx([5e-6, 1e-5, 2e-5])
    assert jobs[0]["spec"]["nuisances"]["GQ"] == 0.01          # the default half-widths
    # the plain section keeps its assessment jobs
    plain = health_jobs({"command": "chirp_1cm", "actuators": 1}, problems)
    assert {j["kind"] for j in plain} == {"health_assessment"}


@pytest.mark.parametrize("section, message", [
    ({"baseline": "yes"}, "health.baseline='yes': true or false"),
    ({"nuisances": {"GQ": 0.01}}, "health.nuisances: only with baseline = true"),
    ({"baseline": True, "nuisances": {"XX": 0.1}}, "XX: unknown; allowed CJ"),
    ({"baseline": True, "nuisances": {"PSR": 0.9}}, "PSR=0.9: allowed range [0, 0.5]"),
    ({"baseline": True, "faults": {"BKL": [0.0]}}, "health.faults.BKL=0.0: with baseline"),
    ({"baseline": True, "faults": ["XYZ"]}, "'XYZ' is not a fault of the change check"),
    ({"baseline": True, "signals": ["xu", "p12"]}, "the change check reads the position only"),
])
def test_bad_baseline_sections_say_what_is_allowed(section, message):
    problems: list[str] = []
    assert health_jobs({"command": "chirp_1cm", "actuators": 1, **section}, problems) == []
    assert any(message in p for p in problems), problems


def test_bad_baseline_campaign_is_refused_before_anything_is_written(tmp_path):
    (tmp_path / "bad.toml").write_text(CAMPAIGN.replace("baseline = true", "baseline = 1"))
    proc = invoke_eha("campaign", "run", str(tmp_path / "bad.toml"), "--results",
                      str(tmp_path / "results"))
    assert "health.baseline=1: true or false" in error_line(proc, 2)
    assert files_under(tmp_path / "results") == []


def test_pairs_are_stored_with_the_injected_change(campaign):
    frame = query(campaign, "SELECT * FROM health_changes ORDER BY grp, seed")
    assert len(frame) == 12
    rows = frame.to_dict("records")
    healthy = [r for r in rows if r["grp"] == "healthy"]
    assert len(healthy) == 8 and all(r["truth_change"] == 0 and pd.isna(r["fault"])
                                     for r in healthy)
    bkl = [r for r in rows if r["grp"] == "BKL=2e-05"]
    assert [r["fault"] for r in bkl] == ["BKL", "BKL"]
    for r in bkl:
        assert r["truth_change"] == pytest.approx(2e-5)
        est = json.loads(r["estimates"])
        lo, hi = json.loads(r["intervals"])["BKL"]
        assert lo < est["BKL"] < hi
        # the linear estimate sees the 20 µm change (not the healthy pairs' few µm)
        assert est["BKL"] > 1e-5
        # the later record is the actuator on another test day: the section's GQ width
        hf = draw_actuator(int(r["seed"]))
        day = json.loads(r["test_day"])
        assert day == pytest.approx({k: v for k, v in
                                     draw_test_day(hf, json.loads(r["nuisances"]),
                                                   int(r["seed"])).items() if k in day})
        assert abs(day["GQ"] / hf["GQ"] - 1) <= 0.005
    # a pair's later record is kept as its trace
    assert query(campaign, "SELECT count(*) AS n FROM traces")["n"][0] > 0


def test_report_health_on_a_change_campaign(campaign, tmp_path):
    out = tmp_path / "report"
    proc = invoke_eha("report", "health", "--campaign", "change-small", "--results",
                      str(campaign), "--out", str(out), "--alpha", "0.01")
    assert proc.returncode == 0, proc.stderr
    names = {p.name for p in files_under(out)}
    assert {"detection.csv", "confusion.csv", "false_alarms.csv", "performance.json",
            "summary.md", "roc_chirp_1cm.png", "confusion_chirp_1cm.png"} <= names
    assert "Minimum detectable change since the earlier record of each pair" in \
        (out / "summary.md").read_text()
    perf = json.loads((out / "performance.json").read_text())["chirp_1cm"]
    assert perf["check"] == "change"
    # thresholds from the campaign's own 8 healthy pairs: none of them alarms in sample
    assert perf["false_alarms"]["n"] == 8 and perf["false_alarms"]["any"] == 0.0
    with open(out / "detection.csv", newline="") as fh:
        det = {r["fault"]: r for r in csv.DictReader(fh)}
    # a 20 µm backlash growth and a 3e-3 N/mA motor-gain loss, far above the change floors
    assert float(det["BKL"]["p_detect"]) == 1.0
    assert float(det["BKL"]["deviation"]) == pytest.approx(2e-5)
    assert float(det["GM"]["p_detect"]) == 1.0
    assert float(det["GM"]["deviation"]) == pytest.approx(3e-3)
    assert float(det["BKL"]["threshold"]) < 2e-5
    conf = perf["confusion"]
    assert conf["none"] == {"none": 8}
    assert conf["BKL"].get("BKL") == 2
