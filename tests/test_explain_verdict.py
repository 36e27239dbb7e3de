"""The residual loop's verdict (:mod:`eha.explain.verdict`), on results built by hand: no
simulation.

Four kinds from four facts (docs/explain.md, "The verdict"): "explained" (at the noise or
the found model's own level, unique), "explained, ambiguous" (at the noise, a rival the record cannot rule out), "partly
explained" (above the noise, within what healthy actuators leave on the command: ``unexplained``
True, ``beyond_healthy`` False, the added effects tentative, the intervals not widened) and
"unexplained" (beyond the healthy band: the leads speak). Every verdict opens with what was
found, in display units with its interval; the JSON, the database row and the HTML report's tag
come from the same facts.
"""

import math

import numpy as np
import pytest

from eha.explain.leads import LeadReport
from eha.explain.results import Evaluation, ExplainResult, Step
from eha.models.params import LFParams

NOISE = 1e-6


def result(rmse_after: float, unexplained: bool, beyond: bool, steps=(), params=None,
           intervals=None) -> ExplainResult:
    p = LFParams() if params is None else params
    ev = lambda r: Evaluation(p, np.zeros(3), r, r, r)  # noqa: E731
    leads = LeadReport(rmse_after, NOISE, rmse_after / NOISE, (), 0.0, {})
    return ExplainResult(
        source="x.csv", fit_bounds={}, faults_before={}, faults_after={},
        before=ev(10 * rmse_after), after=ev(rmse_after), steps=list(steps), rounds=[],
        noise_rmse=NOISE, stop_reason="", holdout="", t=np.zeros(3), measured=np.zeros(3),
        settings={}, seconds=0.0, unexplained=unexplained, beyond_healthy=beyond,
        leads=leads, null={"residual_limit": 3.0, "effects": {}}, intervals=intervals or {},
        level=0.9 if intervals else None)


def step(name: str, params=None) -> Step:
    return Step(name, dict(params or {}), 1.0, 0.5, 1.0, 0.5, 1.0, 0.5, {}, {}, 0.5, 0.5)


def test_at_the_noise_level_the_record_is_explained():
    r = result(1.1e-6, unexplained=False, beyond=False)
    assert r.verdict == ("explained: found nothing beyond the healthy band; residual 1.1 µm "
                         "(1.1× noise), at the noise (1 µm)")
    doc = r.to_json()
    assert doc["unexplained"] is False and doc["beyond_healthy"] is False
    assert doc["verdict_kind"] == "explained"
    assert (doc["at_noise"], doc["within_healthy_band"], doc["unique_explanation"]) == \
        (True, True, True)


def test_above_the_noise_within_the_healthy_band_is_partly_explained():
    r = result(1.6e-6, unexplained=True, beyond=False, steps=[step("leakage", {"Clk": 0.0})])
    text = r.verdict
    assert text.startswith("partly explained: found internal leakage 0 m³/(Pa·s) (tentative); "
                           "residual 1.6 µm (1.6× noise), above the noise (1 µm)"), text
    assert "up to 3×" in text
    doc = r.to_json()
    assert doc["unexplained"] is True and doc["beyond_healthy"] is False
    assert doc["verdict_kind"] == "partly explained" and doc["at_noise"] is False
    assert all(s["tentative"] for s in doc["steps"])


@pytest.mark.parametrize("within", [True, False])
def test_above_the_noise_the_found_models_own_level_says_what_the_rest_is(within):
    """With what the found model leaves on HF re-simulations of itself (``model_level``), a
    record above the noise says whether the rest is within that (the LF's own model form) or
    more; a level without ``explains`` (a result from before it) leaves the kind "partly
    explained", and the figures go to the JSON."""
    from dataclasses import replace

    own = {"record": 1.35, "ratios": [1.2, 1.3, 1.25], "mean": 1.25, "std": 0.05,
           "bound": 1.4 if within else 1.3, "within": within, "seeds": [770000, 770002]}
    r = replace(result(1.35e-6, unexplained=True, beyond=False), model_level=own)
    assert r.verdict.startswith("partly explained: found nothing beyond the healthy band; "
                                "residual 1.35 µm (1.4× noise), above the noise (1 µm)")
    assert ("the found model, simulated again on the HF, leaves 1.25 ± 0.05× "
            f"(3 re-simulations, up to {own['bound']:.2f}×)") in r.verdict
    assert r.verdict.endswith("the rest is within the model's own model form" if within
                              else "more than that: an effect that small may be missing")
    doc = r.to_json()
    assert doc["verdict_kind"] == "partly explained" and doc["model_level"] == own
    # re-simulations that scatter up to the healthy band's limit (3x here) decide nothing
    wide = replace(r, model_level={**own, "std": 1.8, "bound": 6.4})
    assert wide.verdict.endswith("no sharper than the healthy band: it does not say whether "
                                 "an effect is missing")


