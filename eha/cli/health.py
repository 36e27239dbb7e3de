"""Health assessment: ``eha health calibrate`` (thresholds from a healthy fleet) and ``eha
health check`` (a record: every fault with an interval, healthy or degraded, which fault).

The assessment stack (numba kernels, the optimizers) is imported inside the commands: ``eha
query`` and ``eha --help`` must not pay for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from eha.cli.guard import console, err_console, fail, resumable, warn
from eha.cli import defaults
from eha.cli.options import (RESULTS, WORKERS, ColumnsOption, ResultsOption, UnitsOption,
                             WorkersOption, check_out_dir, check_out_file, check_seed,
                             print_paths, record_file)

health_app = typer.Typer(no_args_is_help=True,
                         help="Health assessment: calibrate thresholds on a healthy fleet, "
                              "check a record (every fault with an interval, healthy or "
                              "degraded, which fault).\n\nExample: eha health check record.csv "
                              "--calibration results/health/calibration-chirp_1cm.json")


#: ``eha health calibrate --baseline``'s own options (module level: the command stays short).
NUISANCE = typer.Option(
    None, "--nuisance", help="With --baseline: a test-day difference NAME=HALFWIDTH "
    "(repeatable; defaults CJ=0.05, FDJ=0.05, GQ=0.01, PSR=0.02 relative, Ofs=0.002 mA).")
OPERATING_POINT = typer.Option(
    None, "--at", help="With --baseline: the operating point, a fault level NAME=VALUE the "
    "baseline already has (SI, repeatable, e.g. from eha health check BASELINE): the pairs "
    "and signatures are taken there (default healthy).")


@health_app.command("calibrate")
def health_calibrate(
    command: str = typer.Option("chirp_1cm", "--command",
                                help="Command of the checks (a preset, `eha commands`)."),
    actuators: int = typer.Option(30, "--actuators",
                                  help="Healthy actuators in the fleet, 5 to 10000."),
    alpha: float = typer.Option(
        ..., "--alpha", default_factory=defaults.health_alpha,
        help="Probability that a healthy check raises any alarm, in (0, 1)."),
    t_end: Optional[float] = typer.Option(None, "--t-end", help="Record length in s, 0.2 to "
                                          "10 (default: a command file's own length, else 1)."),
    noise: float = typer.Option(1e-6, "--noise", help="Sensor noise std of the records in m."),
    signals: str = typer.Option("xu", "--signals", help="What the checks fit: xu (the "
                                "position) or xu,p12 (and the load pressure; the records "
                                "checked must then have a p12 column)."),
    noise_p12: float = typer.Option(..., "--noise-p12", default_factory=defaults.noise_p12,
                                    help="Load-pressure sensor noise std "
                                    "of the records in Pa (with --signals xu,p12)."),
    seed: int = typer.Option(0, "--seed", help="First actuator seed (dispersion, dither, "
                             "noise, optimizer)."),
    baseline: bool = typer.Option(False, "--baseline", help="Calibrate the change check "
                                  "instead (eha health check RECORD --baseline EARLIER): "
                                  "healthy pairs, each actuator recorded twice on two test "
                                  "days (--nuisance), in seconds, without the campaign runner."),
    nuisance: Optional[list[str]] = NUISANCE,
    at: Optional[list[str]] = OPERATING_POINT,
    out: Optional[Path] = typer.Option(None, "--out", help="Calibration file (default "
                                       "RESULTS/health/calibration-COMMAND.json, "
                                       "...-baseline.json with --baseline)."),
    results: ResultsOption = RESULTS,
    workers: WorkersOption = WORKERS,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bar."),
):
    """Run a healthy fleet (manufacturing dispersion, sensor noise, dither) through the
    campaign runner and set each fault's threshold for the false-alarm probability --alpha.

    Dispersion (eha.identification.healthy.DISPERSION, declared with the faults: eha faults):
    +-3 % on GP, GQ, CJ, MJ and FSS, +-1 % on GM, FDJ ~ N(200, 20) N, Clk log-uniform in
    [0.7e-13, 1.4e-13] m^3/(Pa*s).

    Example: eha health calibrate --command chirp_1cm --actuators 30 --alpha 0.01

    With --signals xu,p12 the checks fit the load pressure too: a leak that the position
    alone reads as jack friction shows as leakage (docs/design.md).
    """
    check_seed(seed)
    check_out_file(out, "--out", (".json",))
    check_out_dir(results, "--results")
    t_end = _own_length(command) if t_end is None else t_end
    if baseline or nuisance or at:
        return _calibrate_baseline(command, actuators, alpha, t_end, noise, seed,
                                   (nuisance, at), out, results, progress, baseline)
    from eha.health.monitoring import calibrate_fleet
    with resumable("finished assessments are saved, re-run the same command to resume"):
        res = calibrate_fleet(command=command, actuators=actuators, seed=seed, t_end=t_end,
                              noise=noise, alpha=alpha, out=out, results=results,
                              workers=workers, progress=progress,
                              signals=tuple(signals.split(",")), noise_p12=noise_p12)
    _render_calibration(res, actuators, command, alpha, results)


def _own_length(command: str) -> float:
    """A command file's own length, else 1 s (a 0.5-s design is calibrated for 0.5 s)."""
    from eha.models.commands import CommandError, default_duration

    try:
        return default_duration(command)
    except (CommandError, ValueError, OSError):
        return 1.0    # the calibration itself names what is wrong with the command


