"""Health histories of changes (``eha rul --check change``): each record of a manifest judged
by the change check against the same actuator's own baseline record.

The baseline of an actuator is its first record, or the record its rows name in an optional
``baseline`` column of the manifest (a path relative to the manifest's folder, the same on
every row of the actuator). Each later record is one runner job of kind ``change_record``
(registered by :mod:`eha.health.change_history`, found through the job registry: the health
layer is not imported here), judged with the estimator and thresholds of a change calibration
(``eha health calibrate --baseline``, for the records' command, length and noise); its row in
``change_checks`` holds per fault the change since the baseline with its interval and whether
it alarms, with ``reference`` 'baseline' (the check that made it).

:func:`first_alarms` gives, per actuator and fault, the first cycle at which the fault alarms
(the check isolated to it) and the first at which it alarms on two checks in a row (with alpha
0.01 per check, a history of tens of checks will see a lone false alarm somewhere; two in a row
is the confirmed one); :func:`store_alarms` writes them to ``change_alarms``.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eha.campaigns.jobs import register_table
from eha.prognostics.degradation import PrognosticsError

#: What the ``reference`` column of a change-check row holds (as in ``health_verdicts``).
REFERENCE = "baseline"

#: One row per actuator and fault: when the change check first alarmed.
CHANGE_ALARMS = """
        CREATE TABLE IF NOT EXISTS change_alarms (
            run_id          VARCHAR,
            actuator        VARCHAR,
            fault           VARCHAR,
            reference       VARCHAR,  -- the check that made the row: 'baseline'
            baseline_cycle  DOUBLE,
            first_alarm     DOUBLE,   -- first cycle the fault alarms, isolated (NULL: never)
            first_confirmed DOUBLE,   -- first cycle of two such checks in a row
            first_statistic DOUBLE,   -- first cycle its own statistic alarms (any isolation)
            first_degraded  DOUBLE,   -- first cycle any fault alarms
            checks          INTEGER,  -- later records judged
            created_at      TIMESTAMP,
            PRIMARY KEY (run_id, actuator, fault))"""

#: Columns added after the first release: ``at_baseline``, the first alarm is the baseline's
#: own (screened unlike the healthy fleet, farthest in this fault; older rows NULL).
ALARMS_ADDED = (("at_baseline", "BOOLEAN"),)

register_table("change_alarms", CHANGE_ALARMS, added=ALARMS_ADDED)


@dataclass
class Baseline:
    """An actuator's baseline record: its path, cycle (None: outside the manifest) and how it
    is read."""

    record: Path
    cycle: float | None
    columns: dict | None = None
    units: str | None = None
    check: Any = field(default=None, repr=False)


def baselines_of(manifest) -> dict[str, Baseline]:
    """Each actuator's baseline: the record its rows' ``baseline`` cells name, else its first
    record.

    Raises
    ------
    PrognosticsError
        An actuator's rows name different baselines, or a named baseline is not a file.
    """
    out: dict[str, Baseline] = {}
    folder = Path(manifest.source).parent
    problems = []
    for aid in manifest.actuators:
        checks = manifest.of(aid)
        named = {c.extra.get("baseline", "").strip() for c in checks} - {""}
        if len(named) > 1:
            problems.append(f"actuator {aid}: rows name {len(named)} baselines "
                            f"({', '.join(sorted(named))}); one per actuator")
            continue
        if not named:
            first = checks[0]
            out[aid] = Baseline(first.record, first.cycle, first.columns, first.units, first)
            continue
        path = Path(named.pop())
        path = (path if path.is_absolute() else folder / path).resolve()
        if not path.is_file():
            problems.append(f"actuator {aid}: baseline {path}: file not found")
            continue
        same = [c for c in checks if c.record == path]
        out[aid] = Baseline(path, same[0].cycle if same else None, checks[0].columns,
                            checks[0].units, same[0] if same else None)
    if problems:
        raise PrognosticsError(f"`manifest` {manifest.source}: " + "; ".join(problems))
    return out


def operating_points(base_values: Mapping[str, Mapping[str, Any]], names: Sequence[str]
                     ) -> dict[str, dict[str, float]]:
    """Per actuator, its baseline's identified level of each tracked fault (SI), within the
    parameter's range: where its change calibration is made (a fault's signature at a
    degraded point differs from the healthy one's, :class:`eha.health.change.Signatures`)."""
    from eha.models.params import SPECS

    out = {}
    for aid, row in base_values.items():
        est = row.get("estimates") or {}
        out[aid] = {n: min(max(float(est[n]), SPECS[n].lo), SPECS[n].hi)
                    for n in names if est.get(n) is not None and math.isfinite(float(est[n]))}
    return out


