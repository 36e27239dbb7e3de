"""Health histories of changes (eha.prognostics.change_history, change_rul; ``eha rul --check
change``): each record judged against its actuator's baseline record, the first alarm of each
fault, the rows in a real DuckDB, RUL on baseline + change; bad input (one line, exit 2,
nothing written). Records are real CSV files of 0.3-s chirp_1cm HF runs with known changes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from helpers import Inline, error_line, files_under, invoke_eha
from eha.campaigns.query import query
from eha.health.change import draw_test_day
from eha.health.change_calibration import later_seed
from eha.health.change_check import calibrate_baseline
from eha.identification.healthy import draw_actuator
from eha.identification.synthetic import synthetic_record
from eha.campaigns.files import Campaign
from eha.campaigns.runner import run_campaign
from eha.prognostics.change_history import (baselines_of, change_jobs, first_alarms,
                                            read_change_rows, store_alarms)
from eha.prognostics.degradation import PrognosticsError
from eha.prognostics.manifest import read_manifest

T_END = 0.3
#: The friction change of each actuator's records since its first one [N]: below the fleet
#: check's floor (~100 N) until the last record.
GROWTH = (0.0, 5.0, 150.0, 300.0, 600.0)
CYCLES = (0, 100, 200, 300, 400)


def _write_fleet(folder, baseline_column=False):
    """Two actuators, each a record per cycle of GROWTH (each later record on another test
    day); the manifest (optionally naming each actuator's first record in a baseline
    column)."""
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["actuator,cycle,record" + (",baseline" if baseline_column else "")]
    for a, seed in (("A1", 11), ("A2", 12)):
        hf = draw_actuator(seed)
        for k, (cycle, grow) in enumerate(zip(CYCLES, GROWTH)):
            day = hf if k == 0 else draw_test_day(hf, {"FDJ": 0.0}, seed + k)
            params = {**day, "FDJ": hf["FDJ"] + grow}
            df = synthetic_record("chirp_1cm", params, t_end=T_END, noise=1e-6,
                                  seed=seed if k == 0 else later_seed(seed + 100 * k))
            name = f"{a}_{cycle}.csv"
            df[["t", "com", "xu"]].to_csv(folder / name, index=False)
            lines.append(f"{a},{cycle},{name}" + (f",{a}_0.csv" if baseline_column else ""))
    (folder / "manifest.csv").write_text("\n".join(lines) + "\n")
    return folder / "manifest.csv"


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("change-fleet")
    manifest = _write_fleet(root / "fleet")
    cal = calibrate_baseline("chirp_1cm", actuators=12, t_end=T_END, noise=1e-6,
                             out=root / "cal.json", results=None)
    return root, manifest, cal


def _judge(manifest, cal_path, results, name="c"):
    """The manifest's change_record jobs run in this process; their rows."""
    m = read_manifest(manifest)
    jobs = change_jobs(m, baselines_of(m), cal_path, name)
    summary = run_campaign(Campaign(name, "", str(manifest), {}, tuple(jobs)), results,
                           executor=Inline(), progress=False)
    return summary, read_change_rows(results, name)


def test_each_record_judged_against_its_baseline_and_first_alarms(fleet):
    root, manifest, cal = fleet
    bases = baselines_of(read_manifest(manifest))
    assert {a: (b.record.name, b.cycle) for a, b in bases.items()} == \
        {"A1": ("A1_0.csv", 0.0), "A2": ("A2_0.csv", 0.0)}
    summary, rows = _judge(manifest, cal["path"], root / "results")
    assert summary.done == 8 and summary.failed == 0
    assert [(r["actuator"], r["cycle"]) for r in rows] == \
        [("A1", c) for c in CYCLES[1:]] + [("A2", c) for c in CYCLES[1:]]
    for r in rows:
        assert r["reference"] == "baseline" and r["baseline"].endswith(f"{r['actuator']}_0.csv")
        truth = GROWTH[CYCLES.index(r["cycle"])]
        lo, hi = r["intervals"]["FDJ"]
        # the change within its interval, widened by the test day's other nuisances
        # (an open upper end, null: a change beyond the response's growing range)
        assert lo - 30 < truth and (hi is None or truth < hi + 30), (r["cycle"], lo, hi)
    alarms = first_alarms(rows)
    for a in ("A1", "A2"):
        # 5 N is below the change floor (about 24 N on 1-s records): no alarm at cycle 100;
        # 150 N at cycle 200 alarms, and every later check confirms it
        assert alarms[a]["FDJ"]["first_alarm"] == 200.0
        assert alarms[a]["FDJ"]["first_confirmed"] == 200.0
        assert alarms[a]["FDJ"]["checks"] == 4 and alarms[a]["FDJ"]["baseline_cycle"] == 0.0
        # the backlash's own statistic moves with the friction too, but the checks are
        # isolated to the friction (and the leakage, which chirp_1cm does not tell from it)
        assert alarms[a]["BKL"]["first_alarm"] is None
        assert alarms[a]["BKL"]["first_degraded"] == 200.0
    # stored with the check that made the rows; a second store replaces them
    for _ in range(2):
        store_alarms(root / "results", "run-x", alarms)
    first = query(root / "results", "SELECT * FROM change_alarms WHERE fault = 'FDJ'")
    assert sorted(first["first_alarm"]) == [200.0, 200.0]
    assert set(first["reference"]) == {"baseline"}


