"""Command-line interface: a thin typer layer that parses, calls one library function, and maps
errors to exit codes (2 = bad input, 1 = failure)."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, List, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from typer.core import TyperGroup

console = Console()
err_console = Console(stderr=True)

BAD_INPUT = 2
# The option parser's exceptions: click's, or the copy of click that typer >= 0.20 vendors.
_CLICK = sys.modules[typer.BadParameter.__module__]
_NO_ARGS = getattr(_CLICK, "NoArgsIsHelpError", ())
#: Exit status after SIGTERM (128 + 15, what a shell reports for a terminated process).
TERMINATED = 143
#: Exit status after Ctrl-C (128 + SIGINT).
INTERRUPTED = 130
#: Plot file types the figures are written in (matplotlib infers the format from the suffix).
PLOT_SUFFIXES = (".png", ".pdf", ".svg")
#: ``--debug`` (or EHA_DEBUG=1): unexpected errors show their traceback.
_STATE = {"debug": bool(os.environ.get("EHA_DEBUG"))}


_TERMINATED_LINE = "terminated (SIGTERM); outputs are written only when complete"
_INTERRUPTED_LINE = "interrupted (Ctrl-C); outputs are written only when complete"


class Terminated(KeyboardInterrupt):
    """SIGTERM received: unwinds like Ctrl-C (every ``finally`` commits what is finished)."""


def _on_sigterm(signum, frame):  # pragma: no cover - exercised by subprocess tests
    raise Terminated()


def _handle_sigterm():
    """Turn SIGTERM into :class:`Terminated`; returns the previous handler (None when it
    cannot be set: not the main thread, e.g. an embedding application)."""
    try:
        return signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:
        return None


def _error_line(message: str) -> None:
    # escape(): a message with brackets ("[fdi]", "[0, 0.1] m") is text, not console markup
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False,
                      soft_wrap=True)


def _unexpected(exc: BaseException) -> str:
    """One line for an exception no command anticipated (class 1 of docs/reliability.md)."""
    import errno

    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    if isinstance(exc, OSError):
        # no file name: a stream (standard output, a pipe) failed
        what = exc.filename or "writing the output"
        reason = exc.strerror or first or type(exc).__name__
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return f"{what}: {reason}; free some space and run the same command again"
        return f"{what}: {reason}"
    if isinstance(exc, UnicodeDecodeError):
        return f"input is not UTF-8 text ({first})"
    if isinstance(exc, MemoryError):
        return "out of memory; make the input smaller (shorter t_end, fewer runs)"
    if any("duckdb" in cls.__module__ for cls in type(exc).__mro__):
        return (f"results database: {first}; if the file is damaged, move it away and run "
                "the campaign again")
    return (f"internal error ({type(exc).__name__}: {first}); run again with --debug for "
            "the traceback")


class _GuardedGroup(TyperGroup):
    """The top-level command group: the one guard of the CLI.

    Every command runs inside :meth:`invoke`: SIGTERM unwinds like Ctrl-C (exit 143), Ctrl-C
    exits 130, and any exception a command did not map to its own message becomes one
    ``error:`` line and exit 1 (``--debug`` shows the traceback). Usage errors of the option
    parser (a value outside an option's range) are one line too, exit 2.
    """

    def invoke(self, ctx):
        previous = _handle_sigterm()
        try:
            return super().invoke(ctx)
        except (typer.Exit, typer.Abort, _CLICK.ClickException):
            raise
        except Terminated:
            _error_line(_TERMINATED_LINE)
            raise typer.Exit(TERMINATED)
        except KeyboardInterrupt:
            _error_line(_INTERRUPTED_LINE)
            raise typer.Exit(INTERRUPTED)
        except Exception as exc:
            if _STATE["debug"]:
                import traceback

                traceback.print_exc()
            if isinstance(exc, OSError) and _stdout_failed():
                exc = OSError(exc.errno, exc.strerror, "standard output")
            _error_line(_unexpected(exc))
            raise typer.Exit(1)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True,
             **extra):
        if not standalone_mode:
            return super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                                standalone_mode=False, **extra)
        previous = _handle_sigterm()  # from here on: parsing reads defaults from the library
        try:
            rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var,
                              standalone_mode=False, **extra)
        except _NO_ARGS as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except _CLICK.ClickException as exc:
            where = f"{exc.ctx.command_path}: " if getattr(exc, "ctx", None) else ""
            _error_line(where + exc.format_message().replace("\n", " "))
            sys.exit(exc.exit_code)
        except typer.Abort:
            _error_line("aborted")
            sys.exit(1)
        except Terminated:  # while the arguments were parsed, before invoke
            _error_line(_TERMINATED_LINE)
            sys.exit(TERMINATED)
        except KeyboardInterrupt:
            _error_line(_INTERRUPTED_LINE)
            sys.exit(INTERRUPTED)
        except Exception as exc:  # e.g. a default read from the library failed to import
            if _STATE["debug"] or "--debug" in (args if args is not None else sys.argv):
                import traceback

                traceback.print_exc()
            _error_line(_unexpected(exc))
            sys.exit(1)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
        if _stdout_failed():  # e.g. `eha params > /dev/full`: say so, not at the final flush
            _error_line("the output could not be written to standard output")
            sys.exit(1)
        sys.exit(rv if isinstance(rv, int) else 0)


app = typer.Typer(cls=_GuardedGroup, add_completion=False, no_args_is_help=True,
                  help="Model-based prognostics of electro-hydraulic actuators (HF/LF models, "
                       "fault campaigns, identification).")


@app.callback()
def _options(debug: bool = typer.Option(False, "--debug", help="Show the traceback of an "
                                        "unexpected error.")):
    if debug:
        _STATE["debug"] = True


# ---- shared option types: one definition of each option that several commands take
#: Default results folder (database eha.duckdb, traces/, plots/, reports/).
RESULTS = Path("results")
ResultsOption = Annotated[Path, typer.Option(
    "--results", help="Results folder (eha.duckdb, traces/, plots/, reports/).")]
#: Default number of local worker processes.
WORKERS = 2
WorkersOption = Annotated[int, typer.Option("--workers", min=1,
                                            help="Local worker processes.")]
#: How a measured record's command is rebuilt between its samples (eha.identification.measured).
COMMAND_HOLD = "auto"
CommandHoldOption = Annotated[str, typer.Option(
    "--command-hold", help="How the record's command is rebuilt between its samples: zoh "
    "(held, as a digital controller's output), linear (interpolated) or auto (zoh when the "
    "command is flat between jumps, else linear).")]


def check_command_hold(value: str) -> None:
    """One line and exit 2 for a --command-hold outside
    eha.identification.measured.COMMAND_HOLDS."""
    from eha.identification.measured import COMMAND_HOLDS

    if value not in COMMAND_HOLDS:
        fail(f"--command-hold {value!r}: allowed: {', '.join(COMMAND_HOLDS)}")


def library_default(module: str, name: str,
                    pick: Callable[[Any], Any] | None = None) -> Callable[[], Any]:
    """A default read from the library (``module.name``, optionally through ``pick``) when
    the option is parsed: the CLI does not retype it, and ``eha --help`` does not pay for
    importing the numerical modules."""
    def default() -> Any:
        import importlib

        value = getattr(importlib.import_module(module), name)
        return pick(value) if pick is not None else value

    default.__name__ = f"{module}.{name}"
    return default


def signature_default(module: str, function: str, parameter: str) -> Callable[[], Any]:
    """The default of ``parameter`` in the library function's signature (see
    :func:`library_default`)."""
    import inspect

    return library_default(module, function,
                           lambda fn: inspect.signature(fn).parameters[parameter].default)


def fail(message: str, code: int = BAD_INPUT) -> None:
    """Print one line to stderr and exit with ``code``.

    Called from a command's ``except KeyboardInterrupt`` with code 130 while the interrupt is
    SIGTERM (:class:`Terminated`), it says so and exits 143, as the guard does."""
    if code == INTERRUPTED and isinstance(sys.exc_info()[1], Terminated):
        code = TERMINATED
        message = message.replace("interrupted", "terminated (SIGTERM)", 1)
    _error_line(message)
    raise typer.Exit(code)


#: Allowed seeds (numpy's generators take unsigned 32-bit seeds).
SEED_MAX = 2**32 - 1


def _writable_folder(folder: Path, option: str, shown: Path) -> None:
    """Fail unless ``folder`` is (or can be created as) a writable folder."""
    probe = folder.absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        fail(f"{option} {shown}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        fail(f"{option} {shown}: folder {probe} is not writable")


def check_out_file(path: Optional[Path], option: str,
                   suffixes: tuple[str, ...] | None = None) -> None:
    """Refuse an output file before any work starts: wrong type, a folder, or a place that
    cannot be written (a parent that is a file, a read-only folder)."""
    if path is None:
        return
    if suffixes and path.suffix.lower() not in suffixes:
        fail(f"{option} {path}: unsupported file type {path.suffix or '(none)'!r}; allowed: "
             f"{', '.join(suffixes)}")
    if path.is_dir():
        fail(f"{option} {path}: is a folder; give a file name")
    if path.exists() and not os.access(path, os.W_OK):
        fail(f"{option} {path}: the file exists and is not writable")
    _writable_folder(path.parent, option, path)


def check_out_dir(path: Optional[Path], option: str) -> None:
    """Refuse an output folder before any work starts: a file, or not writable."""
    if path is None:
        return
    if path.exists() and not path.is_dir():
        fail(f"{option} {path}: is a file, not a folder")
    _writable_folder(path, option, path)


def check_seed(seed: int, option: str = "--seed") -> None:
    if not 0 <= seed <= SEED_MAX:
        fail(f"{option} {seed}: allowed range [0, {SEED_MAX}]")


def check_names(text: str, option: str) -> None:
    """Refuse a comma-separated list that names a parameter twice (``--fit BKL,BKL``)."""
    names = [item.split("=")[0].strip() for item in text.split(",") if item.strip()]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        fail(f"{option} {text}: {', '.join(twice)} given twice; name each parameter once")


def _stdout_failed() -> bool:
    """Flush stdout; True (and stdout discarded) when it cannot be written (a full disk, a
    closed pipe)."""
    try:
        sys.stdout.flush()
        return False
    except (OSError, ValueError):
        _discard_stdout()
        return True


def _discard_stdout() -> None:
    """After a failed write to stdout: point fd 1 at /dev/null so that the interpreter's
    final flush of the unwritten rest does not fail a second time (with a traceback)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def check_prior(path: Path) -> None:
    """``--prior`` must be the ``--json`` of an earlier ``eha explain``: an object whose
    ``steps`` is a list of ``{"effect": ..., "params": {...}}`` (or that list itself)."""
    import json

    try:
        prior = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        fail(f"--prior {path}: not a readable JSON file "
             f"({getattr(exc, 'strerror', None) or str(exc).splitlines()[0]})")
    steps = prior.get("steps") if isinstance(prior, dict) else prior
    if not isinstance(steps, list) or not all(isinstance(s, dict) and "effect" in s
                                              for s in steps):
        keys = ", ".join(sorted(prior)) if isinstance(prior, dict) else type(prior).__name__
        fail(f"--prior {path}: expected the --json of an earlier eha explain (key 'steps', a "
             f"list of {{effect, params}}); found {keys or 'an empty object'}")


