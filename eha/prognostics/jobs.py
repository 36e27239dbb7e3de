"""The RUL pipeline (``eha rul``): assess every record of a manifest through the campaign
runner, predict at every check, store, evaluate against a truth, plot.

1. :func:`health_campaign` turns the manifest into runner jobs of kind ``"health"``, one per
   record (run key: the record's content hash, actuator, cycle, fitted faults and bounds,
   seed, method). :func:`eha.campaigns.runner.run_campaign` runs them on worker processes into
   ``RESULTS/eha.duckdb`` (table ``health_checks``); a second run of the same or a longer
   manifest only assesses the new records (resume; ``replace``: runs no longer listed are
   dropped).
2. :func:`eha.prognostics.rul.predict_history` predicts, per actuator, at every check from the
   checks up to it.
3. The predictions go to ``rul_predictions``, the JSON file (``--json``) and, with a truth,
   the metrics of :mod:`eha.prognostics.metrics`; plots with ``plots=``.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eha.campaigns.jobs import JobKind
from eha.prognostics.tables import CHECKS  # (importing it declares rul_predictions too)
from eha.models.bounds import Bounds
from eha.models.faults import rul_faults
from eha.prognostics.degradation import LAWS, PrognosticsError
from eha.prognostics.result import RulResult
from eha.prognostics.rul import histories_from_checks, predict_history
from eha.prognostics.rul import LIMIT_ERROR as PRED_LIMIT_ERROR

#: Identification method of the health assessment (eha.identification.problem.METHODS).
HEALTH_METHOD = "ga+ps"


# =========================================================================== inputs
def parse_limits(items: Sequence[str]) -> dict[str, float]:
    """Parse ``NAME=VALUE`` limits (``FDJ=2000``), validated against the parameter ranges.

    Raises
    ------
    PrognosticsError
        One line naming the item and what is allowed.
    """
    from eha.models.params import ParameterError, check_value

    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise PrognosticsError(f"`limits` {item!r}: expected NAME=VALUE, e.g. FDJ=2000")
        try:
            v = float(value)
        except ValueError:
            raise PrognosticsError(f"`limits` {item!r}: {value!r} is not a number") from None
        try:
            out[name] = check_value(name, v, "lf")
        except ParameterError as exc:
            raise PrognosticsError(f"`limits` {exc}") from None
    return out


def health_bounds(names: Sequence[str], limits: Mapping[str, float],
                  bounds: Mapping[str, Sequence[float]] | None = None
                  ) -> Bounds:
    """Search bounds of the assessment: :func:`eha.identification.problem.default_bounds`, widened
    so that a limited fault can be identified up to twice its limit (or down to half of it), then
    ``bounds`` overrides."""
    from eha.identification.problem import default_bounds
    from eha.models.params import SPECS

    out = default_bounds(names)
    for n, lim in limits.items():
        lo, hi = out[n]
        s = SPECS[n]
        if lim >= lo:
            hi = min(max(hi, 2.0 * lim), s.hi)
        else:
            lo = max(min(lo, 0.5 * lim), s.lo)
        out[n] = (lo, hi)
    for n, v in (bounds or {}).items():
        out[n] = (float(v[0]), float(v[1]))
    return out


def file_sha(path: Path) -> str:
    """SHA-256 (16 hex digits) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def run_id_of(manifest_path: Path) -> str:
    """Campaign name of a manifest's health assessment: ``rul-<stem>-<hash of its path>``."""
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", manifest_path.stem)[:40] or "manifest"
    digest = hashlib.sha256(str(manifest_path.resolve()).encode()).hexdigest()[:6]
    return f"rul-{stem}-{digest}"