def test_a_baseline_unlike_the_healthy_fleet_is_the_first_alarm(fleet, tmp_path):
    """An actuator that arrives with 15 µm of backlash (the fleet check's healthy fleet has
    none; its change never grows): its first backlash alarm is its baseline's own cycle, by
    the healthy calibration's screen, also where its checks run on a calibration at another
    operating point; the healthy actuator's is not."""
    root, _, cal = fleet
    folder = tmp_path / "fleet"
    folder.mkdir()
    lines = ["actuator,cycle,record"]
    for a, seed, bkl in (("A1", 31, 1.5e-5), ("A2", 32, 0.0)):
        hf = {**draw_actuator(seed), "BKL": bkl}
        for k, cycle in enumerate(CYCLES[:3]):
            synthetic_record("chirp_1cm", hf, t_end=T_END, noise=1e-6, seed=seed + 100 * k)[
                ["t", "com", "xu"]].to_csv(folder / f"{a}_{cycle}.csv", index=False)
            lines.append(f"{a},{cycle},{a}_{cycle}.csv")
    (folder / "manifest.csv").write_text("\n".join(lines) + "\n")
    m = read_manifest(folder / "manifest.csv")
    # the checks on a calibration of its own (a copy stands for one at an operating point)
    own = tmp_path / "own.json"
    own.write_text(Path(cal["path"]).read_text())
    jobs = change_jobs(m, baselines_of(m), {"A1": own, "A2": own}, "s", screen=cal["path"])
    assert {j.spec["screen_calibration"] for j in jobs} == {str(cal["path"])}
    run_campaign(Campaign("s", "", str(folder), {}, tuple(jobs)), tmp_path / "res",
                 executor=Inline(), progress=False)
    rows = read_change_rows(tmp_path / "res", "s")
    assert {r["actuator"]: r["screen"][0] if r["screen"] else None for r in rows} == \
        {"A1": "BKL", "A2": None}
    alarms = first_alarms(rows)
    assert alarms["A1"]["BKL"]["first_alarm"] == 0.0 and alarms["A1"]["BKL"]["at_baseline"]
    assert alarms["A1"]["BKL"]["first_confirmed"] is None    # no change: none confirmed
    assert alarms["A2"]["BKL"]["first_alarm"] is None
    assert not any(a["at_baseline"] for a in alarms["A2"].values())
    store_alarms(tmp_path / "res", "run-s", alarms)
    stored = query(tmp_path / "res", "SELECT actuator FROM change_alarms WHERE at_baseline")
    assert list(stored["actuator"]) == ["A1"]


def test_a_record_of_another_command_fails_its_job_alone(fleet, tmp_path):
    root, manifest, cal = fleet
    folder = tmp_path / "f"
    folder.mkdir()
    for p in manifest.parent.glob("*.csv"):
        (folder / p.name).write_bytes(p.read_bytes())
    df = synthetic_record("sine", draw_actuator(11), t_end=T_END, noise=1e-6, seed=5)
    df[["t", "com", "xu"]].to_csv(folder / "A1_300.csv", index=False)
    summary, rows = _judge(folder / "manifest.csv", cal["path"], tmp_path / "res")
    assert summary.done == 7 and summary.failed == 1
    err = query(tmp_path / "res", "SELECT error FROM runs WHERE status = 'failed'")
    assert "A1_300.csv: not a 0.3 s record of chirp_1cm" in err["error"][0]
    assert (300.0, "A1") not in {(r["cycle"], r["actuator"]) for r in rows}


