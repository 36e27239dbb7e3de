"""Campaign files: expansion, run keys, validation (one line per problem), CLI validate/plan."""

from pathlib import Path

import pytest
from typer.testing import CliRunner

import eha.models.simulate
from eha.campaigns.files import CampaignError, build_campaign, load_campaign, plan
from eha.cli import app
from helpers import invoke_eha

CAMPAIGNS = Path(__file__).resolve().parents[1] / "campaigns"
runner = CliRunner()


def base(**extra):
    table = {"name": "t", "models": ["hf", "lf"], "commands": ["mixed"], "t_end": 0.05}
    table.update(extra)
    return table


@pytest.mark.parametrize("name, n, fault_sets", [
    ("thesis-nominal", 12, 1), ("thesis-single-fault", 64, 8), ("thesis-matrix", 60, 15)])
def test_thesis_campaigns_expand_to_the_chapter_5_runs(name, n, fault_sets):
    camp = load_campaign(CAMPAIGNS / f"{name}.toml")
    assert camp.name == name and len(camp.jobs) == n
    assert len({j.run_key for j in camp.jobs}) == n
    assert plan(camp)["fault_sets"] == fault_sets
    assert camp.count_by("model") == {"hf": n // 2, "lf": n // 2}


def test_matrix_is_the_cartesian_product_and_single_varies_one_fault_at_a_time():
    matrix = load_campaign(CAMPAIGNS / "thesis-matrix.toml")
    pairs = {(j.columns["faults"]["BKL"], j.columns["faults"]["FDJ"]) for j in matrix.jobs}
    assert pairs == {(b, f) for b in (1e-4, 5e-4, 1e-3) for f in (400, 800, 1600, 3200, 6400)}
    single = load_campaign(CAMPAIGNS / "thesis-single-fault.toml")
    assert all(len(j.columns["faults"]) == 1 for j in single.jobs)
    assert {j.columns["command"] for j in single.jobs} == {"ramp", "chirp_1mm", "mixed",
                                                           "chirp_1cm"}


def test_hf_and_lf_of_the_same_case_share_a_case_key_only():
    camp = build_campaign(base(faults={"grid": {"BKL": [1e-4, 2e-4]}}, seeds=[0, 1]))
    assert len(camp.jobs) == 2 * 2 * 2
    by_case = {}
    for j in camp.jobs:
        by_case.setdefault(j.columns["case_key"], set()).add(j.spec["model"])
    assert len(by_case) == 4 and all(m == {"hf", "lf"} for m in by_case.values())


def test_points_nominal_and_commands_with_overrides():
    camp = build_campaign(base(
        commands=["step_1mm", {"name": "chirp_1cm", "A0": 5e-3}],
        faults={"nominal": True, "points": [{"name": "worn", "BKL": 1e-3, "FDJ": 3200}]}))
    labels = {j.columns["fault_label"] for j in camp.jobs}
    assert labels == {"nominal", "worn"} and len(camp.jobs) == 2 * 2 * 2
    chirp = next(j for j in camp.jobs if j.spec["command"]["name"] == "chirp_1cm")
    assert chirp.spec["command"]["set"] == {"A0": 5e-3}


def test_run_key_is_stable_and_changes_with_spec_and_model_version(monkeypatch):
    a = build_campaign(base())
    assert [j.run_key for j in a.jobs] == [j.run_key for j in build_campaign(base()).jobs]
    assert a.spec_hash == build_campaign(base(description="other words")).spec_hash
    b = build_campaign(base(t_end=0.06))
    assert not {j.run_key for j in a.jobs} & {j.run_key for j in b.jobs}
    c = build_campaign(base(params={"GAP": 2e4}))
    assert a.spec_hash != c.spec_hash
    monkeypatch.setattr(eha.models.simulate, "MODEL_VERSION", "test-bump")
    d = build_campaign(base())
    assert a.spec_hash != d.spec_hash


@pytest.mark.parametrize("table, message", [
    (base(modles=["hf"]), "modles: unknown key (did you mean models?)"),
    (base(faults={"grid": {"NOPE": [1]}}), "NOPE: unknown parameter"),
    (base(faults={"grid": {"BKL": [1.0]}}), "BKL=1 is out of range; allowed range [0, 0.1] m"),
    (base(faults={"grid": {"BKL": []}}), "faults.grid.BKL: empty list"),
    (base(faults={"single": {}}), "faults.single: must be a non-empty table"),
    (base(commands=["square"]), "unknown command 'square'"),
    (base(commands=[{"name": "chirp_1cm", "A9": 1}]), "unknown parameter 'A9'"),
    (base(commands=[]), "commands: must be a non-empty list"),
    (base(models=["mf"]), "models: unknown model 'mf'"),
    (base(t_end=0), "t_end=0 is out of range"),
    (base(seeds=[-1]), "seeds: -1 is out of range"),
    (base(signals=["t", "xu"]), "signals: 'com' is required"),
    (base(params={"lf": {"GAI": 0.1}}), "GAI: not a parameter of the LF model"),
    (base(faults={"grid": {"XJ0": [0.5]}, "nominal": False}, params={"XJM": 0.1}),
     "XJ0=0.5 is out of range; allowed range [-0.1, 0.1] m"),
    (base(name="bad name"), "name: 'bad name' is not a valid campaign name"),
    (base(kind="fit"), "kind: 'fit' is not a campaign kind"),
])
def test_each_problem_is_one_clear_line(table, message):
    with pytest.raises(CampaignError) as info:
        build_campaign(table)
    assert any(message in line for line in info.value.problems), info.value.problems
    assert all("\n" not in line for line in info.value.problems)


def test_all_problems_are_reported_at_once():
    with pytest.raises(CampaignError) as info:
        build_campaign(base(models=["hf", "xf"], commands=["nope"], bogus=1,
                            faults={"grid": {"FDJ": [-5], "BKL": []}}))
    assert len(info.value.problems) == 5, info.value.problems


def test_cli_validate_and_plan(tmp_path):
    res = runner.invoke(app, ["campaign", "validate", str(CAMPAIGNS / "thesis-matrix.toml")],
                        env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "60 jobs" in res.output
    res = runner.invoke(app, ["campaign", "plan", str(CAMPAIGNS / "thesis-single-fault.toml"),
                              "--jobs"], env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "64 jobs" in res.output and "estimated wall time" in res.output
    assert "HF ramp BKL=0.0001 seed=0" in res.output


def test_cli_validate_bad_file_one_line_per_problem_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nmodels = ["hf"]\ncommands = ["mixed", "square"]\n'
                   "t_end = 1\n[faults]\ngrid = {BKL = [], FDJ = [1e9]}\n")
    proc = invoke_eha("campaign", "validate", bad)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 3, proc.stderr
    assert all(line.startswith("error: ") for line in lines)
    missing = invoke_eha("campaign", "validate", tmp_path / "none.toml")
    assert missing.returncode == 2 and "cannot read the campaign file" in missing.stderr
