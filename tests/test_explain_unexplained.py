"""An honest verdict outside the library: records with physics built only for these tests
(tests/foreign_physics.py: a cubic jack spring, an asymmetric motor gain, spool overlap).

No confident mis-attribution: the loop may add library effects that stand in for the foreign
physics, but then the record is declared unexplained, the steps are tentative, the verdict
names the residual, its ratio to the noise and its lead, and the declared faults' intervals are
widened (a fault the stand-ins bias is inside its interval or its interval is wide).
"""

import json

import pytest

from eha.explain import explain
from eha.identification.measured import from_arrays

from foreign_physics import FOREIGN_EFFECTS, foreign_record

TRUTH = {"BKL": 1e-4, "FDJ": 800.0}
#: Magnitudes: the foreign module's defaults, but spool overlap at 50 µm: at 20 µm leakage plus
#: a supply-pressure change mimic it on `mixed` to 1.6x the noise (docs/explain.md, Limits).
MAGNITUDES = {"cubic_spring": 5e9, "asymmetric_gain": 0.2, "spool_overlap": 5e-5}
#: A smaller GA than the loop's default (population 12, at most 20 generations): the verdict
#: does not hang on the search budget, and with the second pass and the one-for-two swap the
#: default budget took 5-6 min per record. The benchmarks run the defaults.
SEARCH = {"pop": 12, "max_gen": 20, "stall": 5, "seed": 0, "null_actuators": 5}


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(MAGNITUDES))
def test_foreign_physics_is_declared_unexplained_not_mis_attributed(effect):
    assert effect in FOREIGN_EFFECTS
    df = foreign_record("mixed", effect, MAGNITUDES[effect], dict(TRUTH), t_end=1.0, seed=1)
    result = explain(from_arrays(df.t, df.com, df.xu, df.p12, source=effect), **SEARCH)
    doc = json.loads(json.dumps(result.to_json()))
    assert doc["unexplained"] is True
    assert result.rmse_after > 3 * result.noise_rmse
    assert doc["verdict"].startswith("unexplained residual") and "noise" in doc["verdict"]
    assert all(step["tentative"] for step in doc["steps"])
    assert doc["leads"]["ratio"] > 3
    # no confident fault estimate: each declared fault's interval covers the truth or is
    # wider than +-25 % of it
    for name, truth in TRUTH.items():
        lo, hi = doc["intervals"][name]
        assert lo <= truth <= hi or (hi - lo) > 0.5 * truth, (name, lo, hi)
