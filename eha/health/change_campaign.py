"""Health campaigns of the change check: ``[health] baseline = true``.

Each actuator of such a campaign is a *pair*: an earlier healthy record and a later one on
another test day (the nuisances of :mod:`eha.health.change`, drawn by
:func:`eha.health.change.draw_test_day` within the default half-widths or the section's
``nuisances = {GQ = 0.01, ...}``), with the injected fault level applied as a *change* from
the actuator's own value in the later record. A job of kind ``health_change`` simulates both
records and stores the linear estimate of every fault's change (the generalized least squares
of :class:`eha.health.change.Signatures`, no hypothesis bank: milliseconds a pair once the
signatures are built) in the table ``health_changes``.

The thresholds come afterwards from the campaign's own healthy pairs
(:func:`performance_change`, what ``eha report health`` runs for such a campaign): per fault
the Student-t prediction bound of :mod:`eha.health.change_calibration` (same mean, std and
noise scaling, ``alpha / m`` per fault), then the detection rate, ROC, the smallest
detectable change and the isolation confusion matrix, in the structure of
:func:`eha.health.detection.performance`.
"""

from __future__ import annotations

import json
import math
import time
from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np

from eha.campaigns.jobs import JobKind, Table
from eha.health.change import check_nuisances, draw_test_day, probe
from eha.identification.healthy import DetectionError, draw_actuator
from eha.models.faults import FAULTS

#: Changes injected for a fault named without levels (``faults = ["BKL"]`` or ``"all"``), in
#: multiples of its signature step (:data:`eha.health.change.PROBE`): about the sizes the
#: change check is built to see.
PROBE_MULTIPLES = (1.0, 2.0, 4.0)

#: One row per pair of a change campaign (``[health] baseline = true``).
HEALTH_CHANGES = """
        CREATE TABLE IF NOT EXISTS health_changes (
            run_key       VARCHAR PRIMARY KEY,
            command       VARCHAR,
            grp           VARCHAR,   -- 'healthy' or the injected change 'NAME=change'
            seed          BIGINT,    -- actuator draw, noise and dither of the earlier record
            t_end         DOUBLE,    -- s
            noise         DOUBLE,    -- m, sensor noise std of each record
            level         DOUBLE,    -- nominal coverage of the intervals
            fault         VARCHAR,   -- injected fault (NULL: a healthy pair)
            truth_change  DOUBLE,    -- injected change of the fault (fault unit, SI)
            nuisances     JSON,      -- half-widths of the test-day differences
            test_day      JSON,      -- the later record's nuisance parameters (SI)
            hf            JSON,      -- HF parameters of the earlier record
            estimates     JSON,      -- linear estimate of every fault's change (SI)
            intervals     JSON,      -- {name: [lo, hi]} at level, the model's spread
            noise2        DOUBLE,    -- m^2, both records' noise variances (from the records)
            noise_rmse    DOUBLE,    -- m, the later record's noise
            baseline_rmse DOUBLE,    -- m, the earlier record's noise
            info          JSON,      -- per fault S^T Sigma^-1 S times the weights' noise variance
            noise_factor  JSON,      -- per fault the estimate's variance per m^2 of white noise
            alike         JSON,      -- per fault the faults its signature is not told from
            blind         JSON,      -- faults the command does not move
            seconds       DOUBLE)    -- s, the pair's wall time in the worker"""


# --------------------------------------------------------------------------------------------
# the section's jobs


def change_groups(faults: Any, problems: list[str]) -> list[tuple[str, str | None, float]]:
    """The groups of a change campaign: ``("healthy", None, 0)`` and one
    ``("NAME=change", NAME, change)`` per injected change; its problems appended.

    ``faults = {NAME = [change, ...]}``: signed changes in the fault's SI unit (a motor-gain
    loss is negative), non-zero and smaller than the parameter's range; ``faults = ["BKL"]``
    or ``"all"``: :data:`PROBE_MULTIPLES` times each fault's signature step.
    """
    from eha.models.params import SPECS

    groups: list[tuple[str, str | None, float]] = [("healthy", None, 0.0)]
    if faults == "all" or (isinstance(faults, list) and all(isinstance(n, str) for n in faults)):
        names = list(FAULTS) if faults == "all" else faults
        for name in names:
            if name not in FAULTS:
                problems.append(f"health.faults: {name!r} is not a fault of the change check; "
                                f"allowed {', '.join(FAULTS)}")
        faults = {n: [m * probe(n) for m in PROBE_MULTIPLES] for n in names if n in FAULTS}
    if not isinstance(faults, Mapping):
        problems.append('health.faults: a table NAME = [change, ...], a list of fault names or '
                        '"all" (with baseline = true, each level is a change)')
        return groups
    for name, levels in faults.items():
        if name not in FAULTS:
            problems.append(f"health.faults.{name}: not a fault of the change check; allowed "
                            f"{', '.join(FAULTS)}")
            continue
        if not isinstance(levels, list) or not levels:
            problems.append(f"health.faults.{name}: a non-empty list of changes")
            continue
        width = SPECS[name].hi - SPECS[name].lo
        for v in levels:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v == 0 or abs(v) > width:
                problems.append(f"health.faults.{name}={v!r}: with baseline = true a change "
                                f"from the actuator's own value, non-zero, |change| <= "
                                f"{width:g} {FAULTS[name].unit}")
                continue
            groups.append((f"{name}={v:g}", name, float(v)))
    return groups


