"""The residual loop's decision rule (eha.explain.decide) on numbers and canned evaluations
(no simulation, no GA).

:func:`~eha.explain.decide.choose` decides from refitted candidates; its model evaluations
(splitting a combination, refitting the kept members) are handed in as callables, here canned.
"""

import math

import pytest

from eha.explain.decide import choose, keeps_effect, past_any, significance, unspecific
from eha.explain.results import Candidate
from eha.explain.settings import ExplainError, LoopSettings

SETTINGS = LoopSettings(min_gain=0.1, penalty=0.02, significance=0.01)


def cand(effect, gain, params=1, p_value=1e-6, n_eff=100.0):
    c = Candidate(effect, math.nan, math.nan, refit=True)
    c.gain = gain
    c.score = gain - SETTINGS.penalty * params
    c.p_value, c.n_eff = p_value, n_eff
    return c


def no_split(best):
    return best.effect.split("+")


def never_refit(best, kept):  # pragma: no cover - must not be called
    raise AssertionError("refit_members called")


def test_the_best_significant_candidate_wins_with_its_close_rivals_as_alternatives():
    choice = choose([cand("external_load", 0.50), cand("offset", 0.47),
                     cand("leakage", 0.20)], SETTINGS, no_split, never_refit)
    assert choice.best.effect == "external_load"
    assert choice.members == ["external_load"]
    # within ALTERNATIVE_MARGIN (0.05) of the chosen score: offset; leakage is not
    assert set(choice.alternatives) == {"offset"}


def test_below_min_gain_nothing_is_added_and_the_reason_names_the_best():
    choice = choose([cand("delay", 0.11), cand("offset", 0.05)], SETTINGS, no_split,
                    never_refit)
    assert choice.best is None
    assert "delay" in choice.stop and "penalised" in choice.stop


def test_a_large_but_insignificant_gain_is_passed_over_for_a_significant_one():
    choice = choose([cand("delay", 0.70, p_value=0.2, n_eff=5),
                     cand("external_load", 0.60, p_value=1e-5)], SETTINGS, no_split,
                    never_refit)
    assert choice.best.effect == "external_load"
    assert "delay" in choice.superseded


def test_when_no_gain_is_significant_the_loop_stops_and_says_why():
    choice = choose([cand("delay", 0.40, p_value=0.2, n_eff=5)], SETTINGS, no_split,
                    never_refit)
    assert choice.best is None
    assert "not significant" in choice.stop and "effective samples" in choice.stop


def test_candidates_that_switched_their_effect_off_are_ignored():
    off = cand("offset", 0.9)
    off.score = -math.inf
    assert choose([off], SETTINGS, no_split, never_refit).best is None


def test_a_combination_whose_members_all_pay_is_kept_in_the_split_order():
    combo = cand("orifice_law+flapper_dynamics", 0.9, params=2)
    choice = choose([combo, cand("flapper_dynamics", 0.3, params=2)], SETTINGS,
                    lambda best: ["flapper_dynamics", "orifice_law"], never_refit)
    assert choice.best is combo
    assert choice.members == ["flapper_dynamics", "orifice_law"]


def test_a_combination_with_a_passenger_is_replaced_by_its_kept_members_refitted():
    combo = cand("orifice_law+flapper_dynamics+delay", 0.92, params=3)
    pair = cand("orifice_law+flapper_dynamics", 0.91, params=2)
    calls = []

    def split(best):
        return ["orifice_law", "flapper_dynamics"] if best is combo else best.effect.split("+")

    def refit(best, kept):
        calls.append((best.effect, tuple(kept)))
        return pair

    choice = choose([combo], SETTINGS, split, refit)
    assert calls == [("orifice_law+flapper_dynamics+delay", ("orifice_law", "flapper_dynamics"))]
    assert choice.best is pair and combo.effect in choice.superseded


