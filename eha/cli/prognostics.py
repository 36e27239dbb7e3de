"""Prognostics: ``eha fleet simulate`` (the test bench of degrading actuators), ``eha rul``
(remaining useful life from health histories) and ``eha limits`` (a fault limit from a
performance requirement).

The prognostics stack (numba kernels, the optimizers) is imported inside the commands: ``eha
query`` and ``eha --help`` must not pay for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer
from rich.table import Table

from eha.cli.guard import console, keywords_as, resumable, warn
from eha.cli import defaults
from eha.cli.options import (RESULTS, WORKERS, ColumnsOption, ResultsOption, UnitsOption,
                             WorkersOption, check_out_dir, check_out_file, check_seed,
                             print_paths, split_names, write_json)

fleet_app = typer.Typer(no_args_is_help=True,
                        help="Simulated fleets of degrading actuators (the prognostics test "
                             "bench).\n\nExample: eha fleet simulate examples/fleet-demo.toml "
                             "--out results/fleet-demo")


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
    from eha.prognostics.fleet import load_fleet, simulate_fleet

    check_out_dir(out, "--out")
    fleet = load_fleet(file)
    with resumable("finished records are kept, re-run the same command to resume"):
        res = simulate_fleet(fleet, out, workers=workers, progress=progress)
    s = res.summary
    console.print(f"{fleet.name}: {res.actuators} actuators, {res.records} records "
                  f"({s.done} simulated now, {s.skipped} already there, {s.failed} failed), "
                  f"{res.censored} without end of life within max_cycles, {s.wall_s:.1f} s")
    console.print(f"manifest: {res.manifest}\ntruth: {res.truth}")
    if s.failed:
        raise typer.Exit(1)


#: The options of ``eha rul`` that only it takes (module level: the command stays short).
RUL_MANIFEST = typer.Argument(..., help="Manifest CSV: actuator, cycle, record (records "
                              "relative to its folder; SI, or see --columns, --units; a row's "
                              "own columns, units cells override them).")
RUL_LIMIT = typer.Option([], "--limit", help="End-of-life limit NAME=VALUE of a fault (SI, "
                         "repeatable), e.g. FDJ=2000.")
RUL_FIT = typer.Option(..., "--fit", default_factory=defaults.rul_faults,
                       help="Faults identified and tracked (comma-separated; limited faults "
                       "are added). GM (motor gain) is tracked by default: its manufacturing "
                       "dispersion would otherwise bias FDJ.")
RUL_BOUNDS = typer.Option([], "--bounds", help="Search bounds NAME=LO:HI (default: eha fdi's, "
                          "widened to twice the limit).")
RUL_JSON = typer.Option(None, "--json", help="Write the predictions (and metrics) as JSON.")
RUL_TRUTH = typer.Option(None, "--truth", help="True end of life: truth.json of eha fleet "
                         "simulate, or CSV actuator,eol; adds the prognostic metrics.")
RUL_PLOTS = typer.Option(None, "--plots", help="Folder for the PNG plots and the fleet summary "
                         "table.")
RUL_LAWS = typer.Option("linear,exponential,power", "--laws", help="Degradation laws averaged "
                        "by evidence.")
RUL_SEED = typer.Option(0, "--seed", help="Seed of the identifications and RUL draws.")
RUL_SKIP_FLAGGED = typer.Option(False, "--skip-flagged", help="Leave records the monitoring "
                                "model does not explain out of the fits.")
RUL_BASE_MODEL = typer.Option(None, "--base-model", help="LF base of the assessment: plain or "
                              "calibrated (default: as eha fdi --data).")
RUL_LIMIT_ERROR = typer.Option(None, "--limit-error", help="Relative std of the assessment's "
                               "systematic error (default 0.02).")
RUL_CHECK = typer.Option("fleet", "--check", help="Health check of the histories: fleet (each "
                         "record identified) or change (each record's change since its "
                         "actuator's baseline: the first record, or the manifest's baseline "
                         "column; needs --calibration).")
RUL_CALIBRATION = typer.Option(None, "--calibration", help="With --check change: a change "
                               "calibration for the records' command, length and noise (eha "
                               "health calibrate --baseline).")
RUL_TREND = typer.Option("identified", "--trend", help="With --check change, the histories of "
                         "the RUL: identified (every record identified, as --check fleet) or "
                         "changes (only the baselines identified, each record its baseline + "
                         "change: faster, biased when several faults grow together).")
RUL_OPERATING_POINT = typer.Option("baseline", "--operating-point", help="With --check change, "
                                   "where each actuator's check is calibrated: baseline (again "
                                   "at its baseline's identified faults, about 20 s each: a "
                                   "fault's signature changes with the faults already there) or "
                                   "calibration (the --calibration file as it is).")
PROGRESS = typer.Option(True, "--progress/--no-progress", help="Progress bar.")


@keywords_as(limits="--limit")
def rul(
    manifest: Path = RUL_MANIFEST,
    limit: List[str] = RUL_LIMIT,
    fit: str = RUL_FIT,
    bounds: List[str] = RUL_BOUNDS,
    json_out: Optional[Path] = RUL_JSON,
    results: ResultsOption = RESULTS,
    truth: Optional[Path] = RUL_TRUTH,
    plots: Optional[Path] = RUL_PLOTS,
    laws: str = RUL_LAWS,
    seed: int = RUL_SEED,
    workers: WorkersOption = WORKERS,
    skip_flagged: bool = RUL_SKIP_FLAGGED,
    base_model: Optional[str] = RUL_BASE_MODEL,
    limit_error: Optional[float] = RUL_LIMIT_ERROR,
    columns: ColumnsOption = None,
    units: UnitsOption = None,
    check: str = RUL_CHECK,
    calibration: Optional[Path] = RUL_CALIBRATION,
    trend: str = RUL_TREND,
    operating_point: str = RUL_OPERATING_POINT,
    progress: bool = PROGRESS,
):
    """Remaining useful life from health histories: assess each record, fit degradation
    trends, predict when each limited fault reaches its limit (median, 5 %, 95 %).

    --columns and --units apply to every record of the manifest but those whose row has its
    own columns or units.

    Example: eha rul results/fleet-demo/manifest.csv --limit BKL=5e-4 --limit FDJ=2000
    --json results/rul.json --truth results/fleet-demo/truth.json --plots results/rul

    Example (records headed time_s,command_mm,position_mm): eha rul manifest.csv --limit
    FDJ=2000 --columns t=time_s,com=command_mm,xu=position_mm
    Example (the change check): eha rul manifest.csv --limit FDJ=2000 --check change
    --calibration CAL.json"""
    from eha.identification.fdi import parse_bounds
    from eha.prognostics.jobs import parse_limits

    run_rul, extra = _rul_of(check, calibration, trend, operating_point)

    check_out_file(json_out, "--json", (".json",))
    check_out_dir(plots, "--plots")
    check_out_dir(results, "--results")
    check_seed(seed)
    with resumable("finished assessments are saved, re-run to resume"):
        res = run_rul(manifest, limits=parse_limits(limit), fit=split_names(fit),
                      bounds=parse_bounds(bounds), results=results, truth=truth, seed=seed,
                      workers=workers, laws=split_names(laws), skip_flagged=skip_flagged,
                      progress=progress, limit_error=limit_error, base_model=base_model,
                      columns=columns, units=units, **extra)
    if json_out is not None:
        res.save(json_out)
    if plots is not None:
        res.plot(plots)
    _render_rul(res, results)
    if res.failed:
        raise typer.Exit(1)


def _rul_of(check: str, calibration: Optional[Path], trend: str, operating_point: str):
    """The library function of ``eha rul --check`` and its extra keywords."""
    if check == "fleet" and calibration is None and trend == "identified" and \
            operating_point == "baseline":
        from eha.prognostics.jobs import run_rul

        return run_rul, {}
    from eha.prognostics.change_rul import run_rul_change   # it refuses a bad pair in one line

    return run_rul_change, {"check": check, "calibration": calibration, "trend": trend,
                            "operating_point": operating_point}


def _render_rul(res, results: Path) -> None:
    """The last prediction of each actuator, the fleet's metrics, the files, the failures."""
    # cycles: the unit of the manifest's cycle column (cycles or hours), the RUL's too
    table = Table("actuator", "checks", "last check [cycles]", "RUL median [cycles]",
                  "RUL 5 % [cycles]", "RUL 95 % [cycles]", "driver")
    fmt = lambda v: "-" if v is None else f"{v:.0f}"  # noqa: E731
    for aid, preds in res.predictions.items():
        last = preds[-1] if preds else None
        table.add_row(aid, str(len(preds)), fmt(last.cycle if last else None),
                      fmt(last.rul if last else None), fmt(last.rul_lo if last else None),
                      fmt(last.rul_hi if last else None), (last.driver if last else None)
                      or "-")
    console.print(table)
    if res.output.get("check") == "change":
        _render_alarms(res.output)
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
    print_paths(res.paths, skip=("database",))
    for line in res.failed:
        warn(line, "failed")


