"""The models: ``eha simulate``, ``eha params``, ``eha commands``.

Imports of the simulation stack (numba kernels) stay inside the command functions: ``eha
query`` and ``eha --help`` must not pay for them.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer
from rich.padding import Padding
from rich.table import Table
from rich.text import Text

from eha.cli.guard import console, fail
from eha.cli.options import PLOT_SUFFIXES, check_out_file, check_seed


def simulate(
    model: str = typer.Option("hf", "--model", help="hf (detailed) or lf (monitoring)."),
    command: str = typer.Option("mixed", "--command", help="Preset or kind (see `eha commands`)."),
    set_: List[str] = typer.Option([], "--set", help="Parameter NAME=VALUE (repeatable)."),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="Simulated time in s "
                                          "(default: a command file's own length, else 1)."),
    seed: int = typer.Option(0, "--seed", help="Dither seed (HF)."),
    out: Path = typer.Option(..., "--out", help="Trace file: .parquet, or .csv (columns t, "
                             "com, xu, ... in SI, cor in mA; for Matlab's readtable)."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Also write a PNG plot."),
):
    """Simulate one model on one command and save the trace.

    Example: eha simulate --model hf --command chirp_1cm --set BKL=1e-4 --set FDJ=800
    --out results/chirp.parquet --plot results/chirp.png

    Example (CSV): eha simulate --command step_1mm --out step.csv
    """
    from eha.models.params import parse_assignments
    from eha.models.simulate import simulate as run

    check_out_file(out, "--out", (".parquet", ".csv"))
    check_out_file(plot, "--plot", PLOT_SUFFIXES)
    check_seed(seed)
    if t_end is None:
        from eha.models.commands import default_duration

        t_end = default_duration(command)
    trace = run(model, command, parse_assignments(set_, "--set"), t_end=t_end, seed=seed)
    from eha.campaigns.traces import write_table_file, write_trace

    if out.suffix.lower() == ".csv":  # what `eha fdi --data` and `eha explain` read back
        write_table_file(trace.to_pandas(), out, "csv")
    else:
        write_trace(trace, out)
    if plot is not None:
        from eha.reports.plots import plot_traces

        plot_traces([trace], plot)
    console.print(f"{model.upper()} {command}: {len(trace)} samples -> {out}"
                  + (f", plot {plot}" if plot else ""))


def params(model: Optional[str] = typer.Option(None, "--model", help="Only hf or lf."),
           faults: bool = typer.Option(False, "--faults", help="Only the fault parameters.")):
    """List the model parameters: name, unit, nominal, range, description.

    Example: eha params --model lf
    """
    from eha.models.params import PARAMETERS, MODELS

    if model is not None and model not in MODELS:
        fail(f"--model {model!r}: allowed hf, lf")
    chosen = [p for p in PARAMETERS
              if not (model and model not in p.models) and not (faults and not p.fault)]
    if console.width >= 120:
        table = Table("name", "unit", "nominal HF", "nominal LF", "range", "models",
                      "description")
        for p in chosen:
            table.add_row(p.name, p.unit, *_nominals(p), f"[{p.lo:g}, {p.hi:g}]",
                          ",".join(p.models), p.description + (" (fault)" if p.fault else ""))
        console.print(table)
        return
    # narrow (80 columns): one line of facts per parameter, its description wrapped below
    for p in chosen:
        hf, lf = _nominals(p)
        nominal = hf if lf in ("-", hf) else (lf if hf == "-" else f"{hf} (LF {lf})")
        facts = (f"{p.unit}, nominal {nominal}, range [{p.lo:g}, {p.hi:g}], "
                 f"{','.join(p.models)}" + (", fault" if p.fault else ""))
        console.print(f"{p.name}  {facts}", highlight=False)
        console.print(Padding(p.description, (0, 0, 0, 4)), highlight=False)


def _nominals(p) -> tuple[str, str]:
    """A parameter's nominal value in the HF and the LF model ("-": not in that model)."""
    return (f"{p.nominal:g}" if "hf" in p.models else "-",
            f"{p.nominal_for('lf'):g}" if "lf" in p.models else "-")


def commands():
    """List the command presets and kinds with their parameters.

    Example: eha commands
    """
    from eha.models.commands import KINDS, PRESETS

    presets = Table("preset", "kind", "parameters", "description", title="presets",
                    title_justify="left")
    for name, (kind, values, desc) in PRESETS.items():
        presets.add_row(name, kind, ", ".join(f"{k}={v:g}" for k, v in values.items()), desc)
    console.print(presets)
    kinds = Table("kind", "parameters: default unit [range]", "description",
                  title="kinds (the shapes the presets are made of)", title_justify="left")
    for kind in KINDS.values():
        kinds.add_row(kind.name, "\n".join(
            f"{k}={d:g}{' ' + u if u not in ('', '-') else ''} [{lo:g}, {hi:g}]"
            for k, (d, u, lo, hi) in kind.params.items()) or "-", kind.description)
    console.print(kinds)


def faults():
    """List the health faults: what degrades, unit, healthy value and scatter, search bounds,
    the detection campaign's levels, RUL tracking, the residual loop's matching effect.

    Every fact comes from one declaration per fault (eha.models.faults).

    Example: eha faults
    """
    from eha.models.faults import FAULTS

    for f in FAULTS.values():
        unit, k = f.display_unit
        scatter = "" if f.scatter is None else f" ({_scatter_text(f.scatter, k)})"
        trend = {1: "degrades up", -1: "degrades down", 0: "degrades either way"}[f.direction]
        tags = ", ".join(t for t in (f.role == "core" and "core", f.rul and "RUL") if t)
        head = f"{f.description} [{unit or '-'}], {trend}" + (f" ({tags})" if tags else "")
        console.print(Text.assemble((f.name, "bold"), f"  {head}"), highlight=False)
        console.print(f"    healthy {f.healthy * k:g}{scatter}; search {f.bounds[0] * k:g} to "
                      f"{f.bounds[1] * k:g}; campaign levels "
                      f"{', '.join(f'{v * k:g}' for v in f.levels) or '-'}; loop effect "
                      f"{f.effect or '-'}", highlight=False, markup=False)
    console.print("core: fitted in every hypothesis of the health bank; RUL: tracked by eha rul "
                  "by default.", highlight=False)


def _scatter_text(scatter: tuple[str, float, float], k: float) -> str:
    law, a, b = scatter
    if law == "uniform_rel":
        return f"+-{100 * a:g} %"
    if law == "normal":
        return f"std {b * k:g}"
    return f"log-uniform {a * k:g}-{b * k:g}"