def test_a_split_already_tried_is_not_refitted_again():
    combo = cand("orifice_law+flapper_dynamics+delay", 0.92, params=3)
    pair = cand("orifice_law+flapper_dynamics", 0.85, params=2)
    choice = choose([combo, pair], SETTINGS,
                    lambda best: (["orifice_law", "flapper_dynamics"] if best is combo
                                  else best.effect.split("+")), never_refit)
    assert choice.best is pair


def test_significance_falls_with_effective_samples_and_rises_with_the_gain():
    # same RMSE reduction, fewer independent samples: less significant
    assert significance(2e-6, 1.6e-6, 1, 400) < significance(2e-6, 1.6e-6, 1, 20)
    assert significance(2e-6, 1.0e-6, 1, 40) < significance(2e-6, 1.8e-6, 1, 40)
    assert significance(2e-6, 2.1e-6, 1, 40) == 1.0       # no reduction
    # a 10 % RMSE reduction on 1000 white samples is overwhelming (F = 0.235 * 999 ~ 235)
    assert significance(1.0, 0.9, 1, 1000) < 1e-20


@pytest.mark.parametrize("field, value", [("holdout", 0.9), ("min_gain", -0.1),
                                          ("alpha", 0.0), ("max_steps", -1), ("pop", 1)])
def test_settings_outside_their_range_are_refused_in_one_line(field, value):
    with pytest.raises(ExplainError) as err:
        LoopSettings(**{field: value})
    assert "\n" not in str(err.value) and "allowed range" in str(err.value)


def test_a_small_gain_that_unrelated_effects_match_is_a_stand_in_and_not_added():
    # healthy chirp_1mm record (measured): a delay, a motor gain change and viscous friction
    # each take ~21 % off the RMSE; the first two stay within their healthy band
    delay = cand("delay", 0.215)
    delay.score = -math.inf
    motor = cand("motor_gain", 0.208)
    motor.score = -math.inf
    viscous = cand("viscous_friction", 0.208)
    choice = choose([delay, motor, viscous], SETTINGS, no_split, never_refit)
    assert choice.best is None
    assert "no specific effect" in choice.stop and "delay" in choice.stop


def test_an_unspecific_round_names_what_it_set_aside_and_a_pair_that_stands_out_wins():
    # bias found on a chirp with hysteresis and a hinge moment left (HF bench record
    # bias+hinge+hysteresis, measured): hysteresis and clogging each gain ~35 %, unspecific;
    # the look-ahead's pair hysteresis + hinge moment gains 88 %: specific, chosen
    hysteresis, clogging = cand("hysteresis", 0.352), cand("clogging", 0.32)
    choice = choose([hysteresis, clogging], SETTINGS, no_split, never_refit)
    assert choice.best is None and "no specific effect" in choice.stop
    assert choice.unspecific == ["hysteresis", "clogging"]
    pair = cand("hysteresis+hinge_moment", 0.877, params=2)
    again = choose([hysteresis, clogging, pair], SETTINGS, no_split, never_refit)
    assert again.best is pair and again.members == ["hysteresis", "hinge_moment"]
    # a round that stops for want of significance sets nothing aside as unspecific
    lone = choose([cand("delay", 0.40, p_value=0.2, n_eff=5)], SETTINGS, no_split,
                  never_refit)
    assert lone.best is None and lone.unspecific == []
    # ... but names it as set aside for chance, which the loop's look-ahead extends on an
    # unexplained record (supply + load on `mixed`: 12-13 % each, p 0.02 on 21 samples)
    assert lone.insignificant == ["delay"]
    load, supply = (cand("external_load", 0.132, p_value=0.02, n_eff=21),
                    cand("supply_pressure", 0.118, p_value=0.03, n_eff=21, params=2))
    both = choose([load, supply], SETTINGS, no_split, never_refit)
    # (the supply's penalised score is below min_gain: only the load is set aside for chance)
    assert both.best is None and both.insignificant == ["external_load"]
    pair = cand("external_load+supply_pressure", 0.93, params=3, n_eff=21)
    again = choose([load, supply, pair], SETTINGS, no_split, never_refit)
    assert again.best is pair


