"""Reports: ``eha report thesis|health|html`` and ``eha reproduce`` (the thesis' chapters 5
and 6 end to end).

Each command imports the report it builds inside its function: ``eha query`` and ``eha
--help`` must not pay for the plotting and simulation stacks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from eha.cli.guard import console, err_console, fail
from eha.cli import defaults
from eha.cli.options import (RESULTS, WORKERS, ResultsOption, WorkersOption, check_out_dir,
                             check_out_file, print_paths)

report_app = typer.Typer(no_args_is_help=True, help="Reports built from the result database."
                         "\n\nExample: eha report thesis --results results")


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

    check_out_dir(out if out is not None else results / "reports" / "thesis", "--out")
    print_paths(thesis_report(results, out))


@report_app.command("health")
def report_health(results: ResultsOption = RESULTS,
                  campaign: str = typer.Option("health-detection", "--campaign",
                                               help="Detection campaign (as in the database)."),
                  alpha: float = typer.Option(
                      ..., "--alpha", default_factory=defaults.health_alpha,
                      help="Probability that a healthy check raises any alarm, in (0, 1)."),
                  out: Optional[Path] = typer.Option(None, "--out", help="Output folder "
                                                     "(default RESULTS/reports/health).")):
    """Detection performance of a detection campaign: ROC curves, minimum detectable faults,
    isolation confusion matrices (CSV and PNG).

    Run the campaign first: eha campaign run campaigns/health-detection.toml

    Example: eha report health --campaign health-detection --results results
    """
    from eha.health.monitoring import health_report

    check_out_dir(out if out is not None else results / "reports" / "health", "--out")
    print_paths(health_report(results, campaign, out, alpha))


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
    from eha.reports.html import build_report

    out = out if out is not None else results / "reports" / "report.html"
    check_out_file(out, "--out", (".html", ".htm"))
    if truth is not None and not truth.is_file():
        fail(f"--truth {truth}: file not found")
    res = build_report(results, out, truth)
    console.print(f"report: {res.path} ({res.bytes / 1e6:.1f} MB, sections "
                  f"{', '.join(res.sections)}, {res.figures} figures, "
                  f"{res.seconds:.1f} s)")


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
    out = reproduce_thesis(results, workers=workers, on_phase=lambda message: err_console.print(
        f"{message} ...", highlight=False, markup=False))
    _render_reproduce(out, results)


def _render_reproduce(out, results: Path) -> None:
    """The campaigns run, the HF-vs-LF errors, where the plots and reports are."""
    table = Table("campaign", "runs", "run now", "already done", "failed", "wall [s]")
    for s in out.summaries:
        table.add_row(s.campaign, str(s.total), str(s.done), str(s.skipped), str(s.failed),
                      f"{s.wall_s:.1f}")
        if s.changed:
            console.print(f"{s.campaign}: its file changed; {s.replaced} old runs discarded")
    console.print(table)
    table = Table("command", "RMSE xu HF vs LF [µm]", "% of command peak")
    for r in out.nominal:
        table.add_row(r["command"], f"{1e6 * r['rmse_xu_m']:.2f}", f"{r['rmse_pct_of_peak']:.3f}")
    console.print(table)
    console.print(f"{len(out.plots)} plots under {results}/plots, reports under "
                  f"{results}/reports (summary.md), database {results}/eha.duckdb")
    console.print(f"thesis fault identification (Figure 6.17): {out.fdi['table']}, "
                  f"{out.fdi['plot'].name}, {out.fdi['summary'].name}")
    html = out.html
    console.print(f"report (open in a browser): {html.path} "
                  f"({html.bytes / 1e6:.1f} MB, {html.seconds:.1f} s)")