def _render_alarms(output) -> None:
    """The change check's first alarm of each fault per actuator (cycles)."""
    acts = output["actuators"]
    names = list(output["fit"])
    table = Table("actuator", "baseline cycle",
                  *[f"{n} first alarm (confirmed)" for n in names],
                  title="change check: first alarm since the baseline")
    fmt = lambda v: "-" if v is None else f"{v:g}"  # noqa: E731
    screened = False
    for aid, a in acts.items():
        fa = a.get("first_alarms", {})
        cells = []
        for n in names:
            f = fa.get(n, {})
            mark = "*" if f.get("at_baseline") else ""
            screened = screened or bool(mark)
            cells.append(f"{fmt(f.get('first_alarm'))}{mark} ({fmt(f.get('first_confirmed'))})")
        table.add_row(aid, fmt(a.get("baseline_cycle")), *cells)
    console.print(table)
    if screened:
        console.print("* at the baseline: the baseline record itself is unlike the healthy "
                      "fleet, farthest in this fault (the calibration's screen)",
                      highlight=False)


@keywords_as(requirement="--require")
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
    t_end: float = typer.Option(1.0, "--t-end", help="Simulated time in s."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the result as JSON."),
):
    """Derive a fault limit from a performance requirement by HF simulation (bisection).

    Example: eha limits --fault FDJ --require "lag(mixed) > 0.02" --lo 200 --hi 20000
    """
    from eha.models.params import parse_assignments
    from eha.prognostics.limits import derive_limit

    check_out_file(json_out, "--json", (".json",))
    check_seed(seed)
    res = derive_limit(fault, require, lo, hi, base=parse_assignments(set_, "--set"), tol=tol,
                       seed=seed, t_end=t_end)
    from eha.models.params import SPECS

    unit = f" {SPECS[fault].unit}" if fault in SPECS and SPECS[fault].unit not in ("", "-") \
        else ""
    nominal = SPECS[fault].nominal if fault in SPECS else None
    change = (f", {100 * (res.limit - nominal) / nominal:+.0f} % of its nominal {nominal:g}"
              f"{unit}" if nominal else f", nominal {nominal:g}{unit}"
              if nominal is not None else "")
    console.print(f"{fault} limit for '{res.requirement}': {res.limit:.6g}{unit}{change} "
                  f"({len(res.points)} HF runs, bracket [{lo:g}, {hi:g}]{unit}, tol {tol:g})",
                  highlight=False)
    if json_out is not None:
        write_json(json_out, res.to_dict(), indent=1)
        console.print(f"json: {json_out}")
