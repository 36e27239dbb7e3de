"""Test design (eha.design, `eha design`): the family within its limits, the prediction against
analytic facts, the search end to end, the verification's statistics, bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from helpers import error_line, files_under, invoke_eha
from eha.design import DesignError, Limits, design
from eha.design.family import (at_rest_at_the_end, command_samples, genes, n_genes,
                               outside_limits)
from eha.design.predict import predict
from eha.design.targets import from_explain, resolve_targets
from eha.design.verify import levels_around, measured, upper_bound
from eha.models.commands import array_command, load_command_file, make_command


@pytest.mark.parametrize("seed", range(6))
def test_every_family_member_respects_the_limits_and_starts_at_rest(seed):
    limits = Limits(duration=0.8, max_stroke=4e-3, max_rate=0.05, max_freq=15.0)
    x = np.random.default_rng(seed).random(n_genes())
    t, com = command_samples(x, limits)
    assert t[0] == 0.0 and t[-1] == pytest.approx(0.8) and com[0] == 0.0
    assert np.max(np.abs(com)) <= 4e-3 + 1e-15
    assert np.max(np.abs(np.diff(com))) / 1e-3 <= 0.05 * (1 + 1e-9)
    if at_rest_at_the_end(com, limits):
        assert abs(com[-1]) < 1e-9


def test_a_family_member_copies_a_slow_chirp():
    """One chirp segment filling the test: the segments left out take no time."""
    limits = Limits()
    t, com = command_samples(genes([{"shape": "chirp", "share": 1.0, "amplitude": 1.0,
                                     "frequency": 1.5}], limits), limits)
    assert np.max(np.abs(com)) == pytest.approx(0.01, rel=0.02)
    assert at_rest_at_the_end(com, limits)
    assert np.count_nonzero(np.abs(com[:900]) > 5e-3) > 100


def test_prediction_facts():
    """(a) the sensor noise: where it dominates (100 µm, far above the healthy scatter's and
    the model form's few µm) a target needs twice the size at twice the noise, within 5 %; at
    1 µm the offset on chirp_1cm is limited by the healthy fleet's scatter instead (twice the
    noise, less than 30 % more); (b) a command that holds
    still shows no backlash (no reversal: no signature, infinite size); (c) the 5 Hz sine
    saturates the jack's rate: the check's LF cannot follow it (its measured campaign detects
    nothing), the slow chirp it can."""
    targets = resolve_targets(["Ofs", "BKL"])
    chirp = make_command("chirp_1cm")
    loud = predict(chirp, targets, 1.0, noise={"xu": 1e-4}, n_actuators=1)
    louder = predict(chirp, targets, 1.0, noise={"xu": 2e-4}, n_actuators=1)
    assert louder.mds["Ofs"] / loud.mds["Ofs"] == pytest.approx(2.0, rel=0.05)
    one = predict(chirp, targets, 1.0, noise={"xu": 1e-6}, n_actuators=1)
    two = predict(chirp, targets, 1.0, noise={"xu": 2e-6}, n_actuators=1)
    assert 1.0 < two.mds["Ofs"] / one.mds["Ofs"] < 1.3
    still = array_command(np.array([0.0, 1.0]), np.array([0.0, 0.0]), "still")
    assert math.isinf(predict(still, targets, 1.0, n_actuators=1).mds["BKL"])
    assert one.followed and not predict(make_command("sine"), targets, 1.0,
                                        n_actuators=1).followed
    assert set(one.separable) == {"Ofs", "BKL"} and one.separable["Ofs"]["BKL"] > 0


def test_a_design_end_to_end_writes_a_command_that_runs(tmp_path):
    """A short search on two targets: the command file loads as a command within the limits,
    the JSON has every target's prediction next to the library's, the PNG exists; the same
    seed gives the same command."""
    limits = Limits(duration=0.5, max_stroke=5e-3)
    kw = dict(faults=["BKL", "Ofs"], limits=limits, seed=3, population=6, generations=2,
              actuators=1)
    result = design(**kw)
    paths = result.save(tmp_path, "d")
    cmd = load_command_file(str(paths["command"]))
    assert np.max(np.abs(cmd.samples[1])) <= 5e-3 + 1e-12
    doc = json.loads(paths["json"].read_text())
    assert set(doc["targets"]) == {"BKL", "Ofs"}
    # the library commands cut to the limits; the step command stays beyond them (its
    # energy above max_freq), named in the settings and not compared
    assert set(doc["targets"]["Ofs"]["library"]) == {"chirp_1cm", "mixed", "sine"}
    assert doc["settings"]["library_cut"]["test"]["beyond"]
    assert doc["settings"]["max_stroke"] == 5e-3 and paths["png"].stat().st_size > 10_000
    assert np.array_equal(design(**kw).com, result.com)
    assert len(result.to_pandas()) == 2


@pytest.mark.parametrize("args, message", [
    (["--duration", "0"], "--duration 0.0: allowed range [0.2, 10] s"),
    (["--max-stroke", "0"], "--max-stroke 0.0: allowed range [0.0001, 0.2] m"),
    (["--faults", "BKX"], "--faults: 'BKX' is not a health fault"),
    (["--separate", "offset,offset"], "--separate: 'offset,offset' must be two different"),
    (["--separate", "offset"], "--separate: 'offset' must be two different"),
    (["--effects", "orifice_law"], "effect 'orifice_law': structure of the LF model"),
    (["--signals", "xs"], "--signals: 'xs'; allowed xu, p12, cor"),
    (["--sampling", "300"], "--sampling 300.0: allowed a divisor of 1000 Hz"),
    (["--alpha", "0.7"], "--alpha 0.7: allowed range (0, 0.5)"),
])
def test_bad_design_input_is_one_line_exit_2_nothing_written(tmp_path, args, message):
    out = tmp_path / "out"
    proc = invoke_eha("design", *args, "--out", out)
    assert message in error_line(proc, 2)
    assert not out.exists() or files_under(out) == []


def test_around_reads_the_rivals_of_an_explain_json():
    doc = {"steps": [{"effect": "orifice_law", "params": {}},
                     {"effect": "external_load", "params": {"FRC": 829.0}}],
           "not_excluded": [{"effect": "offset", "param": "Ofs", "value": -0.009, "unit": "mA"}]}
    pairs, around = from_explain(doc)
    assert pairs == [("external_load", "offset")]
    assert around == {"external_load": 829.0, "offset": -0.009}
    with pytest.raises(DesignError, match="no rival"):
        from_explain({"steps": [], "not_excluded": []})


def test_verification_statistics_on_canned_assessments():
    """Thresholds from the first 10 healthy seeds only; false alarms counted on the 40 others
    with the Clopper-Pearson bound; the measured detectable size is the smallest level with
    P_D >= 0.95; isolation counts the declared fault."""
    from eha.models.faults import FAULTS

    rng = np.random.default_rng(1)

    def row(seed, grp="healthy", ofs=0.0, weight=0.0):
        means = {n: FAULTS[n].healthy for n in FAULTS}
        means["Ofs"] = ofs + rng.normal(0, 0.001)
        return {"command": "c", "grp": grp, "seed": seed, "means": means,
                "spread": {n: 0.0 for n in FAULTS}, "weights": {"Ofs": weight, "none": 1 - weight}}

    rows = [row(s) for s in range(50)]
    rows += [row(100 + s, "Ofs=0.002", 0.002, 0.9) for s in range(10)]
    rows += [row(200 + s, "Ofs=0.02", 0.02, 0.9) for s in range(10)]
    m = measured(rows, 10, 0.01)["c"]
    assert m["calibration_actuators"] == 10 and m["false_alarms"]["n"] == 40
    assert m["false_alarms"]["upper_95"] == pytest.approx(
        upper_bound(m["false_alarms"]["alarms"], 40))
    levels = m["faults"]["Ofs"]["levels"]
    assert [e["deviation"] for e in levels] == pytest.approx([0.002, 0.02])
    assert m["faults"]["Ofs"]["min_detectable"] == pytest.approx(0.02)
    assert levels[1]["isolated"] == 1.0
    assert upper_bound(0, 200) == pytest.approx(1 - 0.05 ** (1 / 200), rel=1e-6)


def test_a_size_detected_at_the_smallest_level_tried_is_reported_as_a_bound():
    """Every level detected: the measured size is the smallest level, which bounds the true
    one from above; the table says ``<=``, and a size found above the smallest level does
    not."""
    from eha.design.verify import Verification
    from eha.models.faults import FAULTS

    def row(seed, grp="healthy", ofs=0.0):
        means = {n: FAULTS[n].healthy for n in FAULTS}
        means["Ofs"] = ofs + 0.001 * ((seed * 7919) % 13 - 6) / 6
        return {"command": "c", "grp": grp, "seed": seed, "means": means,
                "spread": {n: 0.0 for n in FAULTS}, "weights": {"Ofs": 0.9, "none": 0.1}}

    rows = [row(s) for s in range(50)] + [row(100 + s, "Ofs=0.02", 0.02) for s in range(10)]
    rows += [row(200 + s, "Ofs=0.04", 0.04) for s in range(10)]
    figures = measured(rows, 10, 0.01)
    assert figures["c"]["faults"]["Ofs"]["at_lowest_level"]
    table = Verification(figures, {}, {}, "x", "r").markdown()
    assert "| Ofs | <= 0.02" in table
    rows += [row(300 + s, "Ofs=0.0005", 0.0005) for s in range(10)]
    figures = measured(rows, 10, 0.01)
    assert not figures["c"]["faults"]["Ofs"]["at_lowest_level"]
    assert "| Ofs | 0.02" in Verification(figures, {}, {}, "x", "r").markdown()


def test_levels_around_the_prediction_stay_inside_the_bounds():
    lv = levels_around({"GM": 0.001, "Clk": math.inf, "BKL": 1e-3})
    assert lv["GM"] == pytest.approx([0.006, 0.008, 0.009, 0.0095])
    assert lv["Clk"] == [5e-13, 1.5e-12, 4e-12]            # undetectable: campaign levels
    assert max(lv["BKL"]) == 1.25e-3


def test_an_undecided_explain_answer_names_the_test_that_decides_it(tmp_path):
    """`eha explain` with rivals it cannot rule out prints the `eha design --around` line
    (and its --json carries it, eha/explain/outputs.py); without rivals, nothing."""
    from types import SimpleNamespace

    from eha.cli.explain import _next_test
    from eha.cli.guard import console

    res = SimpleNamespace(not_excluded=[{"effect": "offset", "param": "Ofs", "value": -0.009,
                                         "unit": "mA"}], rivals_ruled_out=[])
    with console.capture() as cap:
        _next_test(res, tmp_path / "out.json")
        _next_test(SimpleNamespace(not_excluded=[], rivals_ruled_out=[]), tmp_path / "out.json")
    text = " ".join(cap.get().split())
    assert "offset (Ofs -0.009 mA)" in text
    assert f"eha design --faults none --around {tmp_path / 'out.json'}" in text.replace("\n", "")
    # and how to read that test's record: the first record as prior (eha.explain.settle)
    assert f"eha explain TEST.csv --prior {tmp_path / 'out.json'}" in text.replace("\n", "")
    # a rival the re-simulations ruled out: named with its figures, no design line
    check = {"record": -0.00605, "without": [-0.00696, 0.00022], "with": [-0.00463, 0.00056],
             "size": 0.00242}
    ruled = SimpleNamespace(not_excluded=[], rivals_ruled_out=[
        {"effect": "offset", "param": "Ofs", "value": -0.00605, "value_unit": "mA",
         "unit": "mA", "rival_check": check}])
    with console.capture() as cap:
        _next_test(ruled, tmp_path / "out.json")
    text = " ".join(cap.get().split())
    assert ("offset beside the model: ruled out by re-simulation (the record reads Ofs "
            "-0.00605 mA, the model alone -0.00696 ± 0.00022; with +0.00242 mA of it "
            "-0.00463 ± 0.00056)") in text
    assert "eha design" not in text


def test_a_library_command_within_the_limits_is_outside_only_when_it_breaks_one():
    """``outside_limits`` names the limit a command breaks: chirp_1cm fits a 2-s, 1-cm,
    0.1-m/s test; the 5 Hz sine is too fast for it, and a 1-s cut of chirp_1cm is not at rest
    at its end."""
    t2 = np.round(np.arange(0.0, 2.0 + 5e-4, 1e-3), 9)
    limits = Limits(duration=2.0, max_stroke=1e-2, max_rate=0.1)
    assert outside_limits(make_command("chirp_1cm").sample(t2), limits) is None
    assert "m/s" in outside_limits(make_command("sine").sample(t2), limits)
    t1 = t2[t2 <= 1.0]
    assert "rest" in outside_limits(make_command("chirp_1cm").sample(t1),
                                    Limits(duration=1.0, max_stroke=1e-2, max_rate=0.1))


@pytest.mark.slow
def test_the_design_is_never_worse_than_a_library_command_within_the_limits():
    """With a search too short to find much (4 candidates, 1 generation), the design still
    scores at least as well, by the search's own objective, as every library command that
    fits the limits and that the LF model follows: the incumbent is a candidate."""
    from eha.design.search import best_library, score
    from eha.design.targets import resolve_targets

    limits = Limits(duration=2.0, max_stroke=1e-2, max_rate=0.1)
    result = design(faults=["Ofs", "BKL"], limits=limits, seed=0, population=4,
                    generations=1, actuators=1)
    targets = resolve_targets(["Ofs", "BKL"], (), [])
    reference = best_library(targets, result.library)
    mine = score(predict(array_command(result.t, result.com, "d"), targets, 2.0,
                         n_actuators=1), targets, reference)
    from eha.design.library import best_by_score, cut_to_limits, dominated_by

    cuts = {name: cut_to_limits(name, limits) for name in result.library}
    eligible = [name for name, pred in result.library.items() if pred.followed and
                cuts[name].beyond is None]
    assert eligible, "no library command fits the limits: the test shows nothing"
    for name in eligible:   # 1e-3: a log ratio (0.1 %), the samples against the formula
        assert mine <= score(result.library[name], targets, reference) + 1e-3, name
    # and no target harder to see than on the best library command (by score), cut to the
    # same limits
    top = best_by_score({n: result.library[n] for n in eligible}, targets, reference)
    mine_pred = predict(array_command(result.t, result.com, "d"), targets, 2.0, n_actuators=1)
    assert dominated_by(mine_pred, result.library[top], targets, tolerance=1e-3) == []
    if result.settings["chosen"] != "searched":
        assert result.settings["chosen"].startswith("library command ")
        assert outside_limits(result.com, limits) is None


def test_library_commands_are_cut_to_the_design_limits():
    """Each library command as a test within the limits: within the stroke and the rate,
    at rest at the start and the end; a step command (test) cannot meet a rate limit
    without shrinking to a tenth of a millimetre and is marked beyond the frequency limit."""
    from eha.design.family import at_rest_at_the_end
    from eha.design.library import cut_to_limits

    limits = Limits(duration=0.5, max_stroke=5e-3, max_rate=0.1)
    for name in ("chirp_1cm", "mixed", "test", "sine"):
        cut = cut_to_limits(name, limits)
        assert cut.t[-1] == pytest.approx(0.5) and cut.com[0] == 0.0
        assert np.max(np.abs(cut.com)) <= 5e-3 * (1 + 1e-9)
        assert np.max(np.abs(np.diff(cut.com))) / 1e-3 <= 0.1 * 1.001
        assert at_rest_at_the_end(cut.com, limits)
    assert cut_to_limits("test", limits).beyond is not None
    assert cut_to_limits("chirp_1cm", limits).scale < 1.0


def test_a_pair_member_not_asked_for_counts_only_through_the_pair():
    """A separating test is judged by its separation: detecting the pair's members worse
    than the library costs nothing unless they were asked for in their own right."""
    from types import SimpleNamespace

    from eha.design.search import PAIR_WEIGHT, score

    pair = ("external_load", "offset")
    targets = resolve_targets([], (), [pair])
    reference = {t.name: ("chirp_1cm", 1e-9) for t in targets}
    pred = SimpleNamespace(mds={t.name: 1e-6 for t in targets},
                           separable={"external_load": {"offset": 2.0},
                                      "offset": {"external_load": 2.0}})
    alone = score(pred, targets, reference, [pair], detect=set())
    assert alone == pytest.approx(PAIR_WEIGHT * math.log(2.0))
    assert score(pred, targets, reference, [pair]) > alone + 1.0


def test_a_command_the_lf_cannot_follow_loses_to_every_one_it_can():
    """The best a followed separating test can score (both directions separable at 1e-3 of
    the detectable size) against the worst (never separable): the whole span is below the
    penalty of a command the LF cannot follow, so a search never prefers one; among the
    unfollowed, the less unfollowed wins."""
    from types import SimpleNamespace

    from eha.design.predict import FOLLOW_RATIO
    from eha.design.search import score, unfollowed_penalty

    pair = ("motor_gain", "supply_pressure")
    targets = resolve_targets([], (), [pair])
    reference = {t.name: ("chirp_1cm", 1e-9) for t in targets}

    def pred(separable, followed, model_form=1.0):
        return SimpleNamespace(mds={t.name: 1e-6 for t in targets}, followed=followed,
                               model_form=model_form,
                               separable={"motor_gain": {"supply_pressure": separable},
                                          "supply_pressure": {"motor_gain": separable}})

    best_unfollowed = pred(1e-6, False, 1.01 * FOLLOW_RATIO)
    worst_followed = pred(math.inf, True)
    assert (score(best_unfollowed, targets, reference, [pair], detect=set())
            + unfollowed_penalty(best_unfollowed)
            > score(worst_followed, targets, reference, [pair], detect=set())
            + unfollowed_penalty(worst_followed))
    assert unfollowed_penalty(pred(1.0, False, 20 * FOLLOW_RATIO)) > \
        unfollowed_penalty(pred(1.0, False, 2 * FOLLOW_RATIO)) > 0.0


def test_a_pair_not_told_apart_says_what_would_tell_it_apart(tmp_path):
    """A supply-pressure drop is told from a motor gain by no command the check's LF follows
    (docs/design.md): the design names the pair's separable sizes with the load pressure
    recorded, with a test load and on a 4x longer test, in its JSON and on the console."""
    out = tmp_path / "out"
    proc = invoke_eha("design", "--faults", "none", "--separate", "motor_gain,supply_pressure",
                      "--duration", "0.5", "--population", "4", "--generations", "1",
                      "--actuators", "1", "--out", out)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "design.json").read_text())
    row = doc["pairs"][0]
    assert row["told_apart_at_these_sizes"] is False
    assert set(row["alternatives"]) == {"the load pressure P12 recorded",
                                        "a 2000 N test load", "a 4x longer test"}
    for sizes in row["alternatives"].values():
        assert set(sizes) == {"motor_gain", "supply_pressure"}
        assert 0 < sizes["motor_gain"] < 0.01      # the motor gain is told from the drop
    assert "with a 2000 N test load: motor_gain from" in proc.stdout
    # how closely the check's LF follows the design, against the limit, as the JSON has it
    follows = "follows" if doc["model_form_rms_in_noise"] <= 3.0 else "does not follow"
    assert (f"the check's LF {follows} it: {doc['model_form_rms_in_noise']:.1f} noise stds of "
            "model-form residual on healthy actuators (not followed beyond 3)") in proc.stdout
