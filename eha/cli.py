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


def main() -> None:  # pragma: no cover
    app(prog_name="eha")