def test_baseline_column_names_the_baseline(tmp_path, fleet):
    _, _, cal = fleet
    manifest = _write_fleet(tmp_path / "f", baseline_column=True)
    lines = manifest.read_text().splitlines()
    # A2's baseline: its second record (cycle 100); its first is then not judged
    lines = [ln.rsplit(",", 1)[0] + ",A2_100.csv" if ln.startswith("A2") else ln
             for ln in lines]
    manifest.write_text("\n".join(lines) + "\n")
    m = read_manifest(manifest)
    bases = baselines_of(m)
    assert bases["A2"].record.name == "A2_100.csv" and bases["A2"].cycle == 100.0
    jobs = change_jobs(m, bases, cal["path"], "c")
    assert [j.spec["cycle"] for j in jobs if j.spec["actuator"] == "A2"] == [200.0, 300.0, 400.0]
    assert {j.spec["baseline_cycle"] for j in jobs if j.spec["actuator"] == "A2"} == {100.0}
    # two baselines for one actuator: one line naming it
    lines[1] = lines[1].rsplit(",", 1)[0] + ",A1_100.csv"
    manifest.write_text("\n".join(lines) + "\n")
    with pytest.raises(PrognosticsError, match="actuator A1: rows name 2 baselines"):
        baselines_of(read_manifest(manifest))


@pytest.mark.parametrize("extra, message", [
    (["--check", "change"], "--check change needs a change calibration"),
    (["--check", "other"], "--check 'other': allowed fleet, change"),
    (["--calibration", "CAL"], "--calibration: only with --check change"),
    (["--trend", "changes"], "--trend changes: only with --check change"),
    (["--check", "change", "--trend", "x", "--calibration", "CAL"],
     "--trend 'x': allowed identified, changes"),
    (["--check", "change", "--trend", "changes", "--skip-flagged", "--calibration", "CAL"],
     "--skip-flagged: not with --trend changes"),
    (["--check", "change", "--calibration", "missing.json"], "missing.json: no such file"),
    (["--check", "change", "--operating-point", "x", "--calibration", "CAL"],
     "--operating-point 'x': allowed baseline, calibration"),
    (["--operating-point", "calibration"],
     "--operating-point calibration: only with --check change"),
])
def test_bad_change_options_one_line_nothing_written(fleet, tmp_path, extra, message):
    root, manifest, _ = fleet
    extra = [str(root / "cal.json") if e == "CAL" else e for e in extra]
    proc = invoke_eha("rul", str(manifest), "--limit", "FDJ=1500", "--results",
                      str(tmp_path / "res"), "--no-progress", *extra)
    assert message in error_line(proc, 2)
    assert files_under(tmp_path / "res") == []


def test_a_fleet_calibration_is_refused(fleet, tmp_path):
    root, manifest, _ = fleet
    (tmp_path / "fleet-cal.json").write_text(json.dumps({"format": 1, "thresholds": {}}))
    proc = invoke_eha("rul", str(manifest), "--limit", "FDJ=1500", "--results",
                      str(tmp_path / "res"), "--check", "change", "--calibration",
                      str(tmp_path / "fleet-cal.json"), "--no-progress")
    assert "a fleet calibration" in error_line(proc, 2)
    assert files_under(tmp_path / "res") == []


