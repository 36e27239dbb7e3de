"""Hostile inputs and writers that cannot mix runs (issue 62): command files with a BOM,
underscores, no size limit or a device behind them; JSON and TOML nested 100 000 deep;
``eha design --around`` of the wrong shape or with non-finite values; an over-long ``--name``;
files written together replaced all or none, under names no other writer shares; a campaign
with a command file repaired from any folder."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import Inline, error_line, files_under, invoke_eha, write_campaign

from eha.models.commands import CommandError, load_command_file, write_command_file
from eha.outputs import OutputError

# -- command files


def command_text() -> str:
    t = np.round(np.arange(0.0, 0.2 + 5e-4, 1e-3), 6)
    return "t,com\n" + "".join(f"{a:.6f},{1e-3 * np.sin(20 * a):.9g}\n" for a in t)


def test_a_command_file_with_a_bom_reads_as_without(tmp_path):
    plain, bom = tmp_path / "plain.csv", tmp_path / "bom.csv"
    plain.write_text(command_text(), encoding="utf-8")
    bom.write_bytes(b"\xef\xbb\xbf" + command_text().encode())
    a, b = load_command_file(str(plain)), load_command_file(str(bom))
    assert np.array_equal(a.samples[0], b.samples[0])
    assert np.array_equal(a.samples[1], b.samples[1])


def test_underscores_in_a_number_are_refused_not_read_as_another(tmp_path):
    path = tmp_path / "u.csv"
    path.write_text("t,com\n0,0\n0.1,1_0e-4\n")       # float() reads 1e-3
    with pytest.raises(CommandError, match="data row 2: expected 2 numbers"):
        load_command_file(str(path))


def test_a_command_file_over_the_cap_or_not_a_file_is_refused_before_it_is_read(tmp_path):
    big = tmp_path / "big.csv"
    with open(big, "wb") as fh:          # sparse: 65 MiB without writing them
        fh.write(b"t,com\n")
        fh.truncate(65 * 1024 * 1024)
    t0 = time.perf_counter()
    with pytest.raises(CommandError, match="allowed at most 67108864 bytes"):
        load_command_file(str(big))
    assert time.perf_counter() - t0 < 1.0
    link = tmp_path / "zero.csv"
    link.symlink_to("/dev/zero")
    with pytest.raises(CommandError, match="not a regular file"):
        load_command_file(str(link))
    out = tmp_path / "sim"
    line = error_line(invoke_eha("simulate", "--command", link, "--out", out / "t.parquet"), 2)
    assert "not a regular file" in line and files_under(out) == []


# -- nested too deep


def test_json_and_toml_nested_100000_deep_are_one_line_exit_2(tmp_path):
    deep_json = tmp_path / "deep.json"
    deep_json.write_text("[" * 100_000 + "]" * 100_000)
    out = tmp_path / "out"
    error_line(invoke_eha("design", "--around", deep_json, "--out", out), 2)
    deep_toml = tmp_path / "deep.toml"
    deep_toml.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    line = error_line(invoke_eha("campaign", "validate", deep_toml), 2)
    assert "nested too deeply" in line
    assert files_under(out) == []


# -- eha design --around and --name


SMALL_SEARCH = ("--faults", "none", "--duration", "0.2", "--population", "4", "--generations",
                "1", "--actuators", "1")


def explain_doc(value=829.0, rival=-0.009):
    return {"steps": [{"effect": "external_load", "params": {"FRC": value}}],
            "not_excluded": [{"effect": "offset", "param": "Ofs", "value": rival}]}


@pytest.mark.parametrize("doc, message", [
    ({"steps": [{"effect": "external_load", "params": [1, 2]}]}, "steps[0].params: an object"),
    ({"steps": [], "not_excluded": 5}, "not_excluded: a list of effects expected"),
    (explain_doc(float("nan")), "steps[0].params.FRC = nan: allowed a number in [-8000, 8000]"),
    (explain_doc(float("inf")), "steps[0].params.FRC = inf"),
    (explain_doc(1e300), "steps[0].params.FRC = 1e+300"),
    (explain_doc(True), "steps[0].params.FRC = True"),
    (explain_doc(0), "steps[0].params.FRC = 0: allowed a number in [-8000, 8000] other than "
                     "the effect's off value 0"),
    (explain_doc(rival=float("-inf")), "not_excluded[0].value = -inf"),
])
def test_an_around_json_of_the_wrong_shape_or_value_is_one_line_exit_2(tmp_path, doc, message):
    path = tmp_path / "explain.json"
    path.write_text(json.dumps(doc))          # NaN and Infinity as Python's json writes them
    out = tmp_path / "out"
    # a small search: before the fix the values were accepted and the search ran
    proc = invoke_eha("design", "--around", path, "--out", out, *SMALL_SEARCH)
    assert message in error_line(proc, 2)
    assert files_under(out) == []


def test_an_over_long_name_is_refused_before_the_search(tmp_path):
    t0 = time.perf_counter()
    proc = invoke_eha("design", "--name", "n" * 300, "--out", tmp_path / "out", *SMALL_SEARCH)
    assert "--name: 300 bytes; allowed at most 200" in error_line(proc, 2)
    assert proc.stdout == "" and time.perf_counter() - t0 < 5


# -- writers


def test_temporary_names_are_unique_per_writer(tmp_path):
    from eha.outputs import temp_beside

    dest = tmp_path / "design.json"
    names = {temp_beside(dest, ".part.json") for _ in range(20)}
    assert len(names) == 20 and all(f".design.json.eha-{os.getpid()}-" in n.name for n in names)


def test_a_set_is_replaced_all_or_none(tmp_path):
    from eha.outputs import atomic_set

    paths = [tmp_path / "d.csv", tmp_path / "d.json", tmp_path / "d.png"]
    for p in paths[:2]:
        p.write_text("old")
    paths[2].mkdir()                              # the PNG cannot be replaced
    with pytest.raises(OutputError, match="d.png: could not be written .it is a folder.; "
                                          "none of d.csv, d.json, d.png was replaced"):
        with atomic_set(paths) as tmps:
            for t in tmps:
                t.write_text("new")
    assert [p.read_text() for p in paths[:2]] == ["old", "old"]
    assert sorted(f.name for f in tmp_path.iterdir()) == ["d.csv", "d.json", "d.png"]
    with pytest.raises(RuntimeError):             # a failure while writing: none replaced
        with atomic_set(paths[:2]) as tmps:
            tmps[0].write_text("new")
            raise RuntimeError("figure failed")
    assert [p.read_text() for p in paths[:2]] == ["old", "old"]
    assert sorted(f.name for f in tmp_path.iterdir()) == ["d.csv", "d.json", "d.png"]


def test_two_writers_of_one_set_never_leave_files_of_both(tmp_path):
    """The audit: two `eha design` runs on one --out, 20 rounds; design.csv of seed 17 beside
    design.json of seed 16, both exiting 0."""
    from eha.outputs import atomic_set

    paths = [tmp_path / "design.csv", tmp_path / "design.json", tmp_path / "design.png"]
    errors = []

    def write(seed: int, start: threading.Barrier) -> None:
        try:
            with atomic_set(paths) as tmps:
                start.wait()
                for i, t in enumerate(tmps):
                    t.write_text(str(seed))
                    time.sleep(0.002 * ((seed + i) % 3))
        except Exception as exc:  # collected: a thread's failure fails the test
            errors.append(exc)

    for round_ in range(20):
        start = threading.Barrier(2)
        threads = [threading.Thread(target=write, args=(2 * round_ + k, start))
                   for k in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert errors == []
        assert len({p.read_text() for p in paths}) == 1, round_
    assert sorted(f.name for f in tmp_path.iterdir()) == sorted(p.name for p in paths)


def test_a_command_file_is_written_under_a_name_of_its_own(tmp_path):
    """write_command_file used the fixed name .NAME.tmp that two writers shared."""
    dest = tmp_path / "c.csv"
    fixed = tmp_path / ".c.csv.tmp"
    fixed.mkdir()            # the fixed name taken: the write used to fail
    t = np.array([0.0, 0.1])
    write_command_file(dest, t, np.zeros(2))
    assert load_command_file(str(dest)).samples[0].tolist() == [0.0, 0.1]


# -- campaign verify --repair with a command file


@pytest.mark.slow
def test_verify_repairs_a_campaign_with_a_command_file_from_another_folder(tmp_path,
                                                                          monkeypatch):
    from eha.campaigns.query import query
    from eha.campaigns.runner import run_campaign, verify_results

    work = tmp_path / "work"
    work.mkdir()
    (work / "probe.csv").write_text(command_text())
    write_campaign(work, """
        name = "probe"
        models = ["lf"]
        commands = ["probe.csv"]
        seeds = [0, 1]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    monkeypatch.chdir(work)                       # the file is named relative to here
    assert run_campaign(Path("campaign.toml"), "results", executor=Inline(),
                        progress=False).done == 2
    results = work / "results"
    stored = json.loads(query(results, "SELECT definition FROM campaigns")["definition"][0])
    assert stored["commands"][0].startswith(str(work / "probe.csv") + "#sha=")
    before = query(results, "SELECT * FROM traces ORDER BY run_key, t")
    victim = next((results / "traces" / "probe").glob("*.parquet"))
    with open(victim, "r+b") as fh:
        fh.seek(200)
        b = fh.read(1)[0] ^ 0x80
        fh.seek(200)
        fh.write(bytes([b]))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    v = verify_results(results, repair=True, workers=1)
    assert v.repaired == {"probe": 1}
    assert verify_results(results).damaged == {}
    assert query(results, "SELECT * FROM traces ORDER BY run_key, t").equals(before)
    # the file edited since: one line that names the command that runs it again
    with open(work / "probe.csv", "a") as fh:
        fh.write("0.300000,0\n")
    with open(victim, "r+b") as fh:
        fh.seek(200)
        fh.write(b"\x00\x01")
    proc = invoke_eha("campaign", "verify", "--repair", "--results", results)
    line = error_line(proc, 2)
    assert "changed since it was pinned" in line and "eha campaign run FILE" in line
    assert "verify --replace" not in line


