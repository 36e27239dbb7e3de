"""The thesis' FDI cases and the campaign-runner glue of fault identification.

The identification itself is :mod:`eha.identification.fdi`; this module holds what the thesis
reproduction adds around it: FDI campaign files (``[fdi]`` sections, :class:`FDICampaign`), running
a case (:func:`run_case`) into the one result type :class:`FDIRow`, and the runner's job functions
(:func:`fdi_jobs`, :func:`run_job`; rows of the ``fdi_results`` table), declared to the campaign
runner as one job kind with its campaign section ``fdi`` (:data:`FDI`).
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from eha.campaigns.jobs import JobKind, Table
from eha.models.commands import as_command
from eha.identification.fdi import hf_reference, identify, mean_error_pct, percent_errors
from eha.identification.problem import (DEFAULT_FIT, DEFAULT_LEVEL, DEFAULT_METHOD, METHODS,
                                        METHOD_DEFAULTS, OBJECTIVES, FDIError, FitResult,
                                        check_bounds)
from eha.models.bounds import Bounds
from eha.models.params import LFParams, ParameterError, resolve
from eha.models.simulate import MODEL_VERSION, Trace, simulate

@dataclass(frozen=True)
class FDICase:
    """One identification case: HF reference faults, LF search bounds, GA population.

    ``thesis`` holds the thesis' own result for the report (BKL, FDJ, err_*_pct,
    mean_err_pct, seconds), empty for cases of one's own.
    """

    case: int
    command: str
    faults: dict[str, float]
    bounds: Bounds
    pop: int = 20
    thesis: dict[str, float] = field(default_factory=dict)
    bounds_source: str = ""


@dataclass(frozen=True)
class FDICampaign:
    """An FDI campaign file: shared settings and its cases.

    File format (a top-level ``[fdi]`` table of a campaign file)::

        [fdi]
        fit = ["BKL", "FDJ"]          # LF parameters to identify
        method = "ga+ps"              # METHODS
        objective = "rmse"            # OBJECTIVES
        seeds = [0, 1, 2, 3, 4]       # each seed: HF dither and optimizer
        t_end = 1.0                   # s
        base = { orifice_law = 1 }    # optional: LF parameters held fixed (effects)

        [[fdi.cases]]
        case = 1
        command = "mixed"
        faults = { BKL = 1e-3, FDJ = 6400 }           # injected in the HF reference
        bounds = { BKL = [0, 5e-3], FDJ = [200, 8000] }
        pop = 20
        thesis = { BKL = 0.0046792, FDJ = 2885.5684, err_BKL_pct = -367.92, ... }  # optional
    """

    name: str
    description: str
    fit: tuple[str, ...]
    method: str
    objective: str
    seeds: tuple[int, ...]
    t_end: float
    cases: tuple[FDICase, ...]
    base: dict[str, float] = field(default_factory=dict)


_CASE_KEYS = {"case", "command", "faults", "bounds", "pop", "thesis", "bounds_source"}
_FDI_KEYS = {"fit", "method", "objective", "seeds", "t_end", "base", "cases"}


def parse_fdi_campaign(data: Mapping[str, Any], source: str = "campaign") -> FDICampaign:
    """Validate the ``[fdi]`` part of a campaign (already parsed TOML); one line per problem."""
    fdi = data.get("fdi")
    if not isinstance(fdi, Mapping):
        raise FDIError(f"{source}: missing [fdi] table")
    extra = set(fdi) - _FDI_KEYS
    if extra:
        raise FDIError(f"{source}: unknown key fdi.{sorted(extra)[0]}; allowed "
                       f"{', '.join(sorted(_FDI_KEYS))}")
    fit = tuple(fdi.get("fit", DEFAULT_FIT))
    method = fdi.get("method", DEFAULT_METHOD)
    objective = fdi.get("objective", "rmse")
    if method not in METHODS:
        raise FDIError(f"{source}: fdi.method {method!r}; allowed {', '.join(METHODS)}")
    if objective not in OBJECTIVES:
        raise FDIError(f"{source}: fdi.objective {objective!r}; allowed "
                       f"{', '.join(OBJECTIVES)}")
    seeds = fdi.get("seeds", [0])
    if not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise FDIError(f"{source}: fdi.seeds must be a non-empty list of integers >= 0")
    t_end = fdi.get("t_end", 1.0)
    if isinstance(t_end, bool) or not isinstance(t_end, (int, float)) or \
            not 1e-3 <= t_end <= 3600.0:
        raise FDIError(f"{source}: fdi.t_end={t_end!r}; allowed range [0.001, 3600] s")
    t_end = float(t_end)
    base = fdi.get("base", {})
    try:
        resolve("lf", base)
    except ParameterError as exc:
        raise FDIError(f"{source}: fdi.base: {exc}") from None
    cases = []
    for i, raw in enumerate(fdi.get("cases", [])):
        where = f"{source}: fdi.cases[{i}]"
        extra = set(raw) - _CASE_KEYS
        if extra:
            raise FDIError(f"{where}: unknown key {sorted(extra)[0]!r}; allowed "
                           f"{', '.join(sorted(_CASE_KEYS))}")
        try:
            as_command(raw["command"])
            resolve("hf", raw.get("faults", {}))
            bounds = check_bounds({n: raw["bounds"][n] for n in fit})
        except KeyError as exc:
            raise FDIError(f"{where}: missing {exc.args[0]!r}") from None
        except (ValueError, ParameterError) as exc:
            raise FDIError(f"{where}: {exc}") from None
        pop = raw.get("pop", 20)
        if not isinstance(pop, int) or not 4 <= pop <= 10000:
            raise FDIError(f"{where}: pop={pop!r}; allowed range [4, 10000] individuals")
        cases.append(FDICase(case=int(raw.get("case", i + 1)), command=raw["command"],
                             faults={k: float(v) for k, v in raw.get("faults", {}).items()},
                             bounds=bounds, pop=pop,
                             thesis={k: float(v) for k, v in raw.get("thesis", {}).items()},
                             bounds_source=str(raw.get("bounds_source", ""))))
    if not cases:
        raise FDIError(f"{source}: no [[fdi.cases]]")
    ids = [c.case for c in cases]
    if len(set(ids)) != len(ids):
        raise FDIError(f"{source}: case numbers must be unique")
    return FDICampaign(name=str(data.get("name", Path(source).stem)),
                       description=str(data.get("description", "")), fit=fit, method=method,
                       objective=objective, seeds=tuple(seeds), t_end=t_end,
                       cases=tuple(cases), base={k: float(v) for k, v in base.items()})


def load_fdi_campaign(path: str | Path) -> FDICampaign:
    """Read and validate an FDI campaign TOML file (e.g. campaigns/thesis-fdi.toml)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FDIError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise FDIError(f"{path}: invalid TOML: {exc}") from None
    return parse_fdi_campaign(data, str(path))


