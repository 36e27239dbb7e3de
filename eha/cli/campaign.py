"""Fault campaigns and the result database: ``eha campaign validate|plan|run``, ``eha
query``, ``eha export``, ``eha plot``.

``eha query`` must start fast: nothing here imports the simulation stack (numba kernels) at
module level; each command imports what it calls.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from eha.cli.guard import console, discard_stdout, fail, resumable, warn
from eha.cli.options import (RESULTS, WORKERS, ResultsOption, WorkersOption, check_database,
                             check_out_dir, check_out_file)

campaign_app = typer.Typer(no_args_is_help=True,
                           help="Fault campaigns: validate, plan and run TOML campaign files.\n\n"
                                "Example: eha campaign run campaigns/thesis-matrix.toml")


def _load(file: Path):
    from eha.campaigns.files import load_campaign

    return load_campaign(file)


@campaign_app.command("validate")
def campaign_validate(file: Path = typer.Argument(..., help="Campaign TOML file.")):
    """Check a campaign file; prints one line per problem (exit 2) or the job count.

    Example: eha campaign validate campaigns/thesis-matrix.toml
    """
    camp = _load(file)
    console.print(f"{file}: campaign {camp.name!r} is valid, {len(camp.jobs)} jobs")


@campaign_app.command("plan")
def campaign_plan(file: Path = typer.Argument(..., help="Campaign TOML file."),
                  workers: WorkersOption = WORKERS,
                  jobs: bool = typer.Option(False, "--jobs", help="List every job."),
                  results: ResultsOption = RESULTS):
    """Show what a campaign would run: job counts, how many are already done under
    --results, and an estimated wall time for the rest.

    Example: eha campaign plan campaigns/thesis-single-fault.toml --jobs
    """
    from eha.campaigns.files import plan
    from eha.models.units import duration

    camp = _load(file)
    info = plan(camp, workers, results)
    if jobs:
        table = Table("run_key", "kind", "job")
        for j in camp.jobs:
            table.add_row(j.run_key, j.kind, j.label)
        console.print(table)
    console.print(f"campaign {camp.name}: {info['jobs']} jobs "
                  f"({', '.join(f'{k}: {v}' for k, v in info['by_model'].items() if k)}), "
                  f"{info['fault_sets']} fault sets, commands "
                  f"{', '.join(str(c) for c in info['by_command'] if c)}")
    if info["done"]:
        console.print(f"already done in {results}: {info['done']} of {info['jobs']} runs "
                      f"(not run again)")
    left = "nothing left to run" if info["done"] == info["jobs"] else duration(
        info["estimated_s"])
    console.print(f"estimated wall time on {workers} workers: {left}")


@campaign_app.command("run")
def campaign_run(
    file: Path = typer.Argument(..., help="Campaign TOML file."),
    workers: WorkersOption = WORKERS,
    results: ResultsOption = RESULTS,
    scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                            help="Dask scheduler tcp://HOST:PORT (needs "
                                                 "eha's dask extra)."),
    replace: bool = typer.Option(False, "--replace",
                                 help="The file changed: discard the recorded runs it no "
                                      "longer has (shared runs are kept)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Run or resume a campaign: Parquet traces and DuckDB rows under --results.

    Example: eha campaign run campaigns/thesis-matrix.toml --workers 2 --results results
    """
    from eha.campaigns.executors import check_reachable, check_scheduler
    from eha.campaigns.runner import run_campaign
    from eha.errors import EhaError

    if scheduler is not None:
        check_scheduler(scheduler)
    check_out_dir(results, "--results")
    camp = _load(file)
    if scheduler is not None:
        try:
            check_reachable(scheduler)
        except RuntimeError as exc:
            fail(str(exc), 1)
    with resumable("finished runs are saved, re-run the same command to resume"):
        try:
            s = run_campaign(camp, results, workers=workers, scheduler=scheduler,
                             replace=replace, progress=progress)
        except (EhaError, typer.Exit):  # typer.Exit is a RuntimeError too
            raise
        except RuntimeError as exc:  # e.g. cannot reach the Dask scheduler
            fail(str(exc), 1)
    if s.changed:
        console.print(f"{camp.name} changed since it was recorded: discarded {s.replaced} runs "
                      "it no longer has, kept the shared ones")
    console.print(f"{s.campaign}: {s.total} runs, {s.done} run now, {s.skipped} already "
                  f"done, {s.failed} failed, {s.wall_s:.1f} s -> {results}/eha.duckdb")
    for line in s.errors:  # a worker's message is text, brackets included
        warn(line, "failed")
    if s.failed:
        raise typer.Exit(1)