def test_within_the_found_models_own_level_the_record_is_explained():
    """A record above the noise whose rest is no more than the found model itself leaves on HF
    re-simulations (``model_level`` with ``explains``: within their bound, the bound below
    the healthy band's limit) and that the exclusion check leaves unique is "explained" at
    that level; a rival makes it "explained, ambiguous"; beyond the healthy band nothing
    changes."""
    from dataclasses import replace

    from eha.reports.html.sections import _explain_state

    own = {"record": 1.26, "ratios": [1.38, 1.79, 1.42], "mean": 1.48, "std": 0.16,
           "bound": 1.83, "within": True, "explains": True, "seeds": [770000, 770002]}
    r = replace(result(1.26e-6, unexplained=False, beyond=False), model_level=own)
    assert r.verdict == ("explained: found nothing beyond the healthy band; residual 1.26 µm "
                         "(1.3× noise), at the found model's own level (the found model, "
                         "simulated again on the HF, leaves 1.48 ± 0.16× (3 re-simulations, up "
                         "to 1.83×); the noise 1 µm)")
    doc = r.to_json()
    assert doc["verdict_kind"] == "explained" and doc["unexplained"] is False
    assert (doc["at_noise"], doc["at_model_level"]) == (False, True)
    row = r.run_row("id", "x.csv", None)
    assert row["at_model_level"] is True and row["verdict_kind"] == "explained"
    assert _explain_state(row) == "explained"
    # an effect found at that level is not tentative
    found = replace(r, steps=[step("external_load", {"FRC": 813.0})])
    assert found.verdict.startswith("explained: found external load 0 N; residual")
    rival = {"effect": "offset", "param": "Ofs", "value": -0.00905, "shift": 0.00905,
             "threshold": 0.005, "detectable": 0.00734, "unit": "mA"}
    ambiguous = replace(r, unexplained=True, not_excluded=[rival])
    assert ambiguous.to_json()["verdict_kind"] == "explained, ambiguous"
    assert "cannot be told apart on this command from a motor offset" in ambiguous.verdict
    leak = {"effect": "leakage", "param": "Clk", "value": 1.75e-12, "shift": 1.75e-12,
            "threshold": 1.6e-13, "detectable": 2.25e-13, "unit": "m³/(Pa·s)"}
    assert "from an internal leakage of" in replace(r, unexplained=True,
                                                    not_excluded=[leak]).verdict
    beyond = replace(r, unexplained=True, beyond_healthy=True)
    assert beyond.to_json()["verdict_kind"] == "unexplained"
    assert beyond.to_json()["at_model_level"] is False
    # a level that does not explain (or a result from before `explains`) stays partly
    for level in ({**own, "explains": False}, {k: v for k, v in own.items() if k != "explains"}):
        partly = replace(r, unexplained=True, model_level=level)
        assert partly.to_json()["verdict_kind"] == "partly explained", level
        assert _explain_state(partly.run_row("id", "x.csv", None)) == "above noise"


def test_the_found_models_level_explains_only_below_the_healthy_bands_limit():
    """:func:`eha.explain.replicates.explains`: the record within the prediction bound and the
    bound below the ratio healthy actuators reach; a bound at or beyond that limit decides
    nothing, and no level (fewer than two refits) explains nothing."""
    from eha.explain.replicates import explains

    own = {"record": 1.3, "bound": 1.5, "within": True}
    assert explains(own, 3.0)
    assert not explains(own, 1.5) and not explains(own, 1.4)
    assert not explains({**own, "record": 1.6, "within": False}, 3.0)
    assert not explains({}, 3.0)