def test_a_large_gain_is_specific_even_with_an_equivalent_rival():
    # on a smooth command a load and a motor offset are equivalent: both are reported
    load, offset = cand("external_load", 0.95), cand("offset", 0.94)
    choice = choose([load, offset], SETTINGS, no_split, never_refit)
    assert choice.best is load and "offset" in choice.alternatives


def test_rivals_share_no_effect_and_structure_is_always_specific():
    pair = cand("orifice_law+flapper_dynamics", 0.2, params=2)
    assert unspecific(pair, [cand("delay", 0.3)]) == []
    with_load = cand("orifice_law+flapper_dynamics+external_load", 0.3, params=3)
    assert unspecific(with_load, [cand("external_load", 0.3), pair]) == []
    assert unspecific(with_load, [cand("orifice_law+flapper_dynamics+delay", 0.28)]) == [
        "orifice_law+flapper_dynamics+delay"]
    assert unspecific(with_load, [cand("delay", 0.2)]) == []     # 0.1 below: not a rival


# -- the model's known structure first ------------------------------------------------------

def test_the_structure_comes_before_an_effect_that_gains_more():
    # healthy `test` record (explain_fp seed 2203): a leak gained 0.74, the structural
    # pair 0.69; the leak was a stand-in for the flapper dynamics
    tried = [cand("leakage", 0.74), cand("orifice_law+flapper_dynamics", 0.69, params=2),
             cand("motor_gain", 0.47)]
    choice = choose(tried, SETTINGS, no_split, never_refit)
    assert choice.best.effect == "orifice_law+flapper_dynamics"


def test_a_structure_below_min_gain_does_not_take_precedence():
    tried = [cand("external_load", 0.90), cand("orifice_law+flapper_dynamics", 0.10, params=2)]
    assert choose(tried, SETTINGS, no_split, never_refit).best.effect == "external_load"


def test_an_insignificant_structure_does_not_take_precedence():
    tried = [cand("offset", 0.74),
             cand("orifice_law+flapper_dynamics", 0.72, params=2, p_value=0.2)]
    assert choose(tried, SETTINGS, no_split, never_refit).best.effect == "offset"


# -- an effect chosen with the structure: does it pay for itself? ----------------------------

def test_an_effect_the_structure_explains_alone_is_dropped():
    # left out and the structure refitted, the RMSE rises 1 %
    keep, loss, p = keeps_effect(10e-6, 10.1e-6, 1, 300.0, LoopSettings())
    assert not keep and loss == pytest.approx(1 - 10 / 10.1)


def test_an_effect_that_carries_the_fit_is_kept():
    keep, loss, p = keeps_effect(10e-6, 30e-6, 1, 300.0, LoopSettings())
    assert keep and p < 1e-6 and loss == pytest.approx(2 / 3)


def test_an_effect_is_kept_on_half_the_gain_that_admits_one_but_not_on_less():
    # min_gain 0.1, penalty 0.02 per parameter: kept from a loss of 0.07 with one parameter
    s = LoopSettings()
    assert keeps_effect(9.2e-6, 10e-6, 1, 1e4, s)[0]          # loss 0.08
    assert not keeps_effect(9.4e-6, 10e-6, 1, 1e4, s)[0]      # loss 0.06
    assert not keeps_effect(9.2e-6, 10e-6, 2, 1e4, s)[0]      # 0.08 - 2 x 0.02 < 0.05


def test_a_large_loss_on_few_effective_samples_is_not_significant():
    keep, loss, p = keeps_effect(10e-6, 13e-6, 2, 6.0, LoopSettings())
    assert loss > 0.2 and p >= 0.01 and not keep


def test_an_unstable_run_without_the_effect_keeps_it():
    assert keeps_effect(10e-6, math.inf, 1, 300.0, LoopSettings())[0]


def test_the_loop_refits_with_a_global_method():
    with pytest.raises(ExplainError, match="`method` lm"):
        LoopSettings(method="lm")
    with pytest.raises(ExplainError, match="`method` ps"):
        LoopSettings(method="ps")


