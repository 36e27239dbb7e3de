"""Test design: ``eha design`` (the command that shows the chosen faults and effects, predicted)
and ``eha design verify`` (measured by a simulated detection campaign).

The design stack (numba kernels, pymoo) is imported inside the commands.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from eha.cli import defaults
from eha.cli.guard import console, fail
from eha.outputs import write_atomic
from eha.cli.options import (RESULTS, WORKERS, ResultsOption, WorkersOption, check_out_dir,
                             check_seed, print_paths, split_names)

design_app = typer.Typer(invoke_without_command=True, no_args_is_help=False)

#: Library keyword -> command-line option, for one-line errors in the user's words.
_FLAGS = {"duration=": "--duration ", "max_stroke=": "--max-stroke ",
          "max_rate=": "--max-rate ", "max_freq=": "--max-freq ", "alpha=": "--alpha ",
          "sampling=": "--sampling ", "actuators=": "--actuators ", "seed=": "--seed ",
          "population=": "--population ", "generations=": "--generations ",
          "faults:": "--faults:", "effects:": "--effects:", "separate:": "--separate:",
          "signals:": "--signals:", "around:": "--around:", "noise.xu=": "--noise ",
          "noise.p12=": "--noise-p12 ", "calibration=": "--calibration ",
          "check=": "--check "}


def _flags(message: str) -> str:
    for key, flag in _FLAGS.items():
        if message.startswith(key):
            return flag + message[len(key):]
    return message


# ---- the options, at module level so that the command stays short
_FAULTS = typer.Option("all", "--faults", help="Health faults to detect, comma-"
                       "separated (eha faults), 'all' or 'none'.")
_EFFECTS = typer.Option("", "--effects", help="Effects of the residual loop to "
                        "detect, comma-separated (docs/model.md section 6).")
_SEPARATE = typer.Option([], "--separate", help="A pair to tell apart, A,B "
                         "(faults or effects; repeatable).")
_AROUND = typer.Option(None, "--around", help="An eha explain JSON: tell "
                       "its effects from the rivals it could not rule "
                       "out, at their fitted values.")
_DURATION = typer.Option(1.0, "--duration", help="Test length in s, 0.2 to 10.")
_MAX_STROKE = typer.Option(0.01, "--max-stroke", help="Largest command away from "
                           "zero in m, 1e-4 to 0.2.")
_MAX_RATE = typer.Option(0.1, "--max-rate", help="Largest command rate the servo "
                         "loop follows in m/s, 1e-4 to 1.")
_MAX_FREQ = typer.Option(20.0, "--max-freq", help="Highest frequency in the "
                         "command in Hz, 1 to 100.")
_SIGNALS = typer.Option("xu", "--signals", help="Recorded signals: xu, or xu with "
                        "p12 (load pressure) and cor (motor current).")
_SAMPLING = typer.Option(1000.0, "--sampling", help="Recorded sampling in Hz, a "
                         "divisor of 1000.")
_NOISE = typer.Option(1e-6, "--noise", help="Position sensor noise std in m.")
_NOISE_P12 = typer.Option(..., "--noise-p12", default_factory=defaults.noise_p12,
                          help="Load-pressure sensor noise std in Pa (with --signals xu,p12).")
_ALPHA = typer.Option(0.01, "--alpha", help="False-alarm probability of one "
                      "check, in (0, 0.5).")
_SEED = typer.Option(0, "--seed", help="Search seed (the same seed, the same "
                     "command).")
_ACTUATORS = typer.Option(3, "--actuators", help="Actuators the design must work "
                          "on: the nominal and scattered ones, 1 to 10.")
_GENERATIONS = typer.Option(30, "--generations", help="Search generations, 1 to "
                            "500.")
_POPULATION = typer.Option(32, "--population", help="Search population, 4 to 500.")
_OUT = typer.Option(Path("results/design"), "--out", help="Folder of the command "
                    "file, JSON report and figure.")
#: Longest --name [bytes, UTF-8]: a file name holds 255, the temporary name of NAME.json
#: (.NAME.json.eha-PID-RANDOM.part.json) about 40 more.
MAX_NAME_BYTES = 200
_NAME = typer.Option("design", "--name", help="Base name of the files written.")
_CHECK = typer.Option("fleet", "--check", help="The health check the test is for: fleet "
                      "(against a healthy fleet) or baseline (the change since the "
                      "actuator's own earlier record, eha health check --baseline).")
_RESULTS_TO = typer.Option(None, "--results", help="Also store the design in this results "
                          "folder's database (table design_runs; eha report html shows it).")


@design_app.callback()
def design(
    ctx: typer.Context,
    faults: str = _FAULTS,
    effects: str = _EFFECTS,
    separate: List[str] = _SEPARATE,
    around: Optional[Path] = _AROUND,
    duration: float = _DURATION,
    max_stroke: float = _MAX_STROKE,
    max_rate: float = _MAX_RATE,
    max_freq: float = _MAX_FREQ,
    signals: str = _SIGNALS,
    sampling: float = _SAMPLING,
    noise: float = _NOISE,
    noise_p12: float = _NOISE_P12,
    alpha: float = _ALPHA,
    seed: int = _SEED,
    actuators: int = _ACTUATORS,
    generations: int = _GENERATIONS,
    population: int = _POPULATION,
    out: Path = _OUT,
    name: str = _NAME,
    check: str = _CHECK,
    results: Optional[Path] = _RESULTS_TO,
):
    """Design a test command: within the test's limits, the command on which the chosen
    faults are detectable at the smallest sizes and the pairs told apart, predicted from the
    HF model's signatures against a healthy fleet's scatter, the dither, the sensor noise and
    the check's own model-form error (docs/design.md).

    Writes NAME.csv (the command: t,com in SI, usable wherever a command is named), NAME.json
    and NAME.png; prints per target the predicted minimum detectable size next to the library
    commands', or why it is not detectable and what would make it so.

    Example: eha design --duration 1 --max-stroke 0.01 --alpha 0.01

    Example: eha design --faults none --separate external_load,offset --around explain.json
    """
    if ctx.invoked_subcommand is not None:
        return
    from eha.design import DesignError, Limits, design as run_design

    _check_outputs(seed, out, name, results)
    pairs = [tuple(split_names(p)) for p in separate]
    try:
        around_values = _around(around, pairs)
        fault_list = None if faults == "all" else [] if faults == "none" else split_names(faults)
        result = run_design(
            faults=fault_list, effects=split_names(effects), separate=pairs,
            around=around_values, limits=Limits(duration, max_stroke, max_rate, max_freq),
            signals=split_names(signals), sampling=sampling,
            noise={"xu": noise, "p12": noise_p12} if "p12" in signals else {"xu": noise},
            alpha=alpha, seed=seed, actuators=actuators, population=population,
            generations=generations, check=check,
            on_progress=lambda m: console.print(m, highlight=False))
    except DesignError as exc:
        fail(_flags(str(exc)))
    _show(result)
    _save(result, out, name, results)


def _check_outputs(seed: int, out: Path, name: str, results: Optional[Path]) -> None:
    """Before any work: the seed, the output folders and the base name of the files."""
    check_seed(seed)
    check_out_dir(out, "--out")
    check_out_dir(results, "--results")
    _check_name(name)


def _save(result, out: Path, name: str, results: Optional[Path]) -> None:
    """The command file, JSON and figure; with ``--results``, the design's row there."""
    paths = result.save(out, name)
    print_paths(paths)
    if results is not None:
        from eha.design.runs import save_design_run

        db, run_id = save_design_run(results, result, paths, name)
        console.print(f"database: {db} (design_runs, run {run_id})", highlight=False)