def change_jobs(section: Mapping[str, Any], commands: Sequence[str], t_end: float,
                actuators: int, healthy_actuators: int, seed: int, noise: float, level: float,
                problems: list[str]) -> list[dict[str, Any]]:
    """Jobs of a ``[health]`` section with ``baseline = true`` (its common keys already
    checked by :func:`eha.health.detection.health_jobs`): one ``health_change`` job per
    actuator, command and injected change."""
    from eha.models.commands import command_label

    try:
        widths = check_nuisances(section.get("nuisances"))
    except DetectionError as exc:
        problems.append(f"health.nuisances: {exc}")
        widths = {}
    if "nuisances" in section and not isinstance(section["nuisances"], Mapping):
        problems.append("health.nuisances: a table NAME = half-width, e.g. {GQ = 0.01}")
    if tuple(section.get("signals", ["xu"])) != ("xu",):
        problems.append("health.signals: the change check reads the position only "
                        "(signals = [\"xu\"] with baseline = true)")
    groups = change_groups(section.get("faults", {}), problems)
    if problems:
        return []
    jobs = []
    for command in commands:
        shown = command_label(command)
        first = seed
        for label, name, change in groups:
            size = healthy_actuators if name is None else actuators
            for k in range(size):
                s = first + k
                spec = {"command": command, "t_end": float(t_end), "hf": draw_actuator(s),
                        "noise": float(noise), "seed": s, "level": float(level),
                        "group": label, "fault": name, "change": float(change),
                        "nuisances": dict(widths)}
                jobs.append({"kind": "health_change", "spec": spec, "identity": {},
                             "columns": {"model": "hf", "command": shown,
                                         "faults": {name: change} if name else {},
                                         "seed": s, "t_end": float(t_end),
                                         "fault_label": label,
                                         "label": f"{shown} {label} pair {s} (change)",
                                         "estimated_s": 0.05 * float(t_end)}})
            first += size
    return jobs


# --------------------------------------------------------------------------------------------
# the worker


@lru_cache(maxsize=8)
def _signatures(command: str, t_end: float, noise: float, widths: tuple):
    """The estimator of one campaign's command (built once per worker process: a second of
    simulation, then every pair is a matrix product)."""
    from eha.health.change import Signatures
    from eha.models.commands import as_command

    return Signatures(as_command(command), t_end, noise, dict(widths))


def _record(command, hf: Mapping[str, float], t_end: float, noise: float, seed: int):
    from eha.identification.measured import from_arrays
    from eha.identification.synthetic import synthetic_record

    df = synthetic_record(command, dict(hf), t_end=t_end, noise=noise, seed=seed)
    return from_arrays(df["t"].to_numpy(), df["com"].to_numpy(), df["xu"].to_numpy(),
                       source="health_change")


def grow(hf: Mapping[str, float], name: str, change: float) -> tuple[dict, float]:
    """``hf`` with fault ``name`` changed by ``change`` from its own value, within the
    parameter's range; returns the parameters and the change applied (fault unit)."""
    from eha.models.params import SPECS

    v0 = float(hf.get(name, FAULTS[name].healthy))
    v = min(max(v0 + change, SPECS[name].lo), SPECS[name].hi)
    return {**hf, name: v}, v - v0