def test_a_steps_alternatives_leave_out_its_own_effect():
    """``--json`` steps list the round's candidates that scored within 0.05 of the chosen one;
    a step the final check swapped in keeps its round's list, minus entries with its own
    effect."""
    from eha.explain.results import ExplainResult, Step

    step = Step("delay", {"sensor_delay": 1e-3}, 1.0, 0.5, 1.0, 0.5, 1.0, 0.5, {}, {}, 0.5,
                0.48, alternatives={"motor_gain": 0.47, "delay": 0.46,
                                    "orifice_law+flapper_dynamics+delay": 0.44})
    assert ExplainResult.alternatives_of(step) == {"motor_gain": 0.47}


def test_a_gain_bought_on_p12_with_a_worse_position_trades_the_position():
    """The canned evaluations of the healthy HF `sine` of seed 6003 (bench block 6): with the
    leak the position goes from 2.3 to 4.4 µm while the weighted P12 falls from 8 to 1 µm, so
    the score improves; the loop must not take that gain (POSITION_WORSENING = 1.2)."""
    from eha.explain.decide import trades_position
    from eha.explain.results import Evaluation
    from eha.explain.settings import POSITION_WORSENING
    from eha.models.params import LFParams

    def ev(fit, hold, p12):
        return Evaluation(LFParams(), None, fit * 1e-6, hold * 1e-6, fit * 1e-6,
                          p12_fit=p12 * 1e-6, p12_hold=p12 * 1e-6)

    current, leak = ev(2.31, 2.14, 8.0), ev(4.40, 3.55, 1.0)
    assert leak.rmse_score < current.rmse_score           # a gain on the score ...
    assert trades_position(current, leak)                 # ... bought with the position
    assert not trades_position(current, ev(2.0, 2.0, 1.0))
    # the factor: 1.15x worse is within it, 1.25x is not
    assert not trades_position(current, ev(2.31 * 1.15, 2.14 * 1.15, 1.0))
    assert trades_position(current, ev(2.31 * 1.25, 2.14 * 1.25, 1.0))
    assert POSITION_WORSENING == 1.2


# -- the decision rule's numbers at its thresholds --------------------------------------------

def test_significance_is_the_f_tests_upper_tail_on_effective_samples():
    """A hand case: 2 parameters lower the RMSE from 2 to 1 on 12 effective samples, so
    F = ((4 - 1) / 2) / (1 / 10) = 15 on (2, 10) degrees of freedom."""
    from scipy.stats import f

    assert significance(2.0, 1.0, 2, 12.0) == pytest.approx(f.sf(15.0, 2, 10), rel=1e-12)
    assert significance(2.0, 1.0, 2, 12.0) == pytest.approx(0.00098, abs=1e-5)
    # a pure switch (0 parameters) is tested as one parameter
    assert significance(2.0, 1.0, 0, 12.0) == significance(2.0, 1.0, 1, 12.0) \
        == pytest.approx(f.sf(33.0, 1, 11), rel=1e-12)
    # more parameters for the same reduction: less significant
    assert significance(2.0, 1.0, 3, 12.0) > significance(2.0, 1.0, 2, 12.0)


def test_significance_at_its_edges():
    assert significance(2.0, 0.0, 1, 50.0) == 0.0          # a perfect fit of a residual
    assert significance(0.0, 0.0, 1, 50.0) == 1.0
    assert significance(2.0, 1.0, 1, 2.0) == 1.0           # one degree of freedom left: blind
    assert significance(math.nan, 1.0, 1, 50.0) == 1.0
    assert significance(2.0, math.inf, 1, 50.0) == 1.0
    assert significance(2.0, 2.0, 1, 50.0) == 1.0          # no reduction


def test_choose_admits_a_score_at_min_gain_and_refuses_one_below():
    s = LoopSettings(min_gain=0.25, penalty=0.0, significance=0.01)

    def scored(effect, score):
        c = cand(effect, score)
        c.score = score
        return c

    assert choose([scored("offset", 0.25)], s, no_split, never_refit).best.effect == "offset"
    below = choose([scored("offset", 0.2499)], s, no_split, never_refit)
    assert below.best is None and "offset" in below.stop and "25%" in below.stop