def _input_errors():
    from eha.models.commands import CommandError
    from eha.models.params import ParameterError

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
    from eha.models.params import parse_assignments
    from eha.models.simulate import simulate as run

    if out.suffix != ".parquet":
        fail(f"--out {out}: the trace file must end in .parquet")
    check_out_file(out, "--out")
    check_out_file(plot, "--plot", PLOT_SUFFIXES)
    check_seed(seed)
    try:
        trace = run(model, command, parse_assignments(set_), t_end=t_end, seed=seed)
    except _input_errors() as exc:
        fail(str(exc))
    from eha.campaigns.traces import write_trace

    write_trace(trace, out)
    if plot is not None:
        from eha.reports.plots import plot_traces

        plot_traces([trace], plot)
    console.print(escape(f"{model.upper()} {command}: {len(trace)} samples -> {out}"
                         + (f", plot {plot}" if plot else "")))


@app.command()
def params(model: Optional[str] = typer.Option(None, "--model", help="Only hf or lf."),
           faults: bool = typer.Option(False, "--faults", help="Only the fault parameters.")):
    """List the model parameters: name, unit, nominal, range, description.

    Example: eha params --model lf
    """
    from eha.models.params import PARAMETERS, MODELS

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
    from eha.models.commands import KINDS, PRESETS

    table = Table("name", "kind", "parameters", "description")
    for name, (kind, values, desc) in PRESETS.items():
        table.add_row(name, kind, ", ".join(f"{k}={v:g}" for k, v in values.items()), desc)
    for kind in KINDS.values():
        pars = ", ".join(f"{k}={d:g} {u} [{lo:g}, {hi:g}]"
                         for k, (d, u, lo, hi) in kind.params.items())
        table.add_row(kind.name, kind.name, pars, kind.description)
    console.print(table)


