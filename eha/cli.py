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
                                           help="Output directory."),
              workers: int = typer.Option(2, "--workers", min=1, help="Worker processes.")):
    """Reproduce thesis chapters 5 and 6: all thesis campaigns, figures and reports.

    Runs the nominal, single-fault, matrix and FDI campaigns and writes the reports, the FDI
    table as `eha report thesis` writes it.

    Runs campaigns/thesis-*.toml into --results (resuming what is done), then writes the
    HF-vs-LF figures, reports/summary.md and one CSV per campaign.

    Example: eha reproduce --results results
    """
    from eha.report import reproduce_thesis

    try:
        out = reproduce_thesis(results, workers=workers)
    except _campaign_errors() as exc:
        _fail_lines(str(exc))
    table = Table("campaign", "runs", "run now", "already done", "failed", "wall [s]")
    for s in out["summaries"]:
        table.add_row(s.campaign, str(s.total), str(s.done), str(s.skipped), str(s.failed),
                      f"{s.wall_s:.1f}")
        if s.changed:
            console.print(f"{s.campaign}: its file changed; {s.replaced} old runs discarded")
    console.print(table)
    table = Table("command", "RMSE xu HF vs LF [µm]", "% of command peak")
    for r in out["nominal"]:
        table.add_row(r["command"], f"{1e6 * r['rmse_xu_m']:.2f}", f"{r['rmse_pct_of_peak']:.3f}")
    console.print(table)
    console.print(f"{len(out['plots'])} plots under {results}/plots, reports under "
                  f"{results}/reports (summary.md), database {results}/eha.duckdb")
    console.print(f"thesis fault identification (Figure 6.17): {out['fdi']['table']}, "
                  f"{out['fdi']['plot'].name}, {out['fdi']['summary'].name}")


# --------------------------------------------------------------------------- campaigns
campaign_app = typer.Typer(no_args_is_help=True,
                           help="Fault campaigns: validate, plan and run TOML campaign files.\n\n"
                                "Example: eha campaign run campaigns/thesis-matrix.toml")
app.add_typer(campaign_app, name="campaign")


def _campaign_errors():
    from eha.campaign import CampaignError
    from eha.runner import CampaignChanged
    from eha.store import StoreError

    return (CampaignError, CampaignChanged, StoreError, *_input_errors())


