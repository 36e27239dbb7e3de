"""``eha rul --check change``: first alarms of the change check, and remaining useful life.

1. Every later record is judged by the change check against its actuator's baseline
   (:func:`eha.prognostics.change_history.baselines_of`: its first record or the manifest's
   ``baseline`` column; a job of kind ``change_record``): per fault its change with an
   interval and whether it alarms. The records the RUL needs are identified as ``eha rul``
   identifies them (jobs of kind ``health``): every record (``trend="identified"``, the
   default) or the baselines only (``trend="changes"``). All in one campaign of their own,
   ``rul-<manifest>-<hash>-change`` (resumable as ``eha rul``).
2. The first alarm of each fault per actuator
   (:func:`eha.prognostics.change_history.first_alarms`).
3. The RUL (:func:`eha.prognostics.rul.predict_history`) on the tracked faults' histories:
   ``identified``, the identification of every record (the fleet check's trend, reference
   'fleet' in ``rul_predictions``); ``changes``, the baseline's identified value plus each
   change (the change's interval its spread; reference 'baseline'). Measured on the
   fleet-validation fleet (``validation/baseline_fleet.py``): the changes, estimated one fault
   at a time on signatures of small changes, are biased when two faults grow together and
   large (alpha-lambda 2 % against 53 %): the default keeps the identification's trend.
4. Stored: ``change_checks`` (by the jobs), ``change_alarms`` and ``rul_predictions``; the JSON
   gains ``check``, ``trend``, ``calibration`` and per actuator its baseline, its changes and
   first alarms.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from eha.prognostics.degradation import LAWS, PrognosticsError
from eha.prognostics.result import RulResult

#: The checks ``eha rul --check`` takes.
CHECKS = ("fleet", "change")
#: The histories the RUL of the change check is predicted on (``eha rul --trend``).
TRENDS = ("identified", "changes")
#: Where each actuator's change check is calibrated (``eha rul --operating-point``).
OPERATING_POINTS = ("baseline", "calibration")


def _inputs(check: str, calibration, trend: str, skip_flagged: bool,
            operating_point: str = "baseline") -> dict[str, Any]:
    """The change calibration's file (one line on a wrong check, trend, operating point, a
    missing or wrong file)."""
    from eha.prognostics.change_history import check_calibration

    if operating_point not in OPERATING_POINTS:
        raise PrognosticsError(f"`operating_point` {operating_point!r}: allowed "
                               f"{', '.join(OPERATING_POINTS)}")
    if check not in CHECKS:
        raise PrognosticsError(f"`check` {check!r}: allowed {', '.join(CHECKS)}")
    if trend not in TRENDS:
        raise PrognosticsError(f"`trend` {trend!r}: allowed {', '.join(TRENDS)}")
    if skip_flagged and trend == "changes":
        raise PrognosticsError("`skip_flagged`: not with `trend` changes (no record is "
                               "identified but the baselines)")
    if check != "change" and operating_point != "baseline":
        raise PrognosticsError(f"`operating_point` {operating_point}: only with `check` change")
    if check != "change" and trend != "identified":
        raise PrognosticsError(f"`trend` {trend}: only with `check` change")
    if check != "change":
        raise PrognosticsError("`calibration`: only with `check` change (a change calibration, "
                               "eha health calibrate --baseline)")
    return check_calibration(calibration)


def run_rul_change(manifest_path: str | Path, *, limits: Mapping[str, float],
                   calibration: str | Path | None, fit: Sequence[str] | None = None,
                   bounds: Mapping[str, Sequence[float]] | None = None,
                   results: str | Path = "results", truth: str | Path | None = None,
                   seed: int = 0, workers: int = 2, laws: Sequence[str] = LAWS,
                   progress: bool = True, limit_error: float | None = None,
                   base_model: str | None = None,
                   columns: Mapping[str, str] | str | None = None,
                   units: str | None = None, check: str = "change",
                   skip_flagged: bool = False, trend: str = "identified",
                   operating_point: str = "baseline") -> RulResult:
    """:func:`eha.prognostics.jobs.run_rul` with the change check (see the module docstring);
    the same parameters, ``calibration``: a change calibration
    (:func:`eha.health.change_check.calibrate_baseline`) for the records' command, length and
    noise, ``trend``: the histories of the RUL, ``identified`` or ``changes``, and
    ``operating_point``: ``baseline`` (each actuator's change check calibrated again at its
    baseline's identified faults, a ``change_calibration`` job each, in the campaign
    ``<run>-at``; the files under ``results/calibrations``) or ``calibration`` (the given
    calibration for every actuator, at its own point).

    Raises
    ------
    eha.prognostics.manifest.ManifestError, PrognosticsError, DetectionError
        Bad input (nothing written).
    """
    from eha.campaigns.runner import run_campaign
    from eha.prognostics.change_history import (baselines_of, change_histories, first_alarms,
                                                read_change_rows, store_alarms)
    from eha.prognostics.jobs import (_check_rul_inputs, _predict_all, _split_rows,
                                      _store_predictions, evaluate_predictions,
                                      read_health_rows, run_id_of)
    from eha.prognostics.rul import histories_from_checks

    t0 = time.perf_counter()
    manifest, names, chosen, truth_eol = _check_rul_inputs(
        manifest_path, limits, fit, bounds, truth, laws, limit_error, base_model, columns,
        units)
    cal = _inputs(check, calibration, trend, skip_flagged, operating_point)
    missing = [n for n in names if n not in cal["faults"]]
    if missing:
        raise PrognosticsError(f"`fit` {','.join(missing)}: not judged by the calibration "
                               f"{calibration}")
    baselines = baselines_of(manifest)
    run_id = f"{run_id_of(manifest.source)}-change"
    results = Path(results)
    identify, changes = _campaign(manifest, baselines, chosen, seed, base_model, columns, units,
                                  run_id, Path(calibration), trend)
    files: Any = Path(calibration)
    done_runs = skipped = 0
    if operating_point == "baseline":
        files, done_runs, skipped = _calibrate_at_baselines(
            identify, manifest, baselines, names, Path(calibration), results, workers, progress)
    camp = changes(files)
    summary = run_campaign(camp, results, workers=workers, replace=True, progress=progress)
    done, failed = _split_rows(read_health_rows(results, camp.name), camp)
    done = [r for r in done if r.get("estimates") is not None]   # the identifications
    base_values = _baseline_rows(done, baselines)
    listed = {str(c.record) for c in manifest.checks}   # not a baseline outside the manifest
    done = [r for r in done if r["record"] in listed]
    rows = read_change_rows(results, camp.name)
    t_assess = time.perf_counter() - t0
    alarms = first_alarms(rows)
    hist = change_histories(rows, base_values, names) if trend == "changes" else \
        histories_from_checks(done, names, skip_flagged=skip_flagged)
    t1 = time.perf_counter()
    out_acts, preds_all = _predict_all(manifest.actuators, hist, limits, seed, laws, limit_error)
    for aid in manifest.actuators:
        out_acts[aid].update(_actuator_json(aid, baselines[aid], rows, alarms))
        out_acts[aid]["calibration"] = str(files[aid] if isinstance(files, Mapping) else files)
    output = {"unit": "cycle", "check": "change", "trend": trend,
              "calibration": str(calibration), "operating_point": operating_point,
              "limits": dict(limits), "fit": names,
              "bounds": {k: list(v) for k, v in chosen.items()}, "laws": list(laws),
              "seed": seed, "base_model": camp.definition.get("base_model"),
              "limit_error": limit_error, "run_id": run_id, "manifest": str(manifest.source),
              "actuators": out_acts}
    metrics = evaluate_predictions(preds_all, truth_eol) if truth_eol is not None else None
    if metrics is not None:
        output["metrics"] = metrics
    res = RulResult(run_id, output, preds_all, metrics, failed=failed,
                    assessed=summary.done + done_runs, reused=summary.skipped + skipped,
                    histories=hist,
                    truth=truth_eol)
    _store_predictions(results, run_id, preds_all, limits,
                       reference="baseline" if trend == "changes" else "fleet")
    store_alarms(results, run_id, alarms)
    res.paths["database"] = results / "eha.duckdb"
    res.seconds = {"assess": t_assess, "predict": time.perf_counter() - t1,
                   "total": time.perf_counter() - t0}
    return res


def _campaign(manifest, baselines, chosen, seed, base_model, columns, units, run_id: str,
              calibration: Path, trend: str):
    """The run's identifications (every record, or the baselines only with ``trend``
    changes) as a campaign, and the function that adds a ``change_record`` job per later
    record, given the calibration file (one, or per actuator)."""
    from eha.campaigns.files import Campaign
    from eha.prognostics.change_history import change_jobs
    from eha.prognostics.jobs import health_campaign
    from eha.prognostics.manifest import Check, Manifest

    checks = manifest.checks if trend == "identified" else tuple(
        b.check or Check(aid, manifest.of(aid)[0].cycle, b.record, 0, {}, b.columns, b.units)
        for aid, b in baselines.items())
    if trend == "identified":     # a baseline outside the manifest: identified too
        checks += tuple(Check(aid, manifest.of(aid)[0].cycle, b.record, 0, {}, b.columns,
                              b.units) for aid, b in baselines.items() if b.check is None)
    camp = health_campaign(Manifest(manifest.source, checks), chosen, seed,
                           base_model=base_model, columns=columns, units=units, name=run_id)
    definition = {**camp.definition, "check": "change", "trend": trend,
                  "calibration": str(calibration)}
    identify = Campaign(camp.name, f"change check of {manifest.source}", camp.source,
                        definition, camp.jobs, camp.model_version)

    def with_changes(files) -> Campaign:
        return Campaign(camp.name, identify.description, camp.source, definition,
                        camp.jobs + tuple(change_jobs(manifest, baselines, files, run_id,
                                                      columns, units, screen=calibration)),
                        camp.model_version)

    return identify, with_changes


def _calibrate_at_baselines(identify, manifest, baselines, names: Sequence[str],
                            calibration: Path, results: Path, workers: int, progress: bool):
    """The baselines identified (the campaign ``identify``), then a change calibration per
    actuator at its baseline's identified faults (campaign ``<run>-at``); the file of each
    actuator (the given one where it has none: no baseline identified, a failed job) and the
    runs done and reused."""
    from eha.campaigns.files import Campaign
    from eha.campaigns.runner import run_campaign
    from eha.prognostics.change_history import calibration_jobs, operating_points
    from eha.prognostics.jobs import read_health_rows

    first = run_campaign(identify, results, workers=workers, replace=True, progress=progress)
    points = operating_points(
        _baseline_rows(read_health_rows(results, identify.name), baselines), names)
    (results / "calibrations").mkdir(parents=True, exist_ok=True)
    name = f"{identify.name}-at"
    jobs, files = calibration_jobs(points, calibration, results / "calibrations", name)
    at = run_campaign(Campaign(name, f"change calibrations of {manifest.source}",
                               identify.source, {"calibration": str(calibration),
                                                 "operating_point": "baseline"},
                               tuple(jobs), identify.model_version),
                      results, workers=workers, replace=True, progress=progress)
    files = {aid: files[aid] if aid in files and files[aid].is_file() else calibration
             for aid in manifest.actuators}
    return files, first.done + at.done, first.skipped + at.skipped


def _baseline_rows(rows, baselines) -> dict[str, dict[str, Any]]:
    """Each actuator's baseline identification (its ``health_checks`` row with its
    ``baseline_cycle``)."""
    return {a: {**r, "baseline_cycle": b.cycle} for r in rows if r.get("estimates") is not None
            for a, b in [(str(r["actuator"]), baselines[str(r["actuator"])])]
            if r["record"] == str(b.record)}


def _actuator_json(aid: str, baseline, rows, alarms) -> dict[str, Any]:
    """An actuator's part of the JSON beyond its predictions: its baseline, its changes (per
    later record each fault's change, interval, alarm) and first alarms."""
    return {"baseline": str(baseline.record), "baseline_cycle": baseline.cycle,
            "first_alarms": alarms.get(aid, {}),
            "changes": [{"cycle": float(r["cycle"]), "record": r["record"],
                         "isolated": list(r["isolated"]), "also": list(r.get("also") or []),
                         "screen": list(r["screen"]),
                         "faults": {n: {"change": v, "interval": list(r["intervals"][n]),
                                        "degraded": bool(r["degraded"][n])}
                                    for n, v in r["changes"].items()}}
                        for r in rows if str(r["actuator"]) == aid]}


__all__ = ["CHECKS", "TRENDS", "OPERATING_POINTS", "run_rul_change"]
