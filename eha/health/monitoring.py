"""Health workflows behind ``eha health``: calibrate on a healthy fleet, check a record, report
detection performance. Each runs the library pieces (:mod:`eha.health.assessment`,
:mod:`eha.health.detection`) through the campaign runner and the store, and is what one CLI command
calls.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from eha.health.detection import (DEFAULT_ALPHA, MAX_ACTUATORS, MIN_HEALTHY, Calibration,
                                  calibrate_thresholds, empirical_false_alarms, load_calibration,
                                  performance, verdicts)
from eha.identification.healthy import DISPERSION, DetectionError, command_signature
from eha.identification.problem import BASE_MODELS, DEFAULT_LEVEL
from eha.models.commands import CommandError, as_command, command_label, pin_command

#: Records the health check accepts [s] (the bank runs 6 identifications of the whole record).
RECORD_SECONDS = (0.2, 10.0)


def _assessments(results: str | Path, campaign: str):
    from eha.campaigns.query import query, tables

    if "health_assessments" not in tables(results):
        return []  # no detection campaign has written to this folder
    frame = query(results, "SELECT h.* FROM health_assessments h JOIN runs r USING (run_key) "
                           "WHERE r.campaign = ? AND r.status = 'done' ORDER BY h.seed",
                  [campaign])
    rows = []
    for rec in frame.to_dict("records"):
        for k in ("truth", "hf", "estimates", "means", "spread", "intervals", "weights"):
            if isinstance(rec.get(k), str):
                rec[k] = json.loads(rec[k])
        rows.append(rec)
    return rows


def _campaigns_with_assessments(results: str | Path) -> str:
    """``" (detection campaigns there: a, b)"`` when the folder holds others, else ``""``."""
    from eha.campaigns.query import query

    try:
        names = query(results, "SELECT DISTINCT r.campaign FROM health_assessments h JOIN runs r"
                               " USING (run_key) ORDER BY 1")["campaign"].tolist()
    except Exception:  # no such table: none
        return ""
    return f" (campaigns with health assessments there: {', '.join(names)})" if names else ""


def _command_samples(command: str, t_end: float) -> np.ndarray:
    from eha.models.commands import as_command

    t = np.arange(int(round(t_end / 1e-3)) + 1) * 1e-3
    return as_command(command).sample(t)


def calibrate_fleet(command: str = "chirp_1cm", actuators: int = 30, seed: int = 0,
                    t_end: float = 1.0, noise: float = 1e-6, alpha: float = DEFAULT_ALPHA,
                    base_model: str = "calibrated", level: float = DEFAULT_LEVEL,
                    out: str | Path | None = None, results: str | Path = "results",
                    workers: int = 2, progress: bool = True,
                    signals: tuple[str, ...] | list[str] = ("xu",),
                    noise_p12: float | None = None) -> dict[str, Any]:
    """Run a healthy fleet through the campaign runner and set per-fault thresholds.

    ``signals`` is what the checks fit: ``("xu",)``, the position, or ``("xu", "p12")``, the
    position and the load pressure (recorded with ``noise_p12`` [Pa] of white noise); the
    calibration file says which, and :func:`check_record` assesses its records the same way.

    Returns ``{"calibration": Calibration, "path": file, "summary": RunSummary,
    "campaign": name}``. The file defaults to ``RESULTS/health/calibration-<command>.json``.
    """
    from eha.campaigns.files import build_campaign, CampaignError
    from eha.campaigns.runner import run_campaign
    from eha.models.simulate import MODEL_VERSION
    from eha.campaigns.store import replace_rows

    _check_calibration_inputs(actuators, alpha)
    try:  # a command file is named by its content (the calibration checks its signature)
        as_command(command)  # an unknown name or a folder is said as such, before the name
        command, label = pin_command(command), command_label(command)
    except CommandError as exc:  # "command: unknown ...", "command DIR: a folder ..."
        text = str(exc)
        raise DetectionError(re.sub(r"^command(?=[: ])", "`command`", text)
                             if re.match(r"command(:| (?!file ))", text)
                             else f"`command`: {text}") from None
    section = {"commands": [command], "t_end": t_end, "actuators": actuators, "seed": seed,
               "noise": noise, "base_model": base_model, "level": level}
    if "p12" in signals:          # a position-only calibration keeps its campaign name
        from eha.health.assessment import DEFAULT_NOISE_P12

        section |= {"signals": list(signals),
                    "noise_p12": DEFAULT_NOISE_P12 if noise_p12 is None else noise_p12}
    tag = hashlib.sha256(json.dumps(section, sort_keys=True).encode()).hexdigest()[:8]
    name = f"health-calibrate-{label}-{tag}"
    try:
        camp = build_campaign({"name": name, "kind": "health", "health": section,
                               "description": f"healthy fleet of {actuators} for thresholds"})
    except CampaignError as exc:
        first = str(exc).splitlines()[0].replace("health.commands: command: ", "`command`: ")
        # the section's keys are this function's keywords (the CLI names their flags)
        raise DetectionError(re.sub(r"health\.(\w+)", r"`\1`", first)) from None
    summary = run_campaign(camp, results, workers=workers, progress=progress)
    rows = _assessments(results, name)
    if summary.failed or len(rows) < actuators:
        raise DetectionError(f"calibration: {summary.failed} of {actuators} assessments "
                             f"failed ({'; '.join(summary.errors[:1])})")
    thresholds, healthy = calibrate_thresholds(rows, alpha)
    cal = Calibration(command=command,
                      command_sig=command_signature(_command_samples(command, t_end)),
                      t_end=float(t_end), model_version=MODEL_VERSION, base_model=base_model,
                      level=float(level), alpha=float(alpha), thresholds=thresholds,
                      healthy=healthy,
                      fleet={"actuators": actuators, "seed": seed, "noise": noise,
                             "campaign": name, "dispersion": _dispersion_text()},
                      false_alarms=empirical_false_alarms(rows, thresholds),
                      signals=["xu", "p12"] if "p12" in signals else ["xu"],
                      created_at=datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    path = Path(out) if out is not None else Path(results) / "health" / \
        f"calibration-{label}.json"
    cal.save(path)
    now = datetime.now(timezone.utc).replace(tzinfo=None)
    replace_rows(results, "health_thresholds",
                 [{"calibration": str(path), "command": label, "t_end": float(t_end),
                   "fault": n, "threshold": t, "mean": healthy[n]["mean"],
                   "std": healthy[n]["std"], "n": healthy[n]["n"], "alpha": alpha,
                   "created_at": now, "reference": "fleet"} for n, t in thresholds.items()],
                 {"calibration": str(path)})
    return {"calibration": cal, "path": path, "summary": summary, "campaign": name}


def _check_calibration_inputs(actuators: Any, alpha: Any) -> None:
    """The ranges of :func:`calibrate_fleet`'s fleet, before anything runs: every fault's
    threshold needs :data:`MIN_HEALTHY` healthy assessments."""
    problems = []
    if isinstance(actuators, bool) or not isinstance(actuators, int) or \
            not MIN_HEALTHY <= actuators <= MAX_ACTUATORS:
        problems.append(f"`actuators` {actuators!r}: allowed range [{MIN_HEALTHY}, "
                        f"{MAX_ACTUATORS}] (a threshold needs at least {MIN_HEALTHY} healthy "
                        "actuators)")
    if not 0 < alpha < 1:
        problems.append(f"`alpha` {alpha!r}: allowed range (0, 1)")
    if problems:
        raise DetectionError(problems)


def _dispersion_text() -> dict[str, list]:
    return {k: list(v) for k, v in DISPERSION.items()}


@dataclass
class CheckResult:
    """What ``eha health check`` shows and writes."""

    record: str
    assessment: Any
    verdicts: list
    isolated: list[str]
    calibration: str | None
    check_id: str
    paths: dict[str, Path] = field(default_factory=dict)
    db_error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        a = self.assessment
        return {"record": self.record, "calibration": self.calibration, "level": a.level,
                "estimates": a.estimates, "means": a.means,
                "intervals": {k: list(v) for k, v in a.intervals.items()},
                "faults": {v.name: v.to_dict() for v in self.verdicts},
                "isolated": self.isolated,
                "status": ("unknown" if self.calibration is None else
                           "degraded" if any(v.degraded for v in self.verdicts) else "healthy"),
                "flagged": a.flagged, "noise_rmse": a.noise_rmse,
                "residual_rmse": a.residual_rmse, "seed": a.seed, "seconds": a.seconds,
                "hypotheses": a.to_dict()["hypotheses"], "notes": list(a.notes)}


def check_record(record: str | Path, calibration: str | Path | None = None,
                 level: float | None = None, seed: int = 0,
                 json_path: str | Path | None = None, results: str | Path | None = "results",
                 on_progress: Callable[[str], None] | None = None) -> CheckResult:
    """Assess one record, decide healthy/degraded per fault and isolate.

    Raises
    ------
    DetectionError
        Bad calibration file, a record of another command or length than the calibration, a
        record outside :data:`RECORD_SECONDS`, a level outside (0, 1).
    eha.identification.measured.MeasuredDataError
        The record cannot be read.
    """
    from eha.health.assessment import assess_record
    from eha.identification.intervals import check_level
    from eha.identification.measured import load

    if level is not None:  # the one check of --level, before any file is read
        try:
            level = check_level(level)
        except ValueError:
            raise DetectionError(f"`level` {level!r}: allowed range (0, 1), e.g. 0.9") from None
    cal = load_calibration(calibration) if calibration is not None else None
    if level is None:
        level = cal.level if cal else DEFAULT_LEVEL
        try:
            level = check_level(level)
        except ValueError:
            raise DetectionError(f"`calibration` {calibration}: level {level!r}: allowed "
                                 "range (0, 1)") from None
    data = load(record)
    lo, hi = RECORD_SECONDS
    if not lo <= data.t_end <= hi:
        raise DetectionError(f"{record}: record of {data.t_end:g} s; the health check takes "
                             f"[{lo:g}, {hi:g}] s (cut a longer record)")
    if cal is not None:
        if abs(data.t_end - cal.t_end) > 1.5e-3:
            raise DetectionError(f"{record}: {data.t_end:g} s long, the calibration "
                                 f"{calibration} is for {cal.t_end:g} s records of "
                                 f"{cal.command}")
        sig = command_signature(data.com)
        if sig != cal.command_sig:
            ref = _command_samples(cal.command, cal.t_end)
            diff = float(np.max(np.abs(ref - data.com))) if ref.size == data.com.size else \
                float("nan")
            raise DetectionError(f"{record}: its command is not {cal.command} (largest "
                                 f"difference {1e3 * diff:.3g} mm), the command the calibration "
                                 f"{calibration} was made for; calibrate for this command")
    base = BASE_MODELS[cal.base_model if cal else "calibrated"]
    signals = tuple(cal.signals) if cal else ("xu",)
    if "p12" in signals and data.p12 is None:
        raise DetectionError(f"{record}: no load pressure (p12 column); the calibration "
                             f"{calibration} fits it (calibrated on position and p12)")
    a = assess_record(data, base=base, level=level, seed=seed, on_progress=on_progress,
                      signals=signals)
    vs, isolated = verdicts(a, cal)
    check_id = hashlib.sha256(json.dumps([str(Path(record).resolve()), str(calibration),
                                          level, seed, data.info.get("noise_m")]).encode()
                              ).hexdigest()[:16]
    out = CheckResult(str(record), a, vs, isolated, str(calibration) if calibration else None,
                      check_id)
    if json_path is not None:
        from eha.outputs import write_json

        p = write_json(json_path, out.to_dict())  # a temporary name of its own
        out.paths["json"] = p
    if results is not None:
        from eha.campaigns.store import StoreError, replace_rows

        now = datetime.now(timezone.utc).replace(tzinfo=None)
        rows = [{"check_id": check_id, "record": str(record), "created_at": now,
                 "calibration": out.calibration, "fault": v.name, "estimate": v.estimate,
                 "lo": v.interval[0], "hi": v.interval[1], "level": a.level,
                 "healthy": v.healthy, "threshold": v.threshold, "statistic": v.statistic,
                 "degraded": v.degraded, "weight": v.weight, "isolated": v.name in isolated,
                 "flagged": a.flagged, "reference": "fleet", "baseline": None} for v in vs]
        try:
            out.paths["database"] = replace_rows(results, "health_verdicts", rows,
                                                 {"check_id": check_id})
        except StoreError as exc:
            out.db_error = str(exc)
    return out


def summary_markdown(perf: Mapping[str, Any], alpha: float) -> str:
    """Which command identifies what best: per fault and command the minimum detectable
    deviation (P_D >= 0.95 at the calibrated threshold), the detection rate and the share
    correctly isolated at each injected level; the false-alarm rates."""
    from eha.health.assessment import FAULTS

    commands = list(perf)
    lines = ["| fault | " + " | ".join(commands) + " |",
             "|---|" + "---|" * len(commands)]
    for name in FAULTS:
        cells = []
        for c in commands:
            f = perf[c]["faults"].get(name)
            if not f:
                cells.append("-")
                continue
            md = f["min_detectable_deviation"]
            conf = perf[c]["confusion"].get(name, {})
            total = sum(conf.values()) or 1
            levels = ", ".join(f"{e['p_detect']:.2f}" for e in f["levels"])
            cells.append(f"{'> ' + format(f['levels'][-1]['deviation'], '.3g') if md is None else format(md, '.3g')}"
                         f" (P_D {levels}; isolated {conf.get(name, 0)}/{total})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    fa = ["| command | healthy | false alarms (in fleet) | false alarms (leave-one-out) |",
          "|---|---|---|---|"]
    for c in commands:
        fa.append(f"| {c} | {perf[c]['false_alarms']['n']} | {perf[c]['false_alarms']['any']:.3f}"
                  f" | {perf[c]['false_alarms_loo']['any']:.3f} |")
    what = ("change since the earlier record of each pair (the change check; thresholds "
            "from the healthy pairs)" if any(perf[c].get("check") == "change" for c in perf)
            else "deviation from healthy")
    return (f"Minimum detectable {what} at P_D >= 0.95 (fault unit; '> x': not "
            f"reached at the largest level x), with alpha = {alpha:g} per check; in brackets "
            "the detection rate at each injected level and how many of that fault's records "
            "were isolated as it.\n\n" + "\n".join(lines) + "\n\n" + "\n".join(fa) + "\n")


def health_report(results: str | Path = "results", campaign: str = "health-detection",
                  out: str | Path | None = None, alpha: float = DEFAULT_ALPHA) -> dict[str, Path]:
    """Detection performance of a detection campaign: CSV tables and PNGs (ROC curves per
    command, isolation confusion matrices), ``performance.json``.

    Raises
    ------
    DetectionError
        No assessments of ``campaign`` in the database.
    """
    from eha.health.plots import plot_confusion, plot_roc

    rows = _assessments(results, campaign)
    if rows:
        perf = performance(rows, alpha)
    else:   # a change campaign ([health] baseline = true): its pairs
        from eha.health.change_campaign import change_rows
        from eha.health.change_performance import performance_change

        rows = change_rows(results, campaign)
        if not rows:
            raise DetectionError(f"{campaign}: no detection campaign of that name in "
                                 f"{results}/eha.duckdb{_campaigns_with_assessments(results)}"
                                 f"; run eha campaign run campaigns/{campaign}.toml first")
        perf = performance_change(rows, alpha)
    if not perf:
        raise DetectionError(f"{campaign}: fewer than 5 healthy actuators per command")
    folder = Path(out) if out is not None else Path(results) / "reports" / "health"
    folder.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    import csv

    from eha.outputs import atomic_path, write_atomic, write_json

    det = folder / "detection.csv"
    with atomic_path(det) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["command", "fault", "injected", "deviation", "p_detect", "n", "threshold",
                    "min_detectable_deviation"])
        for command, c in perf.items():
            for name, f in c["faults"].items():
                for lev in f["levels"]:
                    w.writerow([command, name, lev["value"], lev["deviation"], lev["p_detect"],
                                lev["n"], f["threshold"], f["min_detectable_deviation"]])
    paths["detection"] = det
    conf = folder / "confusion.csv"
    with atomic_path(conf) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["command", "injected", "declared", "count"])
        for command, c in perf.items():
            for injected, row in c["confusion"].items():
                for declared, n in sorted(row.items()):
                    w.writerow([command, injected, declared, n])
    paths["confusion"] = conf
    fa = folder / "false_alarms.csv"
    with atomic_path(fa) as tmp, tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["command", "healthy", "any_in_sample", "any_leave_one_out", "alpha"])
        for command, c in perf.items():
            w.writerow([command, c["false_alarms"]["n"], c["false_alarms"]["any"],
                        c["false_alarms_loo"]["any"], alpha])
    paths["false_alarms"] = fa
    write_json(folder / "performance.json", perf, indent=1, default=float)
    paths["summary"] = write_atomic(folder / "summary.md", summary_markdown(perf, alpha))
    paths["json"] = folder / "performance.json"
    for command, c in perf.items():
        paths[f"roc {command}"] = plot_roc(c, command, folder / f"roc_{command}.png")
        paths[f"confusion {command}"] = plot_confusion(c["confusion"], command,
                                                       folder / f"confusion_{command}.png")
    return paths