def calibration_jobs(points: Mapping[str, Mapping[str, float]], calibration: Path,
                     folder: Path, name: str) -> tuple[list, dict[str, Path]]:
    """One ``change_calibration`` job per actuator (the user's change calibration made again
    at the actuator's operating point, written under ``folder``) and the file of each."""
    from eha.campaigns.files import Job
    from eha.models.simulate import MODEL_VERSION
    from eha.prognostics.jobs import file_sha

    base_sha = file_sha(calibration)
    jobs, files = [], {}
    for aid, at in points.items():
        spec = {"actuator": aid, "base": str(calibration), "base_sha": base_sha,
                "at": {n: float(v) for n, v in sorted(at.items())}}
        key = hashlib.sha256(json.dumps({"campaign": name, "kind": "change_calibration",
                                         "spec": spec, "model_version": MODEL_VERSION},
                                        sort_keys=True).encode()).hexdigest()[:16]
        files[aid] = (Path(folder) / f"{name}-{key}.json").resolve()
        jobs.append(Job(name, "change_calibration", key, {**spec, "out": str(files[aid])},
                        {"model": "hf", "seed": 0, "estimated_s": 20.0,
                         "label": f"{aid} change calibration"}))
    return jobs, files


def change_jobs(manifest, baselines: Mapping[str, Baseline], calibration, name: str,
                columns=None, units=None, screen=None) -> list:
    """One ``change_record`` job (:class:`eha.campaigns.files.Job`) per record after its
    actuator's baseline (run key: the campaign, both records' contents, how they are read and
    the calibration's content); ``calibration``: one file for all, or per actuator (each at
    its baseline's operating point: then ``screen``, the healthy calibration, screens the
    baselines against the healthy fleet)."""
    from eha.campaigns.files import Job
    from eha.models.simulate import MODEL_VERSION
    from eha.prognostics.jobs import file_sha

    files = calibration if isinstance(calibration, Mapping) else \
        {aid: calibration for aid in manifest.actuators}
    jobs = []
    screen_sha = None if screen is None else file_sha(screen)
    for aid in manifest.actuators:
        if aid not in files:
            continue
        cal_sha = file_sha(files[aid])
        base = baselines[aid]
        base_sha = file_sha(base.record)
        for c in manifest.of(aid):
            if c.record == base.record or (base.cycle is not None and c.cycle <= base.cycle):
                continue
            spec = {"record": str(c.record), "sha": file_sha(c.record), "actuator": aid,
                    "cycle": float(c.cycle), "baseline": str(base.record),
                    "baseline_sha": base_sha, "baseline_cycle": base.cycle,
                    "calibration": str(files[aid]), "calibration_sha": cal_sha,
                    "columns": c.columns or _columns(columns), "units": c.units or units,
                    "baseline_columns": base.columns or _columns(columns),
                    "baseline_units": base.units or units}
            if screen is not None and str(screen) != str(files[aid]):
                spec.update(screen_calibration=str(screen), screen_calibration_sha=screen_sha)
            key = hashlib.sha256(json.dumps({"campaign": name, "kind": "change_record",
                                             "spec": spec, "model_version": MODEL_VERSION},
                                            sort_keys=True, default=str).encode()
                                 ).hexdigest()[:16]
            # the runs' columns of a health job's (one campaign holds both kinds)
            jobs.append(Job(name, "change_record", key, spec,
                            {"model": "hf", "seed": 0, "estimated_s": 0.05,
                             "label": f"{aid} cycle {c.cycle:g} (change)"}))
    return jobs


def _columns(columns):
    """``--columns`` as the spec carries it (a mapping; text parsed as the loader does)."""
    if columns is None or isinstance(columns, Mapping):
        return dict(columns) if columns else None
    from eha.identification.measured import RecordFile

    return dict(RecordFile(Path("x.csv"), columns, None).columns or {}) or None