# -- a results folder that cannot work


def test_a_traces_file_in_place_of_the_folder_is_one_line_before_any_run(tmp_path):
    """It printed a `failed:` line per run (540)."""
    camp = write_campaign(tmp_path, """
        name = "tf"
        models = ["lf"]
        commands = ["step_1mm"]
        seeds = [0, 1, 2]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    results = tmp_path / "results"
    results.mkdir()
    (results / "traces").write_text("")
    proc = invoke_eha("campaign", "run", camp, "--results", results, "--workers", "1",
                      "--no-progress")
    assert "traces: a file, not the folder of the traces" in error_line(proc, 2)
    assert sorted(p.name for p in results.iterdir()) == ["traces"]


def test_an_unreachable_scheduler_creates_nothing(tmp_path):
    import socket

    with socket.socket() as s:          # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    camp = write_campaign(tmp_path, """
        name = "sc"
        models = ["lf"]
        commands = ["step_1mm"]
        t_end = 0.05
        [faults]
        nominal = true
    """)
    results = tmp_path / "results"
    proc = invoke_eha("campaign", "run", camp, "--results", results, "--scheduler",
                      f"tcp://127.0.0.1:{port}")
    assert f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}" in error_line(proc, 1)
    assert not results.exists()


@pytest.mark.parametrize("eol", ["NaN", "Infinity", "true", "-1", "1e999", "\"12\""])
def test_a_truth_file_with_an_impossible_end_of_life_is_refused(tmp_path, eol):
    """An invalid --truth was ignored or taken as a number, exit 0."""
    from eha.prognostics.degradation import PrognosticsError
    from eha.prognostics.jobs import load_truth

    path = tmp_path / "truth.json"
    path.write_text('{"actuators": {"A1": {"eol": 3.5}, "A2": {"eol": %s}}}' % eol)
    with pytest.raises(PrognosticsError, match="actuator A2: eol .*; allowed a finite number"):
        load_truth(path)
    csv = tmp_path / "truth.csv"
    if eol in ("Infinity", "-1", "1e999"):
        csv.write_text(f"actuator,eol\nA1,3.5\nA2,{eol}\n")
        with pytest.raises(PrognosticsError, match="actuator A2"):
            load_truth(csv)
    path.write_text('{"actuators": {"A1": {"eol": 3.5}, "A2": {"eol": null}}}')
    assert load_truth(path) == {"A1": 3.5, "A2": None}


def test_a_design_whose_png_is_a_folder_replaces_none_of_its_files(tmp_path):
    """design.csv and design.json were replaced, and the message said they were left."""
    from eha.design import Limits, design

    result = design(faults=["Ofs"], limits=Limits(duration=0.2, max_stroke=5e-3), seed=1,
                    population=4, generations=1, actuators=1)
    (tmp_path / "design.csv").write_text("old csv")
    (tmp_path / "design.json").write_text("old json")
    (tmp_path / "design.png").mkdir()
    with pytest.raises(OutputError, match="design.png: could not be written .it is a folder.; "
                                          "none of design.csv, design.json, design.png"):
        result.save(tmp_path)
    assert (tmp_path / "design.csv").read_text() == "old csv"
    assert (tmp_path / "design.json").read_text() == "old json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["design.csv", "design.json",
                                                          "design.png"]
    (tmp_path / "design.png").rmdir()
    paths = result.save(tmp_path)
    assert json.loads(paths["json"].read_text())["settings"]["seed"] == 1
    assert load_command_file(str(paths["command"])).samples[1].size > 10