@dataclass(frozen=True)
class FDIRow:
    """One identification of an FDI case: THE result type of the thesis cases, built from a
    :class:`eha.identification.problem.FitResult` (:meth:`from_fit`), stored as one ``fdi_results``
    row (:meth:`to_record`) and read back from it (:meth:`from_record`). Reports read fields by
    name, also as ``row["case"]`` (read-only mapping access).

    Attributes
    ----------
    case, command, seed, method, objective_name :
        What ran (seed: HF dither and optimizer).
    truth, estimates, errors_pct : dict
        Injected values, identified values, thesis percent errors per fitted parameter.
    mean_err_pct : float
        Mean of the absolute percent errors.
    objective : float
        RMSE (or objfcn) at the estimate [m].
    evaluations, seconds, pop, bounds, history :
        Cost, GA population, search bounds, best objective per generation/poll.
    level, intervals, flagged, noise_rmse :
        The intervals of the estimates (eha.identification.intervals).
    """

    case: int
    command: str
    seed: int
    method: str
    objective_name: str
    truth: dict[str, float]
    estimates: dict[str, float]
    errors_pct: dict[str, float]
    mean_err_pct: float
    objective: float
    evaluations: int
    seconds: float
    pop: int
    bounds: dict[str, list[float]]
    history: tuple[float, ...] = ()
    level: float | None = None
    intervals: dict[str, list[float]] = field(default_factory=dict)
    flagged: bool = False
    noise_rmse: float | None = None

    def __getitem__(self, name: str) -> Any:
        return getattr(self, name)

    def get(self, name: str, default: Any = None) -> Any:
        return getattr(self, name, default)

    @classmethod
    def from_fit(cls, case: "FDICase", seed: int, res: FitResult) -> "FDIRow":
        truth = {n: float(case.faults.get(n, LFParams().as_dict()[n])) for n in res.names}
        errors = percent_errors(truth, res.estimates)
        return cls(case=case.case, command=case.command, seed=int(seed), method=res.method,
                   objective_name=res.objective_name, truth=truth,
                   estimates=dict(res.estimates), errors_pct=errors,
                   mean_err_pct=mean_error_pct(errors), objective=float(res.objective),
                   evaluations=int(res.evaluations), seconds=float(res.seconds), pop=case.pop,
                   bounds={k: list(v) for k, v in res.bounds.items()},
                   history=tuple(res.history), level=res.level,
                   intervals={k: list(v) for k, v in res.intervals.items()},
                   flagged=bool(res.flagged), noise_rmse=res.noise_rmse)

    def to_record(self) -> dict[str, Any]:
        """The ``fdi_results`` columns (:data:`FDI_RESULTS`)."""
        est, truth, err = self.estimates, self.truth, self.errors_pct
        return {"case_id": int(self.case), "command": self.command, "seed": int(self.seed),
                "method": self.method, "objective_name": self.objective_name,
                "fit": list(est), "truth": dict(truth), "estimates": dict(est),
                "errors_pct": dict(err), "bounds": dict(self.bounds),
                "bkl_true": truth.get("BKL"), "bkl_est": est.get("BKL"),
                "err_bkl_pct": err.get("BKL"), "fdj_true": truth.get("FDJ"),
                "fdj_est": est.get("FDJ"), "err_fdj_pct": err.get("FDJ"),
                "mean_err_pct": float(self.mean_err_pct), "objective": float(self.objective),
                "evaluations": int(self.evaluations), "seconds": float(self.seconds),
                "pop": int(self.pop), "history": list(self.history), "level": self.level,
                "intervals": dict(self.intervals), "flagged": bool(self.flagged),
                "noise_rmse": self.noise_rmse}

    @classmethod
    def from_record(cls, rec: Mapping[str, Any]) -> "FDIRow":
        """Back from an ``fdi_results`` row (JSON columns as text or parsed)."""
        import json

        def load(v):
            return json.loads(v) if isinstance(v, str) else (v or {})

        level = rec.get("level")
        flagged = rec.get("flagged")
        noise = rec.get("noise_rmse")
        return cls(case=int(rec["case_id"]), command=rec["command"], seed=int(rec["seed"]),
                   method=rec["method"], objective_name=rec["objective_name"],
                   truth=load(rec["truth"]), estimates=load(rec["estimates"]),
                   errors_pct=load(rec["errors_pct"]),
                   mean_err_pct=float(rec["mean_err_pct"]), objective=float(rec["objective"]),
                   evaluations=int(rec["evaluations"]), seconds=float(rec["seconds"]),
                   pop=int(rec["pop"]), bounds=load(rec["bounds"]),
                   level=None if level is None or level != level else float(level),
                   intervals=load(rec.get("intervals")),
                   flagged=bool(flagged) if flagged is not None and flagged == flagged
                   else False,
                   noise_rmse=None if noise is None or noise != noise else float(noise))