def read_change_rows(results: Path, campaign: str) -> list[dict[str, Any]]:
    """The ``change_checks`` rows of a campaign's done runs (JSON decoded), by actuator and
    cycle."""
    from eha.campaigns.store import connect

    con = connect(results)
    try:
        cur = con.execute("""
            SELECT c.* FROM runs r JOIN change_checks c USING (run_key)
            WHERE r.campaign = ? AND r.status = 'done' ORDER BY c.actuator, c.cycle""",
                          [campaign])
        cols = [d[0] for d in cur.description]
        rows = [dict(zip(cols, r)) for r in cur.fetchall()]
    finally:
        con.close()
    for r in rows:
        for k in ("changes", "intervals", "statistics", "thresholds", "degraded", "isolated",
                  "screen", "also", "beside"):
            if isinstance(r.get(k), str):
                r[k] = json.loads(r[k])
    return rows


def first_alarms(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per actuator and fault, from its ``change_checks`` rows: ``first_alarm`` (the first
    cycle its change alarms and the check is isolated to it, among the faults the records do
    not tell apart, or changed beside it; the baseline's own cycle where the baseline itself
    screened unlike the healthy fleet, farthest in this fault: ``at_baseline``),
    ``first_change`` (the first change alarm, whatever the baseline's screen),
    ``first_confirmed`` (the first of two change alarms in a row), ``first_statistic`` (the
    first cycle its own statistic is beyond its threshold, whatever the isolation),
    ``first_degraded`` (the first cycle any fault alarms), ``checks`` and ``baseline_cycle``;
    None where it never does."""
    out: dict[str, dict[str, dict[str, Any]]] = {}
    by_act: dict[str, list] = {}
    for r in rows:
        by_act.setdefault(str(r["actuator"]), []).append(r)
    for aid, rs in by_act.items():
        rs = sorted(rs, key=lambda r: float(r["cycle"]))
        degraded = next((float(r["cycle"]) for r in rs if any(r["degraded"].values())), None)
        base = rs[0].get("baseline_cycle")
        base = None if base is None or base != base else float(base)
        # the baseline screened unlike the healthy fleet, farthest in this fault: the
        # actuator arrived with it (a baseline outside the manifest has no cycle to alarm at)
        screen = list(rs[0].get("screen") or [])
        out[aid] = {}
        for name in rs[0]["changes"]:
            # the fault's own statistic also moves with another fault's change (each is
            # estimated alone): an alarm of it is a degraded check isolated to it
            # (or changed beside the one it is isolated to: the two-fault reading)
            alarms = [bool(r["degraded"][name]) and name in r["isolated"]
                      or name in (r.get("also") or ()) for r in rs]
            first = next((float(r["cycle"]) for r, a in zip(rs, alarms) if a), None)
            confirmed = next((float(rs[k]["cycle"]) for k in range(len(rs) - 1)
                              if alarms[k] and alarms[k + 1]), None)
            own = next((float(r["cycle"]) for r in rs if r["degraded"][name]), None)
            at_baseline = bool(screen) and screen[0] == name and base is not None
            out[aid][name] = {"first_alarm": base if at_baseline else first,
                              "first_change": first, "first_confirmed": confirmed,
                              "first_statistic": own, "first_degraded": degraded,
                              "checks": len(rs), "baseline_cycle": base,
                              "at_baseline": at_baseline}
    return out


def change_histories(rows: Sequence[Mapping[str, Any]],
                     base_values: Mapping[str, Mapping[str, Any]], names: Sequence[str]):
    """Per actuator, the tracked faults' histories on the change check: at each later record
    the baseline's identified value plus the change (its interval's sigma), and at the
    baseline's own cycle (when it is a check of the manifest) its identified value.

    ``base_values[actuator]``: the baseline's ``health_checks`` row (``estimates``,
    ``intervals``, ``level``) and its ``baseline_cycle``; an actuator without one has no
    history."""
    from eha.prognostics.rul import FaultHistory

    out: dict[str, dict[str, FaultHistory]] = {}
    for aid, row in base_values.items():
        rs = sorted((r for r in rows if str(r["actuator"]) == aid), key=lambda r: r["cycle"])
        b_cycle = row.get("baseline_cycle")
        points = ([(float(b_cycle), row["estimates"], row.get("intervals") or {},
                    float(row.get("level") or 0.9), True)] if b_cycle is not None else [])
        points += [(float(r["cycle"]), r["changes"], r["intervals"], float(r["level"]), False)
                   for r in rs]
        if not points:
            continue
        out[aid] = {}
        for n in names:
            v0 = float(row["estimates"][n])
            vals, sig, lo, hi = [], [], [], []
            for _, values, intervals, level, is_base in points:
                iv = intervals.get(n) or (None, None)
                shift = 0.0 if is_base else v0
                value = float(values.get(n, 0.0 if not is_base else v0))
                vals.append(value + shift)
                sig.append(_sigma(value, iv, level))
                lo.append(math.nan if iv[0] is None else shift + float(iv[0]))
                hi.append(math.nan if iv[1] is None else shift + float(iv[1]))
            h = FaultHistory(n, np.array([p[0] for p in points]), np.array(vals),
                             np.array(sig), np.ones(len(points), dtype=bool), np.array(lo),
                             np.array(hi))
            h.flags = np.zeros(len(points), dtype=bool)
            out[aid][n] = h
    return out


def _sigma(value: float, interval, level: float) -> float:
    """The spread of a value from its interval at ``level``; an open-ended interval (a change
    beyond its response's growing range: null on one side) from its closed side."""
    from eha.prognostics.rul import sigma_from_interval

    lo, hi = interval
    if lo is None and hi is None:
        return 0.0
    if lo is None or hi is None:
        half = abs(value - (hi if lo is None else lo))
        return sigma_from_interval(value - half, value + half, level)
    return sigma_from_interval(float(lo), float(hi), level)


def store_alarms(results, run_id: str,
                 alarms: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> None:
    """The first alarms in ``change_alarms`` (a re-run of the same manifest replaces them)."""
    from eha.campaigns.store import replace_rows

    now = datetime.now(timezone.utc).replace(tzinfo=None)
    rows = [{"run_id": run_id, "actuator": aid, "fault": n, "reference": REFERENCE,
             "baseline_cycle": a["baseline_cycle"], "first_alarm": a["first_alarm"],
             "first_confirmed": a["first_confirmed"],
             "first_statistic": a["first_statistic"],
             "first_degraded": a["first_degraded"], "checks": a["checks"],
             "at_baseline": bool(a.get("at_baseline")), "created_at": now}
            for aid, per in alarms.items() for n, a in per.items()]
    replace_rows(results, "change_alarms", rows, {"run_id": run_id})


def check_calibration(path) -> dict[str, Any]:
    """A change calibration's file, read as far as the run needs before anything is written
    (its faults, level, command); the worker reads it whole.

    Raises
    ------
    PrognosticsError
        Missing, not JSON, a fleet calibration, another format or model version (one line).
    """
    from eha.models.simulate import MODEL_VERSION

    if path is None:
        raise PrognosticsError("`calibration`: `check` change needs a change calibration for "
                               "the records' command and length (eha health calibrate "
                               "--baseline --command ... --noise ...)")
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise PrognosticsError(f"`calibration` {path}: no such file") from None
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise PrognosticsError(f"`calibration` {path}: not a calibration file "
                               f"({type(exc).__name__})") from None
    if not isinstance(data, dict) or data.get("reference") != REFERENCE:
        what = "a fleet calibration" if isinstance(data, dict) and "thresholds" in data \
            else "not a change calibration"
        raise PrognosticsError(f"`calibration` {path}: {what}; the check against a baseline "
                               "record needs one made with eha health calibrate --baseline")
    if data.get("model_version") != MODEL_VERSION or not isinstance(data.get("faults"), dict):
        raise PrognosticsError(f"`calibration` {path}: made for model version "
                               f"{data.get('model_version')!r}, this is {MODEL_VERSION!r}; "
                               "calibrate again (eha health calibrate --baseline)")
    return data


__all__ = ["REFERENCE", "Baseline", "baselines_of", "change_jobs", "read_change_rows",
           "first_alarms", "change_histories", "store_alarms", "check_calibration"]