def test_choose_needs_a_p_value_strictly_below_the_significance_level():
    s = LoopSettings(significance=0.05)
    assert choose([cand("offset", 0.6, p_value=0.0499)], s, no_split,
                  never_refit).best is not None
    at = choose([cand("offset", 0.6, p_value=0.05)], s, no_split, never_refit)
    assert at.best is None and "not significant" in at.stop and "offset" in at.superseded


def test_a_rival_within_its_healthy_band_sets_a_small_gain_aside_only_within_the_healthy_residual():
    # offset 0.015 mA on `mixed` (explain_loop_power, seed 100000, measured): with the
    # structure in, the offset takes 44.9 % off (p 5e-32, past its gate), a sensor bias of
    # 1.6 µm 43.9 %, within its healthy band. Within what healthy actuators leave, that rival
    # says a healthy-size change does as well; beyond it (the record at 1.88x noise, the
    # healthy limit 1.6x) it does not, and only admissible rivals count
    def round_():
        bias = cand("sensor_bias", 0.439)
        bias.score = -math.inf
        return [cand("offset", 0.449), bias, cand("external_load", 0.302)]

    within = choose(round_(), SETTINGS, no_split, never_refit)
    assert within.best is None and within.unspecific[0] == "offset"
    beyond = choose(round_(), SETTINGS, no_split, never_refit, beyond_healthy=True)
    assert beyond.best.effect == "offset"
    # an admissible rival still sets it aside beyond the healthy residual
    load = round_()
    load[2] = cand("external_load", 0.44)
    assert choose(load, SETTINGS, no_split, never_refit, beyond_healthy=True).best is None


def test_a_refused_candidate_is_never_chosen_nor_an_alternative():
    """A refit refused (score -inf: its effect stayed within its healthy band, or it traded
    the position for P12) is out of the choice however large its gain; a candidate that was
    not refitted is ignored too."""
    refused = cand("leakage", 0.95)
    refused.score = -math.inf
    unfitted = cand("delay", 0.9)
    unfitted.refit = False
    choice = choose([refused, unfitted, cand("offset", 0.93)], SETTINGS, no_split,
                    never_refit)
    assert choice.best.effect == "offset"
    assert choice.alternatives == {}
    alone = choose([refused, unfitted], SETTINGS, no_split, never_refit)
    assert alone.best is None and alone.stop.startswith("no candidate improved the model")


def test_a_qualifying_structure_is_chosen_before_a_combination_that_extends_it():
    """A candidate made only of the known structure that clears min_gain and is significant
    comes first, even against the structure plus an effect that scores higher; among several
    qualifying structural candidates the best-scoring."""
    extended = cand("orifice_law+flapper_dynamics+leakage", 0.95, params=3)
    pair = cand("orifice_law+flapper_dynamics", 0.60, params=2)
    law = cand("orifice_law", 0.40, params=0)
    choice = choose([extended, law, pair], SETTINGS, no_split, never_refit)
    assert choice.best is pair
    assert choice.members == ["orifice_law", "flapper_dynamics"]


def test_alternatives_are_the_qualifying_candidates_within_the_margin():
    close = cand("offset", 0.47)                      # 0.03 below: an alternative
    far = cand("sensor_bias", 0.40)                   # 0.10 below: not
    chance = cand("delay", 0.49, p_value=0.5)         # within, but not significant
    choice = choose([cand("external_load", 0.50), close, far, chance], SETTINGS, no_split,
                    never_refit)
    assert choice.best.effect == "external_load"
    assert choice.alternatives == {"offset": close.score}


