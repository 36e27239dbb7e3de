"""Command-line interface: a thin typer layer that parses, calls one library function, and maps
errors to exit codes (2 = bad input, 1 = failure)."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="Model-based prognostics of electro-hydraulic actuators (HF/LF models, "
                       "fault campaigns, identification).")
console = Console()
err_console = Console(stderr=True)

BAD_INPUT = 2


def fail(message: str, code: int = BAD_INPUT) -> None:
    """Print one line to stderr and exit with ``code``."""
    err_console.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _input_errors():
    from eha.commands import CommandError
    from eha.params import ParameterError

    return (ParameterError, CommandError)


@app.command()
def simulate(
    model: str = typer.Option("hf", "--model", help="hf (detailed) or lf (monitoring)."),
    command: str = typer.Option("mixed", "--command", help="Preset or kind (see `eha commands`)."),
    set_: List[str] = typer.Option([], "--set", help="Parameter NAME=VALUE (repeatable)."),
    t_end: float = typer.Option(1.0, "--t-end", help="Simulated time [s]."),
    seed: int = typer.Option(0, "--seed", help="Dither seed (HF)."),
    out: Path = typer.Option(..., "--out", help="Trace file (.parquet)."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Also write a PNG plot."),
):
    """Simulate one model on one command and save the trace.

    Example: eha simulate --model hf --command chirp_1cm --set BKL=1e-4 --set FDJ=800
    --out results/chirp.parquet --plot results/chirp.png
    """
    from eha.params import parse_assignments
    from eha.simulate import simulate as run

    if out.suffix != ".parquet":
        fail(f"--out {out}: the trace file must end in .parquet")
    try:
        trace = run(model, command, parse_assignments(set_), t_end=t_end, seed=seed)
    except _input_errors() as exc:
        fail(str(exc))
    from eha.store import write_trace

    write_trace(trace, out)
    if plot is not None:
        from eha.report import plot_traces

        plot_traces([trace], plot)
    console.print(f"{model.upper()} {command}: {len(trace)} samples -> {out}"
                  + (f", plot {plot}" if plot else ""))


@app.command()
def params(model: Optional[str] = typer.Option(None, "--model", help="Only hf or lf."),
           faults: bool = typer.Option(False, "--faults", help="Only the fault parameters.")):
    """List the model parameters: name, unit, nominal, range, description.

    Example: eha params --model lf
    """
    from eha.params import PARAMETERS, MODELS

    if model is not None and model not in MODELS:
        fail(f"--model {model!r}: allowed hf, lf")
    table = Table("name", "unit", "nominal HF", "nominal LF", "range", "models", "description")
    for p in PARAMETERS:
        if (model and model not in p.models) or (faults and not p.fault):
            continue
        table.add_row(p.name, p.unit,
                      f"{p.nominal:g}" if "hf" in p.models else "-",
                      f"{p.nominal_for('lf'):g}" if "lf" in p.models else "-",
                      f"[{p.lo:g}, {p.hi:g}]", ",".join(p.models),
                      p.description + (" (fault)" if p.fault else ""))
    console.print(table)


@app.command()
def commands():
    """List the command presets and kinds with their parameters.

    Example: eha commands
    """
    from eha.commands import KINDS, PRESETS

    table = Table("name", "kind", "parameters", "description")
    for name, (kind, values, desc) in PRESETS.items():
        table.add_row(name, kind, ", ".join(f"{k}={v:g}" for k, v in values.items()), desc)
    for kind in KINDS.values():
        pars = ", ".join(f"{k}={d:g} {u} [{lo:g}, {hi:g}]"
                         for k, (d, u, lo, hi) in kind.params.items())
        table.add_row(kind.name, kind.name, pars, kind.description)
    console.print(table)


@app.command()
def reproduce(results: Path = typer.Option(Path("results"), "--results",
                                           help="Output directory.")):
    """Run the thesis reproduction: every nominal command through HF and LF, with plots.

    Example: eha reproduce --results results
    """
    from eha.report import nominal_comparison

    rows = nominal_comparison(results)
    table = Table("command", "RMSE xu HF vs LF [µm]", "% of command peak")
    for r in rows:
        table.add_row(r["command"], f"{1e6 * r['rmse_xu_m']:.2f}", f"{r['rmse_pct_of_peak']:.3f}")
    console.print(table)
    console.print(f"traces and plots under {results}/")


# --------------------------------------------------------------------------- fault identification
@app.command()
def fdi(
    command: Optional[str] = typer.Option(None, "--command",
                                          help="Command of the HF reference (`eha commands`)."),
    set_: List[str] = typer.Option([], "--set", help="Fault injected in the HF reference, "
                                   "NAME=VALUE (repeatable)."),
    data: Optional[Path] = typer.Option(None, "--data", help="Measured record instead of an "
                                        "HF reference: CSV/Parquet with t, com, xu (SI)."),
    fit: str = typer.Option("BKL,FDJ", "--fit", help="LF parameters to identify."),
    bounds: List[str] = typer.Option([], "--bounds", help="Search bounds NAME=LO:HI "
                                     "(default BKL=0:1.25e-3, FDJ=200:4000, else the range)."),
    base: List[str] = typer.Option([], "--base", help="LF parameter held fixed, NAME=VALUE "
                                   "(e.g. orifice_law=1)."),
    method: str = typer.Option("ga+ps", "--method", help="ga (the thesis) or ga+ps "
                               "(GA + pattern-search polish)."),
    pop: int = typer.Option(20, "--pop", help="GA population."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed (and HF dither seed)."),
    objective: str = typer.Option("rmse", "--objective", help="rmse or objfcn (the thesis' "
                                  "mean absolute error)."),
    t_end: float = typer.Option(1.0, "--t-end", help="Simulated time of the HF reference [s]."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the result as JSON."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="PNG: reference vs identified LF."),
):
    """Identify LF fault parameters from an HF reference or a measured record.

    Example: eha fdi --command chirp_1cm --set BKL=1e-4 --set FDJ=800 --fit BKL,FDJ --seed 0
    """
    from eha.fdi import FDIError, identify_source, parse_bounds
    from eha.measured import MeasuredDataError
    from eha.params import parse_assignments

    try:
        run = identify_source(command=command, faults=parse_assignments(set_), data=data,
                              fit=[n.strip() for n in fit.split(",") if n.strip()],
                              bounds=parse_bounds(bounds), base=parse_assignments(base),
                              method=method, pop=pop, seed=seed, objective=objective,
                              t_end=t_end)
    except (FDIError, MeasuredDataError, *_input_errors()) as exc:
        fail(str(exc))
    res = run.result
    table = Table("parameter", "bounds", "injected", "identified", "error [%]")
    for name in res.names:
        lo, hi = res.bounds[name]
        table.add_row(name, f"[{lo:g}, {hi:g}]",
                      f"{run.truth[name]:.6g}" if run.truth else "-",
                      f"{res.estimates[name]:.6g}",
                      f"{run.errors_pct[name]:+.3f}" if run.errors_pct else "-")
    console.print(f"reference: {run.source}")
    console.print(table)
    mean = f"mean error {run.mean_err_pct:.3f} %, " if run.mean_err_pct is not None else ""
    console.print(f"{mean}{res.objective_name} {res.objective:.4g} m, {res.evaluations} "
                  f"evaluations, {res.seconds:.2f} s ({res.method}, seed {res.seed})")
    if json_out is not None:
        import json

        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(run.to_dict(), indent=2))
    if plot is not None:
        from eha.report import plot_traces

        plot_traces([run.reference, run.fitted], plot,
                    title=f"Identification ({res.method}): reference vs identified LF")


report_app = typer.Typer(no_args_is_help=True, help="Reports built from the result database.")
app.add_typer(report_app, name="report")


@report_app.command("thesis")
def report_thesis(results: Path = typer.Option(Path("results"), "--results",
                                               help="Results folder (eha.duckdb)."),
                  out: Optional[Path] = typer.Option(None, "--out", help="Output folder "
                                                     "(default RESULTS/reports/thesis).")):
    """Thesis FDI table (Figure 6.17) with the thesis' values side by side, the mean-error
    figure (Figure 6.18) and a summary, from the thesis-fdi campaign's results.

    Example: eha report thesis --results results --out results/reports/thesis
    """
    from eha.report import thesis_report
    from eha.store import StoreError

    try:
        paths = thesis_report(results, out)
    except StoreError as exc:
        fail(str(exc), code=1)
    for kind, path in paths.items():
        console.print(f"{kind}: {path}")


def main() -> None:  # pragma: no cover
    app(prog_name="eha")
