"""The residual loop: ``eha explain`` (trace a measured record's residual to missing LF
effects).

The loop's settings are checked in one place, :class:`eha.explain.settings.LoopSettings`:
the command builds one and the guard prints its problems (``--min-gain nan: allowed range
[0, 1]``). The loop's stack (numba kernels, the optimizers) is imported inside the command:
``eha query`` and ``eha --help`` must not pay for it.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from eha.cli.guard import console, err_console, fail, keywords_as
from eha.cli import defaults
from eha.cli.options import (COMMAND_HOLD, RESULTS, ColumnsOption, CommandHoldOption,
                             ResultsOption, UnitsOption, check_out_dir, check_out_file,
                             check_seed, print_paths, record_file)


_setting = defaults.loop_setting


# ---- the options, at module level so that the command stays short
DATA = typer.Argument(..., help="Measured record: CSV/TSV/Parquet with t, com, xu (SI; aliases "
                      "in docs/explain.md, or see --columns, --units), optional p12, xs.")
FIT = typer.Option(..., "--fit", default_factory=defaults.fit_faults,
                   help="Declared faults to fit: NAME or NAME=LO:HI, comma-separated.")
EFFECTS = typer.Option(None, "--effects", help="Candidate effects, comma-separated names of "
                       "docs/model.md's effect table (default: all 14).")
HOLDOUT = typer.Option(None, "--holdout", help="Fraction of the record held out at its end "
                       "for scoring (default 0.3).")
VALIDATE = typer.Option(None, "--validate", help="Second record used as held-out data "
                        "instead of --holdout.")
PRIOR = typer.Option(None, "--prior", help="--json of an earlier run: its effects start "
                     "switched on (e.g. from nominal data). When it lists rivals it could not "
                     "rule out, this record first settles which explanation stands.")
KNOWN = typer.Option([], "--set", help="Known LF parameter held fixed, NAME=VALUE, repeatable "
                     "(a test condition, e.g. a test load FRC=4000).")
JSON_OUT = typer.Option(None, "--json", help="Write rmse_before/after, faults_before/after "
                        "and the steps as JSON.")
OUT = typer.Option(None, "--out", help="Output folder (default RESULTS/explain/<file stem>).")
METHOD = typer.Option(..., "--method", default_factory=_setting("method", str),
                      help="Optimizer of every fit (eha fdi).")
POP = typer.Option(..., "--pop", default_factory=_setting("pop", int),
                   help="GA population of every fit.")
SEED = typer.Option(0, "--seed", help="Optimizer seed (same seed, same result).")
CANDIDATES = typer.Option(..., "--candidates", default_factory=_setting("candidates", int),
                          help="Effects refitted per round, the best-ranked by signature "
                          "(0 = all).")
MAX_STEPS = typer.Option(..., "--max-steps", default_factory=_setting("max_steps", int),
                         help="Most effects added.")
MIN_GAIN = typer.Option(..., "--min-gain", default_factory=_setting("min_gain"),
                        help="Smallest penalised held-out RMSE reduction that adds an effect.")
P12_WEIGHT = typer.Option(
    ..., "--p12-weight", default_factory=_setting("p12_weight"),
    help="Weight of the record's measured P12 in every fit and score, each signal in its own "
         "noise (0 = position only; records without P12 use the position only).")
FLOW_GAIN_SPREAD = typer.Option(
    ..., "--flow-gain-spread", default_factory=_setting("flow_gain_spread"),
    help="Fit the valve flow gain GQ with the faults within +- this fraction of nominal (the "
         "healthy actuator's own spread; 0 = held at nominal). E.g. 0.1.")
ALPHA = typer.Option(
    ..., "--alpha", default_factory=_setting("alpha"),
    help="False-positive level per record: the chance that a healthy actuator driven by this "
         "command gets an effect added (thresholds from a healthy null).")
HEALTHY = typer.Option(None, "--healthy", help="Folder of healthy records of your own actuators "
                       "(commissioning tests, >= 5): the null instead of a simulated healthy "
                       "fleet.")
NULL_ACTUATORS = typer.Option(
    ..., "--null-actuators", default_factory=_setting("null_actuators", int),
    help="Healthy actuators of the simulated null (cached per command, sampling, noise).")
INTERVAL_REPLICATES = typer.Option(
    ..., "--interval-replicates", default_factory=_setting("interval_replicates", int),
    help="HF re-simulations of the final model whose refits' spread widens the intervals of "
         "the effects found, 0 to 100 (0: none).")
RIVAL_REPLICATES = typer.Option(
    ..., "--rival-replicates", default_factory=_setting("rival_replicates", int),
    help="HF re-simulations of the final model without and with each rival the record cannot "
         "rule out, which rule it out when it reads only the model's own model form, 0 to 100 "
         "(0: none).")
PROGRESS = typer.Option(True, "--progress/--no-progress", help="Progress display.")


@keywords_as(fixed="--set", null="--healthy")
def explain(data: Path = DATA, fit: str = FIT, effects: Optional[str] = EFFECTS,
            holdout: Optional[float] = HOLDOUT, validate: Optional[Path] = VALIDATE,
            prior: Optional[Path] = PRIOR, known: List[str] = KNOWN,
            json_out: Optional[Path] = JSON_OUT, out: Optional[Path] = OUT,
            results: ResultsOption = RESULTS, method: str = METHOD, pop: int = POP,
            seed: int = SEED, candidates: int = CANDIDATES, max_steps: int = MAX_STEPS,
            min_gain: float = MIN_GAIN, p12_weight: float = P12_WEIGHT,
            flow_gain_spread: float = FLOW_GAIN_SPREAD, alpha: float = ALPHA,
            healthy: Optional[Path] = HEALTHY, null_actuators: int = NULL_ACTUATORS,
            interval_replicates: int = INTERVAL_REPLICATES,
            rival_replicates: int = RIVAL_REPLICATES,
            command_hold: CommandHoldOption = COMMAND_HOLD, columns: ColumnsOption = None,
            units: UnitsOption = None, progress: bool = PROGRESS):
    """Trace a measured record's residual to missing LF effects, add them, report the error.

    --columns and --units apply to the record, to --validate and to the --healthy records.

    Example: eha explain data/run1.csv --fit BKL,FDJ --holdout 0.3 --json out.json

    Example (healthy actuator under a known 4 kN test load): eha explain loadtest.csv --set
    FRC=4000 --json calibration.json
    """
    from eha.campaigns.store import StoreError
    from eha.explain.from_file import explain_file
    from eha.explain.settings import LoopSettings

    if holdout is not None and validate is not None:
        fail("--holdout and --validate exclude each other; give one")
    check_out_file(json_out, "--json", (".json",))
    check_out_dir(results, "--results")
    folder = out if out is not None else results / "explain" / data.stem
    check_out_dir(folder, "--out")
    check_seed(seed)
    # the one settings object the library reads (checked there: a bad value exits 2)
    settings = LoopSettings().override(dict(
        holdout=holdout, min_gain=min_gain, alpha=alpha, null_actuators=null_actuators,
        interval_replicates=interval_replicates, rival_replicates=rival_replicates,
        max_steps=max_steps, candidates=candidates, p12_weight=p12_weight,
        flow_gain_spread=flow_gain_spread, method=method, pop=pop, seed=seed))
    record = record_file(data, columns, units)
    with _progress_bar(progress) as step:
        res = explain_file(
            record, settings, fit=fit, effects=effects,
            validate=validate and record.at(validate), prior=prior, known=known,
            command_hold=command_hold, on_progress=step,
            null=record.at(healthy) if healthy is not None else "simulate")
    paths = res.save(folder, json_out)
    try:
        paths["database"] = res.store(results)
    except StoreError as exc:
        db_error = str(exc)
    else:
        db_error = None
    _render(res)
    _next_test(res, json_out)
    print_paths(paths)
    if db_error:
        fail(f"results database not written: {db_error}", code=1)

def _next_test(res, json_out: Optional[Path]) -> None:
    """Rivals ruled out by re-simulation, with the figures; rivals the record could not rule
    out: the command that designs the test deciding it (docs/design.md)."""
    for e in res.rivals_ruled_out:
        c, unit = e["rival_check"], e.get("value_unit", e["unit"])
        if "first_record" in e:
            first = e["first_record"]
            console.print(f"{e['effect']} beside the model: not shown by this command (with "
                          f"{c['size']:+.3g} {unit} of it the reading moves from "
                          f"{c['without'][0]:.3g} to {c['with'][0]:.3g}); the first record "
                          f"excludes it beyond a change of {first['beyond']:.3g} "
                          f"{first.get('unit', unit)} in {first.get('param', e['param'])}",
                          highlight=False)
            continue
        console.print(f"{e['effect']} beside the model: ruled out by re-simulation (the record "
                      f"reads {e['param']} {c['record']:.3g} {unit}, the model alone "
                      f"{c['without'][0]:.3g} ± {c['without'][1]:.2g}; with "
                      f"{c['size']:+.3g} {unit} of it {c['with'][0]:.3g} ± "
                      f"{c['with'][1]:.2g})", highlight=False)
    if not res.not_excluded:
        return
    rivals = ", ".join(f"{e['effect']} ({e['param']} {e['value']:.3g} "
                       f"{e.get('value_unit', e['unit'])})" for e in res.not_excluded)
    around = str(json_out) if json_out is not None else "OUT.json (rerun with --json OUT.json)"
    console.print(f"to decide between the model and {rivals}: design the separating "
                  f"test with: eha design --faults none --around {around}; then explain its "
                  f"record with: eha explain TEST.csv --prior {around}", highlight=False)


#: Off a terminal, at most one progress line per this many seconds [s] (a log stays short).
LINE_EVERY_S = 5.0


class _progress_bar:
    """A transient spinner on stderr counting the fits; yields the ``on_progress`` callback.

    Off a terminal (stderr to a file or a pipe) a spinner shows nothing, and the loop can run
    minutes (the healthy null of a new command): there, each new phase is a line on stderr
    instead, at most one per :data:`LINE_EVERY_S`."""

    def __init__(self, enabled: bool):
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self.lines = enabled and not err_console.is_terminal
        self.bar = Progress(SpinnerColumn(), TextColumn("{task.description}"),
                            TextColumn("[dim]fits done: {task.completed}"), TimeElapsedColumn(),
                            console=err_console, disable=not enabled or self.lines,
                            transient=True)
        self.last, self.printed = "", -math.inf

    def _line(self, message: str) -> None:
        now = time.monotonic()
        if message != self.last and now - self.printed >= LINE_EVERY_S:
            err_console.print(f"{message} ...", highlight=False, markup=False, soft_wrap=True)
            self.last, self.printed = message, now

    def __enter__(self):
        self.bar.__enter__()
        if self.lines:
            self.printed = time.monotonic()  # a quick error (bad input) stays one line
            return self._line
        self.task = self.bar.add_task("reading the record, loading the models", total=None)
        return lambda message: self.bar.update(self.task, description=message, advance=1)

    def __exit__(self, *exc):
        if not self.lines and not self.bar.disable:
            # the spinner drawn away before it stops: rich ends a drawn line with a newline
            # it then moves back over, an empty line above the error where a terminal (or
            # its log) does not move the cursor
            self.bar.update(self.task, visible=False)
            self.bar.refresh()
        return self.bar.__exit__(*exc)


def _render(res) -> None:
    """The steps table, the notes, the verdict (what was found first, then what the record
    cannot rule out, then what it could not have shown, folded to one line)."""
    from eha.explain.verdict import structure_note, unseen_summary
    from eha.models.units import show, show_interval

    console.print(f"record: {res.source} ({len(res.t)} samples at 1 kHz); held "
                  f"out: {res.holdout}", highlight=False)
    if res.settled:
        # the question the prior brought is this record's first finding
        console.print(f"the first record's rivals, on this one: {res.settled['text']}",
                      highlight=False)
    console.print(_steps_table(res))
    console.print(_symbols(res), highlight=False)
    note = structure_note(res)
    for line in ([note] if note else []) + _notes(res):
        console.print(line, highlight=False)
    console.print(f"RMSE {1e6 * res.rmse_before:.3g} → {1e6 * res.rmse_after:.3g} µm; noise "
                  f"level {1e6 * res.noise_rmse:.3g} µm; above the noise "
                  f"{1e6 * res.unexplained_rmse:.3g} µm. Stopped: {res.stop_reason}",
                  highlight=False)
    if res.intervals:
        flow = "GQ" in res.intervals and res.facts.flow_gain_fitted
        console.print(f"final model, {100 * res.level:g} % intervals: " + "; ".join(
            f"{k} {show(k, getattr(res.after.params, k))} {show_interval(k, lo, hi)}"
            + (" (valve flow gain, fitted within a healthy spread)" if k == "GQ" and flow
               else "")
            for k, (lo, hi) in res.intervals.items()), highlight=False)
    facts = res.verdict_facts
    console.print(f"verdict ({facts.kind}): {facts.finding}", highlight=False)
    for rival in facts.rivals:
        console.print(f"  cannot be told apart on this command from {rival}",
                      highlight=False)
    if res.null:
        lines = res.undetectable()
        if lines:
            console.print("  " + unseen_summary(lines), highlight=False)
        console.print(f"  decisions at alpha {res.null['alpha']:g} against "
                      f"{res.null['source']} on this command", highlight=False)
    _warn(res)


def _warn(res) -> None:
    """A warning on stderr when the verdict is not a clean one."""
    if res.beyond_healthy:
        err_console.print("warning: the residual after the best library model is still well "
                          "above the noise: unexplained; the fault intervals are widened, "
                          "do not read the estimates as numbers", highlight=False)
    elif res.not_excluded:
        leaves = ("only what it leaves on HF re-simulations of itself"
                  if (res.model_level or {}).get("explains") else "only noise")
        err_console.print(f"warning: the model leaves {leaves}, but the record cannot rule "
                          "out " + ", ".join(e["effect"] for e in res.not_excluded) +
                          ": an alternative explanation, not a confident one", highlight=False)
    elif res.unexplained:
        err_console.print("warning: the residual is above the noise level: the effects added "
                          "are tentative, and an effect below this command's healthy band may "
                          "be missing", highlight=False)


def _symbols(res) -> str:
    """What the table's parameter symbols are (``SNF: flapper natural frequency``, ...) and
    what "(structure)" means: the table names parameters by their symbols only."""
    from eha.explain.settings import STRUCTURAL
    from eha.models.params import SPECS

    names = dict.fromkeys([*res.faults_before, *(k for s in res.steps
                                                  for k in res.final_params(s))])
    said = [f"{k} {SPECS[k].description.split(' (')[0]}" for k in names if k in SPECS]
    if any(s.effect in STRUCTURAL for s in res.steps):
        said.append("(structure): what the LF model lacks on any actuator, not a finding")
    return "symbols: " + "; ".join(said) if said else ""


def _steps_table(res) -> Table:
    """Readable at 80 columns: the effect's name whole, parameters in display units, the
    RMSE before→after of each part; the faults go in the final model's line."""
    from rich import box

    from eha.explain.settings import STRUCTURAL
    from eha.models.units import show

    table = Table("#", "effect", "parameters", "fit µm", "held-out µm", "all µm",
                  box=box.SIMPLE_HEAD, pad_edge=False)
    table.columns[1].overflow = "fold"
    table.columns[1].min_width = 11
    table.add_row("0", "declared faults", ", ".join(
        f"{k} {show(k, v)}" for k, v in res.faults_before.items()) or "-",
        f"{1e6 * res.before.rmse_fit:.3g}", f"{1e6 * res.before.rmse_hold:.3g}",
        f"{1e6 * res.rmse_before:.3g}")
    for i, s in enumerate(res.steps):
        params = ", ".join(f"{k} {show(k, v)}" for k, v in res.final_params(s).items())
        if s.effect in STRUCTURAL:
            params = (params + " " if params else "") + "(structure)"
        table.add_row(str(i + 1), s.effect, params or "-",
                      f"{1e6 * s.rmse_fit_before:.3g}→{1e6 * s.rmse_fit_after:.3g}",
                      f"{1e6 * s.rmse_hold_before:.3g}→{1e6 * s.rmse_hold_after:.3g}",
                      f"{1e6 * s.rmse_before:.3g}→{1e6 * s.rmse_after:.3g}")
    return table