def _check_name(name: str) -> None:
    """--name: a plain file name, short enough for its files' temporary names; refused before
    the search, not after it."""
    if not name or any(c in name for c in "/\\") or name.startswith("."):
        fail(f"--name {name!r}: a plain file name without folders")
    if len(name.encode("utf-8")) > MAX_NAME_BYTES:
        fail(f"--name: {len(name.encode('utf-8'))} bytes; allowed at most {MAX_NAME_BYTES} "
             "(the file names NAME.csv, NAME.json, NAME.png and their temporary names)")


def _around(path: Optional[Path], pairs: list) -> Optional[dict]:
    """The sizes to design at from an explain JSON (``--around``); its pairs added."""
    from eha.design.targets import from_explain

    if path is None:
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):  # e.g. 100 000 [
        fail(f"--around {path}: not a readable eha explain JSON")
    more, values = from_explain(doc)
    # a pair the user named too is one pair (its block was printed twice)
    pairs += [p for p in more if tuple(p) not in {tuple(q) for q in pairs}
              and tuple(reversed(tuple(p))) not in {tuple(q) for q in pairs}]
    return values


def _show(result) -> None:
    """The finding first: how many targets the design shows and how it compares, then the
    table."""
    shown = [t for t in result.targets if result.prediction.detectable(t)]
    better = [t for t in shown if result.ratio(t.name) <= 0.5]
    console.print(f"designed a {result.settings['duration']:g} s command: {len(shown)} of "
                  f"{len(result.targets)} targets detectable, {len(better)} at half the best "
                  f"library command's size or less (predicted; eha design verify measures "
                  f"it); {result.seconds:.0f} s", highlight=False)
    table = Table("target", "design", "best library command", "ratio")
    best = result.best_library()
    for t in result.targets:
        lib, ref = best[t.name]
        size = result.prediction.mds[t.name]
        shown = t.shown(size) if result.prediction.detectable(t) else "not detectable"
        on_library = f"{t.shown(ref)} ({lib})" if ref < t.limit else "not detectable"
        table.add_row(t.name, shown, on_library, f"{result.ratio(t.name):.2f}")
    console.print(table)
    from eha.design.headlines import beyond_limits_lines

    for line in beyond_limits_lines(result):
        console.print(line, highlight=False)
    if result.settings.get("check") == "baseline":
        console.print("for the change check (each actuator against its own earlier record); "
                      f"chosen: {result.settings['chosen']}", highlight=False)
    else:
        console.print(_followed_line(result.prediction), highlight=False)
    for t in result.targets:
        if not result.prediction.detectable(t):
            console.print(f"{t.name}: {result.verdict(t)}", highlight=False)
    by = {t.name: t for t in result.targets}
    for row in result.pairs():
        f, g = row["pair"]
        sep = result.prediction.separable
        ratio = [f"{n} from {sep[n][m]:.2g}x its detectable size" if math.isfinite(sep[n][m])
                 else f"{n} never" for n, m in ((f, g), (g, f))]
        console.print(f"{f} vs {g}: told apart: {', '.join(ratio)}", highlight=False)
        for how, sizes in row["alternatives"].items():
            shown = [f"{n} from {by[n].shown(v)}" if v is not None else f"{n} never"
                     for n, v in sizes.items()]
            console.print(f"  with {how}: {', '.join(shown)}", highlight=False)