@app.command()
def reproduce(results: ResultsOption = RESULTS, workers: WorkersOption = WORKERS):
    """Reproduce thesis chapters 5 and 6: all thesis campaigns, figures and reports.

    Runs the nominal, single-fault, matrix and FDI campaigns and writes the reports, the FDI
    table as `eha report thesis` writes it.

    Runs campaigns/thesis-*.toml into --results (resuming what is done), then writes the
    HF-vs-LF figures, reports/summary.md, one CSV per campaign and the HTML report of the
    folder, reports/report.html (as eha report html writes it).

    Example: eha reproduce --results results
    """
    from eha.reports.thesis import reproduce_thesis

    check_out_dir(results, "--results")
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
    html = out["html"]
    console.print(escape(f"report (open in a browser): {html.path} "
                         f"({html.bytes / 1e6:.1f} MB, {html.seconds:.1f} s)"))


# --------------------------------------------------------------------------- campaigns
campaign_app = typer.Typer(no_args_is_help=True,
                           help="Fault campaigns: validate, plan and run TOML campaign files.\n\n"
                                "Example: eha campaign run campaigns/thesis-matrix.toml")
app.add_typer(campaign_app, name="campaign")


def _campaign_errors():
    from eha.campaigns.files import CampaignError
    from eha.campaigns.runner import CampaignChanged
    from eha.campaigns.store import StoreError

    return (CampaignError, CampaignChanged, StoreError, *_input_errors())


def _fail_lines(text: str, code: int = BAD_INPUT) -> None:
    """One ``error:`` line per problem, then exit with ``code``."""
    for line in text.splitlines() or [text]:
        _error_line(line)
    raise typer.Exit(code)


def _load(file: Path):
    from eha.campaigns.files import CampaignError, load_campaign

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
    console.print(escape(f"{file}: campaign {camp.name!r} is valid, {len(camp.jobs)} jobs"))


@campaign_app.command("plan")
def campaign_plan(file: Path = typer.Argument(..., help="Campaign TOML file."),
                  workers: WorkersOption = WORKERS,
                  jobs: bool = typer.Option(False, "--jobs", help="List every job.")):
    """Show what a campaign would run: job counts and an estimated wall time.

    Example: eha campaign plan campaigns/thesis-single-fault.toml --jobs
    """
    from eha.campaigns.files import plan

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
    workers: WorkersOption = WORKERS,
    results: ResultsOption = RESULTS,
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
    from eha.campaigns.executors import check_scheduler
    from eha.campaigns.runner import run_campaign

    if scheduler is not None:
        try:
            check_scheduler(scheduler)
        except ValueError as exc:
            fail(str(exc))
    check_out_dir(results, "--results")
    camp = _load(file)
    try:
        s = run_campaign(camp, results, workers=workers, scheduler=scheduler, replace=replace,
                         progress=progress)
    except _campaign_errors() as exc:
        from eha.campaigns.store import StoreWriteError

        _fail_lines(str(exc), 1 if isinstance(exc, StoreWriteError) else BAD_INPUT)
    except RuntimeError as exc:  # e.g. cannot reach the Dask scheduler
        fail(str(exc), 1)
    except Terminated:
        fail("terminated (SIGTERM); finished runs are saved, re-run the same command to resume",
             TERMINATED)
    except KeyboardInterrupt:
        fail("interrupted; finished runs are saved, re-run the same command to resume", 130)
    if s.changed:
        console.print(f"{camp.name} changed since it was recorded: discarded {s.replaced} runs "
                      "it no longer has, kept the shared ones")
    console.print(escape(f"{s.campaign}: {s.total} runs, {s.done} run now, {s.skipped} already "
                         f"done, {s.failed} failed, {s.wall_s:.1f} s -> {results}/eha.duckdb"))
    for line in s.errors:  # a worker's message is text, brackets included
        err_console.print(f"failed: {escape(line)}", highlight=False, soft_wrap=True)
    if s.failed:
        raise typer.Exit(1)


@app.command()
def query(sql: str = typer.Argument(..., help="SQL (DuckDB dialect)."),
          results: ResultsOption = RESULTS,
          format: str = typer.Option("table", "--format", help="table, csv or json.")):
    """Query the result database read-only; Parquet traces are the view `traces`.

    Example: eha query "SELECT r.label, m.rmse_xu_hf_lf FROM runs r JOIN metrics m USING
    (run_key) WHERE r.campaign = 'thesis-matrix' AND r.model = 'hf'" --format csv
    """
    from eha.campaigns.query import query as run_query
    from eha.campaigns.store import StoreError

    if format not in ("table", "csv", "json"):
        fail(f"--format {format!r}: allowed table, csv, json")
    try:
        frame = run_query(results, sql)
    except StoreError as exc:
        fail(str(exc))
    try:
        if format == "csv":
            typer.echo(frame.to_csv(index=False), nl=False)
        elif format == "json":
            typer.echo(frame.to_json(orient="records", date_format="iso"))
        else:
            table = Table(*[str(c) for c in frame.columns])
            for row in frame.itertuples(index=False):
                table.add_row(*[f"{v:.6g}" if isinstance(v, float) else str(v) for v in row])
            console.print(table)
        sys.stdout.flush()  # a full disk or a closed pipe shows here, not silently at exit
    except OSError as exc:
        _discard_stdout()
        fail(f"query: the result could not be written to standard output "
             f"({exc.strerror or exc})", 1)


@app.command()
def export(table: str = typer.Argument(..., help="Table or view (campaigns, runs, metrics, "
                                                 "traces, ...)."),
           csv: Path = typer.Option(..., "--csv", help="CSV file to write."),
           results: ResultsOption = RESULTS):
    """Export a table of the result database to CSV.

    Example: eha export metrics --csv results/metrics.csv
    """
    from eha.campaigns.query import export_csv
    from eha.campaigns.store import StoreError

    check_out_file(csv, "--csv", (".csv",))
    try:
        n = export_csv(results, table, csv)
    except StoreError as exc:
        fail(str(exc))
    console.print(escape(f"{table}: {n} rows -> {csv}"))


@app.command()
def plot(campaign: str = typer.Argument(..., help="Campaign name (as in the database)."),
         results: ResultsOption = RESULTS,
         out: Optional[Path] = typer.Option(None, "--out",
                                            help="Folder (default RESULTS/plots/CAMPAIGN).")):
    """Campaign figures (PNG): HF vs LF xu and P12 per fault set, RMSE summary.

    Example: eha plot thesis-matrix --results results
    """
    from eha.reports.plots import plot_campaign
    from eha.campaigns.store import StoreError

    check_out_dir(out if out is not None else results / "plots" / campaign, "--out")
    try:
        paths = plot_campaign(results, campaign, out)
    except StoreError as exc:
        fail(str(exc))
    for p in paths:
        console.print(escape(str(p)))


