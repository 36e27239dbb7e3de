"""The residual loop on records with an undeclared effect (issue 5 §5).

HF records with faults BKL = 0.1 mm, FDJ = 800 N (declared, fitted) and one undeclared effect,
1 µm RMS white measurement noise, saved as CSV and read back. Fits use a small GA budget
(population 12) to keep the suite short; the checks are on the effect chosen, its estimate and
the RMSE reduction.
"""

import json
import math

import duckdb
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from eha.cli import app
from eha.explain import (P12_NOISE_FLOOR, ExplainError, Fitter, LoopSettings, augmented_base,
                         explain, noise_level, p12_objective_weight, parse_fit)
from eha.identification.measured import load, synthetic_record
from eha.models.params import LFParams

FAULTS = {"BKL": 1e-4, "FDJ": 800.0}
NOISE = 1e-6
FAST = {"pop": 12, "candidates": 4, "max_gen": 20, "stall": 5, "seed": 0,
        "null_actuators": 5, "interval_replicates": 2, "rival_replicates": 2}
#: For records the LF model made: no healthy scatter and no structure to tell from an effect,
#: so no null (an effect is refused only when its fit switches it off).
FAST_LF = {**FAST, "null": None}
#: For the tests that check which effects the loop adds and their values only: no HF
#: re-simulations of the final model (its intervals' replicate term and the rival check run
#: after the rounds and change neither the effects nor their values; the CLI tests and
#: tests/test_explain_replicates.py check them).
FIRST = {**FAST, "interval_replicates": 0, "rival_replicates": 0}
FIRST_LF = {**FIRST, "null": None}
#: The structural differences of HF from LF at the HF's values (docs/model.md §2 vs §6): the prior of
#: the injected-effect tests, so that the undeclared effect is the only thing left to find.
HF_STRUCTURE = [{"effect": "orifice_law", "params": {}},
                {"effect": "flapper_dynamics", "params": {"SNF": 2513.0, "ZF": 0.6}}]


def assert_effects_are_the_model(res):
    """Every effect with parameters that is on in the final model is a reported step (or in
    the prior), and every reported step is on: what the user reads is what was fitted."""
    from eha.explain.effects import EFFECTS

    for name, effect in EFFECTS.items():
        if effect.params and effect.is_on(res.after.params) and \
                not effect.is_on(res.before.params):
            assert name in res.effects, (name, res.effects, res.dismissed)
        if name in res.effects and effect.params:
            assert effect.is_on(res.after.params), name


def _record(tmp_path, name, command, t_end, overrides=None, model="hf", seed=1):
    """A CSV record of FAULTS (and ``overrides``) with NOISE at ``tmp_path/name.csv`` (also
    read by tests/test_explain_null.py)."""
    path = tmp_path / f"{name}.csv"
    synthetic_record(command, {**FAULTS, **(overrides or {})}, t_end=t_end, noise=NOISE,
                     seed=seed, model=model).to_csv(path, index=False)
    return path


@pytest.fixture(scope="session")
def record(tmp_path_factory):
    """``record(command, t_end, overrides=None, model="hf", seed=1)``: the path of a CSV
    record (:func:`_record`), made once per session and shared by the tests that read the
    same record (read-only: a test that changes one copies it first)."""
    folder = tmp_path_factory.mktemp("explain-records")
    made = {}

    def make(command, t_end, overrides=None, model="hf", seed=1):
        key = (command, t_end, tuple(sorted({**FAULTS, **(overrides or {})}.items())), model,
               seed)
        if key not in made:
            made[key] = _record(folder, f"record{len(made)}", command, t_end, overrides,
                                model, seed)
        return made[key]
    return make


def _accept_by_hand(loop, *names):
    """Fit the declared faults, then refit and accept each effect in turn as if a round had
    chosen it (the final check's and the look-ahead's tests start from such a model)."""
    from eha.explain import Candidate, Choice

    loop.baseline()
    for name in names:
        cand = loop.try_candidate(Candidate(name, math.nan, math.nan))
        loop.accept(Choice(cand, set(), name.split("+")))