def _notes(res) -> list[str]:
    """Lines on the alternatives, the final check's removals, the passes, GQ and P12."""
    lines = [f"step {row['step']} ({row['chosen']}, score {row['chosen_score']:+.2f}): nearly "
             f"as good, not told apart by this record: {row['alternatives']}"
             for row in res.steps_table() if row["alternatives"]]
    for d in res.dismissed:
        if d.replaced_by:
            lines.append(f"final check: {d.effect} replaced by {d.replaced_by}: the model "
                         f"with {d.replaced_by} in its place scores {-d.loss:.1%} better "
                         f"(p = {d.p_value:.2g})")
            continue
        when = (f"round {d.round + 1}: {d.effect} chosen but not added" if d.round <
                len(res.rounds) else f"final check: {d.effect} removed")
        lines.append(f"{when}: with the rest of the model refitted without it, it reduces "
                     f"the RMSE by only {d.loss:.1%} (p = {d.p_value:.2g})")
    facts = res.facts
    if facts.passes > 1:
        lines.append("the first pass left the record unexplained; a second pass ran from the "
                     "structure pinned at its physical values: " +
                     ("its result is reported" if facts.structure_pinned
                      else "not better by the loop's rule, the first pass is reported"))
    if facts.flow_gain_released:
        lines.append(f"{facts.flow_gain_released}: a flow loss beyond a healthy "
                     f"actuator's spread; GQ was put back to its nominal value and no longer "
                     f"fitted")
    if facts.p12_used:
        lines.append(f"measured P12 used in every fit and score (noise taken as "
                     f"{facts.p12_noise_pa / 1e5:.3g} bar; --p12-weight "
                     f"{res.settings['p12_weight']:g})")
    return lines