def test_keeps_effect_charges_the_penalty_per_parameter_a_switch_as_one():
    """Kept when ``loss - penalty * n >= CONFIRM_FRACTION * min_gain`` and the loss is
    significant; the p-value returned is the F test of the model without the effect against
    the model with it."""
    from eha.explain.settings import CONFIRM_FRACTION

    s = LoopSettings(min_gain=0.2, penalty=0.05)
    assert CONFIRM_FRACTION * s.min_gain == pytest.approx(0.1)
    # loss 0.17: one parameter (0.12 left) kept, two (0.07) not
    keep1, loss, p = keeps_effect(8.3, 10.0, 1, 1e4, s)
    assert keep1 and loss == pytest.approx(0.17) and p == significance(10.0, 8.3, 1, 1e4)
    assert keeps_effect(8.3, 10.0, 0, 1e4, s)[0]
    assert not keeps_effect(8.3, 10.0, 2, 1e4, s)[0]
    # loss 0.13: free it would be kept, charged one parameter (0.08 left) it is not; a pure
    # switch is charged as one
    assert not keeps_effect(8.7, 10.0, 1, 1e4, s)[0]
    assert not keeps_effect(8.7, 10.0, 0, 1e4, s)[0]
    # the same loss on 10 effective samples is not significant
    keep, _, p = keeps_effect(8.3, 10.0, 1, 10.0, s)
    assert not keep and p >= s.significance
    # nothing lost without it: never kept (the loss is negative when the refit without it
    # found a better fit)
    keep, loss, _ = keeps_effect(10.0, 9.0, 1, 1e4, s)
    assert not keep and loss < 0


def test_unspecific_below_the_specific_gain_lists_unrelated_rivals_within_the_margin():
    from eha.explain.settings import RIVAL_MARGIN, SPECIFIC_GAIN

    assert (SPECIFIC_GAIN, RIVAL_MARGIN) == (0.5, 0.05)
    best = cand("viscous_friction", 0.30)
    refused = cand("delay", 0.27)
    refused.score = -math.inf          # a refused refit still shows what a healthy size does
    rivals = [refused, cand("motor_gain", 0.24),                    # 0.06 below: no rival
              cand("viscous_friction+leakage", 0.40),               # shares the effect
              cand("orifice_law", 0.35, params=0),                  # the structure: no rival
              cand("offset", math.nan)]                             # no gain: no rival
    assert unspecific(best, rivals) == ["delay"]
    # a rival made of structure and an unrelated effect is one
    assert unspecific(best, [cand("orifice_law+flapper_dynamics+offset", 0.26)]) == [
        "orifice_law+flapper_dynamics+offset"]
    # at the specific gain, a best is specific whatever matches it
    assert unspecific(cand("viscous_friction", 0.5), [cand("delay", 0.6)]) == []
    assert unspecific(cand("viscous_friction", 0.49), [cand("delay", 0.6)]) == ["delay"]


def test_trades_position_compares_the_position_only_by_the_given_factor():
    from eha.explain.decide import trades_position
    from eha.explain.results import Evaluation
    from eha.models.params import LFParams

    def ev(fit, hold, p12=0.0):
        return Evaluation(LFParams(), None, fit, hold, fit, p12_fit=p12, p12_hold=p12)

    current = ev(3.0, 4.0)                                   # hypot 5
    assert not trades_position(current, ev(3.0, 4.0), factor=1.0)    # equal: not worse
    assert trades_position(current, ev(3.0, 4.1), factor=1.0)
    assert not trades_position(current, ev(4.8, 3.6), factor=1.2)    # hypot 6.0: at the factor
    assert trades_position(current, ev(4.8, 3.7), factor=1.2)
    # the P12 of either side plays no part
    assert not trades_position(ev(3.0, 4.0, p12=0.0), ev(3.0, 4.0, p12=100.0), factor=1.0)


def test_edge_of_spread_is_two_percent_of_the_width_from_a_bound():
    from eha.explain.decide import edge_of_spread

    assert edge_of_spread(0.200, (0.18, 0.22)) is None
    assert edge_of_spread(0.1812, (0.18, 0.22)) is None              # 3 % of 0.04 inside
    assert edge_of_spread(0.1805, (0.18, 0.22)) == \
        "GQ 0.1805 at the lower bound of its healthy spread 0.18-0.22"
    assert "upper bound" in edge_of_spread(0.2196, (0.18, 0.22))
    assert "lower bound" in edge_of_spread(0.17, (0.18, 0.22))        # outside it too