def test_a_model_pinned_at_a_bound_of_its_range_is_not_tested_by_its_own_level():
    """An added effect's estimate at a bound of its range other than its off value (f10 of the
    foreign set: a motor offset at 1.998 of ±2 mA beside a sensor gain and the bias) is not
    tested by re-simulations refitted within the same range (the bootstrap at a boundary):
    the level does not explain, the kind stays "partly explained" and the clause says why.
    The off side of a range is not such a bound (a delay of 20 µs, off at 0)."""
    from dataclasses import replace

    from eha.explain.replicates import at_a_bound, explains

    pinned = LFParams().replace(Ofs=1.99835, sensor_gain=0.979, sensor_bias=-8.6e-5)
    assert at_a_bound(pinned, ["offset", "sensor_gain", "sensor_bias"]) == ["Ofs"]
    assert at_a_bound(LFParams().replace(sensor_delay=2e-5, CJ=10.0),
                      ["delay", "viscous_friction"]) == []
    assert at_a_bound(LFParams().replace(Ofs=-1.97), ["offset"]) == ["Ofs"]
    own = {"record": 1.81, "ratios": [1.5, 2.4, 1.9], "mean": 1.95, "std": 0.42,
           "bound": 2.85, "within": True, "seeds": [770000, 770002], "at_bound": ["Ofs"]}
    assert not explains(own, 3.0)
    assert explains({k: v for k, v in own.items() if k != "at_bound"}, 3.0)
    r = replace(result(1.81e-6, unexplained=True, beyond=False),
                model_level={**own, "explains": False})
    assert r.to_json()["verdict_kind"] == "partly explained"
    assert r.verdict.endswith("within it, but Ofs at the bound of its range: the "
                              "re-simulations do not test a model pinned there"), r.verdict


def test_the_record_refitted_from_more_starts_is_what_the_level_compares():
    """When the record refitted from the re-simulations' spread of starts reaches lower than
    the loop's own fit (a nearby minimum of the same model), the clause says so and compares
    that level with the bound."""
    from dataclasses import replace

    own = {"record": 1.68, "record_loop": 1.87, "restarts": [1.75, 1.68],
           "ratios": [1.65, 1.45, 1.62], "mean": 1.57, "std": 0.11, "bound": 1.84,
           "within": True, "seeds": [770000, 770002]}
    r = replace(result(1.87e-6, unexplained=True, beyond=False), model_level=own)
    assert ("the found model, refitted from 2 more starts, leaves 1.68× here and, simulated "
            "again on the HF, 1.57 ± 0.11× (3 re-simulations, up to 1.84×): the rest is "
            "within the model's own model form") in r.verdict
    # restarts that reach no lower leave the clause as it was
    same = replace(r, model_level={**own, "record": 1.87, "within": False})
    assert "more starts" not in same.verdict and same.verdict.endswith("may be missing")


def test_beyond_the_healthy_band_the_leads_speak():
    r = result(8.0e-6, unexplained=True, beyond=True)
    assert r.verdict.startswith("unexplained residual 8 µm (8× noise)")
    assert "healthy actuators leave up to 3× noise" in r.verdict
    assert r.to_json()["beyond_healthy"] is True
    row = r.run_row("id", "x.csv", None)
    assert row["beyond_healthy"] is True and row["verdict_kind"] == "unexplained"
    assert row["within_healthy_band"] is False


@pytest.mark.parametrize("ratio", [0.9, 1.25])
def test_the_verdict_states_the_ratio_it_rests_on(ratio):
    r = result(ratio * NOISE, unexplained=False, beyond=False)
    assert f"({ratio:.1f}× noise)" in r.verdict
    assert math.isclose(r.rmse_after / r.noise_rmse, ratio)


