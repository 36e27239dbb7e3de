"""One record of a health history judged by the change check against its actuator's baseline
record: the ``change_record`` job kind (``eha rul --check change``,
:mod:`eha.prognostics.change_rul`) and its table ``change_checks``.

A job's spec names the later record, the baseline record (each with how it is read:
``columns``, ``units``) and a change calibration (``eha health calibrate --baseline``); the
worker reads both records, checks them against the calibration's command and length (one line
naming the record otherwise: the job fails, the others go on), and judges the difference
(:func:`eha.health.change_calibration.judge`): per fault the change since the baseline with its
interval, the statistic, the threshold at the records' noise, whether it alarms, and the faults
the change is isolated to. A record costs a file read and a matrix product; the estimator is
built once per worker and calibration.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache
from typing import Any, Mapping

from eha.campaigns.jobs import JobKind, Table
from eha.identification.healthy import DetectionError

#: What the ``reference`` column of a change-check row holds (as in ``health_verdicts``).
REFERENCE = "baseline"

#: One row per later record of an ``eha rul --check change`` run.
CHANGE_CHECKS = """
        CREATE TABLE IF NOT EXISTS change_checks (
            run_key        VARCHAR PRIMARY KEY,
            campaign       VARCHAR,   -- rul-<manifest>-<hash>-change
            actuator       VARCHAR,
            cycle          DOUBLE,    -- manifest unit
            record         VARCHAR,   -- absolute path of the later record
            record_sha     VARCHAR,   -- SHA-256 (16 hex) of the record file
            baseline       VARCHAR,   -- absolute path of the actuator's baseline record
            baseline_cycle DOUBLE,    -- its cycle (NULL: a record outside the manifest)
            calibration    VARCHAR,   -- the change calibration file
            reference      VARCHAR,   -- the check that made the row: 'baseline'
            level          DOUBLE,    -- probability of the intervals
            changes        JSON,      -- {fault: change since the baseline} (SI)
            intervals      JSON,      -- {fault: [lo, hi]} at level (SI)
            statistics     JSON,      -- {fault: linear estimate less the healthy pairs' mean}
            thresholds     JSON,      -- {fault: threshold of the statistic at the records' noise}
            degraded       JSON,      -- {fault: the fault alarms}
            isolated       JSON,      -- the faults the change is isolated to (best first)
            screen         JSON,      -- faults in which the baseline is unlike the healthy fleet
            noise_rmse     DOUBLE,    -- m, the later record's noise
            baseline_rmse  DOUBLE,    -- m, the baseline's noise
            seconds        DOUBLE)    -- s, wall time in the worker"""

#: Columns added to ``change_checks`` after its first release.
CHECKS_ADDED = (("also", "JSON"),     # faults changed beside the isolated one
                ("beside", "JSON"))   # {fault: its reading beside the first}


@lru_cache(maxsize=4)
def _calibration(path: str, sha: str):
    """The change calibration of ``path`` (``sha``: its content, so that an edited file is
    read again)."""
    from eha.health.change_calibration import load_change_calibration

    return load_change_calibration(path)


#: The estimators built in this worker, by calibration file, content and command.
_ESTIMATORS: dict[tuple[str, str, str], Any] = {}


def _estimator(path: str, sha: str, command_sig: str, command):
    from eha.health.change_check import signatures_of

    key = (path, sha, command_sig)
    if key not in _ESTIMATORS:
        if len(_ESTIMATORS) >= 4:
            _ESTIMATORS.clear()
        _ESTIMATORS[key] = signatures_of(_calibration(path, sha), command)
    return _ESTIMATORS[key]


def _read(path: str, columns, units, cal, what: str):
    from eha.identification.healthy import command_signature
    from eha.identification.measured import RecordFile, load

    data = load(RecordFile(path, columns, units))
    if abs(data.t_end - cal.t_end) > 1.5e-3 or command_signature(data.com) != cal.command_sig:
        raise DetectionError(f"{what} {path}: not a {cal.t_end:g} s record of {cal.command}, "
                             "the command the change calibration is for")
    return data


def _screen(spec: Mapping[str, Any], cal, sig, earlier) -> list[str]:
    """The faults in which the baseline is unlike the healthy fleet, farthest first
    (:func:`eha.health.change_check.screen_baseline`), by the job's healthy calibration: the
    spec's ``screen_calibration`` where the job's own is at an operating point (a fleet
    screened at the baseline's faults would see none of them), else its own."""
    from eha.health.change_check import screen_baseline

    path = spec.get("screen_calibration")
    if path and path != spec["calibration"]:
        healthy = _calibration(path, spec["screen_calibration_sha"])
        sig = _estimator(path, spec["screen_calibration_sha"], healthy.command_sig,
                         earlier.command)
        cal = healthy
    return screen_baseline(cal, sig, earlier.xu)


def run_change_record(spec: Mapping[str, Any], run_key: str, campaign: str,
                      trace_file: str) -> dict[str, Any]:
    """Worker of a ``change_record`` job: its ``change_checks`` row (see the module docstring).

    Raises
    ------
    DetectionError, eha.identification.measured.MeasuredDataError
        A record that cannot be read or is not the calibration's command and length; a
        calibration that is not a change calibration (the job fails with that line).
    """
    from eha.health.change_check import beside_record
    from eha.health.change_second import judge_change
    from eha.identification.measured import noise_level

    start = time.perf_counter()
    cal = _calibration(spec["calibration"], spec["calibration_sha"])
    earlier = _read(spec["baseline"], spec.get("baseline_columns"), spec.get("baseline_units"),
                    cal, "baseline")
    later = _read(spec["record"], spec.get("columns"), spec.get("units"), cal, "record")
    sig = _estimator(spec["calibration"], spec["calibration_sha"], cal.command_sig,
                     later.command)
    n_a, n_b = noise_level(earlier.xu), noise_level(later.xu)
    judged, isolated, second, also = judge_change(cal, sig, later.xu - earlier.xu,
                                                  n_a ** 2 + n_b ** 2)
    row = {"campaign": campaign, "actuator": spec["actuator"], "cycle": float(spec["cycle"]),
           "record": spec["record"], "record_sha": spec["sha"], "baseline": spec["baseline"],
           "baseline_cycle": spec.get("baseline_cycle"), "calibration": spec["calibration"],
           "reference": REFERENCE, "level": float(cal.level),
           "changes": {n: float(v["change"]) for n, v in judged.items()},
           # an open end (a change beyond its response's growing range) is null
           "intervals": {n: [float(x) if math.isfinite(x) else None for x in v["interval"]]
                         for n, v in judged.items()},
           "statistics": {n: float(v["statistic"]) for n, v in judged.items()},
           "thresholds": {n: float(v["threshold"]) for n, v in judged.items()},
           "degraded": {n: bool(v["degraded"]) for n, v in judged.items()},
           "isolated": isolated, "also": also,
           "beside": {g: beside_record(v, g in also) for g, v in second.items()},
           "screen": _screen(spec, cal, sig, earlier),
           "noise_rmse": float(n_b), "baseline_rmse": float(n_a)}
    row["seconds"] = time.perf_counter() - start
    return {"rows": {"change_checks": row}, "sim_s": row["seconds"]}


#: The ``change_record`` job kind (entry point ``eha.job_kinds``; ``eha rul --check change``).
CHANGE_RECORD = JobKind("change_record", run_change_record,
                        tables=(Table("change_checks", CHANGE_CHECKS, per_run=True,
                                      added=CHECKS_ADDED),))


#: One row per ``change_calibration`` job: an actuator's change calibration at its baseline's
#: operating point.
CHANGE_CALIBRATIONS = """
        CREATE TABLE IF NOT EXISTS change_calibrations (
            run_key         VARCHAR PRIMARY KEY,
            campaign        VARCHAR,   -- rul-<manifest>-<hash>-change
            actuator        VARCHAR,
            base            VARCHAR,   -- the user's change calibration (its settings)
            calibration     VARCHAR,   -- the file written: the check at the operating point
            operating_point JSON,      -- {fault: level of the baseline} (SI)
            pairs           INTEGER,   -- healthy pairs at that point
            false_alarms    INTEGER,   -- leave-one-out alarms among them
            seconds         DOUBLE)    -- s, wall time in the worker"""


def run_change_calibration(spec: Mapping[str, Any], run_key: str, campaign: str,
                           trace_file: str) -> dict[str, Any]:
    """Worker of a ``change_calibration`` job: the change calibration of ``spec["base"]``
    (its command, length, noise, pairs, seed, alpha, level and nuisances) made again at the
    operating point ``spec["at"]`` (the actuator's baseline's identified faults), written to
    ``spec["out"]``; its ``change_calibrations`` row.

    Raises
    ------
    DetectionError
        The base is not a change calibration, or the point is outside the faults' ranges.
    """
    from eha.health.change_calibration import calibrate_change

    start = time.perf_counter()
    base = _calibration(spec["base"], spec["base_sha"])
    cal, _ = calibrate_change(base.command, actuators=base.pairs, seed=base.seed,
                              t_end=base.t_end, noise=base.noise, alpha=base.alpha,
                              level=base.level, nuisances=base.nuisances,
                              model=base.signatures, at=spec["at"])
    cal.save(spec["out"])
    row = {"campaign": campaign, "actuator": spec["actuator"], "base": spec["base"],
           "calibration": spec["out"], "operating_point": dict(cal.operating_point),
           "pairs": int(cal.pairs),
           "false_alarms": int(cal.false_alarms.get("loo", {}).get("alarms", 0)),
           "seconds": time.perf_counter() - start}
    return {"rows": {"change_calibrations": row}, "sim_s": row["seconds"]}


#: The ``change_calibration`` job kind (entry point ``eha.job_kinds``; ``eha rul --check change``
#: at each actuator's operating point).
CHANGE_CALIBRATION = JobKind(
    "change_calibration", run_change_calibration,
    tables=(Table("change_calibrations", CHANGE_CALIBRATIONS, per_run=True),))

__all__ = ["REFERENCE", "CHANGE_CHECKS", "CHANGE_CALIBRATIONS", "run_change_record",
           "run_change_calibration", "CHANGE_RECORD", "CHANGE_CALIBRATION"]