@pytest.mark.slow
def test_nominal_hf_record_adds_the_orifice_law_through_the_cli(record, tmp_path):
    """Plain nominal HF data: the missing physics is the orifice law (the 'mixed' command
    opens the spool beyond XSS); found first, RMSE falls >= 3x; all outputs written."""
    data = record("mixed", 1.0)
    js, out, res = tmp_path / "r.json", tmp_path / "out", tmp_path / "results"
    result = CliRunner().invoke(app, ["explain", str(data), "--fit", "BKL,FDJ", "--pop", "12",
                                      "--candidates", "4", "--null-actuators", "5",
                                      # a rival the exclusion check lists is re-checked on
                                      # 2x2 HF re-simulations, not 2x6 (the check's figures
                                      # are tests/test_explain_replicates.py's; either
                                      # outcome is asserted below)
                                      "--rival-replicates", "2",
                                      "--json", str(js),
                                      "--out",
                                      str(out), "--results", str(res), "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads(js.read_text())
    # issue 5's contract, plus the final model's intervals and the unexplained flag (issue 9)
    # and the verdict, its lead, the noise, the command's hold, the effects chosen but
    # dismissed, whether the measured P12 was fitted and the intervals' notes (issue 11); the
    # healthy null the decisions rested on, what the command could not show and whether the
    # residual is beyond the healthy band (issue 24)
    # (separating_test: only when the exclusion check names a rival, docs/design.md)
    assert set(doc) - {"separating_test"} == {
                        "rmse_before", "rmse_after", "faults_before", "faults_after", "steps",
                        "intervals", "level", "unexplained", "beyond_healthy", "verdict",
                        "noise_rmse",
                        "unexplained_rmse", "leads", "command_hold", "dismissed",
                        "p12_in_fit", "interval_notes", "flow_gain_released", "null",
                        "undetectable", "not_excluded", "rivals_ruled_out",
                        # what the exclusion check excluded, and beyond which size (a
                        # follow-up's --prior reads it)
                        "excluded",
                        # a --prior's rivals settled on this record (none here)
                        "settled",
                        # above the noise: what the found model itself leaves on the HF
                        "model_level",
                        # the verdict's kind, facts and finding (issue 42)
                        "verdict_kind", "at_noise", "within_healthy_band",
                        "unique_explanation", "found", "units",
                        # above the noise, at the found model's own level (issue 41)
                        "at_model_level"}
    assert doc["settled"] is None
    assert all(e["shift"] > e["detectable"] > e["threshold"] for e in doc["not_excluded"])
    assert doc["unexplained"] or not doc["not_excluded"]
    assert doc["null"]["records"] == 5 and doc["null"]["alpha"] == 0.05
    assert doc["null"]["source"].startswith("simulated healthy fleet (5 actuators")
    added = {st["effect"] for st in doc["steps"]}
    assert len(doc["undetectable"]) == len(set(doc["null"]["effects"]) - added)
    # at the noise the exclusion check ran: each effect it did not list is excluded, beyond
    # a size past the one this command shows (a follow-up's --prior reads it)
    listed = {e["effect"] for e in doc["not_excluded"]}
    assert set(doc["excluded"]) == set(doc["null"]["effects"]) - added - listed
    for name, e in doc["excluded"].items():
        bar = doc["null"]["effects"][name]
        assert e["beyond"] > bar.get("shift", bar)["detectable"]
    assert all(0 < e["threshold"] < e["detectable"] for e in doc["null"]["effects"].values())
    assert doc["interval_notes"] == []          # explained: nothing to note
    assert doc["flow_gain_released"] is None    # the flow gain stayed inside its spread
    assert doc["p12_in_fit"] is True            # the record has P12
    assert all(set(d) == {"effect", "round", "loss", "p_value", "replaced_by"}
               for d in doc["dismissed"])
    # at the noise level: explained, or not uniquely so when the exclusion check names a
    # rival (a 20 µs delay beside a 5-actuator null here): nothing added for it either way
    assert doc["level"] == 0.9 and doc["unexplained"] is bool(doc["not_excluded"])
    assert doc["beyond_healthy"] is False
    # the verdict opens with its kind and what was found (issue 42; was "not uniquely
    # explained: residual" / "explained: residual")
    assert doc["verdict"].startswith("explained, ambiguous: found " if doc["not_excluded"]
                                     else "explained: found ")
    assert doc["at_noise"] is True and doc["unique_explanation"] is not doc["not_excluded"]
    lo, hi = doc["intervals"]["FDJ"]
    assert lo <= doc["faults_after"]["FDJ"] <= hi
    assert doc["steps"][0]["effect"] == "orifice_law"
    assert set(doc["steps"][0]) == {"effect", "params", "rmse_before", "rmse_after",
                                    "tentative", "alternatives"}
    assert all(isinstance(st["alternatives"], dict) for st in doc["steps"])
    assert doc["rmse_before"] >= 3 * doc["rmse_after"]
    assert doc["steps"][0]["rmse_before"] == pytest.approx(doc["rmse_before"])
    assert doc["steps"][-1]["rmse_after"] == pytest.approx(doc["rmse_after"])
    assert doc["faults_after"]["BKL"] == pytest.approx(1e-4, rel=0.1)
    assert doc["faults_after"]["FDJ"] == pytest.approx(800.0, rel=0.15)
    for name in ("residuals.png", "trace.png", "steps.csv", "candidates.csv", "explain.json"):
        assert (out / name).stat().st_size > 0
    con = duckdb.connect(str(res / "eha.duckdb"), read_only=True)
    run = con.execute("SELECT run_id, rmse_before, rmse_after, effects FROM explain_runs"
                      ).fetchall()
    steps = con.execute("SELECT step, effect, rmse_after FROM explain_steps ORDER BY step"
                        ).fetchall()
    verdict = con.execute("SELECT unexplained, verdict, command_hold FROM explain_runs"
                          ).fetchone()
    con.close()
    assert len(run) == 1 and run[0][1] == pytest.approx(doc["rmse_before"])
    assert verdict == (doc["unexplained"], doc["verdict"], doc["command_hold"])
    assert doc["command_hold"] in ("zoh", "linear")
    assert [s[1] for s in steps] == [s["effect"] for s in doc["steps"]]


@pytest.mark.slow
def test_nominal_hf_on_steps_adds_the_structural_pair(record):
    """On the step-rich 'test' command the orifice law and the flapper dynamics each explain
    little alone; tried together (eha.explain.effects.COMBINATIONS) they are added as two steps."""
    res = explain(load(record("test", 0.6)), **FIRST)
    assert res.effects[:2] == ["orifice_law", "flapper_dynamics"], res.stop_reason
    assert res.rmse_before >= 3 * res.rmse_after
    assert res.steps[0].rmse_after == pytest.approx(res.steps[1].rmse_before)


@pytest.mark.parametrize("effect,overrides,param,rel", [
    ("external_load", {"FRC": 2000.0}, "FRC", 0.10),
    ("offset", {"Ofs": 0.3}, "Ofs", 0.10),
    ("hinge_moment", {"Kaer": 1.5e5}, "Kaer", 0.10),
    ("sensor_bias", {"sensor_bias": 1e-4}, "sensor_bias", 0.05),
])
@pytest.mark.slow
def test_undeclared_effect_is_found_first(record, effect, overrides, param, rel):
    data = load(record("test", 0.6, overrides))
    # one step: only the first effect added is checked (and it alone must cut the RMSE 3x)
    res = explain(data, base=augmented_base(HF_STRUCTURE), max_steps=1, **FIRST)
    assert res.effects[0] == effect, res.stop_reason
    assert res.steps[0].params[param] == pytest.approx(overrides[param], rel=rel)
    assert res.rmse_before >= 3 * res.rmse_after
    assert res.faults_after["BKL"] == pytest.approx(1e-4, rel=0.15)


@pytest.mark.slow
def test_leakage_is_found_first_with_its_order_of_magnitude(record, tmp_path):
    """From the position alone, leakage trades off against jack friction (both soften the
    position loop), so the GA estimates Clk only to within a factor of 3 (docs/explain.md,
    limits; measured: Clk 38 % and FDJ 34 % off). The measured P12 tells them apart (a leak
    lowers the pressure a friction raises): Clk within 10 %, FDJ within 3 % (measured 1.0 %
    and 0.6 %)."""
    frame = pd.read_csv(record("mixed", 1.0, {"Clk": 5e-12}))
    frame["p12"] += np.random.default_rng(5).normal(0.0, 2e4, len(frame))   # 0.2 bar noise
    path = tmp_path / "leakage.csv"     # a copy: the shared record is read-only
    frame.to_csv(path, index=False)
    data = load(path)
    res = explain(data, base=augmented_base(HF_STRUCTURE), max_steps=1, p12_weight=0.0,
                  **FIRST)
    assert res.effects[0] == "leakage", res.stop_reason
    assert 5e-12 / 3 <= res.steps[0].params["Clk"] <= 5e-12 * 3
    assert res.rmse_before >= 3 * res.rmse_after
    assert not res.to_json()["p12_in_fit"]
    res = explain(data, base=augmented_base(HF_STRUCTURE), max_steps=1, **FIRST)
    assert res.to_json()["p12_in_fit"]
    # the noise (2e4 Pa) or the floor, a fraction of P12's spread, whichever is larger
    assert res.facts.p12_noise_pa == pytest.approx(
        max(2e4, P12_NOISE_FLOOR * frame["p12"].std()), rel=0.1)
    assert res.effects[0] == "leakage", res.stop_reason
    assert res.steps[0].params["Clk"] == pytest.approx(5e-12, rel=0.10)
    assert res.faults_after["FDJ"] == pytest.approx(800.0, rel=0.03)
    assert_effects_are_the_model(res)


def test_p12_weight_measures_each_signal_in_its_noise():
    rng = np.random.default_rng(0)
    smooth = 1e5 * np.sin(np.linspace(0.0, 6.0, 1000))           # 1 bar amplitude
    # no P12, or a zero weight: position only
    assert p12_objective_weight(1e-6, None)[0] == 0.0
    assert p12_objective_weight(1e-6, smooth, weight=0.0)[0] == 0.0
    # noisy P12: its noise (2e4 Pa) is measured
    w, sigma = p12_objective_weight(1e-6, smooth + rng.normal(0.0, 2e4, 1000))
    assert sigma == pytest.approx(2e4, rel=0.15) and w == pytest.approx(1e-6 / sigma)
    # noise-free P12 (a simulator): the floor, a fraction of its standard deviation
    w, sigma = p12_objective_weight(1e-6, smooth, weight=2.0)
    assert sigma == pytest.approx(P12_NOISE_FLOOR * np.std(smooth))
    assert w == pytest.approx(2.0 * 1e-6 / sigma)
    # a noise-free position: nothing to weigh P12 against
    assert p12_objective_weight(0.0, smooth)[0] == 0.0
    with pytest.raises(ExplainError, match="`p12_weight`"):
        LoopSettings(p12_weight=-1.0)


@pytest.mark.slow
def test_validation_record_instead_of_holdout(record):
    data = load(record("test", 0.6, {"sensor_bias": -1e-4}))
    check = load(record("mixed", 0.5, {"sensor_bias": -1e-4}, seed=2))
    res = explain(data, base=augmented_base(HF_STRUCTURE), validate=check, **FIRST)
    assert "validation record" in res.holdout
    assert res.effects[0] == "sensor_bias"
    assert res.steps[0].params["sensor_bias"] == pytest.approx(-1e-4, rel=0.05)


@pytest.mark.slow
def test_noise_only_adds_nothing(record):
    """An LF record (the model is exact) plus noise: nothing to explain."""
    data = load(record("mixed", 1.0, model="lf"))
    assert noise_level(data.xu) == pytest.approx(NOISE, rel=0.2)
    res = explain(data, **FIRST_LF)
    assert res.steps == [] and "noise level" in res.stop_reason
    assert res.rmse_after == res.rmse_before < 1.3 * NOISE
    # without the noise-floor stop, the significance test alone rejects every candidate
    res = explain(data, noise_factor=0.0, max_steps=3, **FIRST_LF)
    assert res.steps == [] and res.rmse_after == res.rmse_before
    assert "noise level" not in res.stop_reason
    # refitted: the best-ranked singles, the orifice_law+flapper_dynamics combination, and
    # the combination with each of the effects best explaining its residual
    refits = [c.effect for c in res.rounds[0].candidates if c.refit]
    assert len(refits) == 2 * FAST["candidates"] + 1
    assert sum(name.startswith("orifice_law+flapper_dynamics+") for name in refits) == \
        FAST["candidates"]


@pytest.mark.parametrize("name, command, t_end, overrides, param, tol", [
    ("load", "mixed", 1.0, {"FRC": 2000.0}, "FRC", 0.10),
    ("bias", "test", 0.6, {"sensor_bias": 1e-4}, "sensor_bias", 0.05),
    # the command steps away at t = 0: the LF starts where its *recorded* position is the
    # measured one, so a bias is not taken for a shifted start (was: offset at its bound).
    # Failed (a torque-motor offset chosen for the bias) until the pattern search polled
    # pattern moves (docs/decisions.md); why that fit changed is not analysed
    ("bias_step", "step_1cm", 0.5, {"sensor_bias": 2e-4}, "sensor_bias", 0.05),
])
@pytest.mark.slow
def test_undeclared_effect_without_a_prior(record, name, command, t_end, overrides, param,
                                           tol):
    """No prior: the HF-LF structure and the undeclared effect are found together (the
    orifice law first, as the parameter-free switch, then the effect). On 'mixed' a load is
    only told from a motor offset once the orifice law is in the model (docs/explain.md,
    measured: FRC 2080 N with population 20). Tolerances as the prior tests: 10 % load,
    5 % bias; RMSE falls >= 3x."""
    data = load(record(command, t_end, overrides))
    res = explain(data, **FIRST)
    doc = res.to_json()
    effects = [s["effect"] for s in doc["steps"]]
    assert effects[:2] == ["orifice_law", {"FRC": "external_load"}.get(param, param)]
    assert doc["steps"][1]["params"][param] == pytest.approx(overrides[param], rel=tol)
    assert doc["rmse_before"] >= 3 * doc["rmse_after"]
    assert_effects_are_the_model(res)


def test_bad_inputs_raise_one_line(record):
    assert parse_fit("BKL=0:1e-3, FDJ") == {"BKL": (0.0, 1e-3), "FDJ": (0.0, 8000.0)}
    for spec, match in [("BKL=1e-3", "LOW:HIGH"), ("XYZ", "unknown"), ("BKL,BKL", "twice"),
                        ("", "no parameter")]:
        with pytest.raises(ExplainError, match=match):
            parse_fit(spec)
    data = load(record("step_1mm", 0.1))
    with pytest.raises(ExplainError, match="holdout"):
        explain(data, holdout=0.9)
    with pytest.raises(ExplainError, match="prior"):
        augmented_base([{"effect": "offset", "params": {"Ofs": 99.0}}])


@pytest.mark.slow
def test_load_test_calibration_keeps_the_nominal_leakage_healthy_through_the_cli(record,
                                                                               tmp_path):
    """A healthy actuator's record under a known 4 kN test load, declared with --set: the
    known load is not a candidate, and the HF's nominal leakage (Clk = 1e-13, visible under
    a load because the leakage flow is Clk*P12) is a healthy actuator's: the null, simulated
    under the same known load, has it (Clk 0.7-1.4e-13), so it is not added. FDJ within 10 %."""
    data = record("mixed", 1.0, {"FRC": 4000.0})
    js = tmp_path / "cal.json"
    result = CliRunner().invoke(app, ["explain", str(data), "--set", "FRC=4000", "--pop", "12",
                                      "--candidates", "4", "--null-actuators", "5",
                                      "--interval-replicates", "2", "--rival-replicates", "2",
                                      "--json", str(js),
                                      "--out",
                                      str(tmp_path / "out"), "--results",
                                      str(tmp_path / "results"), "--no-progress"])
    assert result.exit_code == 0, result.output
    doc = json.loads(js.read_text())
    effects = [s["effect"] for s in doc["steps"]]
    assert effects[0] == "orifice_law"
    assert "external_load" not in effects           # the known load is not a candidate
    assert "leakage" not in effects, doc["steps"]   # a healthy actuator's leak
    # without the healthy leak in the model FDJ reads high (measured 856 N, +7 %)
    assert doc["faults_after"]["FDJ"] == pytest.approx(800.0, rel=0.10)
    bad = CliRunner().invoke(app, ["explain", str(data), "--set", "FRC=1e9", "--no-progress",
                                   "--results", str(tmp_path / "r2")])
    assert bad.exit_code == 2 and "FRC" in bad.output and "range" in bad.output
    assert not (tmp_path / "r2").exists()


def test_batch_runs_start_at_the_recorded_position():
    """simulate_lf_batch(recorded_start=x0): every row's recorded xu starts at x0 whatever its
    sensor bias and gain (XJ0 = (x0 - bias)/gain); exact up to float rounding."""
    from eha.models.params import LF, LFParams
    from eha.models.simulate import command_on_grid, grid, simulate_lf_batch
    from eha.models.commands import make_command

    base = LFParams()
    spo, n_out, t_steps = grid(base, 0.02)
    com = command_on_grid(make_command("step_1cm"), t_steps)
    rows = np.stack([base.replace(sensor_bias=b, sensor_gain=g).to_array()
                     for b, g in [(0.0, 1.0), (2e-4, 1.0), (-1e-3, 1.05)]])
    xu = simulate_lf_batch(rows, com, spo, n_out, base, recorded_start=3e-3)
    assert xu[:, 0] == pytest.approx([3e-3] * 3, abs=1e-12)
    assert (rows[:, LF.XJ0] == base.XJ0).all()     # the caller's rows are not modified


class ScriptedFitter(Fitter):
    """A fitter whose every fit returns its start (the declared faults where they start, a
    candidate's effects at their probe values) at no cost, and notes its label (``asked``).
    For the tests of the loop's control flow (which candidates a round refits, when it
    stops), as tests/test_explain_decide.py runs the decision rule on canned numbers: the LF
    runs that score the fits are real."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.asked: list[str] = []

    def fit_with_cost(self, start, free, label, *args, **kwargs):
        self.asked.append(label)
        return start, 0.0


@pytest.mark.slow
def test_max_steps_holds_when_a_combination_wins(record):
    """A combination adds one step per member, so it is only tried when there is room:
    nominal HF on 'test' with max_steps=1 adds one effect (the pair needs two); with room for
    two the orifice law + flapper pair is tried and added as two steps. On a scripted fitter
    (control flow; was a whole explain() with its GA fits and healthy null)."""
    from eha.explain import ResidualLoop

    data = load(record("test", 0.6))
    for max_steps in (1, 2):
        loop = ResidualLoop.on(data, settings=LoopSettings(candidates=4, max_steps=max_steps),
                               fitter=ScriptedFitter)
        asked = loop.fitter.asked
        loop.baseline()
        stop = loop.rounds_until_stop()
        pairs = [c.effect for c in loop.rounds[0].candidates if "+" in c.effect]
        assert asked and stop == f"reached max_steps={max_steps}"
        if max_steps == 1:
            assert len(loop.steps) == 1 and pairs == []
        else:
            assert "orifice_law+flapper_dynamics" in pairs
            assert [st.effect for st in loop.steps] == ["orifice_law", "flapper_dynamics"]


@pytest.mark.slow
def test_known_parameters_are_neither_fitted_nor_candidates(record):
    data = load(record("mixed", 0.3))
    with pytest.raises(ExplainError, match="`fixed` BKL: also a fitted fault"):
        explain(data, fixed=["BKL"], **FAST)
    with pytest.raises(ExplainError, match="`fixed` XJ0"):
        explain(data, fixed=["XJ0"], **FAST)
    # FRC held at 0 (its off value): external_load must still not be a candidate (the
    # candidates are the loop's pool: no healthy null needed to list them)
    res = explain(data, fixed=["FRC"], max_steps=0, **FIRST_LF)
    assert "external_load" not in res.facts.candidates
    assert "offset" in res.facts.candidates


@pytest.mark.slow
def test_final_check_removes_a_stand_in_the_later_effects_made_unnecessary(record):
    """An LF record (the model is exact) with a 2 kN load: a motor offset is accepted first (a
    stand-in: in the linear regime it moves the position like a load), then the load. The
    final check leaves each out and refits the rest: the offset no longer pays and is removed
    — switched off in the model, not only in the report — and the load stays within 2 %."""
    from eha.explain import ResidualLoop

    data = load(record("mixed", 0.6, {"FRC": 2000.0}, model="lf"))
    loop = ResidualLoop.on(data, effects="offset,external_load",
                        settings=LoopSettings(pop=12, seed=0), max_gen=20, stall=5)
    _accept_by_hand(loop, "offset", "external_load")
    assert [s.effect for s in loop.steps] == ["offset", "external_load"]
    removed = loop.prune()
    assert [d.effect for d in removed] == ["offset"]
    assert [s.effect for s in loop.steps] == ["external_load"]
    assert loop.current.Ofs == 0.0 and "Ofs" not in loop.free
    assert loop.current.FRC == pytest.approx(2000.0, rel=0.02)
    assert loop.cur.rmse_all < 1.5 * NOISE


@pytest.mark.slow
def test_final_check_swaps_a_stand_in_for_the_effect_it_stands_in_for(record):
    """An LF record with a 1 ms position delay on `mixed`: a motor-gain change is accepted by
    hand (on `mixed` it stands in for the delay). The final check's swap tries the effects
    whose signature is most like the motor gain's contribution and puts the delay in its
    place (within 5 %); the motor gain is listed as dismissed, replaced by the delay."""
    from eha.explain import ResidualLoop

    data = load(record("mixed", 1.0, {"sensor_delay": 1e-3},
                        model="lf"))
    loop = ResidualLoop.on(data, effects="motor_gain,delay,offset,sensor_bias,external_load",
                        settings=LoopSettings(pop=12, seed=0, flow_gain_spread=0.0), max_gen=20, stall=5)
    _accept_by_hand(loop, "motor_gain")
    removed = loop.prune()
    assert [(d.effect, d.replaced_by) for d in removed] == [("motor_gain", "delay")]
    assert [s.effect for s in loop.steps] == ["delay"]
    assert loop.current.GM == LFParams().GM
    assert loop.current.sensor_delay == pytest.approx(1e-3, rel=0.05)


@pytest.mark.slow
def test_final_check_merges_two_stand_ins_into_the_effect_they_stand_in_for(record):
    """An LF record with a 2 kN load on `mixed`: a motor offset and a sensor bias are accepted
    by hand (together they stand in for the load). The final check's two-for-one tries single
    effects in the pair's place: the load alone fits as well with one parameter less, so the
    pair does not pay for itself and the load replaces it (within 2 %); both are listed as
    dismissed, replaced by the load."""
    from eha.explain import ResidualLoop

    data = load(record("mixed", 0.6, {"FRC": 2000.0}, model="lf"))
    loop = ResidualLoop.on(data, effects="offset,sensor_bias,external_load,delay,motor_gain",
                        settings=LoopSettings(pop=12, seed=0), max_gen=20, stall=5)
    _accept_by_hand(loop, "offset", "sensor_bias")
    merged = loop.merge()
    assert [(d.effect, d.replaced_by) for d in merged] == [("offset", "external_load"),
                                                            ("sensor_bias", "external_load")]
    assert [s.effect for s in loop.steps] == ["external_load"]
    assert loop.current.Ofs == 0.0 and loop.current.sensor_bias == 0.0
    assert "Ofs" not in loop.free and "sensor_bias" not in loop.free
    assert loop.current.FRC == pytest.approx(2000.0, rel=0.02)


@pytest.mark.slow
def test_final_estimates_refit_everything_on_the_whole_record(record):
    """An LF record with a load and a motor offset on `mixed`: the loop's model with both
    effects, its estimates left off the truth (load +10 %, offset -30 %, FDJ +5 %: where a
    search on the first 70 % stopped on the HF bench record load+offset+leak). The final
    estimates (least squares on the whole record) are back within 1 % of the truth, and the
    whole record's objective fell."""
    from eha.explain import ResidualLoop

    data = load(record("mixed", 0.6,
                        {"FRC": 2000.0, "Ofs": 0.3}, model="lf"))
    loop = ResidualLoop.on(data, effects="external_load,offset",
                        settings=LoopSettings(pop=12, seed=0), max_gen=20, stall=5)
    _accept_by_hand(loop, "external_load", "offset")
    loop.current = loop.current.replace(FRC=2200.0, Ofs=0.21, FDJ=840.0)
    loop.cur = loop.fitter.evaluate([loop.current])[0]
    before = loop.cur.rmse_whole
    loop.estimate()
    assert loop.cur.rmse_whole < before
    assert loop.current.FRC == pytest.approx(2000.0, rel=0.01)
    assert loop.current.Ofs == pytest.approx(0.3, rel=0.01)
    assert loop.current.FDJ == pytest.approx(800.0, rel=0.01)
    assert loop.current.BKL == pytest.approx(1e-4, rel=0.01)


@pytest.mark.slow
def test_supply_pressure_is_tried_with_the_orifice_law_it_requires(record):
    """An LF record with the orifice law, a 2 kN load (known, --set) and a 16 MPa supply on
    `chirp_1cm`. With the linear law the supply pressure only clamps P12, so alone it cannot
    act: the round traces and refits it as `orifice_law+supply_pressure`, which recovers the
    pressure within 2 % and gains most of the round."""
    from eha.explain import ResidualLoop

    data = load(record("chirp_1cm", 0.6,
                        {"orifice_law": 1.0, "PSR": 1.6e7, "FRC": 2000.0}, model="lf"))
    loop = ResidualLoop.on(data, effects="orifice_law,supply_pressure,motor_gain,offset",
                        base=LFParams().replace(FRC=2000.0), fixed=["FRC"],
                        settings=LoopSettings(pop=12, seed=0, candidates=3), max_gen=20,
                        stall=5)
    loop.baseline()
    _, tried = loop.candidates_of_round(loop.remaining())
    by_name = {c.effect: c for c in tried}
    assert "supply_pressure" not in by_name
    cand = by_name["orifice_law+supply_pressure"]
    assert cand.params["PSR"] == pytest.approx(1.6e7, rel=0.02)
    assert cand.gain == max(c.gain for c in tried)
    # its law (XSSK) is a parameter more than the motor gain it resembles under the
    # listing's law (flow in proportion to PSR, like a weaker motor: gains 0.965 and 0.962),
    # and pays the penalty of one parameter for it: measured, 0.925 against the motor gain's
    # 0.942; what the rounds then choose is the choice's rules' (the known cost of the law)
    assert cand.score >= max(c.score for c in tried) - loop.settings.penalty


@pytest.mark.slow
def test_look_ahead_finds_the_pair_that_stands_out_together(record):
    """An LF record with a sensor bias, torque-motor hysteresis and an aerodynamic hinge moment
    on `chirp_1cm`, the bias already in the model (by hand). Suppose the round set hysteresis
    aside as unspecific (on the HF bench record a clogging matched it): the look-ahead traces
    the residual of its fit and refits the effects that best explain it on top; hysteresis +
    hinge moment stands out (gain >= SPECIFIC_GAIN) and is chosen, both within 5 %."""
    from eha.explain import Candidate, Choice, ResidualLoop
    from eha.explain.settings import SPECIFIC_GAIN

    data = load(record("chirp_1cm", 0.6,
                        {"sensor_bias": 1e-4, "His": 0.2, "Kaer": 1.5e5}, model="lf"))
    loop = ResidualLoop.on(data, effects="sensor_bias,hysteresis,hinge_moment,delay,offset",
                        settings=LoopSettings(pop=12, seed=0), max_gen=20, stall=5)
    _accept_by_hand(loop, "sensor_bias")
    rnd = loop.trace(loop.cur, loop.free, loop.remaining())
    head = loop.try_candidate(Candidate("hysteresis", math.nan, math.nan))
    choice = loop.look_ahead(rnd, [head], Choice(None, unspecific=["hysteresis"]))
    assert choice.best is not None and choice.best.effect == "hysteresis+hinge_moment"
    assert choice.best.gain >= SPECIFIC_GAIN
    assert choice.best.params["His"] == pytest.approx(0.2, rel=0.05)
    assert choice.best.params["Kaer"] == pytest.approx(1.5e5, rel=0.05)
    # nothing set aside: the look-ahead has nothing to extend
    assert loop.look_ahead(rnd, [head], Choice(None)).best is None


@pytest.mark.slow
def test_final_check_far_from_the_noise_searches_the_swap_globally(record, monkeypatch):
    """An LF record with the orifice law, seal wear (Clk 5e-12) and a viscous jack (CJ 16000)
    on `test`: a low supply pressure and a leak are accepted by hand (on the HF bench record
    leak+viscous@test the rounds took that path: the supply pressure stands in for the
    viscous jack and the model stays at 18 µm). The model leaves the record unexplained, so
    the final check searches the swap globally (a pattern search from the viscous probe stays
    in the supply's valley) and puts the viscous friction in the supply's place (within
    10 %); the model then explains the record. (The loop's default GA: with the tests'
    smaller one the swap's global search leaves CJ inside its healthy band.)

    The supply pressure is held at the listing's law (XSSK not fitted), the law of the HF
    bench record where the rounds took that path: with its law free the supply pressure is a
    closer stand-in (4.6 µm, still unexplained) and the swap is not made (docs/decisions.md,
    the supply pressure's law)."""
    from dataclasses import replace

    from eha.explain import ResidualLoop
    from eha.explain.effects import EFFECTS

    supply = EFFECTS["supply_pressure"]
    monkeypatch.setitem(EFFECTS, "supply_pressure", replace(
        supply, bounds={"PSR": supply.bounds["PSR"]}, probe={"PSR": supply.probe["PSR"]},
        other_starts=(), statistic=""))

    data = load(record("test", 0.6,
                        {"orifice_law": 1.0, "Clk": 5e-12, "CJ": 1.6e4}, model="lf"))
    loop = ResidualLoop.on(data, effects="orifice_law,supply_pressure,leakage,viscous_friction,"
                        "motor_gain,delay", settings=LoopSettings(pop=20, seed=0))
    _accept_by_hand(loop, "orifice_law+supply_pressure", "leakage")
    assert loop.unexplained()
    removed = loop.prune()
    assert ("supply_pressure", "viscous_friction") in [(d.effect, d.replaced_by)
                                                       for d in removed]
    assert "viscous_friction" in [s.effect for s in loop.steps]
    assert loop.current.PSR == LFParams().PSR
    assert loop.current.CJ == pytest.approx(1.6e4, rel=0.10)
    assert not loop.unexplained()


@pytest.mark.slow
def test_final_estimates_restart_the_structure_from_its_physical_values(record):
    """An LF record with the orifice law, the thesis' flapper (2513 rad/s, 0.6), seal wear
    and a viscous jack on `test`; the loop's model is left where a round's GA left it on the
    HF bench record leak+viscous@test (flapper at 1750 rad/s and 0.32, the faults and
    effects compensating: BKL +13 %, FDJ +12 %). Least squares from there stays in that
    basin (BKL 10 % off); the final estimates also restart the flapper from its physical
    values and keep the better fit: faults within 3 %, the flapper within 10 %."""
    from eha.explain import ResidualLoop

    data = load(record("test", 0.6,
                        {"orifice_law": 1.0, "SNF": 2513.0, "ZF": 0.6, "Clk": 5e-12,
                         "CJ": 1.6e4}, model="lf"))
    loop = ResidualLoop.on(data, effects="orifice_law,flapper_dynamics,leakage,viscous_friction",
                        settings=LoopSettings(pop=12, seed=0, flow_gain_spread=0.0), max_gen=20, stall=5)
    _accept_by_hand(loop, "orifice_law+flapper_dynamics", "viscous_friction", "leakage")
    loop.current = loop.current.replace(SNF=1750.0, ZF=0.32, FDJ=897.0, CJ=17500.0,
                                        Clk=4.0e-12, BKL=1.13e-4)
    loop.cur = loop.fitter.evaluate([loop.current])[0]
    before = loop.cur.rmse_whole
    loop.estimate()
    assert loop.cur.rmse_whole < 0.5 * before
    assert loop.current.BKL == pytest.approx(1e-4, rel=0.03)
    assert loop.current.FDJ == pytest.approx(800.0, rel=0.03)
    assert loop.current.SNF == pytest.approx(2513.0, rel=0.10)
    assert loop.current.CJ == pytest.approx(1.6e4, rel=0.05)


@pytest.mark.slow
def test_faults_without_the_tentative_effects(record):
    """The span of an unexplained record's fault intervals: the declared faults refitted with
    every added effect that is not the structure switched off (an LF load record with the load
    accepted: without it the faults move far from their values with it); a model with only
    the structure added has no tentative effect to leave out."""
    from eha.explain import ResidualLoop

    data = load(record("mixed", 0.6, {"FRC": 2000.0}, model="lf"))
    loop = ResidualLoop.on(data, effects="external_load,orifice_law,flapper_dynamics",
                        settings=LoopSettings(pop=12, seed=0), max_gen=20, stall=5)
    _accept_by_hand(loop, "external_load")
    without = loop.faults_without_tentative()
    assert set(without) == {"BKL", "FDJ"}
    assert loop.current.FRC == pytest.approx(2000.0, rel=0.02)
    assert loop.current.FDJ == pytest.approx(800.0, rel=0.02)
    assert abs(without["FDJ"] - 800.0) > 0.2 * 800.0
    loop.steps = [st for st in loop.steps if st.effect != "external_load"]
    loop.current = loop.current.replace(FRC=0.0)
    assert loop.faults_without_tentative() == {}


@pytest.mark.slow
def test_pinned_structure_is_the_first_step_and_held_through_the_rounds(record):
    """The second pass's start (:meth:`ResidualLoop.pin_structure`): on a nominal HF `test`
    record the structure is put in at its physical values (the thesis' flapper) and reported
    as the first steps; the result's "before" stays the plain LF fit of the declared faults;
    the structure is no candidate and its parameters are not refitted by the rounds."""
    from eha.explain import ResidualLoop

    data = load(record("test", 0.6))
    loop = ResidualLoop.on(data, settings=LoopSettings(pop=12, seed=0), pin_structure=True,
                        max_gen=20, stall=5)
    before = loop.baseline()
    assert [st.effect for st in loop.steps] == ["orifice_law", "flapper_dynamics"]
    assert loop.steps[-1].params == {"SNF": 2513.0, "ZF": 0.6}
    assert loop.current.SNF == 2513.0 and loop.current.orifice_law == 1.0
    assert before.params.SNF == LFParams().SNF          # the plain fit, reported as before
    assert loop.cur.rmse_score < 0.5 * before.rmse_score    # the structure is on this record
    assert loop.steps[-1].rmse_after == loop.cur.rmse_all
    assert not {"orifice_law", "flapper_dynamics"} & {e.name for e in loop.remaining()}
    assert not {"SNF", "ZF"} & set(loop.free)


def test_second_pass_replaces_the_first_only_by_the_rule_for_adding_an_effect():
    """:func:`better_pass` on canned results: the second pass is reported when its scored
    RMSE is lower by ``min_gain`` (10 %) after 2 % per extra parameter, else the first."""
    from types import SimpleNamespace

    from eha.explain.decide import better_pass

    def result(rmse, *effects):
        return SimpleNamespace(after=SimpleNamespace(rmse_score=rmse),
                               steps=[SimpleNamespace(effect=e) for e in effects])

    s = LoopSettings()
    first = result(20e-6, "orifice_law", "supply_pressure")
    assert better_pass(first, result(1.6e-6, "orifice_law", "flapper_dynamics",
                                     "clogging", "sensor_bias"), s).after.rmse_score == 1.6e-6
    # 11 % lower with one parameter fewer: taken; with three more (11 - 6 < 10): not
    assert better_pass(first, result(17.8e-6, "orifice_law"), s) is not first
    assert better_pass(first, result(17.8e-6, "supply_pressure", "leakage", "external_load",
                                     "offset"), s) is first
    assert better_pass(first, result(19e-6, "orifice_law"), s) is first       # 5 %: not
    assert better_pass(first, result(math.nan), s) is first


@pytest.mark.slow
def test_global_refits_are_finished_by_least_squares(record, monkeypatch):
    """A short GA (population 8, 6 generations) on 7 parameters (faults, load, leak, motor
    gain, flapper) of an LF `test` record, warm-started near the truth with the flapper at
    its probe (the flapper candidate of the bench record load+leak+motor_gain@steps): finished
    by least squares (the default) the fit is within the noise and the flapper and load
    within 15 % and 2 %, closer than the GA and its pattern search alone (measured: 0.93 µm
    and flapper 3 % off, against 1.08 µm and 9 %; with the compass search before its pattern
    moves the GA stopped on the valley's side, 2.4 µm and 35 % off). It also guards the
    compass polish's early stop (FINISHED_POLISH_XTOL): stopped at 1e-3 of each range, least
    squares stalled at 1.65 µm, the flapper 25 % off."""
    import eha.explain.fitting as fitting
    from eha.explain import ResidualLoop

    truth = {"orifice_law": 1.0, "SNF": 2513.0, "ZF": 0.6, "FRC": 2000.0, "Clk": 5e-12,
             "GM": 0.008}
    data = load(record("test", 0.6, truth, model="lf"))
    loop = ResidualLoop.on(data, settings=LoopSettings(pop=8, seed=0, flow_gain_spread=0.0), max_gen=6, stall=3)
    free = {**loop.bounds, "FRC": (-8000.0, 8000.0), "SNF": (300.0, 2e4), "ZF": (0.1, 2.0),
            "Clk": (0.0, 2e-11), "GM": (0.002, 0.02)}
    start = loop.problem.base.replace(orifice_law=1.0, SNF=2513.0, ZF=0.6, FRC=2078.0, Clk=4.97e-12,
                              GM=0.00809)
    finished = loop.fitter.evaluate([loop.fitter.refit(start, free, "finished",
                                                        warm_start=True)])[0]
    monkeypatch.setattr(fitting, "LEAST_SQUARES_FINISH", False)
    ga_only = loop.fitter.evaluate([loop.fitter.refit(start, free, "GA alone", warm_start=True)])[0]
    assert finished.rmse_fit < 1.5 * NOISE and finished.rmse_fit < ga_only.rmse_fit
    assert finished.rmse_hold < ga_only.rmse_hold
    assert abs(finished.params.SNF / 2513.0 - 1) < abs(ga_only.params.SNF / 2513.0 - 1)
    assert finished.params.SNF == pytest.approx(2513.0, rel=0.15)
    assert finished.params.FRC == pytest.approx(2000.0, rel=0.02)


@pytest.mark.slow
def test_final_check_far_from_the_noise_swaps_one_effect_for_two(record):
    """An LF record with the orifice law, seal wear (Clk 5e-12) and a viscous jack (CJ 16000)
    on `test`; only a low supply pressure is accepted by hand (on the HF bench record
    leak+viscous@test of seed block 1 the rounds took that path and stopped at 20 µm: the
    viscous jack alone does not beat it without the leak). Far from the noise the swap also
    tries its rivals two at a time: the leak and the viscous jack together take the supply
    pressure's place (each within 10 %), and the model explains the record."""
    from eha.explain.effects import EFFECTS
    from eha.explain import ResidualLoop

    data = load(record("test", 0.6,
                        {"orifice_law": 1.0, "Clk": 5e-12, "CJ": 1.6e4}, model="lf"))
    loop = ResidualLoop.on(data, effects="orifice_law,supply_pressure,leakage,viscous_friction,"
                        "delay", settings=LoopSettings(pop=20, seed=0))
    _accept_by_hand(loop, "orifice_law+supply_pressure")
    assert loop.unexplained()
    # the swap as the final check calls it (on this LF record the supply pressure does not
    # even pay for itself, so prune() would remove it before swapping it)
    step = next(st for st in loop.steps if st.effect == "supply_pressure")
    supply = EFFECTS["supply_pressure"]
    free = {k: v for k, v in loop.free.items() if k not in supply.bounds}
    swapped = loop.swap(step, supply.switch_off(loop.current), free)
    assert swapped is not None and swapped.effect == "supply_pressure"
    assert sorted(swapped.replaced_by.split("+")) == ["leakage", "viscous_friction"]
    assert {"leakage", "viscous_friction"} <= {s.effect for s in loop.steps}
    assert "supply_pressure" not in {s.effect for s in loop.steps}
    assert loop.current.PSR == LFParams().PSR
    assert loop.current.CJ == pytest.approx(1.6e4, rel=0.10)
    assert loop.current.Clk == pytest.approx(5e-12, rel=0.10)
    assert not loop.unexplained()
    assert_effects_are_the_model(SimpleLoopResult(loop))


class SimpleLoopResult:
    """What :func:`assert_effects_are_the_model` reads, from a loop (before/after models and
    the effects reported)."""

    def __init__(self, loop):
        self.before = loop.fitter.evaluate([loop.problem.base])[0]
        self.after = loop.cur
        self.effects = [st.effect for st in loop.steps]
        self.dismissed = loop.dismissed


def test_a_candidate_that_trades_the_position_for_p12_is_not_added(record):
    """The refit of a candidate is replaced by a seal-wear leak 40x the LF's truth on an LF
    `test` record with P12: the position gets far worse than the current model's (the truth),
    and the candidate is switched off (score -inf), not merely scored low; without P12 in the
    fit the same candidate keeps its (negative) score."""
    from eha.explain import Candidate, ResidualLoop

    data = load(record("test", 0.6, model="lf"))
    assert data.p12 is not None
    truth = LFParams().replace(**FAULTS)
    for weight, switched_off in ((1.0, True), (0.0, False)):
        loop = ResidualLoop.on(data, settings=LoopSettings(p12_weight=weight))
        loop.current = truth.replace(XJ0=loop.problem.base.XJ0)
        loop.cur = loop.fitter.evaluate([loop.current])[0]
        loop.fitter.fit_with_cost = lambda start, free, label, **kw: (start.replace(Clk=2e-11), 0.0)
        cand = loop.try_candidate(Candidate("leakage", math.nan, math.nan))
        assert cand.rmse_fit > 2 * loop.cur.rmse_fit
        assert (cand.score == -math.inf) is switched_off, (weight, cand.score)


def test_flow_gain_spread_is_fitted_with_the_faults_unless_declared_known_or_off(record):
    """With --flow-gain-spread 0.1 the healthy flow gain GQ joins the declared faults within
    +-10 % of the base's value (default +-4 %), to 6 significant digits as typed; not when the
    spread is 0, not when GQ is known (--set) or declared with its own bounds (--fit), and out of range is one
    line."""
    from eha.explain import ResidualLoop

    data = load(record("test", 0.6, model="lf"))
    spread = LoopSettings(flow_gain_spread=0.1)
    assert ResidualLoop.on(data, settings=spread).bounds == {
        "BKL": (0.0, 2e-3), "FDJ": (0.0, 8000.0), "GQ": (0.18, 0.22)}
    assert ResidualLoop.on(data).bounds["GQ"] == (0.192, 0.208)      # the default 0.04
    assert "GQ" not in ResidualLoop.on(data, settings=LoopSettings(flow_gain_spread=0.0)).bounds
    assert "GQ" not in ResidualLoop.on(data, fixed=("GQ",), settings=spread).bounds
    assert ResidualLoop.on(data, fit="BKL,FDJ,GQ=0.1:0.3", settings=spread).bounds["GQ"] == \
        (0.1, 0.3)
    wide = ResidualLoop.on(data, base=LFParams(GQ=0.25), settings=LoopSettings(flow_gain_spread=0.2))
    assert wide.bounds["GQ"] == (0.2, 0.3)
    with pytest.raises(ExplainError, match=r"`flow_gain_spread` 0.6: allowed range \[0, 0.5\]"):
        LoopSettings(flow_gain_spread=0.6)
    result = CliRunner().invoke(app, ["explain", str(record("test", 0.6, model="lf")),
                                      "--flow-gain-spread", "-1", "--no-progress"])
    assert result.exit_code != 0
    assert "--flow-gain-spread -1.0: allowed range [0, 0.5]" in result.output
    assert "Traceback" not in result.output


def test_flow_gain_at_the_edge_of_its_spread_is_read_as_a_flow_loss():
    """flow_gain_at_edge: a fitted GQ within 2 % of the spread's width from a bound is at its
    edge (the healthy spread cannot hold the flow loss); inside, or GQ declared or not fitted,
    it is not."""
    from types import SimpleNamespace

    from eha.explain.decide import flow_gain_at_edge

    def result(gq, fitted=True, bounds=(0.18, 0.22)):
        return SimpleNamespace(facts=SimpleNamespace(flow_gain_fitted=fitted),
                               fit_bounds={"BKL": (0, 2e-3), "GQ": bounds},
                               faults_after={"BKL": 1e-4, "GQ": gq})

    assert flow_gain_at_edge(result(0.18)) == \
        "GQ 0.18 at the lower bound of its healthy spread 0.18-0.22"
    assert "lower bound" in flow_gain_at_edge(result(0.1807))      # within 2 % of 0.04
    assert "upper bound" in flow_gain_at_edge(result(0.2199))
    assert flow_gain_at_edge(result(0.1809)) is None
    assert flow_gain_at_edge(result(0.206)) is None
    assert flow_gain_at_edge(result(0.18, fitted=False)) is None   # declared: --fit GQ=...


@pytest.mark.slow
def test_a_flow_loss_beyond_the_healthy_spread_is_not_taken_by_the_flow_gain(record,
                                                                              monkeypatch):
    """A torque motor at 80 % of its gain (GM 0.008) on an LF record. With --flow-gain-spread
    0.1 the declared faults' fit takes the flow gain to its bound (0.18); left free it would
    share the loss with the motor gain (measured: GQ 0.188, GM 0.0085). It goes back to
    nominal, is no longer fitted, and the motor gain is found within 1 %, the faults within
    2 %; the JSON says why. A final GQ still at the edge (the safety net; forced here) runs
    the loop again with the flow gain at nominal."""
    import eha.explain.api as api

    data = load(record("mixed", 0.6, {"GM": 0.008}, model="lf"))
    res = explain(data, effects="motor_gain,leakage,external_load", flow_gain_spread=0.1,
                  **FIRST_LF)
    assert res.facts.flow_gain_released == \
        "GQ 0.18 at the lower bound of its healthy spread 0.18-0.22"
    assert res.to_json()["flow_gain_released"] == res.facts.flow_gain_released
    assert "GQ" not in res.faults_after and res.after.params.GQ == LFParams().GQ
    assert res.effects == ["motor_gain"]
    assert res.after.params.GM == pytest.approx(0.008, rel=0.01)
    for name, truth in FAULTS.items():
        assert res.faults_after[name] == pytest.approx(truth, rel=0.02)

    spreads, problems = [], []
    real_passes = api._passes

    def passes(problem, settings, *rest):
        spreads.append(settings.flow_gain_spread)
        problems.append(problem)
        return real_passes(problem, settings, *rest)

    monkeypatch.setattr(api, "_passes", passes)
    monkeypatch.setattr(api, "flow_gain_at_edge", lambda result: "GQ forced to its edge")
    again = explain(data, effects="motor_gain", flow_gain_spread=0.1, max_steps=1, **FIRST_LF)
    assert spreads == [0.1, 0.0]
    # the second run is the same record's problem with GQ held (not built again)
    assert "GQ" in problems[0].bounds and "GQ" not in problems[1].bounds
    assert problems[1].record is problems[0].record
    assert again.facts.flow_gain_released == "GQ forced to its edge"
    assert again.settings["flow_gain_spread"] == 0.1


@pytest.mark.slow
def test_healthy_flow_gain_is_fitted_where_the_valve_saturates(tmp_path):
    """A healthy HF actuator whose flow gain is 3 % above nominal (the FP bench's seed 6001:
    GQ 0.206, FDJ 219 N, BKL 4.8 µm) on the 1 cm, 5 Hz `sine`, where the valve saturates:
    with the flow gain fitted (--flow-gain-spread 0.1) the record is explained without any effect
    beyond the structure, GQ within 1.5 % and FDJ within 10 %; held at nominal the loop
    leaves it unexplained or FDJ more than 30 % off (measured: 24.8 µm, FDJ ~0)."""
    truth = {"GQ": 0.206, "FDJ": 219.0, "BKL": 4.8e-6}
    path = tmp_path / "sine.csv"
    synthetic_record("sine", truth, t_end=1.0, noise=NOISE, seed=6001).to_csv(path, index=False)
    data = load(path)
    fitted = explain(data, flow_gain_spread=0.1, **FIRST)
    assert not fitted.beyond_healthy, fitted.verdict
    assert set(fitted.effects) <= {"orifice_law", "flapper_dynamics"}
    assert fitted.faults_after["GQ"] == pytest.approx(0.206, rel=0.015)
    assert fitted.faults_after["FDJ"] == pytest.approx(219.0, rel=0.10)
    nominal = explain(data, flow_gain_spread=0.0, **FIRST)
    assert nominal.beyond_healthy or abs(nominal.faults_after["FDJ"] / 219.0 - 1) > 0.3