def health_campaign(manifest, bounds: Mapping[str, tuple[float, float]], seed: int = 0,
                    method: str = HEALTH_METHOD, base_model: str | None = None,
                    columns: Mapping[str, str] | str | None = None, units: str | None = None,
                    name: str | None = None):
    """One ``health`` job per manifest record (an :class:`eha.campaigns.files.Campaign`);
    ``base_model``: LF base of the assessment (``eha.identification.problem.BASE_MODELS``; default
    the one ``eha fdi --data`` uses); ``columns`` and ``units``: how every record is read
    (:class:`eha.identification.measured.RecordFile`; a manifest row's own ``columns`` or
    ``units`` override them), carried in each job's spec to the worker (and into its run key:
    other columns or units are another assessment); ``name``: the campaign's (default
    :func:`run_id_of` the manifest)."""
    from eha.campaigns.files import Campaign, Job
    from eha.identification.measured import RecordFile
    from eha.models.simulate import MODEL_VERSION

    from eha.identification.problem import BASE_MODELS, DEFAULT_BASE_MODEL, DEFAULT_LEVEL

    name = name or run_id_of(manifest.source)
    jobs = []
    fit = {k: [float(v[0]), float(v[1])] for k, v in bounds.items()}
    # the assessment's LF base and interval level, spelled out: a change of the identification's
    # defaults (eha.identification.problem) changes the run keys (no stale assessment is reused)
    if base_model is None:
        base_model = DEFAULT_BASE_MODEL["data"]
    base = dict(BASE_MODELS.get(base_model, {}))
    level = float(DEFAULT_LEVEL)
    for c in manifest.checks:
        spec = {"record": str(c.record), "sha": file_sha(c.record), "actuator": c.actuator,
                "cycle": c.cycle, "fit": fit, "seed": int(seed), "method": method,
                "base_model": base_model, "base": base, "level": level}
        # a row's own columns / units (the manifest's optional columns) override the options
        spec.update(_record_format(RecordFile(c.record, c.columns or columns, c.units or units)))
        key = hashlib.sha256(json.dumps({"campaign": name, "kind": "health", "spec": spec,
                                         "model_version": MODEL_VERSION}, sort_keys=True,
                                        default=float).encode()).hexdigest()[:16]
        cols = {"model": "lf", "seed": int(seed), "label": f"{c.actuator} cycle {c.cycle:g}",
                "estimated_s": 1.5}
        jobs.append(Job(name, "health", key, spec, cols))
    return Campaign(name, f"health assessment of {manifest.source}", str(manifest.source),
                    {"manifest": str(manifest.source), "fit": fit, "seed": seed,
                     "method": method, "base_model": base_model,
                     **_record_format(RecordFile(manifest.source, columns, units))},
                    tuple(jobs), MODEL_VERSION)


def _record_format(record) -> dict[str, Any]:
    """A record's ``columns`` and ``units`` for a job's spec, only those given: the run keys of
    records read by their usual names stay what they were."""
    out: dict[str, Any] = {}
    if record.columns:
        out["columns"] = dict(record.columns)
    if record.units is not None:
        out["units"] = record.units
    return out


def run_health_job(spec: Mapping[str, Any], run_key: str, campaign: str,
                   trace_file: str) -> dict[str, Any]:
    """Worker of a ``health`` job: identify the fitted faults of one record with intervals
    (:func:`eha.identification.fdi.identify_source`); returns its ``health_checks`` row."""
    from eha.identification.fdi import identify_source
    from eha.identification.measured import RecordFile

    fit = {k: tuple(v) for k, v in spec["fit"].items()}
    extra = {}
    if spec.get("base_model") is not None:
        extra = {"base_model": spec["base_model"], "level": spec["level"]}
    # the record as its user has it: the spec's columns and units, read by the one loader
    record = RecordFile(spec["record"], spec.get("columns"), spec.get("units"))
    run = identify_source(data=record, fit=tuple(fit), bounds=fit,
                          seed=int(spec["seed"]), method=spec["method"], **extra)
    res = run.result
    intervals = {k: [float(v[0]), float(v[1])]
                 for k, v in (getattr(res, "intervals", None) or {}).items()}
    row = {"campaign": campaign, "actuator": spec["actuator"], "cycle": float(spec["cycle"]),
           "record": spec["record"], "record_sha": spec["sha"], "fit": spec["fit"],
           "estimates": {k: float(v) for k, v in res.estimates.items()},
           "intervals": intervals, "level": float(getattr(res, "level", 0.9) or 0.9),
           "flagged": bool(getattr(res, "flagged", False)),
           "objective": float(res.objective), "seed": int(spec["seed"]),
           "method": spec["method"], "seconds": float(res.seconds)}
    return {"rows": {"health_checks": row}, "sim_s": float(res.seconds)}


def read_health_rows(results: Path, campaign: str) -> list[dict[str, Any]]:
    """The ``health_checks`` rows of a campaign, with their run status (JSON decoded)."""
    from eha.campaigns.store import connect

    con = connect(results)
    try:
        cur = con.execute("""
            SELECT r.status, r.error, r.label AS run_label, h.*
            FROM runs r LEFT JOIN health_checks h USING (run_key)
            WHERE r.campaign = ?""", [campaign])
        cols = [d[0] for d in cur.description]
        rows = [dict(zip(cols, r)) for r in cur.fetchall()]
    finally:
        con.close()
    for r in rows:
        for k in ("fit", "estimates", "intervals"):
            if isinstance(r.get(k), str):
                r[k] = json.loads(r[k])
    return rows


