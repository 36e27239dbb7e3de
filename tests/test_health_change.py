"""The change check (eha.health.change, change_calibration, change_check): a record judged
against the same actuator's own earlier record. Round trips with known truth on simulated pairs
(fixed seeds), the calibration file, `eha health calibrate --baseline` / `eha health check
--baseline` on real files and a real DuckDB, and bad input (one line, exit 2, nothing written)."""

from __future__ import annotations

import json
from pathlib import Path
import math

import numpy as np
import pytest

from helpers import error_line, files_under, invoke_eha
from eha.health.change import GainCurve, NUISANCES, check_nuisances, draw_test_day
from eha.health.change_second import judge_change
from eha.health.change_calibration import (_faulted, _record, calibrate_change, isolate_group,
                                           judge, later_seed, load_change_calibration)
from eha.health.change_check import check_change, signatures_of
from eha.identification.healthy import DetectionError, draw_actuator
from eha.identification.measured import noise_level
from eha.models.commands import as_command

#: A short record keeps the pairs cheap (each HF record of 0.5 s takes a few ms).
T_END = 0.5


@pytest.fixture(scope="module")
def calibrated():
    """A change calibration on 20 healthy pairs of chirp_1cm, 0.5 s (about 2 s)."""
    cal, pairs = calibrate_change("chirp_1cm", actuators=20, seed=0, t_end=T_END)
    return cal, pairs


def _pair(cal, seed, fault=None, change=0.0, at=None, whole=False, beside=None):
    """A pair of records of actuator ``seed`` (at the fault levels ``at``; the later one on
    another test day, with a fault grown by ``change``, and the faults of ``beside`` by
    theirs) judged by ``cal`` (``whole``: :func:`judge_change`'s four parts)."""
    cmd = as_command(cal.command)
    hf = {**draw_actuator(seed), **(at or {})}
    a = _record(cmd, hf, T_END, 1e-6, seed)
    b_hf = draw_test_day(hf, cal.nuisances, seed)
    for name, size in ([(fault, change)] if fault else []) + list((beside or {}).items()):
        b_hf, _ = _faulted(b_hf, name, size)
    b = _record(cmd, b_hf, T_END, 1e-6, later_seed(seed))
    sig = signatures_of(cal, a.command)
    noise2 = noise_level(a.xu) ** 2 + noise_level(b.xu) ** 2
    if whole:
        return judge_change(cal, sig, b.xu - a.xu, noise2)
    return judge(cal, sig, b.xu - a.xu, noise2)


def test_nuisances_are_declared_once_and_checked():
    assert check_nuisances(None) == {n: v.width for n, v in NUISANCES.items()}
    assert check_nuisances({"GQ": 0.02})["GQ"] == 0.02
    with pytest.raises(DetectionError, match="unknown; allowed CJ"):
        check_nuisances({"XX": 0.1})
    with pytest.raises(DetectionError, match=r"PSR=0.9: allowed range \[0, 0.5\]"):
        check_nuisances({"PSR": 0.9})
    # another test day: every nuisance within its half-width of the actuator's own value
    hf = draw_actuator(3)
    later = draw_test_day(hf, check_nuisances(None), 3)
    assert abs(later["FDJ"] / hf["FDJ"] - 1) <= 0.05
    assert abs(later["GQ"] / hf["GQ"] - 1) <= 0.01
    assert abs(later["Ofs"] - 0.0) <= 0.002
    assert later == draw_test_day(hf, check_nuisances(None), 3)          # reproducible


def test_gain_curve_inverts_its_own_response():
    curve = GainCurve((1.0, 2.0, 4.0), (1.0, 0.8, 0.5), (0.1, 0.1, 0.1))
    for size in (0.5, 1.0, 1.7, 3.0, 6.0):
        assert curve.invert(curve.estimate_at(size), 1.0) == pytest.approx(size)
    # a fault that degrades downwards (the motor gain): sizes and estimates negative
    down = GainCurve((-1.0, -2.0), (0.9, 0.9), (0.0, 0.0))
    assert down.invert(down.estimate_at(-1.5), -1.0) == pytest.approx(-1.5)
    # a response that stops growing (a filter near jammed): beyond its growing range an
    # estimate bounds the size from below only
    sat = GainCurve((1.0, 2.0, 4.0, 8.0), (1.0, 1.0, 0.5, 0.1), (0.0,) * 4)
    assert sat.top() == (2.0, 2.0)
    assert not sat.beyond(1.9, 1.0) and sat.beyond(2.5, 1.0)
    assert sat.invert(3.0, 1.0) == pytest.approx(3.0)