def test_split_combination_keeps_the_members_that_pay_in_the_order_they_help():
    """A combination's fit with canned RMSE per member switched on: the orifice law takes 4,
    the supply pressure 3, a leak 2 and a delay 0.01 off 10 (µm). The delay does not pay its
    penalty (0.02 of the RMSE) and is dropped; the law (a switch) comes first, then the
    member that lowers the RMSE most."""
    from eha.explain.effects import EFFECTS
    from eha.explain.decide import split_combination
    from eha.explain.results import Evaluation
    from eha.models.params import LFParams

    def evaluations(gains):
        def run(params_list):
            out = []
            for p in params_list:
                r = 10.0 - sum(g for name, g in gains.items() if EFFECTS[name].is_on(p))
                out.append(Evaluation(p, None, r, r, r))
            return out
        return run

    members = [EFFECTS[n] for n in ("delay", "leakage", "supply_pressure", "orifice_law")]
    params = LFParams().replace(orifice_law=1.0, PSR=1.8e7, Clk=5e-12, sensor_delay=2e-3)
    gains = {"orifice_law": 4.0, "supply_pressure": 3.0, "leakage": 2.0, "delay": 0.01}
    run = evaluations(gains)
    combined = run([params])[0]
    kept = split_combination(members, combined, run, penalty=0.02)
    assert [e.name for e in kept] == ["orifice_law", "supply_pressure", "leakage"]
    # a law that does not pay on its own stays with the supply pressure that requires it
    gains = {"orifice_law": 0.001, "supply_pressure": 3.0, "leakage": 2.0, "delay": 0.01}
    run = evaluations(gains)
    kept = split_combination(members, run([params])[0], run, penalty=0.02)
    assert [e.name for e in kept] == ["orifice_law", "supply_pressure", "leakage"]
    # none pays: the most useful one is kept
    gains = {"orifice_law": 0.0, "supply_pressure": 0.0, "leakage": 0.1, "delay": 0.01}
    run = evaluations(gains)
    kept = split_combination(members, run([params])[0], run, penalty=0.02)
    assert [e.name for e in kept] == ["leakage"]


def test_any_statistic_past_its_own_bar_is_enough():
    """The union bound's rule (the supply pressure's footprint or its PSR shift): one statistic
    past its own bar passes; a statistic without a bar, or not computed, never does; one that
    is not a number (a diverged fit) does."""
    bars = {"supply_pressure": 5e-6, "supply_pressure.PSR": 4e6}
    assert not past_any({"supply_pressure": 4e-6, "supply_pressure.PSR": 3e6}, bars)
    assert past_any({"supply_pressure": 6e-6, "supply_pressure.PSR": 3e6}, bars)
    assert past_any({"supply_pressure": 4e-6, "supply_pressure.PSR": 5e6}, bars)
    assert not past_any({"supply_pressure": 4e-6, "supply_pressure.PSR": None}, bars)
    assert not past_any({"leakage": 1.0}, bars)
    assert past_any({"supply_pressure": math.nan}, bars)


def test_the_relative_gain_is_one_formula_and_zero_from_a_perfect_fit():
    """The gain of a candidate, of a pinned structure, of a step and of a healthy record's
    effect is one function (it was written out four times): the relative reduction of the
    scored RMSE, 0 from a model that already scores 0."""
    from eha.explain.decide import relative_gain
    from eha.explain.results import Evaluation
    from eha.models.params import LFParams

    def scored(r):
        return Evaluation(LFParams(), None, r, r, r)

    assert relative_gain(scored(2e-6), scored(0.5e-6)) == pytest.approx(0.75)
    assert relative_gain(scored(1e-6), scored(2e-6)) == pytest.approx(-1.0)     # worse
    assert relative_gain(scored(0.0), scored(1e-6)) == 0.0