def run_pair(spec: Mapping[str, Any]) -> tuple[dict[str, Any], Any]:
    """One pair of a change campaign: both records, every fault's linear change estimate;
    returns the ``health_changes`` row and the later record."""
    from scipy.stats import norm

    from eha.health.change import NUISANCES
    from eha.health.change_calibration import later_seed
    from eha.identification.measured import noise_level
    from eha.models.commands import as_command, command_label

    start = time.perf_counter()
    t_end, noise, seed = float(spec["t_end"]), float(spec["noise"]), int(spec["seed"])
    widths = dict(spec["nuisances"])
    cmd = as_command(spec["command"])
    hf = dict(spec["hf"])
    earlier = _record(cmd, hf, t_end, noise, seed)
    later_hf = draw_test_day(hf, widths, seed)
    applied = 0.0
    if spec.get("fault"):
        later_hf, applied = grow(later_hf, spec["fault"], float(spec["change"]))
    later = _record(cmd, later_hf, t_end, noise, later_seed(seed))
    sig = _signatures(spec["command"], t_end, noise, tuple(sorted(widths.items())))
    est = sig.estimate(later.xu - earlier.xu)
    n_a, n_b = noise_level(earlier.xu), noise_level(later.xu)
    noise2 = n_a ** 2 + n_b ** 2
    z = float(norm.ppf(0.5 + float(spec["level"]) / 2.0))
    intervals = {}
    for i, name in enumerate(sig.faults):
        # the model's variance (noise and nuisances) with the white part at the records' noise
        var = (1.0 / sig.info[i] - sig.noise_factor[i] * sig.noise2
               + sig.noise_factor[i] * noise2) if sig.info[i] > 0 else 0.0
        half = z * math.sqrt(max(var, 0.0))
        intervals[name] = [float(est[i] - half), float(est[i] + half)]
    alike = {n: [g for j, g in enumerate(sig.faults) if j != i and sig.separation[i, j]
                 <= max(sig.shape_doubt[i], sig.shape_doubt[j])]
             for i, n in enumerate(sig.faults)}
    row = {"command": command_label(spec["command"]), "grp": spec["group"], "seed": seed,
           "t_end": t_end, "noise": noise, "level": float(spec["level"]),
           "fault": spec.get("fault"), "truth_change": float(applied),
           "nuisances": widths, "test_day": {n: float(later_hf[n]) for n in NUISANCES},
           "hf": hf, "estimates": {n: float(v) for n, v in zip(sig.faults, est)},
           "intervals": intervals, "noise2": float(noise2), "noise_rmse": float(n_b),
           "baseline_rmse": float(n_a),
           "info": {n: float(v * sig.noise2) for n, v in zip(sig.faults, sig.info)},
           "noise_factor": {n: float(v) for n, v in zip(sig.faults, sig.noise_factor)},
           "alike": alike, "blind": list(sig.blind),
           "seconds": time.perf_counter() - start}
    return row, later


def run_change_job(spec: Mapping[str, Any], run_key: str, campaign: str,
                   trace_file: str) -> dict[str, Any]:
    """Worker of a ``health_change`` job (:func:`run_pair`): a ``health_changes`` row and the
    later record (t, com, xu) as the trace."""
    from eha.campaigns.traces import write_trace
    from eha.models import O_COM, O_T, O_XU
    from eha.models.simulate import Trace

    row, rec = run_pair(spec)
    data = np.full((len(rec), 9), np.nan)
    data[:, O_T], data[:, O_COM], data[:, O_XU] = rec.t, rec.com, rec.xu
    write_trace(Trace(data, {"model": "hf+noise", "command": spec["command"],
                             "seed": int(spec["seed"]), "run_key": run_key,
                             "campaign": campaign}), trace_file, columns=["t", "com", "xu"])
    return {"rows": {"health_changes": row}, "sim_s": row["seconds"]}


#: The ``health_change`` job kind (entry point ``eha.job_kinds``): its jobs are drafted by the
#: ``[health]`` section (``baseline = true``) of the ``health_assessment`` kind.
HEALTH_CHANGE = JobKind("health_change", run_change_job,
                        tables=(Table("health_changes", HEALTH_CHANGES, per_run=True),))


# --------------------------------------------------------------------------------------------
# reading the rows back


def change_rows(results, campaign: str) -> list[dict[str, Any]]:
    """The ``health_changes`` rows of the done runs of ``campaign`` (JSON decoded); ``[]`` when
    the database has no such table."""
    from eha.campaigns.query import query, tables

    if "health_changes" not in tables(results):
        return []
    frame = query(results, "SELECT h.* FROM health_changes h JOIN runs r USING (run_key) "
                           "WHERE r.campaign = ? AND r.status = 'done' ORDER BY h.seed",
                  [campaign])
    rows = []
    for rec in frame.to_dict("records"):
        for k in ("nuisances", "test_day", "hf", "estimates", "intervals", "info",
                  "noise_factor", "alike", "blind"):
            if isinstance(rec.get(k), str):
                rec[k] = json.loads(rec[k])
        rows.append(rec)
    return rows


__all__ = ["HEALTH_CHANGES", "PROBE_MULTIPLES", "change_groups", "change_jobs", "run_pair",
           "run_change_job", "change_rows", "grow"]