# =========================================================================== truth
def load_truth(path: str | Path) -> dict[str, float | None]:
    """True end of life per actuator: a JSON ``{"actuators": {ID: {"eol": x}}}`` (the
    ``truth.json`` of ``eha fleet simulate``; ``eol`` null = not reached) or a CSV with the
    columns ``actuator, eol``.

    Raises
    ------
    PrognosticsError
        Unreadable file or a missing/invalid field (one line).
    """
    path = Path(path)
    if not path.is_file():
        raise PrognosticsError(f"`truth` {path}: file not found")
    if path.suffix.lower() == ".csv":
        import csv

        try:
            with open(path, newline="", encoding="utf-8") as fh:
                rows = list(csv.DictReader(fh))
        except UnicodeDecodeError as exc:
            raise PrognosticsError(f"`truth` {path}: not UTF-8 text (byte {exc.start})") \
                from None
        if not rows or "actuator" not in rows[0] or "eol" not in rows[0]:
            raise PrognosticsError(f"`truth` {path}: a CSV needs the columns actuator, eol")
        out = {}
        for i, r in enumerate(rows):
            v = (r["eol"] or "").strip()
            try:
                out[r["actuator"].strip()] = float(v) if v and v.lower() not in (
                    "null", "none", "nan") else None
            except ValueError:
                raise PrognosticsError(f"`truth` {path}: line {i + 2}: eol {v!r} is not a "
                                       "number (or empty for not reached)") from None
        return _checked_eol(path, out)
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
        acts = data["actuators"]
        out = {str(k): v.get("eol") for k, v in acts.items()}
    except UnicodeDecodeError as exc:
        raise PrognosticsError(f"`truth` {path}: not UTF-8 text (byte {exc.start})") from None
    except (ValueError, KeyError, TypeError, AttributeError):
        raise PrognosticsError(f"`truth` {path}: expected JSON {{\"actuators\": {{ID: "
                               "{\"eol\": number or null}}}} or a CSV actuator,eol") from None
    return _checked_eol(path, out)


def _checked_eol(path: Path, eol: Mapping[str, Any]) -> dict[str, float | None]:
    """The ends of life of a truth file, each a finite number >= 0 or None (NaN, Infinity,
    ``true`` or -1 were taken as one)."""
    import math

    for k, v in eol.items():
        try:
            ok = v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)
                               and math.isfinite(v) and v >= 0)
        except OverflowError:  # an integer beyond any float
            ok = False
        if not ok:
            raise PrognosticsError(f"`truth` {path}: actuator {k}: eol {v!r}; allowed a "
                                   "finite number >= 0, or null (not reached)")
    return {k: None if v is None else float(v) for k, v in eol.items()}