def run_case(case: FDICase, seed: int = 0, method: str = DEFAULT_METHOD,
             objective: str = "rmse", t_end: float = 1.0, base: LFParams | None = None,
             level: float | None = DEFAULT_LEVEL, **options: float) -> FDIRow:
    """Run one case with one seed: HF reference (dither seed ``seed``), then identification
    (with intervals at ``level``). Percent errors as the thesis computes them
    (:func:`eha.identification.fdi.percent_errors`)."""
    ref = hf_reference(case.command, case.faults, seed=seed, t_end=t_end)
    res = identify(ref.xu, case.command, case.bounds, base=base, method=method, pop=case.pop,
                   seed=seed, objective=objective, t_end=t_end, level=level, **options)
    return FDIRow.from_fit(case, seed, res)


def run_campaign(campaign: FDICampaign, seeds: Sequence[int] | None = None,
                 method: str | None = None, objective: str | None = None,
                 cases: Sequence[int] | None = None, base: LFParams | None = None,
                 on_row: Callable[[FDIRow], None] | None = None,
                 **options: float) -> list[FDIRow]:
    """Run every case of ``campaign`` for every seed, one after the other (each
    identification already uses every core through the batched LF kernel).

    ``seeds``, ``method``, ``objective`` override the campaign's; ``cases`` selects case
    numbers; ``on_row`` is called after each run (progress bars).
    """
    seeds = tuple(campaign.seeds if seeds is None else seeds)
    if base is None and campaign.base:
        base = resolve("lf", campaign.base)
    method = method or campaign.method
    objective = objective or campaign.objective
    chosen = [c for c in campaign.cases if cases is None or c.case in set(cases)]
    if cases is not None and len(chosen) != len(set(cases)):
        missing = sorted(set(cases) - {c.case for c in chosen})
        raise FDIError(f"cases: no case {missing[0]} in {campaign.name}")
    rows = []
    for case in chosen:
        for seed in seeds:
            row = run_case(case, seed, method, objective, campaign.t_end, base=base, **options)
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows


