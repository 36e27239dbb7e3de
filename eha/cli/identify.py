"""Fault identification: ``eha fdi`` (LF fault parameters with intervals, from an HF
reference or a measured record).

The identification stack (numba kernels, the optimizers) is imported inside the command:
``eha query`` and ``eha --help`` must not pay for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from eha.cli.guard import console, err_console, fail, warn
from eha.cli import defaults
from eha.cli.options import (COMMAND_HOLD, PLOT_SUFFIXES, ColumnsOption, CommandHoldOption,
                             UnitsOption, check_names, check_out_dir, check_out_file, check_seed,
                             record_file, split_names,
                             write_json)


# ---- the options, at module level so that the command stays short
COMMAND = typer.Option(None, "--command", help="Command of the HF reference (`eha commands`).")
FAULTS = typer.Option([], "--set", help="Fault injected in the HF reference, NAME=VALUE "
                      "(repeatable).")
DATA = typer.Option(None, "--data", help="Measured record instead of an HF reference: "
                    "CSV/Parquet with t, com, xu (SI, or see --columns, --units).")
FIT = typer.Option(..., "--fit", default_factory=defaults.fit_faults,
                   help="LF parameters to identify.")
BOUNDS = typer.Option([], "--bounds", help="Search bounds NAME=LO:HI (default BKL=0:1.25e-3, "
                      "FDJ=200:4000, else the range).")
BASE = typer.Option([], "--base", help="LF parameter held fixed, NAME=VALUE (e.g. "
                    "orifice_law=1).")
METHOD = typer.Option(
    ..., "--method", default_factory=defaults.fit_method,
    help="ga (the thesis), ga+ps (GA + pattern-search polish), ps (pattern search from the "
         "--base / nominal values) or lm (least squares from them).")
POP = typer.Option(..., "--pop", default_factory=defaults.fdi_population,
                   help="GA population.")
SEED = typer.Option(0, "--seed", help="Optimizer seed (and HF dither seed).")
OBJECTIVE = typer.Option("rmse", "--objective", help="rmse or objfcn (the thesis' mean "
                         "absolute error).")
T_END = typer.Option(None, "--t-end", help="Simulated time of the HF reference, in seconds "
                     "(default: a command file's own length, else 1).")
JSON_OUT = typer.Option(None, "--json", help="Write the result as JSON.")
PLOT = typer.Option(None, "--plot", help="PNG: reference vs identified LF.")
LEVEL = typer.Option(..., "--level", default_factory=defaults.interval_level,
                     help="Nominal coverage of the parameter intervals, in (0, 1).")
RESULTS_TO = typer.Option(None, "--results", help="Also store the fit in this results "
                          "folder's database (table fdi_runs; eha report html shows it).")
BASE_MODEL = typer.Option(None, "--base-model", help="LF model: plain (the thesis') or "
                          "calibrated (by eha explain). Default: plain against an HF "
                          "reference, calibrated on --data.")


def fdi(command: Optional[str] = COMMAND, set_: List[str] = FAULTS,
        data: Optional[Path] = DATA, fit: str = FIT, bounds: List[str] = BOUNDS,
        base: List[str] = BASE, method: str = METHOD, pop: int = POP, seed: int = SEED,
        objective: str = OBJECTIVE, t_end: Optional[float] = T_END, json_out: Optional[Path] = JSON_OUT,
        plot: Optional[Path] = PLOT, level: float = LEVEL,
        base_model: Optional[str] = BASE_MODEL, command_hold: CommandHoldOption = COMMAND_HOLD,
        columns: ColumnsOption = None, units: UnitsOption = None,
        results: Optional[Path] = RESULTS_TO):
    """Identify LF fault parameters, each with an interval, from an HF reference or a
    measured record.

    Example: eha fdi --command chirp_1cm --set BKL=1e-4 --set FDJ=800 --fit BKL,FDJ --seed 0

    Example: eha fdi --data record.csv --fit BKL,FDJ,Clk --level 0.95 --json fit.json

    Example (stored for eha report html): eha fdi --command chirp_1cm --set FDJ=800 --fit FDJ
    --results results

    Example (a record in millimetres, headed time_s,command_mm,position_mm): eha fdi --data
    rec.csv --columns t=time_s,com=command_mm,xu=position_mm
    """
    from eha.identification.fdi import identify_source, parse_bounds
    from eha.models.params import parse_assignments

    check_names(fit, "--fit")
    check_seed(seed)
    if data is None and (command_hold != COMMAND_HOLD or columns or units):
        fail("--command-hold, --columns, --units: only with --data (an HF reference is "
             "driven by its preset)")
    check_out_file(json_out, "--json", (".json",))
    check_out_file(plot, "--plot", PLOT_SUFFIXES)
    if results is not None:
        check_out_dir(results, "--results")
    record = record_file(data, columns, units) if data is not None else None
    if t_end is None:
        from eha.models.commands import default_duration

        t_end = default_duration(command) if command is not None else 1.0
    with err_console.status(f"identifying ({method}) ...") as status:
        def progress(gen: int, best: float) -> None:
            status.update(f"identifying ({method}): generation {gen}, best "
                          f"{objective} {1e6 * best:.4g} µm")

        run = identify_source(command=command, faults=parse_assignments(set_, "--set"), data=record,
                              fit=split_names(fit), bounds=parse_bounds(bounds),
                              base=parse_assignments(base, "--base"), method=method, pop=pop, seed=seed,
                              objective=objective, t_end=t_end, on_generation=progress,
                              level=level, base_model=base_model, command_hold=command_hold)
    _render(run)
    write_json(json_out, run.to_dict())
    if results is not None:
        from eha.identification.runs import save_fdi_run

        db, run_id = save_fdi_run(results, run)
        console.print(f"database: {db} (fdi_runs, run {run_id})", highlight=False)
    if plot is not None:
        from eha.reports.plots import plot_traces

        plot_traces([run.reference, run.fitted], plot,
                    title=f"Identification ({run.result.method}): reference vs identified LF")


def _render(run) -> None:
    """The identification's table in each parameter's display unit (eha.models.units):
    bounds, injected, identified, interval, error; the error's sign convention below it."""
    from rich import box

    from eha.models.units import display_unit, number

    res = run.result
    table = Table("param", "unit", "bounds", "injected", "identified",
                  f"{100 * res.level:g} % interval", "error %", box=box.SIMPLE_HEAD,
                  pad_edge=False)
    for name in res.names:
        lo, hi = res.bounds[name]
        ilo, ihi = res.intervals[name]
        table.add_row(name, display_unit(name)[0] or "-",
                      f"[{number(name, lo, 3)}, {number(name, hi, 3)}]",
                      number(name, run.truth[name], 4) if run.truth else "-",
                      number(name, res.estimates[name], 4),
                      f"[{number(name, ilo, 4)}, {number(name, ihi, 4)}]",
                      f"{run.errors_pct[name]:+.3f}" if run.errors_pct else "-")
    hold = f"; command {run.command_hold}" if run.command_hold else ""
    console.print(f"reference: {run.source}; LF model: {run.base_model}{hold}",
                  highlight=False)
    console.print(table)
    if run.errors_pct:
        console.print("error % = (injected - identified) / injected x 100: positive when the "
                      "fit reads low (0 when nothing was injected)", highlight=False)
    for note in res.notes:
        warn(note)
    mean = (f"mean error {run.mean_err_pct:.3f} % (of |error|), "
            if run.mean_err_pct is not None else "")
    console.print(f"{mean}{res.objective_name} {1e6 * res.objective:.4g} µm, "
                  f"{res.evaluations} evaluations, {res.seconds:.2f} s ({res.method}, seed "
                  f"{res.seed})", highlight=False)