def _fail_lines(text: str, code: int = BAD_INPUT) -> None:
    """One ``error:`` line per problem, then exit with ``code``."""
    for line in text.splitlines() or [text]:
        err_console.print(f"[bold red]error:[/] {line}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _load(file: Path):
    from eha.campaign import CampaignError, load_campaign

    try:
        return load_campaign(file)
    except CampaignError as exc:
        _fail_lines(str(exc))


@campaign_app.command("validate")
def campaign_validate(file: Path = typer.Argument(..., help="Campaign TOML file.")):
    """Check a campaign file; prints one line per problem (exit 2) or the job count.

    Example: eha campaign validate campaigns/thesis-matrix.toml
    """
    camp = _load(file)
    console.print(f"{file}: campaign {camp.name!r} is valid, {len(camp.jobs)} jobs")


@campaign_app.command("plan")
def campaign_plan(file: Path = typer.Argument(..., help="Campaign TOML file."),
                  workers: int = typer.Option(2, "--workers", min=1, help="Worker processes."),
                  jobs: bool = typer.Option(False, "--jobs", help="List every job.")):
    """Show what a campaign would run: job counts and an estimated wall time.

    Example: eha campaign plan campaigns/thesis-single-fault.toml --jobs
    """
    from eha.campaign import plan

    camp = _load(file)
    info = plan(camp, workers)
    if jobs:
        table = Table("run_key", "kind", "job")
        for j in camp.jobs:
            table.add_row(j.run_key, j.kind, j.label)
        console.print(table)
    console.print(f"campaign {camp.name}: {info['jobs']} jobs "
                  f"({', '.join(f'{k}: {v}' for k, v in info['by_model'].items() if k)}), "
                  f"{info['fault_sets']} fault sets, commands "
                  f"{', '.join(str(c) for c in info['by_command'] if c)}")
    console.print(f"estimated wall time on {workers} workers: {info['estimated_s']:.1f} s")


@campaign_app.command("run")
def campaign_run(
    file: Path = typer.Argument(..., help="Campaign TOML file."),
    workers: int = typer.Option(2, "--workers", min=1, help="Local worker processes."),
    results: Path = typer.Option(Path("results"), "--results", help="Results folder."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler",
                                            help="Dask scheduler tcp://HOST:PORT (eha[dask])."),
    replace: bool = typer.Option(False, "--replace",
                                 help="The file changed: discard the recorded runs it no "
                                      "longer has (shared runs are kept)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Run or resume a campaign: Parquet traces and DuckDB rows under --results.

    Example: eha campaign run campaigns/thesis-matrix.toml --workers 2 --results results
    """
    from eha.runner import run_campaign

    camp = _load(file)
    try:
        s = run_campaign(camp, results, workers=workers, scheduler=scheduler, replace=replace,
                         progress=progress)
    except _campaign_errors() as exc:
        _fail_lines(str(exc))
    except RuntimeError as exc:  # e.g. cannot reach the Dask scheduler
        fail(str(exc), 1)
    except KeyboardInterrupt:
        fail("interrupted; finished runs are saved, re-run the same command to resume", 130)
    if s.changed:
        console.print(f"{camp.name} changed since it was recorded: discarded {s.replaced} runs "
                      "it no longer has, kept the shared ones")
    console.print(f"{s.campaign}: {s.total} runs, {s.done} run now, {s.skipped} already done, "
                  f"{s.failed} failed, {s.wall_s:.1f} s -> {results}/eha.duckdb")
    for line in s.errors:
        err_console.print(f"failed: {line}", highlight=False, soft_wrap=True)
    if s.failed:
        raise typer.Exit(1)


@app.command()
def query(sql: str = typer.Argument(..., help="SQL (DuckDB dialect)."),
          results: Path = typer.Option(Path("results"), "--results", help="Results folder."),
          format: str = typer.Option("table", "--format", help="table, csv or json.")):
    """Query the result database read-only; Parquet traces are the view `traces`.

    Example: eha query "SELECT r.label, m.rmse_xu_hf_lf FROM runs r JOIN metrics m USING
    (run_key) WHERE r.campaign = 'thesis-matrix' AND r.model = 'hf'" --format csv
    """
    from eha.store import StoreError, query as run_query

    if format not in ("table", "csv", "json"):
        fail(f"--format {format!r}: allowed table, csv, json")
    try:
        frame = run_query(results, sql)
    except StoreError as exc:
        fail(str(exc))
    if format == "csv":
        typer.echo(frame.to_csv(index=False), nl=False)
    elif format == "json":
        typer.echo(frame.to_json(orient="records", date_format="iso"))
    else:
        table = Table(*[str(c) for c in frame.columns])
        for row in frame.itertuples(index=False):
            table.add_row(*[f"{v:.6g}" if isinstance(v, float) else str(v) for v in row])
        console.print(table)


@app.command()
def export(table: str = typer.Argument(..., help="Table or view (campaigns, runs, metrics, "
                                                 "traces, ...)."),
           csv: Path = typer.Option(..., "--csv", help="CSV file to write."),
           results: Path = typer.Option(Path("results"), "--results", help="Results folder.")):
    """Export a table of the result database to CSV.

    Example: eha export metrics --csv results/metrics.csv
    """
    from eha.store import StoreError, export_csv

    try:
        n = export_csv(results, table, csv)
    except StoreError as exc:
        fail(str(exc))
    console.print(f"{table}: {n} rows -> {csv}")


@app.command()
def plot(campaign: str = typer.Argument(..., help="Campaign name (as in the database)."),
         results: Path = typer.Option(Path("results"), "--results", help="Results folder."),
         out: Optional[Path] = typer.Option(None, "--out",
                                            help="Folder (default RESULTS/plots/CAMPAIGN).")):
    """Campaign figures (PNG): HF vs LF xu and P12 per fault set, RMSE summary.

    Example: eha plot thesis-matrix --results results
    """
    from eha.report import plot_campaign
    from eha.store import StoreError

    try:
        paths = plot_campaign(results, campaign, out)
    except StoreError as exc:
        fail(str(exc))
    for p in paths:
        console.print(str(p))


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
    method: str = typer.Option("ga+ps", "--method", help="ga (the thesis), ga+ps "
                               "(GA + pattern-search polish) or ps (pattern search from the "
                               "--base / nominal values)."),
    pop: int = typer.Option(20, "--pop", help="GA population."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed (and HF dither seed)."),
    objective: str = typer.Option("rmse", "--objective", help="rmse or objfcn (the thesis' "
                                  "mean absolute error)."),
    t_end: float = typer.Option(1.0, "--t-end",
                                help="Simulated time of the HF reference, in seconds."),
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
        with err_console.status(f"identifying ({method}) ...") as status:
            def progress(gen: int, best: float) -> None:
                status.update(f"identifying ({method}): generation {gen}, best "
                              f"{objective} {best:.4g} m")

            run = identify_source(command=command, faults=parse_assignments(set_), data=data,
                                  fit=[n.strip() for n in fit.split(",") if n.strip()],
                                  bounds=parse_bounds(bounds), base=parse_assignments(base),
                                  method=method, pop=pop, seed=seed, objective=objective,
                                  t_end=t_end, on_generation=progress)
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


@app.command()
def explain(
    data: Path = typer.Argument(..., help="Measured record: CSV/TSV/Parquet with t, com, xu "
                                "(SI; aliases in docs/explain.md), optional p12, xs."),
    fit: str = typer.Option("BKL,FDJ", "--fit", help="Declared faults to fit: NAME or "
                            "NAME=LO:HI, comma-separated."),
    effects: Optional[str] = typer.Option(None, "--effects", help="Candidate effects, "
                                          "comma-separated SPEC §7 names (default: all 14)."),
    holdout: Optional[float] = typer.Option(None, "--holdout", help="Fraction of the record "
                                            "held out at its end for scoring (default 0.3)."),
    validate: Optional[Path] = typer.Option(None, "--validate", help="Second record used as "
                                            "held-out data instead of --holdout."),
    prior: Optional[Path] = typer.Option(None, "--prior", help="--json of an earlier run: its "
                                         "effects start switched on (e.g. from nominal data)."),
    known: List[str] = typer.Option([], "--set", help="Known LF parameter held fixed, "
                                    "NAME=VALUE, repeatable (a test condition, e.g. a test "
                                    "load FRC=4000)."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write rmse_before/after, "
                                            "faults_before/after and the steps as JSON."),
    out: Optional[Path] = typer.Option(None, "--out", help="Output folder (default "
                                       "RESULTS/explain/<file stem>)."),
    results: Path = typer.Option(Path("results"), "--results", help="Folder of eha.duckdb."),
    method: str = typer.Option("ga+ps", "--method", help="Optimizer of every fit (eha fdi)."),
    pop: int = typer.Option(20, "--pop", help="GA population of every fit."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed (same seed, same result)."),
    candidates: int = typer.Option(6, "--candidates", help="Effects refitted per round, the "
                                   "best-ranked by signature (0 = all)."),
    max_steps: int = typer.Option(4, "--max-steps", help="Most effects added."),
    min_gain: float = typer.Option(0.1, "--min-gain", help="Smallest penalised held-out RMSE "
                                   "reduction that adds an effect."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress display."),
):
    """Trace a measured record's residual to missing LF effects, add them, report the error.

    Example: eha explain data/run1.csv --fit BKL,FDJ --holdout 0.3 --json out.json

    Example (healthy actuator under a known 4 kN test load): eha explain loadtest.csv --set
    FRC=4000 --json calibration.json
    """
    from eha.explain import ExplainError
    from eha.fdi import FDIError
    from eha.measured import MeasuredDataError
    from eha.report import explain_report

    if holdout is not None and validate is not None:
        fail("--holdout and --validate exclude each other; give one")
    from eha.params import ParameterError, parse_assignments

    try:
        known_values = parse_assignments(known)
    except ParameterError as exc:
        fail(f"--set {exc}")
    if json_out is not None and json_out.suffix.lower() != ".json":
        fail(f"--json {json_out}: the file must end in .json")
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    bar = Progress(SpinnerColumn(), TextColumn("{task.description}"),
                   TextColumn("[dim]{task.completed} fits"), TimeElapsedColumn(),
                   console=err_console, disable=not progress, transient=True)
    with bar:
        task = bar.add_task("reading the record", total=None)

        def step(message: str) -> None:
            bar.update(task, description=message, advance=1)

        try:
            run = explain_report(data, fit=fit, effects=effects, holdout=holdout,
                                 validate=validate, prior=prior, json_path=json_out, out=out,
                                 known=known_values,
                                 results=results, on_progress=step, method=method, pop=pop,
                                 seed=seed, candidates=candidates, max_steps=max_steps,
                                 min_gain=min_gain)
        except MeasuredDataError as exc:
            bar.stop()
            _fail_lines("\n".join(f"{exc.source}: {p}" for p in exc.problems))
        except (ExplainError, FDIError, *_input_errors()) as exc:
            bar.stop()
            fail(str(exc))
    res = run["result"]
    table = Table("step", "effect", "parameters", "RMSE fit [µm]", "RMSE held-out [µm]",
                  "RMSE all [µm]", "faults after")
    table.add_row("0", "(declared faults)", "-", f"{1e6 * res.before.rmse_fit:.3g}",
                  f"{1e6 * res.before.rmse_hold:.3g}", f"{1e6 * res.rmse_before:.3g}",
                  ", ".join(f"{k}={v:.4g}" for k, v in res.faults_before.items()))
    for row, s in zip(res.steps_table(), res.steps):
        table.add_row(str(row["step"]), s.effect, row["params"],
                      f"{1e6 * s.rmse_fit_before:.3g} → {1e6 * s.rmse_fit_after:.3g}",
                      f"{1e6 * s.rmse_hold_before:.3g} → {1e6 * s.rmse_hold_after:.3g}",
                      f"{1e6 * s.rmse_before:.3g} → {1e6 * s.rmse_after:.3g}",
                      row["faults_after"])
    console.print(f"record: {res.source} ({len(res.t)} samples at 1 kHz); held out: "
                  f"{res.holdout}")
    console.print(table)
    for row in res.steps_table():
        if row["alternatives"]:
            console.print(f"step {row['step']} ({row['chosen']}, score "
                          f"{row['chosen_score']:+.2f}): "
                          f"nearly as good, not told apart by this record: "
                          f"{row['alternatives']}")
    console.print(f"RMSE {1e6 * res.rmse_before:.3g} → {1e6 * res.rmse_after:.3g} µm; noise "
                  f"level {1e6 * res.noise_rmse:.3g} µm; unexplained (above noise) "
                  f"{1e6 * res.unexplained_rmse:.3g} µm. Stopped: {res.stop_reason}")
    for kind, path in run["paths"].items():
        console.print(f"{kind}: {path}")
    if run["db_error"]:
        fail(f"results database not written: {run['db_error']}", code=1)


report_app = typer.Typer(no_args_is_help=True, help="Reports built from the result database."
                         "\n\nExample: eha report thesis --results results")
app.add_typer(report_app, name="report")


@report_app.command("thesis")
def report_thesis(results: Path = typer.Option(Path("results"), "--results",
                                               help="Results folder (eha.duckdb)."),
                  out: Optional[Path] = typer.Option(None, "--out", help="Output folder "
                                                     "(default RESULTS/reports/thesis).")):
    """Thesis FDI table (Figure 6.17) beside the thesis' own values, figures, summary.

    From the thesis-fdi campaign's results: fdi_table.csv, mean_error.png (Figure 6.18),
    one HF-vs-identified-LF figure per case, fdi_summary.md.

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
