"""Residual leads (eha.explain.leads): features, the STLSQ sparse regression, the report.

The signals are analytic (no simulation), so the file runs in well under a second: a 2 s,
1 kHz record of a two-sine command, a position that follows it with a 15 ms lag, its velocity
and a load pressure that is neither.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from eha.explain.leads import (FEATURES, LEAD_SHARE, Lead, LeadReport, LeadsError,
                               command_steps, feature_matrix, residual_leads, sparse_regression)

N = 2001
T = np.arange(N) * 1e-3


def signals(command=None):
    """(t, command, position, velocity, p12) of a smooth 1 cm tracking record."""
    c = (0.01 * np.sin(2 * np.pi * 1.0 * T) + 0.004 * np.sin(2 * np.pi * 3.1 * T + 0.5)
         if command is None else command)
    x = np.empty(N)
    x[0] = c[0]
    a = math.exp(-1e-3 / 0.015)
    for k in range(1, N):  # first-order lag, 15 ms
        x[k] = a * x[k - 1] + (1 - a) * c[k]
    v = np.gradient(x, T)
    p12 = 2e6 * np.sin(2 * np.pi * 2.3 * T) + 3e8 * v
    return T, c, x, v, p12


def columns(names, X):
    return {n: X[:, i] for i, n in enumerate(names)}


def test_feature_names_and_order():
    names, X = feature_matrix(*signals())
    assert names == [n for n in FEATURES if n != "command_steps"]  # smooth command: no jumps
    assert X.shape == (N, len(names)) and X.dtype == np.float64
    col = columns(names, X)
    t, c, x, v, p12 = signals()
    np.testing.assert_array_equal(col["position_cubed"], x ** 3)
    np.testing.assert_array_equal(col["tracking_error"], c - x)
    np.testing.assert_array_equal(col["velocity_abs_velocity"], v * np.abs(v))
    assert set(np.unique(col["velocity_sign"])) <= {-1.0, 0.0, 1.0}
    assert np.all(col["constant"] == 1.0)


def test_zero_variance_features_are_dropped_but_constant_kept():
    # held at +5 mm: no velocity, one side of the stroke, command without jumps, no pressure
    c = np.full(N, 5e-3)
    names, X = feature_matrix(T, c, c.copy(), np.zeros(N), np.zeros(N))
    assert names == ["constant"]
    names, _ = feature_matrix(T, c, c.copy(), np.zeros(N), None)
    assert names == ["constant"]


def test_command_steps_feature():
    c = np.where(T >= 0.5, 1e-2, 0.0) + np.where(T >= 1.2, -4e-3, 0.0)
    f = command_steps(T, c)
    k1, k2 = 500, 1200
    assert np.all(f[:k1] == 0.0)
    assert f[k1] == 1.0 and f[k1 + 20] == pytest.approx(math.exp(-1.0))
    # the second (negative) jump adds -1 to what is left of the first
    assert f[k2] == pytest.approx(math.exp(-0.7 / 0.02) - 1.0)
    # a step spread over two samples is one jump, at its first sample
    c2 = c.copy()
    c2[500] = 5e-3
    f2 = command_steps(T, c2)
    assert f2[499] == 0.0 and f2[500] == 1.0 and f2[501] == pytest.approx(math.exp(-0.05))
    # a chirp or a ramp has no jumps; noise on a held command is not one either
    assert not command_steps(T, 0.01 * np.sin(2 * np.pi * (0.1 + 0.7 * T) * T)).any()
    assert not command_steps(T, 0.02 * T).any()
    rng = np.random.default_rng(3)
    assert not command_steps(T, 1e-3 + rng.normal(0, 1e-6, N)).any()


def test_known_features_are_found_with_their_coefficients():
    t, c, x, v, p12 = signals()
    rng = np.random.default_rng(0)
    names, X = feature_matrix(t, c, x, v, p12)
    col = columns(names, X)
    # 20 m^-2 * (1 cm)^3 = 20 µm cubic spring term, 3 µm of dry friction, 1 µm noise
    r = 20.0 * col["position_cubed"] + 3e-6 * col["velocity_sign"] + rng.normal(0, 1e-6, N)
    fit = sparse_regression(r, X, names)
    found = {L.feature: L for L in fit.terms}
    assert set(found) == {"position_cubed", "velocity_sign"}
    # tolerance: 3 % of each coefficient (1 µm white noise on 2000 samples)
    assert found["position_cubed"].coefficient == pytest.approx(20.0, rel=0.03)
    assert found["velocity_sign"].coefficient == pytest.approx(3e-6, rel=0.03)
    assert fit.terms[0].feature == "position_cubed"  # larger share first
    assert fit.r2 > 0.95
    assert 0 < fit.terms[1].share < fit.terms[0].share <= fit.r2
    assert set(fit.correlations) == set(names) - {"constant"}
    assert fit.correlations["position_cubed"] > 0.8


def test_bias_and_p12_terms():
    t, c, x, v, p12 = signals()
    rng = np.random.default_rng(1)
    r = 8e-6 + 2e-12 * p12 + rng.normal(0, 1e-6, N)  # a bias and a load compliance
    rep = residual_leads(r, t, c, x, v, p12, noise_rmse=1e-6)
    found = {L.feature: L.coefficient for L in rep.terms}
    assert set(found) == {"constant", "p12"}
    assert found["constant"] == pytest.approx(8e-6, rel=0.03)
    assert found["p12"] == pytest.approx(2e-12, rel=0.03)


def test_pure_noise_has_no_terms():
    t, c, x, v, p12 = signals()
    rng = np.random.default_rng(2)
    r = rng.normal(0, 1e-6, N)
    rep = residual_leads(r, t, c, x, v, p12, noise_rmse=1e-6)
    assert rep.terms == () and rep.r2 == 0.0
    assert rep.ratio == pytest.approx(1.0, abs=0.05)
    assert all(abs(v) < 0.1 for v in rep.correlations.values())
    assert rep.describe().endswith("not correlated with any candidate feature")


def test_collinear_features_do_not_blow_up():
    t, c, x, v, p12 = signals()
    names, X = feature_matrix(t, c, x, v, p12)
    col = columns(names, X)
    # tracking_error = command - position exactly; add a near-duplicate of position too
    rng = np.random.default_rng(4)
    X2 = np.column_stack([X, col["position"] * (1 + 1e-9 * rng.normal(size=N))])
    names2 = names + ["position_copy"]
    r = col["tracking_error"] + 0.05 * col["position"] + rng.normal(0, 1e-7, N)  # ~0.5 mm each
    fit = sparse_regression(r, X2, names2)
    assert 1 <= len(fit.terms) <= 3
    coef = {L.feature: L.coefficient for L in fit.terms}
    assert all(math.isfinite(a) and abs(a) < 10.0 for a in coef.values())
    pred = sum(a * X2[:, names2.index(f)] for f, a in coef.items())
    assert np.sqrt(np.mean((pred - r) ** 2)) < 0.02 * np.sqrt(np.mean(r ** 2))
    assert fit.r2 > 0.999
    # each kept term explains something of its own (no exactly dependent pair survives)
    assert all(L.share >= 0.01 for L in fit.terms)


def test_max_terms_and_determinism():
    t, c, x, v, p12 = signals()
    names, X = feature_matrix(t, c, x, v, p12)
    col = columns(names, X)
    r = (5.0 * col["position_cubed"] + 1e-6 * col["velocity_sign"] + 2e-6
         + 1e-3 * col["velocity_abs_velocity"] + 2e-13 * col["p12"])
    a = sparse_regression(r, X, names, max_terms=3)
    b = sparse_regression(r.copy(), X.copy(), list(names), max_terms=3)
    assert len(a.terms) == 3
    assert a == b
    assert len(sparse_regression(r, X, names, max_terms=1).terms) == 1


def test_residual_leads_report_and_json():
    t, c, x, v, p12 = signals()
    rng = np.random.default_rng(5)
    names, X = feature_matrix(t, c, x, v, p12)
    r = 20.0 * columns(names, X)["position_cubed"] + rng.normal(0, 1e-6, N)
    rep = residual_leads(r, t, c, x, v, p12, noise_rmse=1e-6)
    assert rep.rmse == pytest.approx(np.sqrt(np.mean(r ** 2)))
    assert rep.ratio == pytest.approx(rep.rmse / 1e-6)
    assert rep.terms[0].feature == "position_cubed" and rep.r2 >= LEAD_SHARE
    text = rep.describe()
    assert text.startswith(f"unexplained residual {1e6 * rep.rmse:.3g} µm (")
    assert "× noise), correlated with position_cubed (" in text and "% of it)" in text
    doc = json.loads(json.dumps(rep.to_json(), allow_nan=False))
    assert doc["terms"][0]["feature"] == "position_cubed"
    assert doc["terms"][0]["unit"] == "m/m^3"
    assert doc["leads"] == [L.feature for L in rep.terms] and doc["text"] == text
    # unknown noise level: no ratio (JSON null), said in the text
    rep0 = residual_leads(r, t, c, x, v, p12, noise_rmse=0.0)
    assert rep0.to_json()["ratio"] is None and "(noise level not known)" in rep0.describe()


def test_describe_text():
    rep = LeadReport(rmse=12.3e-6, noise_rmse=12.3e-6 / 8.1, ratio=8.1,
                     terms=(Lead("position_cubed", 20.0, 0.61), Lead("velocity_sign", 3e-6, 0.09)),
                     r2=0.7)
    assert rep.describe() == ("unexplained residual 12.3 µm (8.1× noise), correlated with "
                              "position_cubed (61 % of it), velocity_sign (9 %)")
    weak = LeadReport(12.3e-6, 1.5e-6, 8.2, (Lead("velocity", 1e-4, 0.06),), 0.06)
    assert weak.describe() == ("unexplained residual 12.3 µm (8.2× noise), not correlated "
                               "with any candidate feature")
    assert weak.leads == () and weak.to_json()["leads"] == []
    # correlated terms: small drop-one shares, a large R² together; the R² decides and is said
    joint = LeadReport(31.8e-6, 1e-6, 31.8, (Lead("velocity_sign", 1e-5, 0.12),
                                             Lead("velocity", 1e-4, 0.02)), 0.91)
    assert joint.describe() == ("unexplained residual 31.8 µm (31.8× noise), correlated with "
                                "velocity_sign (12 % of it), velocity (2 %); together 91 %")


def test_bad_input_is_one_error():
    t, c, x, v, p12 = signals()
    with pytest.raises(LeadsError, match="position has 10 samples"):
        residual_leads(np.zeros(N), t, c, x[:10], v, p12, 1e-6)
    bad = v.copy()
    bad[3] = np.nan
    with pytest.raises(LeadsError, match="velocity has a non-finite value"):
        feature_matrix(t, c, x, bad, p12)
    # a zero residual: nothing to explain
    assert residual_leads(np.zeros(N), t, c, x, v, p12, 1e-6).terms == ()