# =========================================================================== the pipeline
def run_rul(manifest_path: str | Path, *, limits: Mapping[str, float],
            fit: Sequence[str] | None = None,
            bounds: Mapping[str, Sequence[float]] | None = None,
            results: str | Path = "results", truth: str | Path | None = None,
            seed: int = 0, workers: int = 2, laws: Sequence[str] = LAWS,
            skip_flagged: bool = False, progress: bool = True,
            limit_error: float | None = None, base_model: str | None = None,
            columns: Mapping[str, str] | str | None = None,
            units: str | None = None) -> RulResult:
    """Assess, predict, store and (with a truth) evaluate one manifest; the result's
    ``.save(json_path)``, ``.plot(folder)`` and ``.to_pandas()`` are separate steps (on the
    change check: :func:`eha.prognostics.change_rul.run_rul_change`).

    Parameters
    ----------
    manifest_path : path
        Manifest CSV (:mod:`eha.prognostics.manifest`).
    limits : mapping
        ``{fault: limit}`` [SI units of the fault]: the faults that end life.
    fit : sequence of str, optional
        Faults identified and tracked (default the registry's, :func:`eha.models.faults.rul_faults`); the limited ones are added.
    bounds : mapping, optional
        Search bounds overriding :func:`health_bounds`.
    results : path
        Results folder (``eha.duckdb``): the assessments and the predictions are stored.
    truth : path, optional
        True end of life (:func:`load_truth`): adds the metrics.
    seed : int
        Optimizer seed of every assessment and base seed of the RUL draws.
    workers : int
        Worker processes of the assessment.
    laws : sequence of str
        Degradation laws averaged.
    skip_flagged : bool
        Leave records whose identification is flagged out of the fits.
    limit_error : float, optional
        Relative std of the assessment's systematic error (default
        :data:`eha.prognostics.rul.LIMIT_ERROR`).
    base_model : str, optional
        LF base of the assessment (``eha.identification.problem.BASE_MODELS``, default that of
        ``eha fdi --data``).
    columns, units : optional
        How the records are read, each as :class:`eha.identification.measured.RecordFile`
        reads one: the header of a signal (``"t=time_s,com=command_mm"`` or a mapping) and
        the unit (m, mm, um) of length columns whose header declares none. Checked before
        anything is written; a record without a named header fails its assessment.

    Raises
    ------
    eha.prognostics.manifest.ManifestError, PrognosticsError
        Bad input (nothing written).
    """
    from eha.campaigns.runner import run_campaign

    t0 = time.perf_counter()
    manifest, names, chosen, truth_eol = _check_rul_inputs(
        manifest_path, limits, fit, bounds, truth, laws, limit_error, base_model, columns,
        units)
    results = Path(results)
    camp = health_campaign(manifest, chosen, seed, base_model=base_model, columns=columns,
                           units=units)
    summary = run_campaign(camp, results, workers=workers, replace=True, progress=progress)
    t_assess = time.perf_counter() - t0
    done, failed = _split_rows(read_health_rows(results, camp.name), camp)
    hist = histories_from_checks(done, names, skip_flagged=skip_flagged)
    t1 = time.perf_counter()
    out_acts, preds_all = _predict_all(manifest.actuators, hist, limits, seed, laws, limit_error)
    t_predict = time.perf_counter() - t1
    output = {"unit": "cycle", "limits": dict(limits), "fit": names,
              "bounds": {k: list(v) for k, v in chosen.items()}, "laws": list(laws),
              "seed": seed, "base_model": camp.definition.get("base_model"),
              "limit_error": PRED_LIMIT_ERROR if limit_error is None else limit_error,
              "run_id": camp.name, "manifest": str(manifest.source),
              **{k: camp.definition[k] for k in ("columns", "units") if k in camp.definition},
              "actuators": out_acts}
    metrics = None
    if truth_eol is not None:
        metrics = evaluate_predictions(preds_all, truth_eol)
        output["metrics"] = metrics
    res = RulResult(camp.name, output, preds_all, metrics, failed=failed,
                    assessed=summary.done, reused=summary.skipped, histories=hist,
                    truth=truth_eol)
    _store_predictions(results, camp.name, preds_all, limits)
    res.paths["database"] = results / "eha.duckdb"
    res.seconds = {"assess": t_assess, "predict": t_predict,
                   "total": time.perf_counter() - t0}
    return res


def _split_rows(rows: list[dict[str, Any]], camp) -> tuple[list[dict[str, Any]], list[str]]:
    """The assessed rows of the campaign's jobs, and one line per failed record."""
    # a failed run has no health_checks row: its label ("A1 cycle 3") names the record
    failed = [f"{r.get('run_label') or '?'}: {r['error']}" for r in rows if r["status"] != "done"]
    keys = {j.run_key for j in camp.jobs}
    return [r for r in rows if r["status"] == "done" and r.get("run_key") in keys], failed


def _check_rul_inputs(manifest_path, limits, fit, bounds, truth, laws, limit_error,
                      base_model, columns=None, units=None):
    """Validate :func:`run_rul`'s inputs (nothing written): the manifest, the records' columns
    and units, the tracked fault names, the checked bounds and the true end of life (or None)."""
    from eha.identification.measured import MeasuredDataError, RecordFile
    from eha.prognostics.manifest import read_manifest

    manifest = read_manifest(manifest_path)
    try:  # the loader's own check of --columns and --units, once for every record
        RecordFile(manifest.source, columns, units)
    except MeasuredDataError as exc:
        raise PrognosticsError(exc.problems) from None
    _check_records(manifest, columns, units)
    if limit_error is not None and not 0 <= limit_error < 1:
        raise PrognosticsError(f"`limit_error` {limit_error:g}: allowed range [0, 1) "
                               "(relative standard deviation)")
    if not limits:
        raise PrognosticsError("`limits`: give at least one NAME=VALUE (a fault's end-of-life "
                               "limit), e.g. `limits` FDJ=2000")
    names = list(dict.fromkeys(list(fit or rul_faults()) + list(limits)))
    bad_laws = [x for x in laws if x not in LAWS]
    if bad_laws or not laws:
        raise PrognosticsError(f"`laws` {','.join(bad_laws) or '(none)'}: allowed "
                               f"{', '.join(LAWS)}")
    from eha.identification.problem import BASE_MODELS, FDIError, check_bounds

    try:
        chosen = check_bounds(health_bounds(names, limits, bounds))
    except FDIError as exc:
        raise PrognosticsError(str(exc)) from None
    if base_model is not None and base_model not in BASE_MODELS:
        raise PrognosticsError(f"`base_model` {base_model!r}: allowed {', '.join(BASE_MODELS)}")
    truth_eol = load_truth(truth) if truth is not None else None
    return manifest, names, chosen, truth_eol