# --------------------------------------------------------------------------- fault identification
@app.command()
def fdi(
    command: Optional[str] = typer.Option(None, "--command",
                                          help="Command of the HF reference (`eha commands`)."),
    set_: List[str] = typer.Option([], "--set", help="Fault injected in the HF reference, "
                                   "NAME=VALUE (repeatable)."),
    data: Optional[Path] = typer.Option(None, "--data", help="Measured record instead of an "
                                        "HF reference: CSV/Parquet with t, com, xu (SI)."),
    fit: str = typer.Option(
        ..., "--fit", default_factory=library_default("eha.identification.problem",
                                                      "DEFAULT_FIT", ",".join),
        help="LF parameters to identify."),
    bounds: List[str] = typer.Option([], "--bounds", help="Search bounds NAME=LO:HI "
                                     "(default BKL=0:1.25e-3, FDJ=200:4000, else the range)."),
    base: List[str] = typer.Option([], "--base", help="LF parameter held fixed, NAME=VALUE "
                                   "(e.g. orifice_law=1)."),
    method: str = typer.Option(
        ..., "--method", default_factory=library_default("eha.identification.problem",
                                                         "DEFAULT_METHOD"),
        help="ga (the thesis), ga+ps "
                               "(GA + pattern-search polish), ps (pattern search from the "
                               "--base / nominal values) or lm (least squares from them)."),
    pop: int = typer.Option(
        ..., "--pop", default_factory=signature_default("eha.identification.fdi",
                                                        "identify_source", "pop"),
        help="GA population."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed (and HF dither seed)."),
    objective: str = typer.Option("rmse", "--objective", help="rmse or objfcn (the thesis' "
                                  "mean absolute error)."),
    t_end: float = typer.Option(1.0, "--t-end",
                                help="Simulated time of the HF reference, in seconds."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the result as JSON."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="PNG: reference vs identified LF."),
    level: float = typer.Option(
        ..., "--level", default_factory=library_default("eha.identification.problem",
                                                        "DEFAULT_LEVEL"),
        help="Nominal coverage of the parameter intervals, in (0, 1)."),
    base_model: Optional[str] = typer.Option(
        None, "--base-model", help="LF model: plain (the thesis') or calibrated (by eha "
        "explain). Default: plain against an HF reference, calibrated on --data."),
    command_hold: CommandHoldOption = COMMAND_HOLD,
):
    """Identify LF fault parameters, each with an interval, from an HF reference or a
    measured record.

    Example: eha fdi --command chirp_1cm --set BKL=1e-4 --set FDJ=800 --fit BKL,FDJ --seed 0

    Example: eha fdi --data record.csv --fit BKL,FDJ,Clk --level 0.95 --json fit.json
    """
    from eha.identification.fdi import identify_source, parse_bounds
    from eha.identification.problem import FDIError
    from eha.identification.measured import MeasuredDataError
    from eha.models.params import parse_assignments

    check_names(fit, "--fit")
    check_seed(seed)
    check_command_hold(command_hold)
    if data is None and command_hold != COMMAND_HOLD:
        fail("--command-hold: only with --data (an HF reference is driven by its preset)")
    check_out_file(json_out, "--json", (".json",))
    check_out_file(plot, "--plot", PLOT_SUFFIXES)
    try:
        with err_console.status(f"identifying ({method}) ...") as status:
            def progress(gen: int, best: float) -> None:
                status.update(f"identifying ({method}): generation {gen}, best "
                              f"{objective} {best:.4g} m")

            run = identify_source(command=command, faults=parse_assignments(set_), data=data,
                                  fit=[n.strip() for n in fit.split(",") if n.strip()],
                                  bounds=parse_bounds(bounds), base=parse_assignments(base),
                                  method=method, pop=pop, seed=seed, objective=objective,
                                  t_end=t_end, on_generation=progress, level=level,
                                  base_model=base_model, command_hold=command_hold)
    except (FDIError, MeasuredDataError, *_input_errors()) as exc:
        fail(str(exc))
    res = run.result
    table = Table("parameter", "bounds", "injected", "identified",
                  f"{100 * res.level:g} % interval", "error [%]")
    for name in res.names:
        lo, hi = res.bounds[name]
        ilo, ihi = res.intervals[name]
        table.add_row(name, f"[{lo:g}, {hi:g}]",
                      f"{run.truth[name]:.6g}" if run.truth else "-",
                      f"{res.estimates[name]:.6g}", f"[{ilo:.5g}, {ihi:.5g}]",
                      f"{run.errors_pct[name]:+.3f}" if run.errors_pct else "-")
    hold = f"; command {run.command_hold}" if run.command_hold else ""
    console.print(f"reference: {run.source}; LF model: {run.base_model}{hold}")
    console.print(table)
    for note in res.notes:
        err_console.print(f"warning: {escape(note)}", highlight=False)
    mean = f"mean error {run.mean_err_pct:.3f} %, " if run.mean_err_pct is not None else ""
    console.print(f"{mean}{res.objective_name} {res.objective:.4g} m, {res.evaluations} "
                  f"evaluations, {res.seconds:.2f} s ({res.method}, seed {res.seed})")
    if json_out is not None:
        import json

        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(run.to_dict(), indent=2))
    if plot is not None:
        from eha.reports.plots import plot_traces

        plot_traces([run.reference, run.fitted], plot,
                    title=f"Identification ({res.method}): reference vs identified LF")


@app.command()
def explain(
    data: Path = typer.Argument(..., help="Measured record: CSV/TSV/Parquet with t, com, xu "
                                "(SI; aliases in docs/explain.md), optional p12, xs."),
    fit: str = typer.Option(
        ..., "--fit", default_factory=library_default("eha.identification.problem",
                                                      "DEFAULT_FIT", ",".join),
        help="Declared faults to fit: NAME or NAME=LO:HI, comma-separated."),
    effects: Optional[str] = typer.Option(None, "--effects", help="Candidate effects, "
                                          "comma-separated names of docs/model.md's effect "
                                          "table (default: all 14)."),
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
    results: ResultsOption = RESULTS,
    method: str = typer.Option(
        ..., "--method", default_factory=library_default("eha.identification.problem",
                                                         "DEFAULT_METHOD"),
        help="Optimizer of every fit (eha fdi)."),
    pop: int = typer.Option(
        ..., "--pop", default_factory=signature_default("eha.explain.api", "explain", "pop"),
        help="GA population of every fit."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed (same seed, same result)."),
    candidates: int = typer.Option(
        ..., "--candidates", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: int(d["candidates"])),
        help="Effects refitted per round, the best-ranked by "
                                        "signature (0 = all)."),
    max_steps: int = typer.Option(
        ..., "--max-steps", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: int(d["max_steps"])),
        help="Most effects added."),
    min_gain: float = typer.Option(
        ..., "--min-gain", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: d["min_gain"]),
        help="Smallest penalised held-out RMSE reduction that adds "
                                        "an effect."),
    p12_weight: float = typer.Option(
        ..., "--p12-weight", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: d["p12_weight"]),
        help="Weight of the record's measured P12 in every fit and score, each signal in its "
             "own noise (0 = position only; records without P12 use the position only)."),
    flow_gain_spread: float = typer.Option(
        ..., "--flow-gain-spread", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: d["flow_gain_spread"]),
        help="Fit the valve flow gain GQ with the faults within +- this fraction of nominal "
             "(the healthy actuator's own spread; 0 = held at nominal). E.g. 0.1."),
    alpha: float = typer.Option(
        ..., "--alpha", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: d["alpha"]),
        help="False-positive level per record: the chance that a healthy actuator driven by "
             "this command gets an effect added (thresholds from a healthy null)."),
    healthy: Optional[Path] = typer.Option(
        None, "--healthy", help="Folder of healthy records of your own actuators "
        "(commissioning tests, >= 5): the null instead of a simulated healthy fleet."),
    null_actuators: int = typer.Option(
        ..., "--null-actuators", default_factory=library_default(
            "eha.explain.settings", "DEFAULTS", lambda d: int(d["null_actuators"])),
        help="Healthy actuators of the simulated null (cached per command, sampling, noise)."),
    command_hold: CommandHoldOption = COMMAND_HOLD,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress display."),
):
    """Trace a measured record's residual to missing LF effects, add them, report the error.

    Example: eha explain data/run1.csv --fit BKL,FDJ --holdout 0.3 --json out.json

    Example (healthy actuator under a known 4 kN test load): eha explain loadtest.csv --set
    FRC=4000 --json calibration.json
    """
    from eha.explain import ExplainError
    from eha.identification.problem import FDIError
    from eha.identification.measured import MeasuredDataError
    from eha.explain.outputs import explain_report

    if holdout is not None and validate is not None:
        fail("--holdout and --validate exclude each other; give one")
    from eha.models.params import ParameterError, parse_assignments

    try:
        known_values = parse_assignments(known)
    except ParameterError as exc:
        fail(f"--set {exc}")
    if json_out is not None and json_out.suffix.lower() != ".json":
        fail(f"--json {json_out}: the file must end in .json")
    check_out_file(json_out, "--json")
    check_out_dir(results, "--results")
    check_out_dir(out if out is not None else results / "explain" / data.stem, "--out")
    check_names(fit, "--fit")
    check_seed(seed)
    check_command_hold(command_hold)
    if candidates < 0:
        fail(f"--candidates {candidates}: allowed range [0, ...] (0 = all)")
    if max_steps < 0:
        fail(f"--max-steps {max_steps}: allowed range [0, ...]")
    if not 0.0 <= min_gain <= 1.0:  # also refuses nan
        fail(f"--min-gain {min_gain}: allowed range [0, 1]")
    if not 0.0 <= p12_weight <= 100.0:
        fail(f"--p12-weight {p12_weight}: allowed range [0, 100]")
    if not 0.0 <= flow_gain_spread <= 0.5:
        fail(f"--flow-gain-spread {flow_gain_spread}: allowed range [0, 0.5]")
    if not 0.0 < alpha < 1.0:
        fail(f"--alpha {alpha}: allowed range (0, 1)")
    if null_actuators < 5:
        fail(f"--null-actuators {null_actuators}: allowed range [5, ...]")
    if healthy is not None and not healthy.is_dir():
        fail(f"--healthy {healthy}: not a folder")
    if prior is not None:
        check_prior(prior)
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
                                 known=known_values, command_hold=command_hold,
                                 results=results, on_progress=step, method=method, pop=pop,
                                 seed=seed, candidates=candidates, max_steps=max_steps,
                                 min_gain=min_gain, p12_weight=p12_weight,
                                 flow_gain_spread=flow_gain_spread, alpha=alpha,
                                 null=str(healthy) if healthy is not None else "simulate",
                                 null_actuators=null_actuators)
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
    for d in res.dismissed:
        if d.replaced_by:
            console.print(f"final check: {d.effect} replaced by {d.replaced_by}: the model "
                          f"with {d.replaced_by} in its place scores {-d.loss:.1%} better "
                          f"(p = {d.p_value:.2g})")
            continue
        when = (f"round {d.round + 1}: {d.effect} chosen but not added" if d.round <
                len(res.rounds) else f"final check: {d.effect} removed")
        console.print(f"{when}: with the rest of the model refitted without it, it reduces "
                      f"the RMSE by only {d.loss:.1%} (p = {d.p_value:.2g})")
    if res.settings.get("passes", 1) > 1:
        console.print("the first pass left the record unexplained; a second pass ran from the "
                      "structure pinned at its physical values: " +
                      ("its result is reported" if res.settings.get("structure_pinned")
                       else "not better by the loop's rule, the first pass is reported"))
    if res.settings.get("flow_gain_released"):
        console.print(f"{res.settings['flow_gain_released']}: a flow loss beyond a healthy "
                      f"actuator's spread; GQ was put back to its nominal value and no longer "
                      f"fitted")
    if res.settings.get("p12_used"):
        console.print(f"measured P12 used in every fit and score (noise taken as "
                      f"{res.settings['p12_noise_pa'] / 1e5:.3g} bar; --p12-weight "
                      f"{res.settings['p12_weight']:g})")
    console.print(f"RMSE {1e6 * res.rmse_before:.3g} → {1e6 * res.rmse_after:.3g} µm; noise "
                  f"level {1e6 * res.noise_rmse:.3g} µm; unexplained (above noise) "
                  f"{1e6 * res.unexplained_rmse:.3g} µm. Stopped: {res.stop_reason}")
    if res.intervals:
        console.print(f"final model, {100 * res.level:g} % intervals: " + "; ".join(
            f"{k} {getattr(res.after.params, k):.4g} [{lo:.4g}, {hi:.4g}]"
            for k, (lo, hi) in res.intervals.items()))
    console.print(f"verdict: {escape(res.verdict)}", highlight=False)
    if res.null:
        console.print(f"decisions at alpha {res.null['alpha']:g} against {res.null['source']}"
                      f" on this command; what this record could not have shown (the null's "
                      f"prediction, a lower bound: measured power in docs/explain.md):",
                      highlight=False)
        for line in res.undetectable():
            console.print(f"  {escape(line)}", highlight=False)
    if res.beyond_healthy:
        err_console.print("warning: the residual after the best library model is still well "
                          "above the noise: unexplained; the fault intervals are widened, "
                          "do not read the estimates as numbers", highlight=False)
    elif res.unexplained:
        err_console.print("warning: the residual is above the noise level: the effects added "
                          "are tentative, and an effect below this command's healthy band may "
                          "be missing", highlight=False)
    for kind, path in run["paths"].items():
        console.print(f"{kind}: {path}")
    if run["db_error"]:
        fail(f"results database not written: {run['db_error']}", code=1)