def _parse_pairs(items: Optional[list[str]], flag: str, example: str) -> dict[str, float]:
    """``NAME=NUMBER`` items of a repeatable option."""
    out = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            fail(f"{flag} {item!r}: {example}")
        if not sep:
            fail(f"{flag} {item!r}: {example}")
    return out


def _calibrate_baseline(command, actuators, alpha, t_end, noise, seed, nuisance_at, out,
                        results, progress, baseline) -> None:
    from eha.health.change_check import calibrate_baseline
    from eha.models.units import show

    nuisance, at = nuisance_at
    if not baseline:
        flag = "--nuisance" if nuisance else "--at"
        fail(f"{flag}: only with --baseline (the test-day differences and the operating point "
             "of the change check)")
    widths = _parse_pairs(nuisance, "--nuisance", "NAME=HALFWIDTH, e.g. GQ=0.01")
    point = _parse_pairs(at, "--at", "NAME=VALUE, e.g. BKL=2e-5")
    with err_console.status("calibrating the change check ...") as status:
        res = calibrate_baseline(command=command, actuators=actuators, seed=seed, t_end=t_end,
                                 noise=noise, alpha=alpha, nuisances=widths, out=out,
                                 results=results, at=point,
                                 on_progress=(lambda m: status.update(f"calibrating: {m}"))
                                 if progress else None)
    cal = res["calibration"]
    table = Table("fault", "what", "alarm at a change since the baseline of",
                  "healthy pairs' std of the change")
    from eha.health.change_calibration import sign_of
    from eha.models.faults import FAULTS

    for name, f in cal.faults.items():
        curve = cal.gain(name)
        sign = "±" if f["two_sided"] else ("+" if sign_of(name) > 0 else "-")
        at = curve.invert(sign_of(name) * f["threshold"], sign_of(name))
        table.add_row(name, FAULTS[name].description, f"{sign}{show(name, abs(at))}",
                      show(name, f["std"] / max(curve.gains[0] if curve.gains else 1.0, 1e-12)))
    console.print(f"change check calibrated on {actuators} healthy pairs of {command} "
                  f"({t_end:g} s, {1e6 * noise:g} µm noise); test-day differences: "
                  + ", ".join(f"{n} ±{w:g}{' mA' if n == 'Ofs' else ''}"
                              for n, w in cal.nuisances.items())
                  + ("; at " + ", ".join(f"{n} {show(n, v)}" for n, v in
                                          cal.operating_point.items())
                     if cal.operating_point else ""), highlight=False)
    console.print(table)
    heavy = [n for n, f in cal.faults.items() if f.get("tail", 1.0) > 1.1]
    if heavy and actuators < 100:
        warn(f"the healthy pairs' tail is heavier than normal in {', '.join(heavy)} on this "
             f"command (thresholds widened for it); with {actuators} pairs the widening may "
             "fall short (on the step command test: 5 of 200 held-out pairs alarmed at alpha "
             "0.01 with 30 pairs, 6 of 600 with 100): calibrate with --actuators 100")
    fa = cal.false_alarms
    console.print(f"alarms among the calibration's pairs: {fa['in_sample']} of {fa['n']} "
                  f"(leave-one-out {fa['loo']['alarms']} of {fa['loo']['n']}; target alpha "
                  f"{alpha:g}); calibration: {res['path']}", highlight=False)


