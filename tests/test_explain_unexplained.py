"""An honest verdict outside the library: a record with physics built only for the tests
(tests/foreign_physics.py: here an asymmetric motor gain).

No confident mis-attribution: the loop may add library effects that stand in for the foreign
physics, but then the record is declared unexplained, the steps are tentative, the verdict
names the residual, its ratio to the noise and its lead, and the declared faults' intervals are
widened (a fault the stand-ins bias is inside its interval or its interval is wide).

The same check on the cubic spring and the spool overlap (5-6 min of the suite's 2 cores:
the final check's global swap search far from the noise) runs in
validation/explain_outside.py, which fails when any of its records does.
"""

import json

import pytest

from eha.explain import explain
from eha.identification.measured import from_arrays

from foreign_physics import (FOREIGN_EFFECTS, OUTSIDE_MAGNITUDES, OUTSIDE_SEARCH, OUTSIDE_TRUTH,
                             foreign_record, outside_verdict_problems)


@pytest.mark.slow
def test_foreign_physics_is_declared_unexplained_not_mis_attributed():
    effect = "asymmetric_gain"
    assert set(OUTSIDE_MAGNITUDES) <= set(FOREIGN_EFFECTS)
    df = foreign_record("mixed", effect, OUTSIDE_MAGNITUDES[effect], dict(OUTSIDE_TRUTH),
                        t_end=1.0, seed=1)
    result = explain(from_arrays(df.t, df.com, df.xu, df.p12, source=effect), **OUTSIDE_SEARCH)
    doc = json.loads(json.dumps(result.to_json()))
    assert outside_verdict_problems(doc) == []


def test_outside_check_names_each_failure():
    """The check itself (no simulation): a confident, explained verdict fails every clause."""
    doc = {"unexplained": False, "rmse_after": 1.1e-6, "noise_rmse": 1e-6,
           "verdict": "explained: residual 1.1 µm (1.1× noise)",
           "steps": [{"effect": "leakage", "tentative": False}], "leads": {"ratio": 1.0},
           "intervals": {"BKL": [2e-4, 2.1e-4], "FDJ": [790.0, 810.0]}}
    problems = outside_verdict_problems(doc)
    assert len(problems) == 6, problems
    assert any("BKL" in p for p in problems) and not any("FDJ" in p for p in problems)
    ok = {"unexplained": True, "rmse_after": 5e-6, "noise_rmse": 1e-6,
          "verdict": "unexplained residual 5 µm (5× noise)", "steps": [],
          "leads": {"ratio": 5.0}, "intervals": {"BKL": [0.0, 2e-3], "FDJ": [700.0, 900.0]}}
    assert outside_verdict_problems(ok) == []