report_app = typer.Typer(no_args_is_help=True, help="Reports built from the result database."
                         "\n\nExample: eha report thesis --results results")
app.add_typer(report_app, name="report")


@report_app.command("thesis")
def report_thesis(results: ResultsOption = RESULTS,
                  out: Optional[Path] = typer.Option(None, "--out", help="Output folder "
                                                     "(default RESULTS/reports/thesis).")):
    """Thesis FDI table (Figure 6.17) beside the thesis' own values, figures, summary.

    From the thesis-fdi campaign's results: fdi_table.csv, mean_error.png (Figure 6.18),
    one HF-vs-identified-LF figure per case, fdi_summary.md.

    Example: eha report thesis --results results --out results/reports/thesis
    """
    from eha.reports.thesis import thesis_report
    from eha.campaigns.store import StoreError

    check_out_dir(out if out is not None else results / "reports" / "thesis", "--out")
    try:
        paths = thesis_report(results, out)
    except StoreError as exc:
        fail(str(exc), code=1)
    for kind, path in paths.items():
        console.print(f"{kind}: {path}")


@report_app.command("health")
def report_health(results: ResultsOption = RESULTS,
                  campaign: str = typer.Option("health-detection", "--campaign",
                                               help="Detection campaign (as in the database)."),
                  alpha: float = typer.Option(
                      ..., "--alpha", default_factory=library_default("eha.health.detection",
                                                                      "DEFAULT_ALPHA"),
                      help="Probability that a healthy check raises any alarm, in (0, 1)."),
                  out: Optional[Path] = typer.Option(None, "--out", help="Output folder "
                                                     "(default RESULTS/reports/health).")):
    """Detection performance of a detection campaign: ROC curves, minimum detectable faults,
    isolation confusion matrices (CSV and PNG).

    Run the campaign first: eha campaign run campaigns/health-detection.toml

    Example: eha report health --campaign health-detection --results results
    """
    from eha.identification.healthy import DetectionError
    from eha.health.monitoring import health_report
    from eha.campaigns.store import StoreError

    if not 0 < alpha < 1:
        fail(f"--alpha {alpha!r}: allowed range (0, 1)")
    check_out_dir(out if out is not None else results / "reports" / "health", "--out")
    try:
        paths = health_report(results, campaign, out, alpha)
    except (DetectionError, StoreError) as exc:
        fail(str(exc))
    for kind, path in paths.items():
        console.print(f"{kind}: {path}")