def test_calibration_is_reproducible_and_holds_its_false_alarms(calibrated):
    cal, pairs = calibrated
    assert cal.pairs == 20 and cal.reference == "baseline"
    assert set(cal.faults) == {"BKL", "FDJ", "GM", "Kintas", "Clk", "Ofs", "FSS"}
    assert all(f["threshold"] > 0 and f["std"] > 0 for f in cal.faults.values())
    assert cal.faults["Ofs"]["two_sided"] and not cal.faults["FDJ"]["two_sided"]
    # the leave-one-out alarms of 20 healthy pairs at alpha 0.01: 0 expected, 2 would be rare
    assert cal.false_alarms["loo"]["alarms"] <= 1
    # the same settings give the same calibration (a small one: the property, not the size)
    small = [calibrate_change("chirp_1cm", actuators=5, seed=3, t_end=0.3)[0] for _ in "ab"]
    assert small[0].faults == small[1].faults and small[0].gains == small[1].gains


@pytest.mark.parametrize("fault, change", [("FDJ", 150.0), ("BKL", 2e-5), ("Ofs", -0.03),
                                           ("GM", -2e-3)])
def test_a_grown_fault_is_detected_isolated_and_its_change_covered(calibrated, fault, change):
    """Round trip with known truth: a fault grown well beyond its threshold (about 5x) on a
    held-out actuator is detected, the change is isolated to a group holding it, and the
    interval covers the true change; the same actuator without the fault is healthy."""
    cal, _ = calibrated
    judged = _pair(cal, 900, fault, change)
    assert judged[fault]["degraded"] and not judged[fault]["open_ended"]
    assert fault in isolate_group(judged)
    lo, hi = judged[fault]["interval"]
    assert lo <= change <= hi, (lo, change, hi)
    healthy = _pair(cal, 900)
    assert not any(v["degraded"] for v in healthy.values())


def test_held_out_healthy_pairs_alarm_at_most_alpha(calibrated):
    """40 held-out healthy pairs with the nuisances: at alpha 0.01 the expected count is 0.4;
    3 or more has probability 0.8 % under the target (binomial)."""
    cal, _ = calibrated
    alarms = sum(any(v["degraded"] for v in _pair(cal, 5000 + k).values()) for k in range(40))
    assert alarms <= 2


@pytest.mark.slow
def test_at_a_degraded_point_the_check_is_calibrated_there(calibrated):
    """A fault's signature depends on the faults already there (at 20 µm of backlash and
    230 N of friction the backlash's is nearly orthogonal to its healthy one on chirp_1cm):
    a 10 µm growth of the backlash there is missed or given to another fault by the healthy
    calibration, and detected and isolated by the calibration made at that point, which holds
    its false alarms there."""
    cal0, _ = calibrated
    at = {"BKL": 2e-5, "FDJ": 230.0}
    cal1, _ = calibrate_change("chirp_1cm", actuators=20, seed=0, t_end=T_END, at=at,
                               gains=False)         # the isolation needs no sizes
    assert cal1.operating_point == at and cal1.false_alarms["loo"]["alarms"] <= 1
    seeds = range(900, 906)
    there = [isolate_group(_pair(cal1, s, "BKL", 1e-5, at)) for s in seeds]
    healthy_point = [isolate_group(_pair(cal0, s, "BKL", 1e-5, at)) for s in seeds]
    assert all(g[:1] == ["BKL"] for g in there), there
    assert sum(g[:1] == ["BKL"] for g in healthy_point) <= 3, healthy_point
    assert not any(any(v["degraded"] for v in _pair(cal1, s, at=at).values()) for s in seeds)
    with pytest.raises(DetectionError, match=r"`at` BKL=0.5: allowed range"):
        calibrate_change("chirp_1cm", actuators=5, t_end=T_END, at={"BKL": 0.5})


@pytest.mark.parametrize("fault, change", [("FDJ", 150.0), ("BKL", 2e-5), ("GM", -2e-3),
                                           ("Kintas", 0.5)])
def test_a_lone_fault_names_nothing_beside_it(calibrated, fault, change):
    """The two-fault reading on pairs with one grown fault (large enough to bend its
    response): nothing is named beside it on 6 held-out actuators."""
    cal, _ = calibrated
    for seed in range(900, 906):
        _, isolated, _, also = _pair(cal, seed, fault, change, whole=True)
        assert fault in isolated and also == [], (seed, isolated, also)