def _render_calibration(res: dict, actuators: int, command: str, alpha: float,
                        results: Path) -> None:
    from eha.health.detection import alarm_value
    from eha.models.faults import FAULTS
    from eha.models.units import display_unit, show

    cal = res["calibration"]
    # the fleet's statistic is a deviation from the healthy value; the alarm an absolute value
    table = Table("fault", "healthy value", "fleet's deviation from it: mean", "std",
                  "alarm at (value)", "alarms in fleet")
    for name, thr in cal.thresholds.items():
        h = cal.healthy[name]
        unit, scale = display_unit(name)
        table.add_row(name, show(name, FAULTS[name].healthy),
                      show(name, h["mean"]), show(name, h["std"]),
                      f"{alarm_value(name, thr, scale)} {unit}".rstrip(),
                      f"{cal.false_alarms['per_fault'][name]:.3f}")
    console.print(table)
    console.print(f"{actuators} healthy actuators on {command}; any-fault alarms in the fleet "
                  f"{cal.false_alarms['any']:.3f} (target {alpha:g}); calibration: "
                  f"{res['path']}; database {results}/eha.duckdb (health_thresholds, "
                  f"health_assessments)")


@health_app.command("check")
def health_check(
    record: Path = typer.Argument(..., help="Record: CSV/TSV/Parquet with t, com, xu (SI, or "
                                  "see --columns, --units)."),
    calibration: Optional[Path] = typer.Option(None, "--calibration", help="Thresholds from "
                                               "eha health calibrate (without it: estimates "
                                               "and intervals, no verdict)."),
    level: Optional[float] = typer.Option(None, "--level", help="Nominal coverage of the "
                                          "intervals, in (0, 1) (default: the calibration's, "
                                          "else 0.9)."),
    seed: int = typer.Option(0, "--seed", help="Optimizer seed."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Write the check as JSON."),
    baseline: Optional[Path] = typer.Option(None, "--baseline", help="The same actuator's "
                                            "earlier record on the same command (its "
                                            "acceptance test): judge the change since it, "
                                            "with a calibration made by eha health calibrate "
                                            "--baseline."),
    results: ResultsOption = RESULTS,
    columns: ColumnsOption = None,
    units: UnitsOption = None,
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress display."),
):
    """Assess a record: every fault's estimate with its interval, healthy or degraded (with a
    calibration), and which fault(s) are isolated.

    Example: eha health check record.csv --calibration results/health/calibration-chirp_1cm.json
    --json check.json

    Example (a record in millimetres without units in its header): eha health check rec.csv
    --units mm
    """
    from eha.health.monitoring import check_record

    check_seed(seed)
    if calibration is not None and calibration.is_dir():
        fail(f"--calibration {calibration}: a folder, not a calibration file (give the JSON "
             "eha health calibrate wrote)")
    if calibration is not None and not calibration.is_file():
        fail(f"--calibration {calibration}: no such file; make one with eha health calibrate "
             f"--command COMMAND (it writes RESULTS/health/calibration-COMMAND.json)")
    check_out_file(json_out, "--json", (".json",))
    check_out_dir(results, "--results")
    if baseline is not None:
        _check_baseline(record, baseline, calibration, level, json_out, results, columns, units)
        return
    with err_console.status("assessing ...") as status:
        run = check_record(record_file(record, columns, units), calibration, level=level,
                           seed=seed, json_path=json_out, results=results,
                           on_progress=(lambda m: status.update(f"assessing: {m}"))
                           if progress else None)
    _render_check(run, record)
    if run.db_error:
        fail(f"results database not written: {run.db_error}", code=1)


def _check_baseline(record, baseline, calibration, level, json_out, results, columns,
                    units) -> None:
    from eha.health.change_check import check_change, interval_text
    from eha.models.faults import FAULTS
    from eha.models.units import show

    if calibration is None:
        fail("--baseline: the change check needs --calibration FILE made with eha health "
             "calibrate --baseline --command COMMAND")
    run = check_change(record_file(record, columns, units), record_file(baseline, columns, units),
                       calibration, level=level, json_path=json_out, results=results)
    console.print(run.finding(), highlight=False)
    table = Table("fault", "change since the baseline", f"{100 * run.level:g} % interval",
                  "alarm at", "verdict")
    for name, v in run.judged.items():
        verdict = "DEGRADED" if v["degraded"] else "healthy"
        if name in run.isolated:
            verdict += " (isolated)"
        elif name in run.also:
            verdict += f" (beside {run.isolated[0]})"
        sign = "±" if FAULTS[name].direction == 0 else ("+" if v["alarm_change"] >= 0 else "-")
        alarm = f"{sign}{show(name, abs(v['alarm_change']))}"
        if name in run.also:         # its change as read jointly with the isolated one's
            v, alarm = run.second[name], "-"
        table.add_row(name, _signed(name, v["change"]), interval_text(name, *v["interval"]),
                      alarm, verdict)
    console.print(f"record: {record}; baseline: {baseline}; calibration: {calibration}",
                  highlight=False)
    console.print(table)
    console.print(f"status: {run.status}; isolated: {' or '.join(run.isolated) or 'none'}"
                  + (f"; beside it: {', '.join(run.also)}" if run.also else "") + "; "
                  f"noise {1e6 * run.noise_rmse['record']:.3g} µm (baseline "
                  f"{1e6 * run.noise_rmse['baseline']:.3g} µm); {run.seconds:.1f} s",
                  highlight=False)
    for note in run.notes:
        warn(note)
    print_paths(run.paths)
    if run.db_error:
        fail(f"results database not written: {run.db_error}", code=1)


def _signed(name: str, value: float) -> str:
    from eha.models.units import show

    return ("+" if value >= 0 else "-") + show(name, abs(value))


_NO_CALIBRATION = ("none, so no healthy/degraded verdicts: make the thresholds once with eha "
                   "health calibrate --command COMMAND, then give --calibration FILE")


def _render_check(run, record: Path) -> None:
    """The faults' table, the status line, the warnings and the files written."""
    from eha.health.detection import alarm_value
    from eha.models.units import display_unit, number

    a = run.assessment
    table = Table("fault", "unit", "estimate", f"{100 * a.level:g} % interval", "healthy",
                  "alarm at", "verdict", "weight")
    for v in run.verdicts:
        verdict = "-" if v.degraded is None else ("DEGRADED" if v.degraded else "healthy")
        if v.name in run.isolated:
            verdict += " (isolated)"
        unit, scale = display_unit(v.name)
        table.add_row(v.name, unit or "-", number(v.name, v.estimate, 4),
                      f"[{number(v.name, v.interval[0])}, {number(v.name, v.interval[1])}]",
                      number(v.name, v.healthy, 4), "-" if v.threshold is None else
                      alarm_value(v.name, v.threshold, scale),
                      verdict, "-" if v.weight is None else f"{v.weight:.2f}")
    console.print(f"record: {record}; calibration: {run.calibration or _NO_CALIBRATION}",
                  highlight=False)
    console.print(table)
    status_text = run.to_dict()["status"]
    console.print(f"status: {status_text}; isolated: {', '.join(run.isolated) or 'none'}; "
                  f"residual {1e6 * a.residual_rmse:.3g} µm, noise {1e6 * a.noise_rmse:.3g} µm, "
                  f"{a.seconds:.1f} s (seed {a.seed})")
    for note in a.notes:
        warn(note)
    print_paths(run.paths)
