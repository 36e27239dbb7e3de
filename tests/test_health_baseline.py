"""The baseline-referenced health check (eha.health.baseline): campaign jobs, pairing, and a
real record pair of one actuator."""

from __future__ import annotations

import numpy as np
import pytest

from eha.health.baseline import (BASELINE_GROUP, baseline_record_seed, pair_with_baselines,
                                 referenced)
from eha.health.detection import health_jobs, performance, run_health_job
from eha.health.assessment import FAULTS
from eha.identification.healthy import DetectionError, draw_actuator
from eha.models import O_XU


def _row(means, seed, grp="healthy", command="chirp_1cm", spread=0.0):
    full = {n: FAULTS[n].healthy for n in FAULTS}
    full.update(means)
    return {"command": command, "grp": grp, "seed": seed, "means": full, "estimates": full,
            "spread": {n: spread for n in FAULTS}, "weights": {"none": 1.0}}


def test_a_baseline_section_adds_one_healthy_record_of_every_actuator():
    """``baseline = true``: each actuator of every group gets a healthy job of its own seed,
    recorded with another noise and dither seed; the jobs without it keep their specs."""
    ok: list[str] = []
    plain = health_jobs({"command": "chirp_1cm", "actuators": 2, "faults": {"GM": [0.009]}}, ok)
    jobs = health_jobs({"command": "chirp_1cm", "actuators": 2, "faults": {"GM": [0.009]},
                        "baseline": True}, ok)
    assert ok == [] and len(jobs) == 2 * len(plain)
    mine = [j for j in jobs if j["spec"]["group"] != BASELINE_GROUP]
    assert [j for j in mine if j["spec"]["group"] == "healthy"] == \
        [j for j in plain if j["spec"]["group"] == "healthy"]
    for j in mine:            # a fault's level: a change from the actuator's own value
        if j["spec"]["group"] == "GM=0.009":
            own_gm = draw_actuator(j["spec"]["seed"])["GM"]
            assert j["spec"]["hf"]["GM"] == pytest.approx(own_gm + 0.009 - FAULTS["GM"].healthy)
            assert j["spec"]["truth"]["GM"] == j["spec"]["hf"]["GM"]
    base = [j["spec"] for j in jobs if j["spec"]["group"] == BASELINE_GROUP]
    assert sorted(s["seed"] for s in base) == sorted(j["spec"]["seed"] for j in plain)
    for b in base:
        own = next(j["spec"] for j in plain if j["spec"]["seed"] == b["seed"])
        assert b["record_seed"] == baseline_record_seed(b["seed"]) != b["seed"]
        assert b["hf"] == draw_actuator(b["seed"])
        assert {k: v for k, v in b["hf"].items() if k != "GM"} == \
            {k: v for k, v in own["hf"].items() if k != "GM"}
        assert b["truth"]["GM"] == b["hf"]["GM"] != 0.009   # healthy, its own scatter
    problems: list[str] = []
    health_jobs({"command": "chirp_1cm", "baseline": "yes"}, problems)
    assert problems == ["health.baseline='yes': allowed true or false"]


def test_referenced_rows_are_changes_from_the_actuators_own_baseline():
    """A record's means become healthy + (new - baseline); spreads add in quadrature; the
    baseline rows are dropped; a record without its baseline is one line."""
    gm0 = FAULTS["GM"].healthy
    rows = [_row({"GM": gm0 - 3e-4, "FDJ": 260.0}, 1, spread=1.0),
            _row({"GM": gm0 - 2e-4, "FDJ": 250.0}, 1, grp=BASELINE_GROUP, spread=1.0)]
    out = pair_with_baselines(rows)
    assert len(out) == 1
    assert out[0]["means"]["GM"] == pytest.approx(gm0 - 1e-4)
    assert out[0]["means"]["FDJ"] == pytest.approx(FAULTS["FDJ"].healthy + 10.0)
    assert out[0]["spread"]["GM"] == pytest.approx(np.sqrt(2.0))
    assert referenced(rows[0], rows[1])["baseline_seed"] == 1
    plain = [_row({}, 3)]
    assert pair_with_baselines(plain) == plain
    with pytest.raises(DetectionError, match="no baseline record of actuator 2"):
        pair_with_baselines(rows + [_row({}, 2, grp="GM=0.009")])


def test_performance_of_a_baseline_campaign_removes_the_fleet_scatter():
    """Twenty healthy actuators whose GM scatters by 2e-4 between them but repeats within
    1e-6 on their own: against the fleet a 1e-4 loss hides in the scatter; against each
    actuator's baseline it is detected in every record."""
    rng = np.random.default_rng(3)
    gm0 = FAULTS["GM"].healthy
    own = gm0 + rng.normal(0, 2e-4, 40)
    rows = []
    for s in range(40):
        grp = "healthy" if s < 20 else "GM=0.0099"
        loss = 0.0 if s < 20 else 1e-4
        rows.append(_row({"GM": own[s] - loss + rng.normal(0, 1e-6)}, s, grp=grp))
        rows.append(_row({"GM": own[s] + rng.normal(0, 1e-6)}, s, grp=BASELINE_GROUP))
    fleet = performance([r for r in rows if r["grp"] != BASELINE_GROUP])["chirp_1cm"]
    mine = performance(rows)["chirp_1cm"]
    assert fleet["faults"]["GM"]["levels"][0]["p_detect"] < 0.5
    assert mine["faults"]["GM"]["levels"][0]["p_detect"] == 1.0
    assert mine["false_alarms"]["any"] == 0.0


