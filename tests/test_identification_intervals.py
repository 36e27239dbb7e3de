"""Identification intervals (eha.identification.intervals) and the health assessment's bank
(eha.health.assessment).

Statistical checks use fixed seeds and state their tolerance: a nominal-90 % interval on
N independent repetitions covers the truth a Binomial(N, 0.9) number of times, so with
N = 400 the coverage lies in [0.86, 0.94] with probability > 0.99.
"""

from __future__ import annotations

import numpy as np
import pytest

from eha.identification.intervals import (bandwidth, check_level, estimate_intervals,
                                          hac_covariance, normal_quantile)


def _ar1(rng, n, phi, sigma):
    e = rng.normal(0.0, sigma, n)
    out = np.empty(n)
    out[0] = e[0]
    for i in range(1, n):
        out[i] = phi * out[i - 1] + e[i]
    return out


def test_normal_quantile_and_level_checks():
    assert normal_quantile(0.9) == pytest.approx(1.6449, abs=1e-4)
    assert normal_quantile(0.95) == pytest.approx(1.9600, abs=1e-4)
    for bad in (0, 1, 1.5, -0.1, float("nan"), "0.9", True):
        with pytest.raises(ValueError, match="allowed range \\(0, 1\\)"):
            check_level(bad)


def test_bandwidth_follows_the_correlation_time():
    rng = np.random.default_rng(0)
    assert bandwidth(rng.normal(size=2000)) <= 3                 # white: no correlation
    # AR(1) with phi = 0.9: integrated time 1 + 2*sum(0.9^k) = 19, window cut at acf < 0.05
    # (lag ~28) gives ~17; the bandwidth is twice that (tolerance for the estimate: 25 %)
    lag = bandwidth(_ar1(rng, 20000, 0.9, 1.0))
    assert 26 <= lag <= 45


def test_hac_covers_under_autocorrelated_noise():
    """Offset + sine + AR(1) noise (phi 0.5): the HAC interval covers the sine's amplitude at the nominal
    rate, where the white-noise (OLS) interval is far too narrow (its variance is 3x too
    small). HAC is asymptotic: with phi 0.8 and 500 samples it covers about 80 %, one reason
    the tool's intervals carry a measured model-form term (docs/health.md)."""
    rng = np.random.default_rng(1)
    n, reps, z = 500, 400, normal_quantile(0.9)
    t = np.linspace(0.0, 1.0, n)
    jac = np.column_stack([np.ones(n), np.sin(8.0 * t)])   # oscillating, as a chirp's J
    hac_in = ols_in = 0
    for _ in range(reps):
        y = 0.3 + 2.0 * jac[:, 1] + _ar1(rng, n, 0.5, 0.1)
        coef, *_ = np.linalg.lstsq(jac, y, rcond=None)
        r = y - jac @ coef
        cov = hac_covariance(jac, r, bandwidth(r))
        hac_in += abs(coef[1] - 2.0) <= z * np.sqrt(cov[1, 1])
        s2 = r @ r / (n - 2)
        ols_in += abs(coef[1] - 2.0) <= z * np.sqrt(s2 * np.linalg.inv(jac.T @ jac)[1, 1])
    assert 0.84 <= hac_in / reps <= 0.95
    assert ols_in / reps < 0.75


def test_estimate_intervals_linear_model_round_trip():
    """A linear 'simulator' in the unit cube: the interval contains the truth and is clipped to
    the bounds; a residual far above the noise is flagged and widens the interval."""
    rng = np.random.default_rng(2)
    n = 800
    basis = np.column_stack([np.sin(np.linspace(0, 6, n)), np.linspace(-1, 1, n) ** 2])
    lo, span = np.array([0.0, 10.0]), np.array([1.0, 100.0])
    truth = np.array([0.4, 60.0])

    def sim(units):
        values = lo + np.clip(units, 0, 1) * span
        return values @ basis.T * 1e-6

    ref = sim(((truth - lo) / span)[None, :])[0] + rng.normal(0, 1e-8, n)
    x = (truth - lo) / span
    iv = estimate_intervals(ref, sim, x, ["a", "b"], lo, span, noise=1e-8)
    for i, name in enumerate("ab"):
        a, b = iv.bounds[name]
        assert a <= truth[i] <= b
        assert lo[i] <= a and b <= lo[i] + span[i]
    assert not iv.flagged
    wavy = ref + 2e-7 * np.sin(np.linspace(0, 40, n))         # 14x the noise, unmodelled
    iv2 = estimate_intervals(wavy, sim, x, ["a", "b"], lo, span, noise=1e-8)
    assert iv2.flagged and iv2.excess > 10
    assert iv2.std["a"] > 5 * iv.std["a"]


def test_mixture_interval_normal_point_mass_and_bound():
    from eha.health.assessment import mixture_interval

    lo, hi = mixture_interval([(1.0, 5.0, 1.0)], 0.9, (-100.0, 100.0))
    assert lo == pytest.approx(5 - 1.645, abs=0.06) and hi == pytest.approx(5 + 1.645, abs=0.06)
    # a healthy value at its bound stays inside (censored, not truncated)
    lo, hi = mixture_interval([(1.0, 0.0, 0.1)], 0.9, (0.0, 1.0))
    assert lo == 0.0 and hi == pytest.approx(0.1645, abs=0.002)
    # two hypotheses, equal weight, far apart: the interval spans both
    lo, hi = mixture_interval([(0.5, 10.0, 0.5), (0.5, 20.0, 0.5)], 0.9, (0.0, 40.0))
    assert lo < 10.0 and hi > 20.0