@campaign_app.command("verify")
def campaign_verify(
    results: ResultsOption = RESULTS,
    repair: bool = typer.Option(False, "--repair",
                                help="Re-run the runs of the damaged trace files (each "
                                     "campaign from the definition stored with it)."),
    workers: WorkersOption = WORKERS,
):
    """Check every trace file of a results folder against the size and checksum recorded with
    its runs (every byte read, nothing run); exit 1 while a file is damaged.

    Example: eha campaign verify --results results --repair
    """
    from eha.campaigns.integrity import repair_hint
    from eha.campaigns.runner import verify_results

    if repair:
        check_out_dir(results, "--results")
    with resumable("finished runs are saved, re-run the same command to resume"):
        v = verify_results(results, repair=repair, workers=workers, progress=False)
    for path, reason in sorted(v.damaged.items()):
        warn(f"{results / path}: {reason}", "damaged")
    for path in v.strays:
        warn(f"{results / path}: recorded by no run (a copy or a leftover); never read, "
             "remove it", "not recorded")
    for name, n in sorted(v.repaired.items()):
        console.print(f"{name}: {n} runs of its damaged trace files run again")
    console.print(f"{results}: {v.files} trace files of {v.runs} runs checked, "
                  f"{len(v.damaged)} damaged"
                  + (", repaired" if v.repaired else "")
                  + (f", {len(v.strays)} not recorded" if v.strays else ""))
    if v.damaged and not repair:
        fail(f"{len(v.damaged)} damaged trace files; repair them with: "
             f"{repair_hint(results)}", 1)


def _write_rows(columns, rows, format: str, limit: int = 0) -> None:
    """The query's result on standard output as a table (its first ``limit`` rows, 0 all),
    CSV or JSON (every row, every value exact: :mod:`eha.campaigns.values`)."""
    from eha.campaigns.values import csv_lines, json_records

    if format in ("csv", "json"):
        pieces = csv_lines(columns, rows) if format == "csv" else json_records(columns, rows)
        out = sys.stdout
        for piece in pieces:
            out.write(piece)
        if format == "json":
            out.write("\n")
        return
    hidden = len(rows) - limit if 0 < limit < len(rows) else 0
    table = Table(*[str(c) for c in columns])
    for row in rows[:len(rows) - hidden]:
        table.add_row(*[_cell(v) for v in row])
    console.print(table)
    if hidden:
        console.print(f"{hidden} more rows not shown (--limit 0 shows all; --format csv "
                      "or json writes every row)")


def _cell(v) -> str:
    """A value as the table shows it: SQL NULL (pandas' None, NaN, NaT or NA, whichever
    the column's type made of it) as ``NULL``, never ``nan`` or ``None``."""
    import pandas as pd

    try:
        missing = v is None or bool(pd.isna(v))
    except (TypeError, ValueError):  # a list or an array: a value
        missing = False
    if missing:
        return "NULL"
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def query(sql: str = typer.Argument(..., help="SQL (DuckDB dialect)."),
          results: ResultsOption = RESULTS,
          format: str = typer.Option("table", "--format", help="table, csv or json."),
          limit: int = typer.Option(1000, "--limit", min=0,
                                    help="Rows shown in the table format (0 = all); csv and "
                                         "json write every row.")):
    """Query the result database read-only; Parquet traces are the view `traces`.

    CSV and JSON keep every value exact: floats in their shortest round-trip form, every digit
    of an integer; in JSON NaN and infinities are "NaN", "Infinity", "-Infinity" and BLOBs hex.

    Only reading statements run (SELECT, WITH, EXPLAIN, DESCRIBE, SHOW, PRAGMA table_info);
    SET, ATTACH, COPY, EXPORT, INSTALL, CREATE, INSERT, ... are refused (exit 2).

    Example: eha query "SELECT r.label, m.rmse_xu_hf_lf FROM runs r JOIN metrics m USING
    (run_key) WHERE r.campaign = 'thesis-matrix' AND r.model = 'hf'" --format csv
    """
    from eha.campaigns.query import query_rows

    if format not in ("table", "csv", "json"):
        fail(f"--format {format!r}: allowed table, csv, json")
    check_database(results)
    columns, rows = query_rows(results, sql)
    try:
        _write_rows(columns, rows, format, limit)
        sys.stdout.flush()  # a full disk or a closed pipe shows here, not silently at exit
    except OSError as exc:
        discard_stdout()
        fail(f"query: the result could not be written to standard output "
             f"({exc.strerror or exc})", 1)


def export(table: str = typer.Argument(..., help="Table or view (campaigns, runs, metrics, "
                                                 "traces, ...)."),
           csv: Optional[Path] = typer.Option(None, "--csv", help="CSV file to write."),
           json: Optional[Path] = typer.Option(None, "--json",
                                               help="JSON file to write (a list of records)."),
           results: ResultsOption = RESULTS):
    """Export a table of the result database to CSV or JSON, every value exact (floats in
    their shortest round-trip form; in JSON NaN and infinities as "NaN", "Infinity",
    "-Infinity", BLOBs in hex).

    Example: eha export metrics --csv results/metrics.csv
    """
    from eha.campaigns.query import export_table

    if (csv is None) == (json is None):
        fail("export: give one of --csv FILE or --json FILE")
    path, format = (csv, "csv") if csv is not None else (json, "json")
    check_out_file(path, f"--{format}", (f".{format}",))
    check_database(results)
    n = export_table(results, table, path, format)
    console.print(f"{table}: {n} rows -> {path}")


def plot(campaign: str = typer.Argument(..., help="Campaign name (as in the database)."),
         results: ResultsOption = RESULTS,
         out: Optional[Path] = typer.Option(None, "--out",
                                            help="Folder (default RESULTS/plots/CAMPAIGN).")):
    """Campaign figures (PNG): HF vs LF xu and P12 per fault set, RMSE summary.

    Example: eha plot thesis-matrix --results results
    """
    from eha.reports.plots import plot_campaign

    check_out_dir(out if out is not None else results / "plots" / campaign, "--out")
    for p in plot_campaign(results, campaign, out):
        console.print(str(p))