@report_app.command("html")
def report_html(results: ResultsOption = RESULTS,
                out: Optional[Path] = typer.Option(None, "--out", help="HTML file to write "
                                                   "(default RESULTS/reports/report.html)."),
                truth: Optional[Path] = typer.Option(None, "--truth", help="True end of life "
                                                     "of the fleet (truth.json of eha fleet "
                                                     "simulate, or CSV actuator,eol); default: "
                                                     "a truth.json beside the records.")):
    """One self-contained, interactive HTML report of a results folder (opens offline).

    Sections for what the folder holds: Fleet (eha rul), Health (eha health check, detection
    campaigns), Identification (FDI campaigns, the thesis table), Residual loop (eha explain),
    Campaigns (runs by status, HF-vs-LF errors). See docs/report.md.

    Example: eha report html --results results --out report.html
    """
    from eha.reports.html import ReportError, build_report
    from eha.campaigns.store import StoreError

    out = out if out is not None else results / "reports" / "report.html"
    check_out_file(out, "--out", (".html", ".htm"))
    if truth is not None and not truth.is_file():
        fail(f"--truth {truth}: file not found")
    try:
        res = build_report(results, out, truth)
    except ReportError as exc:
        fail(str(exc))
    except StoreError as exc:
        fail(str(exc), code=1)
    console.print(escape(f"report: {res.path} ({res.bytes / 1e6:.1f} MB, sections "
                         f"{', '.join(res.sections)}, {res.figures} figures, "
                         f"{res.seconds:.1f} s)"))


# --------------------------------------------------------------------------- health
health_app = typer.Typer(no_args_is_help=True,
                         help="Health assessment: calibrate thresholds on a healthy fleet, "
                              "check a record (every fault with an interval, healthy or "
                              "degraded, which fault).\n\nExample: eha health check record.csv "
                              "--calibration results/health/calibration-chirp_1cm.json")
app.add_typer(health_app, name="health")