@pytest.mark.slow
def test_rul_on_the_change_check_end_to_end(fleet, tmp_path):
    root, manifest, _ = fleet
    proc = invoke_eha("rul", str(manifest), "--limit", "FDJ=1500", "--fit", "FDJ",
                      "--check", "change", "--trend", "changes",
                      "--calibration", str(root / "cal.json"),
                      "--results", str(tmp_path / "res"), "--json", str(tmp_path / "rul.json"),
                      "--workers", "1", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "change check: first alarm since the baseline" in proc.stdout
    out = json.loads((tmp_path / "rul.json").read_text())
    assert out["check"] == "change" and out["trend"] == "changes"
    assert out["run_id"].endswith("-change")
    a1 = out["actuators"]["A1"]
    assert a1["first_alarms"]["FDJ"]["first_alarm"] == 200.0
    assert [c["cycle"] for c in a1["changes"]] == [100.0, 200.0, 300.0, 400.0]
    preds = a1["predictions"]
    # the history: the baseline's identified friction, then it plus each change
    base = preds[0]["estimates"]["FDJ"]
    assert 100 < base < 400
    assert preds[-1]["estimates"]["FDJ"] == pytest.approx(
        base + a1["changes"][-1]["faults"]["FDJ"]["change"])
    # only the baselines were identified (one run per actuator); the 8 later records judged
    runs = query(tmp_path / "res", "SELECT count(*) AS n FROM health_checks")
    assert runs["n"][0] == 2
    judged = query(tmp_path / "res", "SELECT count(*) AS n FROM change_checks")
    assert judged["n"][0] == 8
    stored = query(tmp_path / "res", "SELECT DISTINCT reference FROM rul_predictions")
    assert list(stored["reference"]) == ["baseline"]
    alarms = query(tmp_path / "res", "SELECT * FROM change_alarms WHERE fault = 'FDJ'")
    assert sorted(alarms["first_alarm"]) == [200.0, 200.0]
    # each actuator's check calibrated again at its baseline's identified friction
    cals = query(tmp_path / "res", "SELECT * FROM change_calibrations ORDER BY actuator")
    assert list(cals["actuator"]) == ["A1", "A2"] and list(cals["pairs"]) == [12, 12]
    own = json.loads(Path(a1["calibration"]).read_text())
    assert Path(a1["calibration"]).parent == tmp_path / "res" / "calibrations"
    assert own["operating_point"]["FDJ"] == pytest.approx(base)
    assert {r["calibration"] for r in query(tmp_path / "res", "SELECT calibration FROM "
            "change_checks WHERE actuator = 'A1'").to_dict("records")} == {a1["calibration"]}


def test_the_identified_trend_identifies_every_record_and_a_named_baseline(fleet, tmp_path):
    from eha.prognostics.change_rul import _campaign

    _, _, cal = fleet
    manifest = _write_fleet(tmp_path / "f", baseline_column=True)
    text = manifest.read_text().replace(",A1_0.csv\n", ",acceptance.csv\n")
    (tmp_path / "f" / "acceptance.csv").write_bytes((tmp_path / "f" / "A1_0.csv").read_bytes())
    manifest.write_text(text)
    m = read_manifest(manifest)
    bases = baselines_of(m)
    assert bases["A1"].record.name == "acceptance.csv" and bases["A1"].cycle is None
    kinds = {}
    for trend in ("identified", "changes"):
        camp = _campaign(m, bases, {"FDJ": (200.0, 4000.0)}, 0, None, None, None, "c",
                         cal["path"], trend)[1](cal["path"])
        kinds[trend] = [(j.kind, Path(j.spec["record"]).name) for j in camp.jobs]
    ident = [r for k, r in kinds["identified"] if k == "health"]
    # every record of the manifest, and A1's baseline outside it
    assert sorted(ident) == sorted([f"{a}_{c}.csv" for a in ("A1", "A2") for c in CYCLES]
                                   + ["acceptance.csv"])
    assert sorted(r for k, r in kinds["changes"] if k == "health") == ["A2_0.csv",
                                                                       "acceptance.csv"]
    # A1's every record is judged against the acceptance record (its first one too)
    judged = [r for k, r in kinds["changes"] if k == "change_record"]
    assert sorted(judged) == sorted([f"A1_{c}.csv" for c in CYCLES]
                                    + [f"A2_{c}.csv" for c in CYCLES[1:]])


def test_the_console_marks_a_first_alarm_at_the_baseline():
    """The first-alarm table: an alarm at the baseline (the screen) is marked and said."""
    from eha.cli.guard import console
    from eha.cli.prognostics import _render_alarms

    output = {"fit": ["BKL", "FDJ"], "actuators": {
        "A1": {"baseline_cycle": 0.0, "first_alarms": {
            "BKL": {"first_alarm": 0.0, "first_confirmed": None, "at_baseline": True},
            "FDJ": {"first_alarm": 200.0, "first_confirmed": 300.0, "at_baseline": False}}},
        "A2": {"baseline_cycle": 0.0, "first_alarms": {
            "BKL": {"first_alarm": None, "first_confirmed": None, "at_baseline": False},
            "FDJ": {"first_alarm": 100.0, "first_confirmed": 100.0, "at_baseline": False}}}}}
    with console.capture() as cap:
        _render_alarms(output)
    text = cap.get()
    assert "0* (-)" in text and "200 (300)" in text and "100 (100)" in text
    assert "* at the baseline: the baseline record itself is unlike the healthy fleet" in text
    del output["actuators"]["A1"]
    with console.capture() as cap:
        _render_alarms(output)
    assert "*" not in cap.get()