# --------------------------------------------------------------------------------------------
# campaign-runner jobs (kind "fdi", section [fdi]; registered with eha.campaigns.jobs, which
# expands, runs and keeps them)


def fdi_jobs(table: Mapping[str, Any], source: str = "campaign") -> list[dict[str, Any]]:
    """Jobs of the ``[fdi]`` section of a campaign: one per case and seed.

    Returns dicts with ``kind`` ("fdi"), ``spec`` (what :func:`run_job` needs, with the method
    options resolved so that a change of a default changes the run key), ``identity`` and the
    descriptive ``columns`` of the ``runs`` table.
    """
    camp = parse_fdi_campaign(table, source)
    jobs = []
    for case in camp.cases:
        for seed in camp.seeds:
            spec = {"case": case.case, "command": case.command, "faults": case.faults,
                    "bounds": {k: list(v) for k, v in case.bounds.items()}, "pop": case.pop,
                    "seed": seed, "method": camp.method, "objective": camp.objective,
                    "t_end": camp.t_end, "base": camp.base,
                    "options": METHOD_DEFAULTS[camp.method], "level": DEFAULT_LEVEL}
            jobs.append({"kind": "fdi", "spec": spec,
                         "identity": {"hf": resolve("hf", case.faults).as_dict()},
                         "columns": {"model": "lf", "command": case.command,
                                     "faults": case.faults, "seed": seed, "t_end": camp.t_end,
                                     "fault_label": ",".join(f"{k}={v:g}" for k, v in
                                                             case.faults.items()),
                                     "label": f"case {case.case} seed {seed}",
                                     "estimated_s": 1.5 * camp.t_end}})
    return jobs


def run_job(spec: Mapping[str, Any]) -> tuple[dict[str, Any], Trace]:
    """Execute one FDI job (:func:`fdi_jobs`): the ``fdi_results`` row and the identified LF
    trace (meta: case, seed, truth, estimates)."""
    case = FDICase(case=int(spec["case"]), command=spec["command"], faults=spec["faults"],
                   bounds=Bounds(spec["bounds"]), pop=int(spec["pop"]))
    base = resolve("lf", spec.get("base") or {})
    row = run_case(case, int(spec["seed"]), spec["method"], spec["objective"],
                   float(spec["t_end"]), base=base, level=spec.get("level", DEFAULT_LEVEL),
                   **spec.get("options", {}))
    fitted = simulate("lf", case.command, base.replace(**row.estimates),
                      t_end=float(spec["t_end"]))
    meta = {**fitted.meta, "fdi": {"case": case.case, "seed": row.seed, "truth": row.truth,
                                   "estimates": row.estimates,
                                   "mean_err_pct": row.mean_err_pct}}
    return row.to_record(), Trace(fitted.data, meta)


def rows_from_results(frame) -> list[FDIRow]:
    """``fdi_results`` table rows (a DataFrame, JSON as text) back as :class:`FDIRow`."""
    return [FDIRow.from_record(rec) for rec in frame.to_dict("records")]


def run_fdi_job(spec: Mapping[str, Any], run_key: str, campaign: str,
                trace_file: str) -> dict[str, Any]:
    """Worker of an ``fdi`` job (:func:`run_job`): an ``fdi_results`` row and the trace of the
    identified LF model."""
    from eha.campaigns.traces import write_trace

    row, fitted = run_job(spec)
    write_trace(Trace(fitted.data, {**fitted.meta, "run_key": run_key, "campaign": campaign}),
                trace_file)
    return {"rows": {"fdi_results": row}, "sim_s": row["seconds"], "trace_rows": len(fitted)}