def test_a_backlash_grown_beside_a_friction_is_named_beside_it(calibrated):
    """Round trip: friction +100 N and backlash +10 µm grown together. The single-fault
    reading names one of them (the friction, or the leakage it cannot tell from it, or the
    backlash); the two-fault reading names the other beside it on at least 5 of 6 held-out
    actuators (another fault on at most 1), with the backlash's change read back within a
    factor 2 when it is the one beside."""
    cal, _ = calibrated
    both = wrong = read = covered = 0
    for seed in range(900, 906):
        judged, isolated, second, also = _pair(cal, seed, "FDJ", 100.0, whole=True,
                                               beside={"BKL": 1e-5})
        named = set(isolated) | set(also)
        assert len(also) <= 1 and named & {"FDJ", "Clk", "BKL"}, (isolated, also)
        both += "BKL" in named and bool(named & {"FDJ", "Clk"})
        wrong += bool(named - {"FDJ", "Clk", "BKL"})
        if also == ["BKL"]:
            b = second["BKL"]
            assert 5e-6 < b["change"] < 2e-5, b
            # its interval (90 %) holds the reading and, on most actuators, the truth
            lo, hi = b["interval"]
            assert lo < b["change"] < hi, b
            read += 1
            covered += lo <= 1e-5 <= hi
    assert covered >= read - 1, (covered, read)
    # on 0.5-s records one actuator's backlash is just under its threshold beside the
    # friction and the offset's reading (which the backlash moves) is just over its own
    assert both >= 5 and wrong <= 1


def _write(path, df):
    df[["t", "com", "xu"]].to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory, calibrated):
    """A calibration file and records of one actuator: earlier, later healthy, later with
    +150 N of jack friction, one on another command, one of another length."""
    from eha.identification.synthetic import synthetic_record

    folder = tmp_path_factory.mktemp("change")
    cal, _ = calibrated
    cal_path = cal.save(folder / "cal-baseline.json")
    hf = draw_actuator(777)
    later = draw_test_day(hf, cal.nuisances, 777)
    rec = lambda params, seed, command="chirp_1cm", t=T_END: synthetic_record(  # noqa: E731
        command, params, t_end=t, noise=1e-6, seed=seed)
    out = {"cal": cal_path, "folder": folder,
           "earlier": _write(folder / "earlier.csv", rec(hf, 777)),
           "later": _write(folder / "later.csv", rec(later, later_seed(777))),
           "worse": _write(folder / "worse.csv", rec({**later, "FDJ": later["FDJ"] + 150},
                                                     later_seed(777))),
           "other": _write(folder / "other.csv", rec(hf, 777, "mixed")),
           "short": _write(folder / "short.csv", rec(hf, 777, t=0.4)),
           "stuck": _write(folder / "stuck.csv", rec({**hf, "BKL": 2e-4}, 777)),
           "both": _write(folder / "both.csv", rec({**later, "FDJ": later["FDJ"] + 150,
                                                    "BKL": later.get("BKL", 0.0) + 2e-5},
                                                   later_seed(777)))}
    return out


def test_cli_check_against_a_baseline(files, tmp_path):
    res = tmp_path / "res"
    out = tmp_path / "out.json"
    proc = invoke_eha("health", "check", files["worse"], "--baseline", files["earlier"],
                      "--calibration", files["cal"], "--json", out, "--results", res)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("degraded: "), proc.stdout      # the finding first
    data = json.loads(out.read_text())
    assert data["status"] == "degraded" and "FDJ" in data["isolated"]
    assert data["check"] == "change" and data["faults"]["FDJ"]["display_unit"] == "N"
    lo, hi = data["faults"]["FDJ"]["interval"]
    assert lo <= 150 <= hi
    # a lone friction change: nothing changed beside it; the faults judged beside it say so
    assert data["also_changed"] == [] and "beside it" not in proc.stdout
    assert not any("two-fault" in n for n in data["notes"])
    assert data["faults"]["BKL"]["beside"]["fault"] == data["isolated"][0]
    assert not data["faults"]["BKL"]["beside"]["degraded"]
    lo, hi = data["faults"]["BKL"]["beside"]["interval"]
    assert lo <= data["faults"]["BKL"]["beside"]["change"] <= hi
    from eha.campaigns.query import query

    rows = query(res, "SELECT fault, reference, baseline, degraded FROM health_verdicts")
    assert set(rows["reference"]) == {"baseline"} and len(rows) == 7
    assert rows.set_index("fault").loc["FDJ", "degraded"]
    # a friction and a backlash grown together: the backlash's row shows its change as read
    # beside the isolated fault, with that reading's interval (the JSON's and the finding's)
    proc = invoke_eha("health", "check", files["both"], "--baseline", files["earlier"],
                      "--calibration", files["cal"], "--json", out, "--results", res)
    data = json.loads(out.read_text())
    assert data["also_changed"] == ["BKL"], proc.stdout
    b = data["faults"]["BKL"]["beside"]
    row = next(line for line in proc.stdout.splitlines() if line.startswith("│ BKL"))
    shown = [c.strip() for c in row.strip("│").split("│")]
    assert shown[1] == f"+{1e6 * b['change']:.3g} µm" and shown[3] == "-", shown
    assert shown[4] == f"DEGRADED (beside {data['isolated'][0]})"
    assert f"changed beside it, by +{1e6 * b['change']:.3g} µm" in proc.stdout
    # the same actuator on its later test day without a fault
    proc = invoke_eha("health", "check", files["later"], "--baseline", files["earlier"],
                      "--calibration", files["cal"], "--json", out, "--results", res)
    assert proc.returncode == 0 and json.loads(out.read_text())["status"] == "healthy"