def _check_records(manifest, columns, units) -> None:
    """Read every record the manifest names, as its job will (a row's own columns and units
    over the options), before anything is written: a record the loader refuses (a NaN, too
    short, a column missing) is one line naming its manifest line, not a failed run found
    after the others were assessed and stored.

    Raises
    ------
    PrognosticsError
        One line per refused record.
    """
    from eha.identification.measured import MeasuredDataError, RecordFile, load

    problems = []
    for c in manifest.checks:
        try:
            load(RecordFile(c.record, c.columns or columns, c.units or units))
        except MeasuredDataError as exc:
            problems.append(f"{manifest.source.name} line {c.row} (actuator {c.actuator}, "
                            f"cycle {c.cycle:g}): {exc}")
    if problems:
        raise PrognosticsError(problems)


def _predict_all(actuators, hist, limits, seed, laws, limit_error):
    """RUL predictions of every actuator of the manifest (none where it has no history): the
    JSON part ``{actuator: {"predictions": [...]}}`` and ``{actuator: [Prediction]}``."""
    out_acts: dict[str, Any] = {}
    preds_all: dict[str, list] = {}
    for aid in actuators:
        if aid not in hist:
            out_acts[aid] = {"predictions": []}
            preds_all[aid] = []
            continue
        preds, _ = predict_history(aid, hist[aid], limits, seed=seed, laws=laws,
                                   limit_error=limit_error)
        preds_all[aid] = preds
        out_acts[aid] = {"predictions": [p.to_dict() for p in preds]}
    return out_acts, preds_all




def evaluate_predictions(preds_all: Mapping[str, list], truth_eol: Mapping[str, float | None]
                         ) -> dict[str, Any]:
    """Metrics of every actuator with a known end of life, and the fleet summary."""
    from eha.prognostics.metrics import Profile, evaluate, fleet_summary, public

    per: dict[str, Any] = {}
    skipped = []
    for aid, preds in preds_all.items():
        eol = truth_eol.get(aid)
        if eol is None or not preds or not eol > preds[0].cycle:
            skipped.append(aid)
            continue
        samples = [p.samples if p.samples is not None else np.array([]) for p in preds]
        prof = Profile(np.array([p.cycle for p in preds]), samples, float(eol))
        per[aid] = evaluate(prof)
    fleet = fleet_summary(per) if per else {}
    return {"fleet": fleet, "actuators": {k: public(v) for k, v in per.items()},
            "not_evaluated": skipped}


def _store_predictions(results: Path, run_id: str, preds_all: Mapping[str, list],
                       limits: Mapping[str, float], reference: str = "fleet") -> None:
    from eha.campaigns.store import replace_rows

    now = datetime.now(timezone.utc).replace(tzinfo=None)
    rows = [{"run_id": run_id, "actuator": aid, "cycle": p.cycle, "rul": p.rul,
             "rul_lo": p.rul_lo, "rul_hi": p.rul_hi, "driver": p.driver,
             "estimates": p.estimates, "intervals": p.intervals, "flagged": p.flagged,
             "crossings": p.crossings, "law_weights": p.law_weights, "limits": dict(limits),
             "n_used": p.n_used, "seed": p.seed, "created_at": now, "reference": reference}
            for aid, preds in preds_all.items() for p in preds]
    # one transaction: a re-run of the same manifest replaces its predictions
    replace_rows(results, "rul_predictions", rows, {"run_id": run_id})

#: The ``health`` job kind (entry point ``eha.job_kinds``): ``eha rul``'s assessment of one
#: record, made by :func:`health_campaign` (not the ``[health]`` section of a campaign file,
#: which makes ``health_assessment`` jobs, :data:`eha.health.detection.HEALTH`).
HEALTH = JobKind("health", run_health_job, tables=(CHECKS,))


__all__ = ["run_rul", "RulResult", "parse_limits", "load_truth", "health_campaign",
           "run_health_job", "health_bounds", "evaluate_predictions", "run_id_of"]