def _followed_line(prediction) -> str:
    """How closely the check's LF model follows the design: its healthy model-form residual
    against the ratio beyond which a command counts as not followed. A design near that
    limit is one whose promise rests on an LF that barely follows it (docs/design.md: the
    sensor gain / hinge moment separation lives there)."""
    from eha.design.predict import FOLLOW_RATIO

    state = "follows" if prediction.followed else "does not follow"
    return (f"the check's LF {state} it: {prediction.model_form:.1f} noise stds of model-form "
            f"residual on healthy actuators (not followed beyond {FOLLOW_RATIO:g})")


@design_app.command("verify")
def verify(
    design_json: Path = typer.Argument(..., help="The design's JSON report (eha design)."),
    command_file: Optional[Path] = typer.Option(None, "--command", help="Its command file "
                                                "(default: the .csv beside the JSON)."),
    library: str = typer.Option("chirp_1cm,mixed", "--library", help="Library commands run "
                                "on the same fleets, comma-separated."),
    healthy: int = typer.Option(230, "--healthy", help="Healthy actuators per command: the "
                                "first --calibration set the thresholds, the rest measure "
                                "false alarms."),
    calibration: int = typer.Option(30, "--calibration", help="Healthy actuators that set "
                                    "the thresholds."),
    per_level: int = typer.Option(10, "--per-level", help="Actuators per fault level."),
    with_design: bool = typer.Option(True, "--with-design/--library-only", help="Run the "
                                     "design's command too, or the library commands alone "
                                     "(another fleet size)."),
    seed: int = typer.Option(0, "--seed", help="First actuator seed."),
    results: ResultsOption = RESULTS,
    workers: WorkersOption = WORKERS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Verify a design by simulation: a health-detection campaign on the designed command and
    the library commands (the same fleets and alpha), through the campaign runner
    (resumable). Measures per fault the minimum detectable size (P_D >= 0.95), isolation,
    and the false-alarm rate on healthy actuators not used to calibrate, with its 95 % bound.

    Example: eha design verify results/design/design.json --healthy 230 --per-level 10
    """
    from eha.design import DesignError
    from eha.design.verify import verify as run_verify

    check_seed(seed)
    try:
        v = run_verify(design_json, command_file, split_names(library), healthy, calibration,
                       per_level, results, workers, progress, seed, with_design)
    except DesignError as exc:
        fail(_flags(str(exc)))
    out = design_json.with_name(design_json.stem + ("-verification.json" if with_design
                                                    else "-library-verification.json"))
    v.save(out)
    md = out.with_suffix(".md")
    write_atomic(md, v.markdown())
    from eha.design.headlines import verification_headline

    for line in verification_headline(v):
        console.print(line, highlight=False)
    console.print(v.markdown(), highlight=False)
    print_paths({"json": out, "table": md})