def test_a_baseline_record_is_the_same_actuator_with_other_noise_and_dither():
    """The worker: a baseline job records the same HF actuator with its record seed; the
    estimates of the two records agree far better than the fleet scatters."""
    ok: list[str] = []
    jobs = health_jobs({"command": "chirp_1cm", "actuators": 1, "t_end": 0.3,
                        "baseline": True}, ok)
    (row, rec), (brow, brec) = (run_health_job(j["spec"]) for j in jobs)
    assert row["hf"] == brow["hf"] and brow["grp"] == BASELINE_GROUP
    assert not np.allclose(rec.data[:, O_XU], brec.data[:, O_XU])
    assert abs(row["means"]["FDJ"] - brow["means"]["FDJ"]) < 20.0   # the fleet's std: 20 N


def test_the_shared_model_form_floor_leaves_the_spread_of_a_difference():
    """Two records of one actuator share the check's model-form floor (Kintas: 0.05 absolute
    on the calibrated LF): the referenced spread is the noise parts in quadrature."""
    from eha.identification.intervals import MODEL_FORM

    floor = MODEL_FORM["calibrated"]["Kintas"].abs
    new = _row({}, 1, spread=0.0)
    new["spread"]["Kintas"] = float(np.hypot(0.003, floor))
    old = _row({}, 1, grp=BASELINE_GROUP, spread=0.0)
    old["spread"]["Kintas"] = float(np.hypot(0.004, floor))
    assert referenced(new, old)["spread"]["Kintas"] == pytest.approx(0.005)


def _cal_file(tmp_path, reference):
    from eha.health.detection import Calibration
    from eha.health.monitoring import _command_samples
    from eha.identification.healthy import command_signature
    from eha.models.simulate import MODEL_VERSION

    cal = Calibration(command="chirp_1cm", t_end=0.3, model_version=MODEL_VERSION,
                      command_sig=command_signature(_command_samples("chirp_1cm", 0.3)),
                      base_model="calibrated", level=0.9, alpha=0.01,
                      thresholds={n: 1.0 for n in FAULTS}, healthy={}, fleet={},
                      reference=reference)
    return cal.save(tmp_path / f"cal-{reference}.json")


def _actuator_record(path, seed, **faults):
    from eha.identification.synthetic import synthetic_record

    synthetic_record("chirp_1cm", {**draw_actuator(77), **faults}, t_end=0.3, noise=1e-6,
                     seed=seed).to_csv(path, index=False)
    return path


def test_a_baseline_check_needs_its_record_and_its_calibration(tmp_path):
    """A baseline calibration without --baseline, or --baseline with a fleet calibration: one
    line naming the option, exit 2, nothing written."""
    from helpers import error_line, files_under, invoke_eha

    rec = _actuator_record(tmp_path / "r.csv", 1)
    old = _actuator_record(tmp_path / "old.csv", 2)
    own, fleet = _cal_file(tmp_path, "baseline"), _cal_file(tmp_path, "fleet")
    before = files_under(tmp_path)
    proc = invoke_eha("health", "check", rec, "--calibration", own, "--results",
                      tmp_path / "res", cwd=tmp_path)
    assert "--baseline: the calibration" in error_line(proc, 2)
    proc = invoke_eha("health", "check", rec, "--calibration", fleet, "--baseline", old,
                      "--results", tmp_path / "res", cwd=tmp_path)
    assert "a baseline record needs a calibration made for the baseline check" in \
        error_line(proc, 2)
    proc = invoke_eha("health", "check", rec, "--calibration", own, "--baseline", rec,
                      "--results", tmp_path / "res", cwd=tmp_path)
    assert "the same samples as the record" in error_line(proc, 2)
    assert files_under(tmp_path) == before


