"""The fault registry (eha.models.faults): every fact of a health fault declared once, every
table derived from it, and a new fault on an existing LF parameter as one declaration."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from eha.models import faults as registry
from eha.models.faults import FAULTS, Fault, register, registered
from eha.models.params import SPECS, ParameterError

#: A toy fault on an existing LF parameter (the magnetic hysteresis half-width, mA).
TOY = Fault("His", "magnetic hysteresis", +1, (0.0, 0.5), healthy_std=0.002,
            scatter=("uniform_rel", 0.0, 0.0), levels=(0.02, 0.05, 0.1), effect="hysteresis",
            model_form={"calibrated": (0.0, 0.004)})


def test_the_seven_faults_and_every_table_derived_from_them():
    from eha.health.assessment import FAULTS as ASSESSED
    from eha.identification.healthy import DISPERSION
    from eha.identification.intervals import MODEL_FORM
    from eha.identification.problem import SEARCH_BOUNDS
    from eha.explain.settings import DEFAULT_FAULT_BOUNDS
    from eha.models.units import display_unit
    from eha.prognostics.plots import _unit
    from eha.reports.html.data import unit_of

    assert list(FAULTS) == ["BKL", "FDJ", "GM", "Kintas", "Clk", "Ofs", "FSS"]
    assert ASSESSED is FAULTS
    assert registry.core_faults() == ("BKL", "FDJ")
    assert registry.rul_faults() == ("BKL", "FDJ", "GM")
    assert dict(SEARCH_BOUNDS) == {f.name: f.fdi_bounds for f in FAULTS.values()}
    assert SEARCH_BOUNDS["FDJ"] == (200.0, 4000.0) and FAULTS["FDJ"].bounds == (50.0, 4000.0)
    # the healthy fleet's draw order is the historic one (a seed gives the same actuator)
    assert list(DISPERSION) == ["GP", "GQ", "CJ", "MJ", "FSS", "GM", "FDJ", "Clk"]
    assert MODEL_FORM["calibrated"]["Kintas"].abs == 0.05 and "Kintas" not in MODEL_FORM["plain"]
    # the loop's bounds when none are given: declared with BKL and FDJ (issue 63)
    assert DEFAULT_FAULT_BOUNDS == {"BKL": (0.0, 2e-3), "FDJ": (0.0, 8000.0)}
    assert registry.search_bounds(["BKL", "FDJ", "GM"], "loop") == {
        "BKL": (0.0, 2e-3), "FDJ": (0.0, 8000.0), "GM": (0.003, 0.012)}
    assert registry.search_bounds(["FDJ"], "assessment") == {"FDJ": (50.0, 4000.0)}
    # one home of display units: the registry, the report and the RUL plots read it
    assert display_unit("BKL") == ("µm", 1e6) and display_unit("FDJ") == ("N", 1.0)
    for f in FAULTS.values():
        assert f.display_unit == display_unit(f.name)
        assert unit_of(f.name) == _unit(f.name) == (f.display_unit[0] or "-", f.display_unit[1])
    for f in FAULTS.values():
        assert f.healthy == SPECS[f.name].nominal and f.unit == SPECS[f.name].unit


def test_each_fault_names_the_loop_effect_that_fits_its_parameter():
    from eha.explain.effects import EFFECTS

    linked = {f.name: f.effect for f in FAULTS.values() if f.effect}
    assert linked == {"GM": "motor_gain", "Kintas": "clogging", "Clk": "leakage",
                      "Ofs": "offset"}
    for name, effect in linked.items():
        assert EFFECTS[effect].params == (name,)


@pytest.mark.parametrize("fault, message", [
    (Fault("PSRx", "no such parameter", +1, (0.0, 1.0)), "not an LF parameter"),
    (Fault("GAI", "an HF-only parameter", +1, (0.0, 1.0)), "not an LF parameter"),
    (Fault("His", "bounds beyond the range", +1, (0.0, 50.0)), "must lie inside [0, 5] mA"),
    (Fault("His", "a bad role", +1, (0.0, 1.0), role="main"), "role 'main'"),
    (Fault("His", "a bad law", +1, (0.0, 1.0), scatter=("gauss", 1, 1)), "scatter law"),
    (Fault("BKL", "twice", +1, (0.0, 1e-3)), "registered twice"),
])
def test_a_bad_declaration_is_one_line(fault, message):
    with pytest.raises(ParameterError, match=message.replace("[", r"\[")):
        register(fault)
    assert list(FAULTS) == ["BKL", "FDJ", "GM", "Kintas", "Clk", "Ofs", "FSS"]


def test_a_new_fault_is_one_declaration_identified_assessed_and_reported(tmp_path):
    """Declared once (TOY), the hysteresis becomes a health fault everywhere: the bank gets
    its hypothesis, identification its bounds, the healthy fleet its scatter, the detection
    campaign its levels; on an LF record with His = 0.08 mA the check finds it (the
    interval covers the truth), calls it degraded and isolated, and the JSON, DuckDB and
    `eha faults` report it."""
    from eha.campaigns.query import query
    from eha.health.detection import CALIBRATION_FORMAT, Calibration, calibrate_thresholds
    from eha.health.detection import health_jobs
    from eha.health.monitoring import check_record
    from eha.identification.healthy import DISPERSION, command_signature
    from eha.identification.measured import synthetic_record
    from eha.identification.problem import SEARCH_BOUNDS, default_bounds
    from eha.models.simulate import MODEL_VERSION

    df = synthetic_record("chirp_1cm", {"BKL": 1e-4, "FDJ": 400.0, "His": 0.08}, t_end=0.5,
                          noise=1e-6, seed=3, model="lf")
    record = tmp_path / "his.csv"
    df.to_csv(record, index=False)
    assert "His" not in SEARCH_BOUNDS
    with registered(TOY):
        assert registry.extra_faults()[-1] == "His"
        assert SEARCH_BOUNDS["His"] == default_bounds(["His"])["His"] == (0.0, 0.5)
        assert "His" in DISPERSION
        problems: list[str] = []
        jobs = health_jobs({"faults": ["His"], "actuators": 1, "healthy_actuators": 1},
                           problems)
        assert not problems and [j["columns"]["fault_label"] for j in jobs] == \
            ["healthy", "His=0.02", "His=0.05", "His=0.1"]
        healthy = [{"means": {n: FAULTS[n].healthy + 0.001 * k * (FAULTS[n].healthy_std or 1)
                              for n in FAULTS},
                    "spread": {n: FAULTS[n].healthy_std for n in FAULTS}} for k in range(8)]
        thresholds, stats = calibrate_thresholds(healthy, alpha=0.01)
        calibration = Calibration("chirp_1cm", command_signature(df["com"].to_numpy()), 0.5,
                                  MODEL_VERSION, "calibrated", 0.9, 0.01, thresholds, stats,
                                  {"actuators": 8}, format=CALIBRATION_FORMAT)
        cal = calibration.save(tmp_path / "cal.json")
        out = check_record(record, cal, json_path=tmp_path / "check.json",
                           results=tmp_path / "res")
        lo, hi = out.assessment.intervals["His"]
        assert lo <= 0.08 <= hi and abs(out.assessment.estimates["His"] - 0.08) < 0.004
        assert "His" in out.isolated
        doc = json.loads((tmp_path / "check.json").read_text())
        assert doc["faults"]["His"]["degraded"] is True and doc["status"] == "degraded"
        rows = query(tmp_path / "res", "SELECT fault, degraded, isolated FROM health_verdicts "
                                       "WHERE fault = 'His'")
        assert rows.to_dict("records") == [{"fault": "His", "degraded": True, "isolated": True}]
        from eha.cli.app import app

        listing = CliRunner().invoke(app, ["faults"], env={"COLUMNS": "100"})
        assert listing.exit_code == 0 and "His  magnetic hysteresis [mA]" in listing.output
    assert "His" not in FAULTS and "His" not in SEARCH_BOUNDS


def test_a_fault_declares_its_loop_bounds_and_display_unit_once():
    """A fault's loop bounds and display unit are two more fields of its one declaration
    (issue 63): the bounds reach ``search_bounds(purpose="loop")``, the unit every reader of
    display units (console, report, RUL plots, ``eha faults``); a bad loop bound is one line."""
    from eha.models.units import display_unit, show
    from eha.prognostics.plots import _unit
    from eha.reports.html.data import unit_of

    toy = Fault("His", "magnetic hysteresis", +1, (0.0, 0.5), loop_bounds=(0.0, 1.0),
                display=("µA", 1e3))
    with registered(toy):
        assert registry.search_bounds(["His"], "loop") == {"His": (0.0, 1.0)}
        assert registry.search_bounds(["His"], "fdi") == {"His": (0.0, 0.5)}
        assert display_unit("His") == unit_of("His") == _unit("His") == ("µA", 1e3)
        assert show("His", 0.02) == "20 µA"
    assert display_unit("His") == ("mA", 1.0)
    with pytest.raises(ParameterError, match=r"loop_bounds \[0, 50\] must lie inside"):
        register(Fault("His", "too wide", +1, (0.0, 0.5), loop_bounds=(0.0, 50.0)))
    with pytest.raises(ParameterError, match="`purpose` 'rul': allowed assessment, fdi, loop"):
        registry.search_bounds(["BKL"], "rul")