@health_app.command("calibrate")
def health_calibrate(
    command: str = typer.Option("chirp_1cm", "--command",
                                help="Command of the checks (a preset, `eha commands`)."),
    actuators: int = typer.Option(30, "--actuators", min=5, max=10000,
                                  help="Healthy actuators in the fleet."),
    alpha: float = typer.Option(
        ..., "--alpha", default_factory=library_default("eha.health.detection", "DEFAULT_ALPHA"),
        help="Probability that a healthy check raises any alarm, in (0, 1)."),
    t_end: float = typer.Option(1.0, "--t-end", help="Record length [s], 0.2 to 10."),
    noise: float = typer.Option(1e-6, "--noise", help="Sensor noise std of the records [m]."),
    seed: int = typer.Option(0, "--seed", help="First actuator seed (dispersion, dither, "
                             "noise, optimizer)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Calibration file (default "
                                       "RESULTS/health/calibration-COMMAND.json)."),
    results: ResultsOption = RESULTS,
    workers: WorkersOption = WORKERS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Run a healthy fleet (manufacturing dispersion, sensor noise, dither) through the
    campaign runner and set each fault's threshold for the false-alarm probability --alpha.

    Dispersion (eha.identification.healthy.DISPERSION): +-3 % on GP, GQ, CJ, MJ and FSS, +-1 % on
    GM, FDJ ~ N(200, 20) N, Clk log-uniform in [0.7e-13, 1.4e-13].

    Example: eha health calibrate --command chirp_1cm --actuators 30 --alpha 0.01
    """
    from eha.campaigns.files import CampaignError
    from eha.identification.healthy import DetectionError
    from eha.health.monitoring import calibrate_fleet
    from eha.campaigns.store import StoreError

    check_seed(seed)
    check_out_file(out, "--out", (".json",))
    check_out_dir(results, "--results")
    if not 0 < alpha < 1:
        fail(f"--alpha {alpha!r}: allowed range (0, 1)")
    if not 0.2 <= t_end <= 10:
        fail(f"--t-end {t_end!r}: allowed range [0.2, 10] s")
    if not 0 <= noise <= 1e-3:
        fail(f"--noise {noise!r}: allowed range [0, 0.001] m")
    try:
        res = calibrate_fleet(command=command, actuators=actuators, seed=seed, t_end=t_end,
                              noise=noise, alpha=alpha, out=out, results=results,
                              workers=workers, progress=progress)
    except (DetectionError, CampaignError, StoreError, *_input_errors()) as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        fail("interrupted; finished assessments are saved, re-run the same command to resume",
             INTERRUPTED)
    cal = res["calibration"]
    from eha.health.detection import alarm_value

    table = Table("fault", "statistic: healthy mean", "healthy std", "alarm at",
                  "alarms in fleet")
    for name, thr in cal.thresholds.items():
        h = cal.healthy[name]
        table.add_row(name, f"{h['mean']:.4g}", f"{h['std']:.3g}", alarm_value(name, thr),
                      f"{cal.false_alarms['per_fault'][name]:.3f}")
    console.print(table)
    console.print(f"{actuators} healthy actuators on {command}; any-fault alarms in the fleet "
                  f"{cal.false_alarms['any']:.3f} (target {alpha:g}); calibration: "
                  f"{res['path']}; database {results}/eha.duckdb (health_thresholds, "
                  f"health_assessments)")


@health_app.command("check")
def health_check(
    record: Path = typer.Argument(..., help="Record: CSV/TSV/Parquet with t, com, xu (SI)."),
    calibration: Optional[Path] = typer.Option(None, "--calibration", help="Thresholds from "
                                               "eha health calibrate (without it: estimates "
                                               "and intervals, no verdict)."),
    level: Optional[float] = typer.Option(None, "--level", help="Nominal coverage of the "
                                          "intervals, in (0, 1) (default: the calibration's, "
                                          "else 0.9)."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the check as JSON."),
    results: ResultsOption = RESULTS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress display."),
):
    """Assess a record: every fault's estimate with its interval, healthy or degraded (with a
    calibration), and which fault(s) are isolated.

    Example: eha health check record.csv --calibration results/health/calibration-chirp_1cm.json
    --json check.json
    """
    from eha.identification.healthy import DetectionError
    from eha.identification.measured import MeasuredDataError
    from eha.health.monitoring import check_record

    check_seed(seed)
    check_out_file(json_out, "--json", (".json",))
    check_out_dir(results, "--results")
    if level is not None and not 0 < level < 1:
        fail(f"--level {level!r}: allowed range (0, 1)")
    try:
        with err_console.status("assessing ...") as status:
            run = check_record(record, calibration, level=level, seed=seed, json_path=json_out,
                               results=results,
                               on_progress=(lambda m: status.update(f"assessing: {m}"))
                               if progress else None)
    except MeasuredDataError as exc:
        _fail_lines("\n".join(f"{exc.source}: {p}" for p in exc.problems))
    except (DetectionError, *_input_errors()) as exc:
        fail(str(exc))
    from eha.health.detection import alarm_value

    a = run.assessment
    table = Table("fault", "estimate", f"{100 * a.level:g} % interval", "healthy", "alarm at",
                  "verdict", "weight")
    for v in run.verdicts:
        verdict = "-" if v.degraded is None else ("DEGRADED" if v.degraded else "healthy")
        if v.name in run.isolated:
            verdict += " (isolated)"
        table.add_row(v.name, f"{v.estimate:.4g}", f"[{v.interval[0]:.3g}, {v.interval[1]:.3g}]",
                      f"{v.healthy:.4g}", "-" if v.threshold is None else
                      alarm_value(v.name, v.threshold),
                      verdict, "-" if v.weight is None else f"{v.weight:.2f}")
    console.print(f"record: {record}; calibration: {run.calibration or 'none (no verdicts)'}")
    console.print(table)
    status_text = run.to_dict()["status"]
    console.print(f"status: {status_text}; isolated: {', '.join(run.isolated) or 'none'}; "
                  f"residual {1e6 * a.residual_rmse:.3g} µm, noise {1e6 * a.noise_rmse:.3g} µm, "
                  f"{a.seconds:.1f} s (seed {a.seed})")
    for note in a.notes:
        err_console.print(f"warning: {escape(note)}", highlight=False)
    for kind, path in run.paths.items():
        console.print(f"{kind}: {path}")
    if run.db_error:
        fail(f"results database not written: {run.db_error}", code=1)


# --------------------------------------------------------------------------- prognostics
fleet_app = typer.Typer(no_args_is_help=True,
                        help="Simulated fleets of degrading actuators (the prognostics test "
                             "bench).\n\nExample: eha fleet simulate examples/fleet-demo.toml "
                             "--out results/fleet-demo")
app.add_typer(fleet_app, name="fleet")


@fleet_app.command("simulate")
def fleet_simulate(
    file: Path = typer.Argument(..., help="Fleet TOML file (format in docs/prognostics.md)."),
    out: Path = typer.Option(..., "--out", help="Output folder: records/, manifest.csv, "
                             "truth.json, eha.duckdb."),
    workers: int = typer.Option(2, "--workers", min=1, help="Worker processes."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Simulate a fleet: HF check records with sensor noise, the manifest and the truth.

    Example: eha fleet simulate examples/fleet-demo.toml --out results/fleet-demo
    """
    from eha.prognostics.fleet import FleetError, load_fleet, simulate_fleet

    check_out_dir(out, "--out")
    try:
        fleet = load_fleet(file)
    except FleetError as exc:
        _fail_lines(str(exc))
    try:
        res = simulate_fleet(fleet, out, workers=workers, progress=progress)
    except FleetError as exc:
        _fail_lines(str(exc))
    except _campaign_errors() as exc:
        _fail_lines(str(exc))
    except KeyboardInterrupt:
        fail("interrupted; finished records are kept, re-run the same command to resume", 130)
    s = res.summary
    console.print(f"{fleet.name}: {res.actuators} actuators, {res.records} records "
                  f"({s.done} simulated now, {s.skipped} already there, {s.failed} failed), "
                  f"{res.censored} without end of life within max_cycles, {s.wall_s:.1f} s")
    console.print(f"manifest: {res.manifest}\ntruth: {res.truth}")
    if s.failed:
        raise typer.Exit(1)