@pytest.mark.slow
def test_calibrate_and_check_against_the_actuators_own_baseline(tmp_path):
    """`eha health calibrate --baseline` (6 actuators recorded twice) then `eha health check
    --baseline`: a 5 % motor-gain loss, inside what the fleet's scatter and flow gain hide
    (docs/design.md: about 1e-3 N/mA on any command), is declared degraded and its change
    measured within 30 %; a second healthy record of the same actuator stays healthy."""
    import json

    from helpers import invoke_eha

    res, cal = tmp_path / "res", tmp_path / "cal.json"
    proc = invoke_eha("health", "calibrate", "--actuators", "6", "--t-end", "0.3",
                      "--baseline", "--results", res, "--out", cal, "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert json.loads(cal.read_text())["reference"] == "baseline"
    assert "alarm at a change from the baseline of" in proc.stdout
    old = _actuator_record(tmp_path / "old.csv", 11)
    gm = draw_actuator(77)["GM"]
    for name, faults, status in (("same", {}, "healthy"), ("gm", {"GM": 0.95 * gm},
                                                          "degraded")):
        rec = _actuator_record(tmp_path / f"{name}.csv", 12, **faults)
        out = tmp_path / f"{name}.json"
        proc = invoke_eha("health", "check", rec, "--calibration", cal, "--baseline", old,
                          "--results", res, "--json", out, "--no-progress")
        assert proc.returncode == 0, proc.stdout + proc.stderr
        check = json.loads(out.read_text())
        assert check["status"] == status and check["baseline"] == str(old), check["isolated"]
        assert "against its baseline record" in proc.stdout
    gm_row = check["faults"]["GM"]
    assert gm_row["statistic"] == pytest.approx(0.05 * gm, rel=0.3)
    assert "GM" in check["isolated"]


def test_baseline_thresholds_are_a_prediction_bound_on_the_pairs_own_spread():
    """Referenced rows: the threshold is mean + t(1 - alpha/7; n - 1) std sqrt(1 + 1/n) of the
    pairs' changes, whatever one check's (model-form laden) measurement std says; plain rows
    keep the fleet rule with that std as a floor."""
    from scipy.stats import t as student

    from eha.health.detection import calibrate_thresholds

    rng = np.random.default_rng(0)
    gm0 = FAULTS["GM"].healthy
    rows = []
    for s in range(30):
        base = _row({"GM": gm0}, s, grp=BASELINE_GROUP, spread=1e-3)
        rows.append(referenced(_row({"GM": gm0 + rng.normal(0, 1e-5)}, s, spread=1e-3), base))
    thr, healthy = calibrate_thresholds(rows, 0.01)
    d = np.array([gm0 - r["means"]["GM"] for r in rows])   # GM degrades downwards
    want = d.mean() + student.ppf(1 - 0.01 / 7, 29) * d.std(ddof=1) * np.sqrt(1 + 1 / 30)
    assert thr["GM"] == pytest.approx(want) and thr["GM"] < 1e-4
    assert healthy["GM"]["spread"] == 0.0
    plain, _ = calibrate_thresholds([{k: v for k, v in r.items() if k != "baseline_seed"}
                                     for r in rows], 0.01)
    assert plain["GM"] > 2e-3      # the 1e-3 std of one check as the floor


def test_verdicts_refuse_a_check_against_the_wrong_reference(tmp_path):
    """The library guards what the CLI guards: a baseline calibration judges only with a
    baseline assessment, a fleet one only without; an unknown reference is one line."""
    import json

    from eha.health.detection import load_calibration, verdicts

    own = load_calibration(_cal_file(tmp_path, "baseline"))
    fleet = load_calibration(_cal_file(tmp_path, "fleet"))

    class _A:     # what verdicts reads of an assessment
        estimates = means = {n: FAULTS[n].healthy for n in FAULTS}
        intervals = {n: (0.0, 1.0) for n in FAULTS}

        def weights(self):
            return {"none": 1.0}

    a = _A()
    with pytest.raises(DetectionError, match="baseline record"):
        verdicts(a, own)
    with pytest.raises(DetectionError, match="baseline record"):
        verdicts(a, fleet, a)
    vs, isolated = verdicts(a, own, a)
    assert not any(v.degraded for v in vs) and isolated == []
    bad = json.loads((tmp_path / "cal-fleet.json").read_text()) | {"reference": "mine"}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(DetectionError, match="reference 'mine'; allowed fleet or baseline"):
        load_calibration(tmp_path / "bad.json")


def test_the_offset_degrades_either_way_so_its_baseline_bound_is_two_sided():
    """The offset's statistic is |change|: its threshold is the larger end of the two-sided
    prediction bound of the signed changes (a one-sided bound on |change| would alarm about
    6 times too often, measured on normal samples by the review)."""
    from scipy.stats import t as student

    from eha.health.detection import calibrate_thresholds

    rng = np.random.default_rng(4)
    rows = []
    for s in range(30):
        base = _row({}, s, grp=BASELINE_GROUP)
        rows.append(referenced(_row({"Ofs": rng.normal(0, 1e-3)}, s), base))
    thr, _ = calibrate_thresholds(rows, 0.01)
    d = np.array([r["means"]["Ofs"] for r in rows])
    half = student.ppf(1 - 0.01 / 14, 29) * d.std(ddof=1) * np.sqrt(1 + 1 / 30)
    assert thr["Ofs"] == pytest.approx(max(abs(d.mean() + half), abs(d.mean() - half)))