def test_identify_reports_intervals_that_cover_an_lf_truth():
    """LF record (no model-form error) with 1 µm noise: BKL and FDJ intervals contain the
    truth, are narrow (< 5 % of FDJ) and are in the FitResult, its JSON and the level."""
    from eha.identification.fdi import identify
    from eha.identification.measured import from_arrays, synthetic_record

    df = synthetic_record("chirp_1cm", {"BKL": 3e-4, "FDJ": 900.0}, t_end=0.6, noise=1e-6,
                          seed=3, model="lf")
    rec = from_arrays(df["t"].to_numpy(), df["com"].to_numpy(), df["xu"].to_numpy())
    # the record is the LF model itself: no model-form term (the plain LF's measured floors
    # are for HF or measured records, below)
    res = identify(rec.xu, rec.command, {"BKL": (0.0, 1.25e-3), "FDJ": (200.0, 4000.0)},
                   seed=0, noise=rec.info["noise_m"], model_form="none")
    assert res.level == 0.9 and not res.flagged
    for name, true in (("BKL", 3e-4), ("FDJ", 900.0)):
        lo, hi = res.intervals[name]
        assert lo <= true <= hi, (name, lo, hi)
    assert (res.intervals["FDJ"][1] - res.intervals["FDJ"][0]) / 900.0 < 0.05
    floors = identify(rec.xu, rec.command, {"BKL": (0.0, 1.25e-3), "FDJ": (200.0, 4000.0)},
                      seed=0, noise=rec.info["noise_m"])          # plain LF: its floors
    assert floors.model_form == "plain" and floors.std["FDJ"] > 3 * res.std["FDJ"]
    assert floors.intervals["FDJ"][0] <= 900.0 <= floors.intervals["FDJ"][1]
    d = res.to_dict()
    assert d["level"] == 0.9 and set(d["intervals"]) == {"BKL", "FDJ"}
    assert isinstance(d["intervals"]["FDJ"], list)


def test_identify_rejects_a_bad_level():
    from eha.identification.fdi import identify
    from eha.identification.problem import FDIError

    with pytest.raises(FDIError, match="level=1.2: allowed range"):
        identify(np.zeros(101), "chirp_1cm", level=1.2)


@pytest.mark.slow
def test_health_bank_isolates_an_offset_and_covers_it():
    """HF record with an offset current of -0.19 mA: the bank gives H_Ofs almost all the
    weight, and every fault's interval covers its truth (healthy values for the others)."""
    from eha.health.assessment import FAULTS, assess_record
    from eha.identification.measured import from_arrays, synthetic_record

    faults = {"BKL": 8e-4, "FDJ": 750.0, "Ofs": -0.19}
    df = synthetic_record("mixed", faults, t_end=1.0, noise=1e-6, seed=3)
    rec = from_arrays(df["t"].to_numpy(), df["com"].to_numpy(), df["xu"].to_numpy())
    a = assess_record(rec, seed=3)
    assert a.best.fault == "Ofs" and a.best.weight > 0.9
    for name, spec in FAULTS.items():
        lo, hi = a.intervals[name]
        assert lo <= faults.get(name, spec.healthy) <= hi, (name, lo, hi)


def test_flag_compares_the_residual_with_the_floored_noise():
    """The flag of an unexplained fit (shared by the intervals and the residual loop): the
    residual against FLAG_RATIO times the noise, the noise floored at NOISE_FLOOR of the
    record's spread (a noise-free record is not flagged for a tiny model-form residual)."""
    from eha.identification.intervals import FLAG_RATIO, NOISE_FLOOR, is_flagged, noise_reference

    ref = np.linspace(-1e-2, 1e-2, 101)
    assert noise_reference(1e-6, ref) == 1e-6
    assert noise_reference(0.0, ref) == pytest.approx(NOISE_FLOOR * np.std(ref))
    assert is_flagged(1.01 * FLAG_RATIO * 1e-6, 1e-6)
    assert not is_flagged(0.99 * FLAG_RATIO * 1e-6, 1e-6)
    assert not is_flagged(1.0, 0.0)


def test_loop_floor_joins_the_base_terms_in_quadrature():
    """A model the residual loop built: every parameter gets LOOP_MODEL_FORM's relative floor,
    in quadrature with its base's terms (a parameter without a base term gets the floor)."""
    import math

    from eha.identification.intervals import LOOP_MODEL_FORM, ModelForm, loop_terms, total_std

    base = {"BKL": ModelForm(rel=0.001, abs=1.5e-6)}
    terms = loop_terms(base, ["BKL", "FRC"])
    assert terms["BKL"].rel == pytest.approx(math.hypot(0.001, LOOP_MODEL_FORM.rel))
    assert terms["BKL"].abs == pytest.approx(1.5e-6)
    assert terms["FRC"].rel == pytest.approx(LOOP_MODEL_FORM.rel) and LOOP_MODEL_FORM.rel > 0
    # a load of 2000 N with a HAC std of 1 N: the floor dominates
    assert total_std(1.0, 2000.0, terms["FRC"]) == pytest.approx(
        math.hypot(1.0, LOOP_MODEL_FORM.rel * 2000.0))