@app.command()
def rul(
    manifest: Path = typer.Argument(..., help="Manifest CSV: actuator, cycle, record "
                                    "(records relative to its folder)."),
    limit: List[str] = typer.Option([], "--limit", help="End-of-life limit NAME=VALUE of a "
                                    "fault (SI, repeatable), e.g. FDJ=2000."),
    fit: str = typer.Option(
        ..., "--fit", default_factory=library_default("eha.prognostics.jobs", "RUL_FIT",
                                                      ",".join),
        help="Faults identified and tracked (comma-separated; limited faults are added). "
        "GM (motor gain) is tracked by default: its manufacturing dispersion would "
        "otherwise bias FDJ."),
    bounds: List[str] = typer.Option([], "--bounds", help="Search bounds NAME=LO:HI "
                                     "(default: eha fdi's, widened to twice the limit)."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the predictions "
                                            "(and metrics) as JSON."),
    results: ResultsOption = RESULTS,
    truth: Optional[Path] = typer.Option(None, "--truth", help="True end of life: truth.json "
                                         "of eha fleet simulate, or CSV actuator,eol; adds the "
                                         "prognostic metrics."),
    plots: Optional[Path] = typer.Option(None, "--plots", help="Folder for the PNG plots and "
                                         "the fleet summary table."),
    laws: str = typer.Option("linear,exponential,power", "--laws", help="Degradation laws "
                             "averaged by evidence."),
    seed: int = typer.Option(0, "--seed", help="Seed of the identifications and RUL draws."),
    workers: WorkersOption = WORKERS,
    skip_flagged: bool = typer.Option(False, "--skip-flagged", help="Leave records the "
                                      "monitoring model does not explain out of the fits."),
    base_model: Optional[str] = typer.Option(None, "--base-model", help="LF base of the "
                                             "assessment: plain or calibrated (default: as "
                                             "eha fdi --data)."),
    limit_error: Optional[float] = typer.Option(None, "--limit-error", help="Relative std "
                                                "of the assessment's systematic error "
                                                "(default 0.02)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Remaining useful life from health histories: assess each record, fit degradation
    trends, predict when each limited fault reaches its limit (median, 5 %, 95 %).

    Example: eha rul results/fleet-demo/manifest.csv --limit BKL=5e-4 --limit FDJ=2000
    --json results/rul.json --truth results/fleet-demo/truth.json --plots results/rul
    """
    from eha.identification.fdi import parse_bounds
    from eha.identification.problem import FDIError
    from eha.prognostics.manifest import ManifestError
    from eha.prognostics.degradation import PrognosticsError
    from eha.prognostics.jobs import parse_limits, run_rul

    check_out_file(json_out, "--json", (".json",))
    check_out_dir(plots, "--plots")
    check_out_dir(results, "--results")
    check_seed(seed)
    try:
        res = run_rul(manifest, parse_limits(limit),
                      fit=[n.strip() for n in fit.split(",") if n.strip()],
                      bounds=parse_bounds(bounds), results=results, json_out=json_out,
                      truth=truth, plots=plots, seed=seed, workers=workers,
                      laws=[x.strip() for x in laws.split(",") if x.strip()],
                      skip_flagged=skip_flagged, progress=progress, limit_error=limit_error,
                      base_model=base_model)
    except ManifestError as exc:
        _fail_lines(str(exc))
    except (PrognosticsError, FDIError) as exc:
        fail(str(exc))
    except _campaign_errors() as exc:
        _fail_lines(str(exc))
    except KeyboardInterrupt:
        fail("interrupted; finished assessments are saved, re-run to resume", 130)
    table = Table("actuator", "checks", "last cycle", "RUL median", "RUL 5 %", "RUL 95 %",
                  "driver")
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    for aid, preds in res.predictions.items():
        last = preds[-1] if preds else None
        table.add_row(aid, str(len(preds)), fmt(last.cycle if last else None),
                      fmt(last.rul if last else None), fmt(last.rul_lo if last else None),
                      fmt(last.rul_hi if last else None), (last.driver if last else None)
                      or "-")
    console.print(table)
    if res.metrics:
        f = res.metrics["fleet"]
        pct = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
        console.print(f"alpha-lambda (alpha 0.2) over lambda in [0.5, 0.95]: "
                      f"{pct(f.get('alpha_lambda_fraction'))} of "
                      f"{f.get('alpha_lambda_checks')} checks; at 0.5: "
                      f"{pct(f['alpha_lambda'].get('0.5'))}, at 0.75: "
                      f"{pct(f['alpha_lambda'].get('0.75'))}; 90 % interval coverage "
                      f"{pct(f.get('coverage'))}; median width at lambda 0.5: "
                      f"{f.get('median_width_rel_at_0.5') or float('nan'):.2f} x true RUL")
    console.print(f"{res.assessed} records assessed now, {res.reused} reused; "
                  f"{res.seconds['total']:.1f} s -> {results}/eha.duckdb ({res.run_id})")
    for kind, path in res.paths.items():
        if kind != "database":
            console.print(f"{kind}: {path}")
    for line in res.failed:
        err_console.print(f"failed: {line}", highlight=False, soft_wrap=True)
    if res.failed:
        raise typer.Exit(1)


@app.command()
def limits(
    fault: str = typer.Option(..., "--fault", help="HF fault parameter, e.g. FDJ or BKL."),
    require: str = typer.Option(..., "--require", help="Failure condition METRIC(COMMAND) "
                                "OP VALUE, e.g. 'lag(mixed) > 0.02' (docs/prognostics.md)."),
    lo: float = typer.Option(..., "--lo", help="Fault value where the requirement holds."),
    hi: float = typer.Option(..., "--hi", help="Fault value where it fails."),
    set_: List[str] = typer.Option([], "--set", help="Other HF parameter NAME=VALUE held "
                                   "fixed (repeatable)."),
    tol: float = typer.Option(1e-3, "--tol", help="Bisection stops below tol*(hi-lo)."),
    seed: int = typer.Option(0, "--seed", help="HF dither seed."),
    t_end: float = typer.Option(1.0, "--t-end", help="Simulated time [s]."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the result as JSON."),
):
    """Derive a fault limit from a performance requirement by HF simulation (bisection).

    Example: eha limits --fault FDJ --require "lag(mixed) > 0.02" --lo 200 --hi 20000
    """
    from eha.models.params import parse_assignments
    from eha.prognostics.degradation import PrognosticsError
    from eha.prognostics.limits import derive_limit

    check_out_file(json_out, "--json", (".json",))
    check_seed(seed)
    try:
        res = derive_limit(fault, require, lo, hi, base=parse_assignments(set_), tol=tol,
                           seed=seed, t_end=t_end)
    except (PrognosticsError, *_input_errors()) as exc:
        fail(str(exc))
    console.print(f"{fault} limit for '{res.requirement}': {res.limit:.6g} "
                  f"({len(res.points)} HF runs, bracket [{lo:g}, {hi:g}], tol {tol:g})")
    if json_out is not None:
        import json

        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(res.to_dict(), indent=1))
        console.print(f"json: {json_out}")


def main() -> None:  # pragma: no cover
    app(prog_name="eha")
