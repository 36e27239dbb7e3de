"""Detection and isolation: from health assessments to decisions with a known false-alarm rate.

Pipeline
--------
1. **Fleets** (:func:`health_jobs`, the ``[health]`` section of a campaign file): actuators
   drawn with manufacturing dispersion (:data:`eha.identification.healthy.DISPERSION`, declared with
   the faults in :mod:`eha.models.faults`), optionally
   with one injected fault at given levels, one HF record each (sensor noise, dither seed), each
   assessed by the hypothesis bank (:func:`eha.health.assessment.assess_record`). Run by the
   campaign runner (2 workers, resumable); rows in the DuckDB table ``health_assessments``.
2. **Thresholds** (:func:`calibrate_thresholds`): from a healthy fleet, per fault, the
   detection statistic (the estimate's deviation from healthy in the direction of
   degradation, :func:`statistic`) gets the threshold of a one-sided normal tail with
   probability ``alpha / m`` (``m`` faults): the probability that a healthy check raises any
   alarm is then at most ``alpha`` (union bound). A normal tail because the 1e-3 quantiles it
   needs cannot be read from a fleet of tens; the empirical false-alarm rate is measured on
   other healthy actuators (docs/health.md).
3. **Check** (:func:`check`): a record's assessment against a calibration: per fault
   estimate, interval, threshold, healthy/degraded; the *isolated* faults are the degraded
   ones, BKL/FDJ always candidates and the others only when the bank supports their hypothesis
   (weight >= :data:`ISOLATION_WEIGHT`).
4. **Performance** (:func:`performance`): per fault and command, the ROC curve (healthy vs
   each injected level), the minimum detectable fault at P_D >= 0.95 with P_FA <= 1 %, and the
   isolation confusion matrix.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eha.campaigns.jobs import JobKind
from eha.health.tables import ASSESSMENTS  # (importing it declares verdicts, thresholds too)
from eha.identification.healthy import (DetectionError, built_calibration, draw_actuator,
                                        tail_threshold)
from eha.health.assessment import FAULTS
from eha.models.faults import core_faults, detection_levels
from eha.models.simulate import MODEL_VERSION

#: Smallest posterior weight of a one-more-fault hypothesis for its fault to be isolated.
ISOLATION_WEIGHT = 0.5
#: Default probability that a healthy check raises any alarm.
DEFAULT_ALPHA = 0.01
#: Version of the calibration file format.
CALIBRATION_FORMAT = 1
#: Fewest healthy assessments of a fault its threshold is set from (:func:`calibrate_thresholds`).
MIN_HEALTHY = 5
#: Most actuators of a fleet (per group of a campaign's ``[health]`` section).
MAX_ACTUATORS = 10000


# --------------------------------------------------------------------------------------------
# fleets


_SECTION_KEYS = {"command", "commands", "t_end", "actuators", "healthy_actuators", "seed",
                 "noise", "faults", "base_model", "level", "signals", "noise_p12",
                 "baseline", "nuisances"}


def health_jobs(section: Mapping[str, Any], problems: list[str]) -> list[dict[str, Any]]:
    """Jobs of a ``[health]`` section: one assessment per actuator, command and fault level.

    Section keys::

        [health]
        commands = ["chirp_1cm", "mixed"]    # or command = "chirp_1cm"
        t_end = 1.0                          # s
        actuators = 20                       # per command and fault level
        healthy_actuators = 20               # healthy group (default: actuators)
        seed = 0                             # first actuator seed
        noise = 1e-6                         # m, white sensor noise
        faults = { GM = [0.009, 0.008, 0.007], Clk = [5e-13, 1e-12, 2e-12] }   # optional
        # or faults = ["GM", "Clk"] / "all": the levels declared with each fault
        baseline = true                      # each actuator a pair; nuisances = {GQ = 0.01}
        base_model = "calibrated"            # LF of the assessment
        level = 0.9
        signals = ["xu", "p12"]              # optional: the check fits the load pressure too
        noise_p12 = 5e4                      # Pa, white noise of the recorded p12

    Without ``faults`` every actuator is healthy (a calibration fleet); with it, each fault
    level is injected into ``actuators`` actuators (of their own seeds) and a healthy group is
    added. ``baseline = true``: the change check's pairs (:mod:`eha.health.change_campaign`).
    """
    from eha.models.commands import CommandError, as_command, command_label, pin_command
    from eha.identification.problem import BASE_MODELS

    extra = set(section) - _SECTION_KEYS
    for key in sorted(extra):
        problems.append(f"health.{key}: unknown key; allowed {', '.join(sorted(_SECTION_KEYS))}")
    commands = section.get("commands", [section.get("command", "chirp_1cm")])
    if isinstance(commands, str) or not isinstance(commands, list) or not commands:
        problems.append("health.commands: a non-empty list of command presets")
        commands = []
    pinned = []
    for c in commands:
        try:
            as_command(c)
            pinned.append(pin_command(c))  # a command file by its content hash
        except (CommandError, ValueError, TypeError) as exc:
            problems.append(f"health.commands: {exc}")
    commands = pinned
    t_end = section.get("t_end", 1.0)
    if isinstance(t_end, bool) or not isinstance(t_end, (int, float)) or not 0.2 <= t_end <= 10:
        problems.append(f"health.t_end={t_end!r}: allowed range [0.2, 10] s")
    n = section.get("actuators", 20)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_ACTUATORS:
        problems.append(f"health.actuators={n!r}: allowed range [1, {MAX_ACTUATORS}]")
    n_healthy = section.get("healthy_actuators", n)
    if isinstance(n_healthy, bool) or not isinstance(n_healthy, int) or \
            not 1 <= n_healthy <= MAX_ACTUATORS:
        problems.append(f"health.healthy_actuators={n_healthy!r}: allowed range "
                        f"[1, {MAX_ACTUATORS}]")
    seed = section.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**31:
        problems.append(f"health.seed={seed!r}: allowed range [0, 2147483647]")
    noise = section.get("noise", 1e-6)
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0 <= noise <= 1e-3:
        problems.append(f"health.noise={noise!r}: allowed range [0, 0.001] m")
    base_model = section.get("base_model", "calibrated")
    if base_model not in BASE_MODELS:
        problems.append(f"health.base_model={base_model!r}: allowed {', '.join(BASE_MODELS)}")
    level = section.get("level", 0.9)
    if isinstance(level, bool) or not isinstance(level, (int, float)) or not 0 < level < 1:
        problems.append(f"health.level={level!r}: allowed range (0, 1)")
    signals, noise_p12 = _signals(section, problems)
    jobs = _change_jobs(section, problems, commands, t_end, n, n_healthy, seed, noise, level)
    if jobs is not None:                 # baseline = true: pairs judged by the change check
        return jobs
    groups = _fault_groups(section.get("faults", {}), problems)
    if problems:
        return []
    # only a check that fits p12 says so: the position-only runs keep their keys
    recorded = {"signals": list(signals), "noise_p12": noise_p12} if "p12" in signals else {}
    tag = " (xu,p12)" if recorded else ""
    jobs = []
    for command in commands:
        shown = command_label(command)
        first = seed
        for label, injected in groups:
            size = n_healthy if label == "healthy" else n
            for k in range(size):
                s = first + k
                hf = {**draw_actuator(s), **injected}
                truth = {name: float(hf.get(name, FAULTS[name].healthy)) for name in FAULTS}
                spec = {"command": command, "t_end": float(t_end), "hf": hf, "noise": float(noise),
                        "seed": s, "base_model": base_model, "level": float(level),
                        "group": label, "truth": truth, **recorded}
                jobs.append({"kind": "health_assessment", "spec": spec, "identity": {},
                             "columns": {"model": "hf", "command": shown, "faults": injected,
                                         "seed": s, "t_end": float(t_end),
                                         "fault_label": label,
                                         "label": f"{shown} {label} actuator {s}{tag}",
                                         "estimated_s": 10.0 * float(t_end)}})
            first += size
    return jobs


def _change_jobs(section: Mapping[str, Any], problems: list[str], *common: Any
                 ) -> list[dict[str, Any]] | None:
    """The jobs of a ``[health]`` section with ``baseline = true`` (each actuator a pair of
    records, :func:`eha.health.change_campaign.change_jobs`; ``[]`` when ``baseline`` cannot be
    read), None for a section of the fleet check; its problems appended."""
    baseline = section.get("baseline", False)
    if not isinstance(baseline, bool):
        problems.append(f"health.baseline={baseline!r}: true or false")
        return []
    if baseline:
        from eha.health.change_campaign import change_jobs

        return change_jobs(section, *common, problems)
    if "nuisances" in section:
        problems.append("health.nuisances: only with baseline = true (the test-day differences "
                        "of a pair)")
    return None


def _signals(section: Mapping[str, Any], problems: list[str]) -> tuple[tuple[str, ...], float]:
    """The recorded signals the check fits and the load-pressure noise [Pa] of a ``[health]``
    section; its problems appended."""
    from eha.health.assessment import ASSESSED_SIGNALS, DEFAULT_NOISE_P12

    signals = section.get("signals", ["xu"])
    if isinstance(signals, str):
        signals = signals.split(",")
    if not isinstance(signals, list) or "xu" not in signals or \
            any(s not in ASSESSED_SIGNALS for s in signals):
        problems.append(f"health.signals={section.get('signals')!r}: allowed [\"xu\"] or "
                        f"[\"xu\", \"p12\"]")
        signals = ["xu"]
    noise_p12 = section.get("noise_p12", DEFAULT_NOISE_P12)
    if isinstance(noise_p12, bool) or not isinstance(noise_p12, (int, float)) or \
            not 0 < noise_p12 <= 1e7:
        problems.append(f"health.noise_p12={noise_p12!r}: allowed range (0, 1e7] Pa")
    return tuple(dict.fromkeys(signals)), float(noise_p12)


def _fault_groups(faults: Any, problems: list[str]) -> list[tuple[str, dict[str, float]]]:
    """The groups of a ``[health]`` section's fleet: ``("healthy", {})`` and one
    ``("NAME=level", {NAME: level})`` per level of ``faults``; its problems appended."""
    from eha.models.params import ParameterError, check_value

    groups: list[tuple[str, dict[str, float]]] = [("healthy", {})]
    if faults == "all" or (isinstance(faults, list) and all(isinstance(n, str) for n in faults)):
        # the levels declared with each fault (eha.models.faults.Fault.levels)
        names = list(FAULTS) if faults == "all" else faults
        unknown = [n for n in names if n not in FAULTS]
        for name in unknown:
            problems.append(f"health.faults: {name!r} is not a fault of the assessment; "
                            f"allowed {', '.join(FAULTS)}")
        faults = detection_levels([n for n in names if n in FAULTS])
    if not isinstance(faults, Mapping):
        problems.append('health.faults: a table NAME = [level, ...], a list of fault names or '
                        '"all" (their declared levels)')
        return groups
    for name, levels in faults.items():
        if name not in FAULTS:
            problems.append(f"health.faults.{name}: not a fault of the assessment; allowed "
                            f"{', '.join(FAULTS)}")
            continue
        if not isinstance(levels, list) or not levels:
            problems.append(f"health.faults.{name}: a non-empty list of levels")
            continue
        for v in levels:
            try:
                check_value(name, v, "hf")
            except ParameterError as exc:
                problems.append(f"health.faults.{name}: {exc}")
                continue
            groups.append((f"{name}={v:g}", {name: float(v)}))
    return groups


def run_health_job(spec: Mapping[str, Any]):
    """Worker side of a ``health`` job: the HF record with noise, its assessment; returns the
    ``health_assessments`` row and the record as a Trace."""
    from eha.identification.problem import BASE_MODELS
    from eha.health.assessment import assess_record
    from eha.identification.measured import from_arrays, synthetic_record
    from eha.models import O_COM, O_P12, O_T, O_XU
    from eha.models.commands import command_label
    from eha.models.simulate import Trace

    signals = tuple(spec.get("signals", ("xu",)))
    df = synthetic_record(spec["command"], dict(spec["hf"]), t_end=float(spec["t_end"]),
                          noise=float(spec["noise"]), seed=int(spec["seed"]),
                          noise_p12=float(spec.get("noise_p12", 0.0)))
    rec = from_arrays(df["t"].to_numpy(), df["com"].to_numpy(), df["xu"].to_numpy(),
                      p12=df["p12"].to_numpy() if "p12" in signals else None,
                      source=f"{spec['command']} {spec['group']} {spec['seed']}")
    a = assess_record(rec, base=BASE_MODELS[spec["base_model"]], level=float(spec["level"]),
                      seed=int(spec["seed"]), signals=signals)
    row = {"command": command_label(spec["command"]), "grp": spec["group"], "seed": int(spec["seed"]),
           "t_end": float(spec["t_end"]), "noise": float(spec["noise"]),
           "base_model": spec["base_model"], "level": a.level, "truth": dict(spec["truth"]),
           "hf": dict(spec["hf"]), "estimates": a.estimates, "means": a.means,
           "spread": a.spread,
           "intervals": {k: list(v) for k, v in a.intervals.items()},
           "weights": a.weights(), "best": a.best.fault or "none", "flagged": a.flagged,
           "residual_rmse": a.residual_rmse, "noise_rmse": a.noise_rmse, "n_eff": a.n_eff,
           "seconds": a.seconds}
    data = np.full((len(rec), 9), np.nan)
    data[:, O_T], data[:, O_COM], data[:, O_XU] = rec.t, rec.com, rec.xu
    if rec.p12 is not None:
        data[:, O_P12] = rec.p12
    return row, Trace(data, {"model": "hf+noise", "command": spec["command"],
                             "params": dict(spec["hf"]), "seed": int(spec["seed"])})


def run_health_assessment_job(spec: Mapping[str, Any], run_key: str, campaign: str,
                              trace_file: str) -> dict[str, Any]:
    """Worker of a ``health_assessment`` job (:func:`run_health_job`): a
    ``health_assessments`` row and the record (t, com, xu) as the trace."""
    from eha.campaigns.traces import write_trace
    from eha.models.simulate import Trace

    row, record = run_health_job(spec)
    columns = ["t", "com", "xu", *(["p12"] if "p12" in spec.get("signals", ()) else [])]
    write_trace(Trace(record.data, {**record.meta, "run_key": run_key, "campaign": campaign}),
                trace_file, columns=columns)
    return {"rows": {"health_assessments": row}, "sim_s": row["seconds"]}


def expand_health_section(section: Mapping[str, Any], table: Mapping[str, Any],
                          problems: list[str]) -> list:
    """``[health]`` of a campaign file: one health assessment per actuator
    (:func:`health_jobs`), as :class:`eha.campaigns.files.JobDraft`."""
    from eha.campaigns.files import JobDraft

    return [JobDraft(**job, version=MODEL_VERSION) for job in health_jobs(section, problems)]


#: The ``health_assessment`` job kind (entry point ``eha.job_kinds``): the ``[health]`` section
#: of a campaign file makes its jobs (one assessment per actuator; a section with ``baseline =
#: true`` also makes ``health_change`` pairs, :mod:`eha.health.change_campaign`).
HEALTH = JobKind("health_assessment", run_health_assessment_job, section="health",
                 drafts=expand_health_section, tables=(ASSESSMENTS,))


# --------------------------------------------------------------------------------------------
# thresholds and the calibration file


def statistic(name: str, estimate: float) -> float:
    """Detection statistic of a fault value (an assessment's posterior mean): deviation from
    healthy in the direction of degradation (both directions for the offset), in the fault's
    unit."""
    spec = FAULTS[name]
    d = estimate - spec.healthy
    return abs(d) if spec.direction == 0 else spec.direction * d


def alarm_value(name: str, threshold: float, scale: float = 1.0) -> str:
    """The fault value at which ``threshold`` raises an alarm, as text (``>= 250``,
    ``<= 0.0097``, ``|x - 0| >= 0.004``), in the parameter's unit times ``scale`` (its
    display unit's factor, :func:`eha.models.units.display_unit`)."""
    spec = FAULTS[name]
    if spec.direction == 0:
        return f"|x - {scale * spec.healthy:g}| > {scale * threshold:.4g}"
    value = spec.healthy + spec.direction * threshold
    return f"{'>' if spec.direction > 0 else '<'} {scale * value:.4g}"


@dataclass(frozen=True)
class Calibration:
    """Per-fault thresholds from a healthy fleet, for one command, record length and model."""

    command: str
    command_sig: str
    t_end: float
    model_version: str
    base_model: str
    level: float
    alpha: float
    thresholds: dict[str, float]
    healthy: dict[str, dict[str, float]]
    fleet: dict[str, Any]
    false_alarms: dict[str, Any] = field(default_factory=dict)
    created_at: str = ""
    format: int = CALIBRATION_FORMAT
    #: What the checks fit: the position (files made before this field), or with the load
    #: pressure; a check assesses its record on the same signals.
    signals: list[str] = field(default_factory=lambda: ["xu"])

    def save(self, path: str | Path) -> Path:
        from eha.outputs import write_json

        return write_json(path, asdict(self))  # a temporary name of its own


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; one-line :class:`DetectionError` on any problem."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DetectionError(f"`calibration` {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DetectionError(f"`calibration` {path}: not a calibration file "
                             f"({type(exc).__name__})") from None
    if isinstance(data, dict) and data.get("reference") == "baseline":
        raise DetectionError(f"`calibration` {path}: a calibration of the change check; judge "
                             "a record with it against the actuator's earlier record (eha "
                             "health check RECORD --baseline EARLIER), or give a fleet "
                             "calibration (eha health calibrate)")
    required = {"format", "model_version", "command", "command_sig", "t_end", "thresholds"}
    if not isinstance(data, dict) or data.get("format") != CALIBRATION_FORMAT or \
            not required <= set(data):
        raise DetectionError(f"`calibration` {path}: not a calibration file of format "
                             f"{CALIBRATION_FORMAT} (make one with eha health calibrate)")
    return built_calibration(Calibration, data, path, "eha health calibrate")


def calibrate_thresholds(rows: Sequence[Mapping[str, Any]], alpha: float = DEFAULT_ALPHA,
                         faults: Sequence[str] | None = None) -> tuple[dict, dict]:
    """Thresholds of each fault from healthy-fleet assessments.

    The statistic of a check is :func:`statistic` of the fault's posterior mean; its
    threshold is :func:`tail_threshold` at ``alpha / m`` (``m`` faults), with the median of
    the fault's ``spread`` (the measurement uncertainty of one check) as the spread a small
    fleet can under-sample — a fault that the bank keeps at its healthy value in every healthy
    record would otherwise get a zero threshold.

    Returns ``(thresholds, healthy)``: ``thresholds[name]`` of the statistic, and per fault
    the fleet's mean, std, spread and count of the statistic.
    """
    if not 0 < alpha < 1:
        raise DetectionError(f"alpha={alpha!r}: allowed range (0, 1)")
    names = list(faults or FAULTS)
    thresholds, healthy = {}, {}
    for name in names:
        d = np.array([statistic(name, r["means"][name]) for r in rows if name in r["means"]])
        sp = np.array([r["spread"][name] for r in rows if name in r.get("spread", {})])
        sp = sp[np.isfinite(sp)]
        if d.size < MIN_HEALTHY:
            raise DetectionError(f"calibration: {d.size} healthy assessments of {name}; "
                                 f"at least {MIN_HEALTHY} are needed (use more actuators)")
        spread = float(np.median(sp)) if sp.size else 0.0
        thresholds[name], summary = tail_threshold(d, alpha / len(names), spread)
        healthy[name] = {k: summary[k] for k in ("mean", "std", "spread", "n", "max")}
    return thresholds, healthy


def empirical_false_alarms(rows: Sequence[Mapping[str, Any]], thresholds: Mapping[str, float]
                           ) -> dict[str, Any]:
    """Fraction of healthy checks raising an alarm, per fault and any."""
    per = {n: float(np.mean([statistic(n, r["means"][n]) > t for r in rows]))
           for n, t in thresholds.items()}
    anyf = float(np.mean([any(statistic(n, r["means"][n]) > t
                              for n, t in thresholds.items()) for r in rows]))
    return {"per_fault": per, "any": anyf, "n": len(rows)}


def leave_one_out_false_alarms(rows: Sequence[Mapping[str, Any]], alpha: float
                               ) -> dict[str, Any]:
    """False-alarm rate measured out of sample: each healthy record checked against the
    thresholds of the fleet without it."""
    alarms = []
    for i, r in enumerate(rows):
        thr, _ = calibrate_thresholds([o for j, o in enumerate(rows) if j != i], alpha)
        alarms.append(any(statistic(n, r["means"][n]) > t for n, t in thr.items()))
    return {"any": float(np.mean(alarms)), "n": len(rows)}


# --------------------------------------------------------------------------------------------
# a check


@dataclass(frozen=True)
class Verdict:
    """One fault of one check."""

    name: str
    estimate: float
    interval: tuple[float, float]
    healthy: float
    threshold: float | None
    statistic: float
    degraded: bool | None
    weight: float | None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["interval"] = list(self.interval)
        return d


def verdicts(assessment, calibration: Calibration | None) -> tuple[list[Verdict], list[str]]:
    """Per-fault verdicts of an assessment and the isolated faults (see the module doc)."""
    weights = assessment.weights()
    out, isolated = [], []
    for name, est in assessment.estimates.items():
        stat = statistic(name, assessment.means[name])
        thr = calibration.thresholds.get(name) if calibration else None
        degraded = None if thr is None else bool(stat > thr)
        w = weights.get(name)
        out.append(Verdict(name, float(est), tuple(assessment.intervals[name]),
                           FAULTS[name].healthy, thr, float(stat), degraded, w))
        supported = name in core_faults() or (w is not None and w >= ISOLATION_WEIGHT)
        if degraded and supported:
            isolated.append(name)
    return out, isolated


# --------------------------------------------------------------------------------------------
# performance


def isolate_row(row: Mapping[str, Any], thresholds: Mapping[str, float]) -> str:
    """The fault declared for one assessed record: the isolated fault whose statistic is the
    largest multiple of its threshold, ``"none"`` when nothing is degraded."""
    best, score = "none", 1.0
    weights = row["weights"]
    for name, thr in thresholds.items():
        if name not in row["means"] or thr <= 0:
            continue
        s = statistic(name, row["means"][name]) / thr
        supported = name in core_faults() or weights.get(name, 0.0) >= ISOLATION_WEIGHT
        if s > score and supported:
            best, score = name, s
    return best


def roc_curve(healthy: np.ndarray, faulty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """False-alarm and detection probabilities over every threshold (ascending P_FA)."""
    cuts = np.unique(np.concatenate([healthy, faulty, [np.inf, -np.inf]]))[::-1]
    pfa = np.array([np.mean(healthy > c) for c in cuts])
    pd_ = np.array([np.mean(faulty > c) for c in cuts])
    return pfa, pd_


def performance(rows: Sequence[Mapping[str, Any]], alpha: float = DEFAULT_ALPHA,
                p_detect: float = 0.95) -> dict[str, Any]:
    """Detection and isolation figures of a detection campaign's assessments.

    Per command: thresholds from its healthy group (:func:`calibrate_thresholds`), the
    empirical false-alarm rate, per fault and level the detection rate, and the minimum
    detectable fault (the smallest injected deviation from healthy whose detection rate is
    >= ``p_detect``, None when no level reaches it), the ROC curves and the confusion matrix
    (rows: injected fault, columns: declared fault).
    """
    out: dict[str, Any] = {}
    for command in sorted({r["command"] for r in rows}):
        mine = [r for r in rows if r["command"] == command]
        healthy = [r for r in mine if r["grp"] == "healthy"]
        if len(healthy) < 5:
            continue
        thresholds, stats = calibrate_thresholds(healthy, alpha)
        groups: dict[str, list] = {}
        for r in mine:
            if r["grp"] != "healthy":
                groups.setdefault(r["grp"], []).append(r)
        per_fault: dict[str, Any] = {}
        confusion: dict[str, dict[str, int]] = {"none": {}}
        for r in healthy:
            d = isolate_row(r, thresholds)
            confusion["none"][d] = confusion["none"].get(d, 0) + 1
        for label, rs in sorted(groups.items()):
            name, _, value = label.partition("=")
            stat_h = np.array([statistic(name, r["means"][name]) for r in healthy])
            stat_f = np.array([statistic(name, r["means"][name]) for r in rs])
            deviation = statistic(name, float(value))
            det = float(np.mean(stat_f > thresholds[name]))
            pfa, pdet = roc_curve(stat_h, stat_f)
            entry = per_fault.setdefault(name, {"levels": []})
            entry["levels"].append({"value": float(value), "deviation": deviation,
                                    "p_detect": det, "n": len(rs),
                                    "roc": {"pfa": pfa.tolist(), "pd": pdet.tolist()}})
            row = confusion.setdefault(name, {})
            for r in rs:
                d = isolate_row(r, thresholds)
                row[d] = row.get(d, 0) + 1
        for name, entry in per_fault.items():
            entry["levels"].sort(key=lambda e: e["deviation"])
            ok = [e["deviation"] for e in entry["levels"] if e["p_detect"] >= p_detect]
            entry["min_detectable_deviation"] = min(ok) if ok else None
            entry["threshold"] = thresholds[name]
        out[command] = {"thresholds": thresholds, "healthy": stats,
                        "false_alarms": empirical_false_alarms(healthy, thresholds),
                        "false_alarms_loo": leave_one_out_false_alarms(healthy, alpha),
                        "faults": per_fault, "confusion": confusion}
    return out


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
