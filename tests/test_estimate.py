"""The estimate and bounds types (eha.models.estimate, eha.models.bounds; issue 63): what the
fdi, health, explain and RUL results hand out, and the JSON and pandas forms built from them
(the JSON keys unchanged)."""

from __future__ import annotations

import json
import math
import pickle

import pytest

from eha.identification.problem import FitResult, check_bounds, default_bounds
from eha.models.bounds import Bounds
from eha.models.estimate import Estimate, estimates, frame, intervals_json


def _fit(**kw) -> FitResult:
    base = dict(names=("BKL", "FDJ"), estimates={"BKL": 2e-4, "FDJ": 410.0}, objective=1e-6,
                objective_name="rmse", evaluations=10, seconds=0.1, history=(1e-5, 1e-6),
                method="lm", seed=0, bounds=Bounds(BKL=(0.0, 1e-3), FDJ=(200.0, 4000.0)),
                level=0.9, intervals={"BKL": (1.8e-4, 2.2e-4), "FDJ": (400.0, 420.0)},
                std={"BKL": 1e-5, "FDJ": 6.0})
    base.update(kw)
    return FitResult(**base)


def test_an_estimate_has_its_interval_level_unit_and_plain_form():
    e = Estimate("FDJ", 410.0, 400.0, 420.0, level=0.9, unit="N", std=6.0)
    assert e.interval == (400.0, 420.0) and e.width == 20.0
    assert e.contains(400.0) and not e.contains(421.0)
    assert e.to_dict() == {"name": "FDJ", "value": 410.0, "lo": 400.0, "hi": 420.0,
                           "level": 0.9, "unit": "N", "std": 6.0}
    bare = Estimate("BKL", 1e-4)
    assert bare.to_dict()["lo"] is None and not bare.contains(1e-4)
    json.dumps(bare.to_dict(), allow_nan=False)
    with pytest.raises(AttributeError):
        e.value = 1.0                                            # frozen


def test_bounds_are_a_plain_dict_of_pairs():
    b = Bounds({"BKL": [0.0, 1e-3]}, FDJ=(200, 4000))
    assert b == {"BKL": (0.0, 1e-3), "FDJ": (200, 4000)} and isinstance(b["BKL"], tuple)
    b["GM"] = [0.003, 0.012]
    assert b["GM"] == (0.003, 0.012) and b.span("FDJ") == 3800
    assert json.loads(json.dumps(b)) == b.to_dict() == {
        "BKL": [0.0, 1e-3], "FDJ": [200, 4000], "GM": [0.003, 0.012]}
    assert pickle.loads(pickle.dumps(b)) == b
    assert isinstance(check_bounds({"BKL": (0, 1e-3)}), Bounds)
    assert isinstance(default_bounds(["BKL", "GP"]), Bounds)


def test_the_fit_result_hands_out_estimates_and_keeps_its_json_keys():
    fit = _fit()
    est = fit.as_estimates()
    assert est["FDJ"] == Estimate("FDJ", 410.0, 400.0, 420.0, 0.9, "N", 6.0)
    assert est["BKL"].unit == "m"
    d = fit.to_dict()
    assert d["intervals"] == {"BKL": [1.8e-4, 2.2e-4], "FDJ": [400.0, 420.0]}
    assert d["bounds"] == {"BKL": [0.0, 1e-3], "FDJ": [200.0, 4000.0]}
    assert {"estimates", "intervals", "bounds", "level", "std"} <= set(d)
    # no interval computed: none written, NaN in the frame
    bare = _fit(level=None, intervals={})
    assert bare.to_dict()["intervals"] == {}
    df = frame(bare.as_estimates(), key="parameter")
    assert list(df["parameter"]) == ["BKL", "FDJ"] and df["lo"].isna().all()


def test_the_frame_and_the_json_intervals_come_from_the_estimates():
    est = estimates({"BKL": 2e-4, "X": 1.0}, {"BKL": (1e-4, 3e-4)}, 0.9)
    assert est["X"].unit == "" and est["X"].level is None and math.isnan(est["X"].lo)
    assert intervals_json(est) == {"BKL": [1e-4, 3e-4]}
    df = frame(est, key="fault", extra={"weight": {"BKL": 1.0}})
    assert list(df.columns) == ["fault", "unit", "estimate", "lo", "hi", "level", "weight"]
    assert df.loc[0, "weight"] == 1.0 and math.isnan(df.loc[1, "weight"])


def test_a_rul_prediction_is_an_estimate_in_cycles():
    from eha.prognostics.result import RulResult
    from eha.prognostics.rul import Prediction

    p = Prediction(cycle=100.0, rul=50.0, rul_lo=30.0, rul_hi=80.0, driver="FDJ",
                   estimates={"FDJ": 600.0}, intervals={"FDJ": [580.0, 620.0]})
    none = Prediction(cycle=10.0, rul=None, rul_lo=None, rul_hi=None, driver=None,
                      estimates={}, intervals={})
    assert p.rul_estimate == Estimate("RUL", 50.0, 30.0, 80.0, pytest.approx(0.9), "cycles")
    assert p.as_estimates()["FDJ"].interval == (580.0, 620.0)
    assert {k: p.to_dict()[k] for k in ("rul", "rul_lo", "rul_hi")} == {
        "rul": 50.0, "rul_lo": 30.0, "rul_hi": 80.0}
    assert none.to_dict()["rul_lo"] is None and math.isnan(none.rul_estimate.lo)
    res = RulResult(run_id="r", output={}, predictions={"A1": [none, p]}, metrics=None)
    df = res.to_pandas()
    assert list(df.columns) == ["actuator", "cycle", "rul", "rul_lo", "rul_hi", "driver"]
    assert df["rul_lo"].isna().iloc[0] and df["rul_hi"].iloc[1] == 80.0


def test_the_explain_result_hands_out_the_final_models_estimates():
    from types import SimpleNamespace

    from eha.explain.results import ExplainResult

    res = ExplainResult.__new__(ExplainResult)
    res.faults_after = {"BKL": 2e-4, "FDJ": 410.0}
    res.intervals = {"FDJ": (400.0, 420.0), "FRC": (800.0, 850.0)}
    res.level = 0.9
    res.after = SimpleNamespace(params=SimpleNamespace(FRC=829.0))
    est = res.as_estimates()
    assert list(est) == ["FDJ", "FRC", "BKL"] and est["FRC"].value == 829.0
    assert est["FRC"].unit == "N" and est["BKL"].level is None
    assert intervals_json(est) == {"FDJ": [400.0, 420.0], "FRC": [800.0, 850.0]}
    df = res.to_pandas("estimates")
    assert list(df["parameter"]) == ["FDJ", "FRC", "BKL"] and df.loc[1, "hi"] == 850.0
    from eha.explain.settings import ExplainError

    with pytest.raises(ExplainError, match="`table` 'x': allowed steps, estimates"):
        res.to_pandas("x")