def test_a_finding_opens_the_verdict_with_its_value_unit_and_interval():
    """f01 of the foreign set (an undeclared 800 N load, an offset the record cannot rule
    out): the verdict says what was found, then the rival with its value and unit. Before
    issue 42 it opened with "not uniquely explained" and named FRC nowhere."""
    rival = {"effect": "offset", "param": "Ofs", "value": -0.00905, "shift": 0.00905,
             "threshold": 0.005, "detectable": 0.00734, "unit": "mA"}
    r = result(1.03e-6, unexplained=True, beyond=False, params=LFParams().replace(FRC=829.4),
               steps=[step("orifice_law"), step("external_load", {"FRC": 800.0})],
               intervals={"FRC": (818.2, 839.4)})
    r.not_excluded = [rival]
    assert r.verdict == (
        "explained, ambiguous: found external load 829 N [818, 839] (90 %); residual 1.03 µm "
        "(1.0× noise), at the noise (1 µm); cannot be told apart on this command from a "
        "motor offset of -0.00905 mA (beyond the 0.00734 mA change this command shows)")
    doc = r.to_json()
    assert doc["not_excluded"] == [rival] and doc["unexplained"] is True
    assert doc["verdict_kind"] == "explained, ambiguous" and doc["at_noise"] is True
    assert doc["unique_explanation"] is False
    assert doc["units"]["FRC"] == "N" and doc["units"]["rmse"] == "m"
    (found,) = doc["found"]
    assert found["effect"] == "external_load" and found["text"] == "829 N"
    assert found["interval"] == [818.2, 839.4]
    row = r.run_row("id", "x.csv", None)
    assert (row["verdict"], row["verdict_kind"], row["at_noise"], row["unique_explanation"]) \
        == (doc["verdict"], doc["verdict_kind"], True, False)
    r.not_excluded = []
    r.unexplained = False
    assert r.verdict.startswith("explained: found external load 829 N")
    assert r.to_json()["not_excluded"] == []


def test_the_report_tags_by_the_residual_not_by_uniqueness():
    """The HTML report's state is the verdict's residual: an ambiguous record at the noise is
    "explained" (its kind says "explained, ambiguous"), not "above noise" (as it was before
    issue 42)."""
    from eha.reports.html.sections import _explain_state

    rival = {"effect": "offset", "param": "Ofs", "value": -0.009, "shift": 0.009,
             "threshold": 0.005, "detectable": 0.007, "unit": "mA"}
    r = result(1.03e-6, unexplained=True, beyond=False)
    r.not_excluded = [rival]
    assert _explain_state(r.run_row("id", "x.csv", None)) == "explained"
    partly = result(1.6e-6, unexplained=True, beyond=False)
    assert _explain_state(partly.run_row("id", "x.csv", None)) == "above noise"
    far = result(8e-6, unexplained=True, beyond=True)
    assert _explain_state(far.run_row("id", "x.csv", None)) == "unexplained"
    # a database row from before the verdict's facts keeps its old reading
    assert _explain_state({"unexplained": False}) == "explained"
    assert _explain_state({"unexplained": True, "beyond_healthy": False}) == "above noise"


def test_the_report_names_the_absent_sections_and_the_error_sign(tmp_path):
    """Issue 42, item 5: the page says which sections are absent and which command fills
    each; the identification table states its error's sign and shows the comparison first."""
    import inspect

    import eha.reports.html as html
    from eha.reports.html import sections

    r = result(1.1e-6, unexplained=False, beyond=False)
    from eha.explain.tables import save_explain

    save_explain(tmp_path, r.run_row("id", "x.csv", "2026-11-26 07:00:00"), [])
    out = html.build_report(tmp_path, tmp_path / "r.html")
    text = out.path.read_text(encoding="utf-8")
    assert "Not in this report" in text and "eha fleet simulate, then eha rul" in text
    assert "<b>Campaigns</b>" in text and out.sections == ["explain"]
    src = inspect.getsource(sections.identification_section)
    assert "Error = (in − out) / in × 100" in src
    assert src.index('"thesis_mean_err_pct", "thesis mean err') < src.index('f"{ln}_in"')


def test_an_effect_of_two_parameters_names_each_in_its_unit():
    r = result(1.0e-6, unexplained=False, beyond=False,
               params=LFParams().replace(PSR=1.71e7, XSSK=0.0, orifice_law=1.0),
               steps=[step("orifice_law"), step("supply_pressure", {"PSR": 1.8e7, "XSSK": 0})],
               intervals={"PSR": (1.68e7, 1.74e7), "XSSK": (0.0, 0.1)})
    assert r.verdict.startswith("explained: found supply pressure PSR 17.1 MPa (-14 % of its "
                                "nominal 20 MPa) [16.8, 17.4], "
                                "XSSK 0 [0, 0.1] (90 %); residual 1 µm"), r.verdict