def expand_fdi_section(section: Mapping[str, Any], table: Mapping[str, Any],
                       problems: list[str]) -> list:
    """``[fdi]`` of a campaign file: one fault-identification job per case and seed
    (:func:`fdi_jobs`), as :class:`eha.campaigns.files.JobDraft`; every problem of the section
    is appended to ``problems``, one line each."""
    from eha.campaigns.files import JobDraft

    try:
        return [JobDraft(**job, version=MODEL_VERSION) for job in fdi_jobs(table, source="fdi")]
    except FDIError as exc:
        problems.extend(_all_fdi_problems(table, str(exc)))
        return []


def _all_fdi_problems(table: Mapping[str, Any], first: str, most: int = 50) -> list[str]:
    """Every problem of an ``[fdi]`` section, one line each.

    :func:`parse_fdi_campaign` stops at its first problem. The part a message names
    (``fdi.KEY`` or ``fdi.cases[i]``) is taken out of a copy of the section (a top-level key
    falls back to its default, a case is dropped) and the copy validated again, until it
    passes, a message names no part, or the same message comes back.
    """
    section = dict(table.get("fdi", {}))
    cases = list(enumerate(section.get("cases", []) or []))
    had_cases = bool(cases)
    found = [first]
    message = first
    for _ in range(most):
        case = re.search(r"fdi\.cases\[(\d+)\]", message)
        key = re.search(r"fdi\.(\w+)", message)
        if case and int(case.group(1)) < len(cases):
            del cases[int(case.group(1))]
        elif key and key.group(1) in section and key.group(1) != "cases":
            del section[key.group(1)]
        else:
            break
        section["cases"] = [c for _, c in cases]
        try:
            fdi_jobs({**table, "fdi": section}, source="fdi")
            break
        except FDIError as exc:
            message = str(exc)
        if had_cases and not cases and "no [[fdi.cases]]" in message:
            break  # every case was taken out for its own problem: nothing more to learn
        # report case indices as they are in the file, not in the shortened copy
        shown = re.sub(r"fdi\.cases\[(\d+)\]",
                       lambda m: f"fdi.cases[{cases[int(m.group(1))][0]}]"
                       if int(m.group(1)) < len(cases) else m.group(0), message)
        if shown in found:
            break
        found.append(shown)
    return found


#: The ``fdi`` kind's result table: one row per run.
FDI_RESULTS = """
        CREATE TABLE IF NOT EXISTS fdi_results (
            run_key        VARCHAR PRIMARY KEY,
            case_id        INTEGER,   -- case number (thesis Figure 6.17 numbering)
            command        VARCHAR,
            seed           BIGINT,    -- HF dither and optimizer seed
            method         VARCHAR,   -- eha.identification.problem.METHODS ('ga': thesis)
            objective_name VARCHAR,   -- 'rmse' or 'objfcn' (thesis' mean absolute error)
            fit            JSON,      -- fitted LF parameters, e.g. ["BKL", "FDJ"]
            truth          JSON,      -- injected values (SI)
            estimates      JSON,      -- identified values (SI)
            errors_pct     JSON,      -- (input - output)/input*100, 0 when input is 0
            bounds         JSON,      -- search bounds {name: [lo, hi]}
            bkl_true DOUBLE, bkl_est DOUBLE, err_bkl_pct DOUBLE,  -- m, m, %
            fdj_true DOUBLE, fdj_est DOUBLE, err_fdj_pct DOUBLE,  -- N, N, %
            mean_err_pct   DOUBLE,    -- mean of the absolute percent errors
            objective      DOUBLE,    -- m, at the estimate
            evaluations    INTEGER,   -- LF simulations
            seconds        DOUBLE,    -- s, identification wall time in the worker
            pop            INTEGER,   -- GA population
            history        JSON,      -- best objective per generation/poll [m]
            level          DOUBLE,    -- nominal coverage of the intervals (0.9)
            intervals      JSON,      -- {name: [lo, hi]} at level (SI)
            flagged        BOOLEAN,   -- residual well above the noise: not a confident fit
            noise_rmse     DOUBLE)    -- m, sensor noise estimated from the reference"""

#: The ``fdi`` job kind (entry point ``eha.job_kinds``): the ``[fdi]`` section, its worker and
#: its ``fdi_results`` table.
FDI = JobKind("fdi", run_fdi_job, section="fdi", drafts=expand_fdi_section,
              tables=(Table("fdi_results", FDI_RESULTS, per_run=True,
                            added=(("level", "DOUBLE"), ("intervals", "JSON"),
                                   ("flagged", "BOOLEAN"), ("noise_rmse", "DOUBLE"))),))