def test_a_calibration_without_the_two_fault_reading_says_so(files, tmp_path):
    """A change calibration of an older eha (no operating point, no leaks) is still read; a
    degraded check then says that no fault is judged beside the isolated one."""
    old = json.loads(Path(files["cal"]).read_text())
    del old["operating_point"], old["second"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    out = check_change(files["worse"], files["earlier"], tmp_path / "old.json", results=None)
    assert out.status == "degraded" and out.also == [] and out.second == {}
    assert any("no two-fault reading" in n for n in out.notes)


def test_a_baseline_unlike_the_fleet_is_used_and_said_so(files, tmp_path):
    out = tmp_path / "o.json"
    proc = invoke_eha("health", "check", files["later"], "--baseline", files["stuck"],
                      "--calibration", files["cal"], "--json", out, "--results", tmp_path)
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    assert data["baseline_screen"]["faults"]          # a linear screen: which, not asserted
    assert "looks unlike the healthy fleet" in proc.stderr


@pytest.mark.parametrize("case, args, message", [
    ("other command", ("later", "other"), "another command"),
    ("other length", ("later", "short"), "0.4 s long"),
    ("missing", ("later", "nothing"), "file not found"),
])
def test_a_baseline_unfit_for_its_purpose_is_refused(files, tmp_path, case, args, message):
    record, baseline = (files.get(a, files["folder"] / "nothing.csv") for a in args)
    out = tmp_path / "o.json"
    proc = invoke_eha("health", "check", record, "--baseline", baseline, "--calibration",
                      files["cal"], "--json", out, "--results", tmp_path / "r")
    assert message in error_line(proc, 2)
    assert files_under(tmp_path) == []


def test_calibrations_of_the_other_check_are_refused(files, tmp_path):
    from eha.health.detection import load_calibration

    with pytest.raises(DetectionError, match="change check"):
        load_calibration(files["cal"])
    fleet = tmp_path / "fleet.json"
    fleet.write_text(json.dumps({"format": 1, "thresholds": {}, "command": "chirp_1cm"}))
    with pytest.raises(DetectionError, match="a fleet calibration"):
        load_change_calibration(fleet)
    proc = invoke_eha("health", "check", files["later"], "--baseline", files["earlier"],
                      "--calibration", fleet, "--results", tmp_path / "r")
    assert "fleet calibration" in error_line(proc, 2)
    proc = invoke_eha("health", "check", files["later"], "--baseline", files["earlier"],
                      "--results", tmp_path / "r")
    assert "--calibration" in error_line(proc, 2)
    damaged = tmp_path / "damaged.csv"
    damaged.write_text(files["earlier"].read_text().replace("\n0.1,", "\n0.1,nan,", 1)[:5000])
    proc = invoke_eha("health", "check", files["later"], "--baseline", damaged,
                      "--calibration", files["cal"], "--results", tmp_path / "r")
    error_line(proc, 2)
    assert not (tmp_path / "r").exists()


def test_cli_calibrate_baseline(tmp_path):
    out = tmp_path / "cal.json"
    proc = invoke_eha("health", "calibrate", "--baseline", "--command", "chirp_1cm",
                      "--actuators", "6", "--t-end", "0.3", "--nuisance", "GQ=0.02",
                      "--out", out, "--results", tmp_path / "res", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    data = json.loads(out.read_text())
    assert data["reference"] == "baseline" and data["nuisances"]["GQ"] == 0.02
    assert data["pairs"] == 6 and math.isclose(data["t_end"], 0.3)
    for bad, msg in ((["--nuisance", "GQ"], "NAME=HALFWIDTH"),
                     (["--nuisance", "XX=0.1"], "unknown"),
                     (["--actuators", "2"], "allowed range [5"),):
        proc = invoke_eha("health", "calibrate", "--baseline", *bad, "--out",
                          tmp_path / "bad.json", "--results", tmp_path / "bad")
        assert msg in error_line(proc, 2)
        assert not (tmp_path / "bad.json").exists() and not (tmp_path / "bad").exists()
    proc = invoke_eha("health", "calibrate", "--nuisance", "GQ=0.1", "--out",
                      tmp_path / "bad.json")
    assert "only with --baseline" in error_line(proc, 2)


@pytest.mark.slow
def test_design_for_the_change_check_is_never_worse_than_the_best_library_command(tmp_path):
    """`eha design --check baseline` with a search too short to find much: the command it
    returns is predicted no worse on any target than the best library command (by the
    search's score) cut to the same limits, or is that command; then `eha design verify`
    measures it on simulated pairs (a small run: the figures are not the point here)."""
    from eha.design import Limits, design
    from eha.design.library import best_by_score, cut_to_limits, dominated_by
    from eha.design.search import best_library

    limits = Limits(duration=0.5, max_stroke=5e-3, max_rate=0.1)
    result = design(faults=["BKL", "Ofs"], limits=limits, seed=0, population=4,
                    generations=1, check="baseline")
    assert result.settings["check"] == "baseline"
    cuts = {n: cut_to_limits(n, limits) for n in result.library}
    reference = best_library(result.targets, result.library)
    top = best_by_score(result.library, result.targets, reference, None, cuts)
    assert dominated_by(result.prediction, result.library[top], result.targets) == []
    paths = result.save(tmp_path / "d")
    doc = json.loads(paths["json"].read_text())
    assert doc["settings"]["check"] == "baseline"
    proc = invoke_eha("design", "verify", paths["json"], "--library", "chirp_1cm",
                      "--healthy", "26", "--calibration", "10", "--per-level", "2")
    assert proc.returncode == 0, proc.stderr
    ver = json.loads((tmp_path / "d" / "design-verification.json").read_text())
    assert set(ver["measured"]) == {"design", "chirp_1cm"}
    assert ver["measured"]["design"]["false_alarms"]["n"] == 16
    assert set(ver["measured"]["design"]["faults"]) == {"BKL", "Ofs"}


def test_design_check_baseline_refuses_what_the_change_check_does_not_judge(tmp_path):
    proc = invoke_eha("design", "--check", "baseline", "--effects", "external_load",
                      "--out", tmp_path / "o")
    assert "--check baseline" in error_line(proc, 2)
    proc = invoke_eha("design", "--check", "nope", "--out", tmp_path / "o")
    assert "allowed fleet or baseline" in error_line(proc, 2)
    assert files_under(tmp_path) == []


def test_calibration_folder_and_command_file_length(tmp_path):
    """`--calibration DIR` says it is a folder; a command file's own length is the default
    record length of a calibration (a 0.4-s command calibrated for 0.4 s)."""
    from eha.models.commands import make_command, write_command_file

    proc = invoke_eha("health", "check", tmp_path / "r.csv", "--calibration", tmp_path)
    assert "a folder, not a calibration file" in error_line(proc, 2)
    t = np.arange(401) * 1e-3
    cmd = write_command_file(tmp_path / "short.csv", t, make_command("chirp_1cm").sample(t)
                             * np.where(t < 0.35, 1.0, 0.0), {"eha": "test"})
    out = tmp_path / "cal.json"
    proc = invoke_eha("health", "calibrate", "--baseline", "--command", cmd, "--actuators",
                      "5", "--out", out, "--results", tmp_path / "res", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(out.read_text())["t_end"] == pytest.approx(0.4)


def test_a_diverged_hf_run_stops_the_calibration_with_one_line(monkeypatch):
    """A calibration whose HF run is not finite (a diverged integration) says so, naming the
    run's fault levels, instead of carrying NaN into its thresholds."""
    from eha.health import change_runs
    from eha.identification import synthetic
    from eha.identification.healthy import DetectionError

    real = synthetic.synthetic_positions

    def diverged(*args, **kwargs):
        xs = real(*args, **kwargs)
        xs[-1, 50:] = np.nan
        return xs
    monkeypatch.setattr(synthetic, "synthetic_positions", diverged)
    with pytest.raises(DetectionError, match=r"^`command`: an HF run of the calibration "
                                             r"diverged \(parameters .*BKL"):
        change_runs._positions("chirp_1cm", [({}, 1), ({"BKL": 2e-5}, 2)], 0.1, 1e-6)
