"""The residual loop's three verdicts (:attr:`eha.explain.results.ExplainResult.verdict`), on
results built by hand: no simulation.

A residual at the noise level is "explained"; above it but within what healthy actuators leave
on the command it is "not explained to the noise" (``unexplained`` True, ``beyond_healthy``
False: the added effects are tentative, the intervals are not widened); beyond the healthy
band the leads speak.
"""

import math

import numpy as np
import pytest

from eha.explain.leads import LeadReport
from eha.explain.results import Evaluation, ExplainResult, Step
from eha.models.params import LFParams

NOISE = 1e-6


def result(rmse_after: float, unexplained: bool, beyond: bool, steps=()) -> ExplainResult:
    p = LFParams()
    ev = lambda r: Evaluation(p, np.zeros(3), r, r, r)  # noqa: E731
    leads = LeadReport(rmse_after, NOISE, rmse_after / NOISE, (), 0.0, {})
    return ExplainResult(
        source="x.csv", fit_bounds={}, faults_before={}, faults_after={},
        before=ev(10 * rmse_after), after=ev(rmse_after), steps=list(steps), rounds=[],
        noise_rmse=NOISE, stop_reason="", holdout="", t=np.zeros(3), measured=np.zeros(3),
        settings={}, seconds=0.0, unexplained=unexplained, beyond_healthy=beyond,
        leads=leads, null={"residual_limit": 3.0, "effects": {}})


def step(name: str) -> Step:
    return Step(name, {}, 1.0, 0.5, 1.0, 0.5, 1.0, 0.5, {}, {}, 0.5, 0.5)


def test_at_the_noise_level_the_record_is_explained():
    r = result(1.1e-6, unexplained=False, beyond=False)
    assert r.verdict == "explained: residual 1.1 µm (1.1× noise)"
    doc = r.to_json()
    assert doc["unexplained"] is False and doc["beyond_healthy"] is False


def test_above_the_noise_within_the_healthy_band_is_not_explained_to_the_noise():
    r = result(1.6e-6, unexplained=True, beyond=False, steps=[step("leakage")])
    text = r.verdict
    assert text.startswith("not explained to the noise: residual 1.6 µm (1.6× noise)")
    assert "up to 3×" in text and "tentative" in text
    doc = r.to_json()
    assert doc["unexplained"] is True and doc["beyond_healthy"] is False
    assert all(s["tentative"] for s in doc["steps"])


def test_beyond_the_healthy_band_the_leads_speak():
    r = result(8.0e-6, unexplained=True, beyond=True)
    assert r.verdict.startswith("unexplained residual 8 µm (8× noise)")
    assert "healthy actuators leave up to 3× noise" in r.verdict
    assert r.to_json()["beyond_healthy"] is True
    assert r.run_row("id", "x.csv", None)["beyond_healthy"] is True


@pytest.mark.parametrize("ratio", [0.9, 1.25])
def test_the_verdict_states_the_ratio_it_rests_on(ratio):
    r = result(ratio * NOISE, unexplained=False, beyond=False)
    assert f"({ratio:.1f}× noise)" in r.verdict
    assert math.isclose(r.rmse_after / r.noise_rmse, ratio)


def test_an_effect_the_record_cannot_rule_out_makes_it_not_uniquely_explained():
    """At the noise level, an effect outside the model that fits as well beyond the size the
    command shows (``not_excluded``) turns "explained" into "not uniquely explained", names
    the effect, its value and the detectable size, and is in the JSON."""
    rival = {"effect": "viscous_friction", "param": "CJ", "value": 9300.0, "shift": 9250.0,
             "threshold": 1860.0, "detectable": 2540.0, "unit": "N*s/m"}
    r = result(1.03e-6, unexplained=True, beyond=False, steps=[step("motor_gain")])
    r.not_excluded = [rival]
    text = r.verdict
    assert text.startswith("not uniquely explained: residual 1.03 µm (1.0× noise) with "
                           "motor_gain, but viscous_friction (CJ 9.3e+03 N*s/m, a change "
                           "beyond the 2.54e+03 this command shows) also fits as well")
    assert not text.startswith("explained")
    doc = r.to_json()
    assert doc["not_excluded"] == [rival] and doc["unexplained"] is True
    r.not_excluded = []
    r.unexplained = False
    assert r.verdict.startswith("explained") and r.to_json()["not_excluded"] == []
