"""The numerical test bench of prognostics: a simulated fleet of degrading actuators.

``eha fleet simulate FLEET.toml --out DIR`` draws N actuators, lets each fault degrade along
a law, checks every actuator every K cycles with an HF run of a chosen command plus sensor
noise, and writes the records (through the campaign runner: 2 workers, resumable), the
manifest and the truth.

File format
-----------
::

    name = "fleet-demo"          # [A-Za-z0-9_.-]+ (campaign name in DIR/eha.duckdb)
    description = "..."
    seed = 7                     # every draw of the fleet derives from it
    actuators = 24               # N, 1 to 10000
    command = "chirp_1cm"        # check command: preset or {name = "chirp", A0 = 5e-3, ...}
    t_end = 1.0                  # record length [s]
    noise = 2e-6                 # sensor noise std on xu [m]
    check_every = 100            # K [cycles]
    first_check = 0              # cycle of the first check
    max_cycles = 20000           # an actuator still healthy then is censored (eol = null)
    format = "csv"               # record files: csv or parquet

    [limits]                     # end of life: the first fault to reach its limit
    BKL = 5e-4                   # m
    FDJ = 2000                   # N

    [dispersion]                 # manufacturing: relative std of HF parameters (optional)
    GM = 0.02

    [faults.BKL]                 # one table per degrading fault (HF parameter)
    initial = [0.0, 2e-5]        # value when new: uniform in [lo, hi] (or a number)
    laws = ["linear", "exponential", "power"]   # each actuator draws one per fault
    rate = {median = 3e-7, sigma = 0.3}  # lognormal slope scale r [unit/cycle]
    tau = [400, 1500]            # exponential time constant range [cycles] (uniform)
    exponent = [1.5, 3.0]        # power-law exponent range (uniform)
    t_scale = 1000               # power-law scale [cycles]
    process_noise = 0.1          # relative std of each increment between checks (>= 0)

Laws: ``x(t) = x0 + r·h(t)`` with ``h = t`` (linear), ``h = τ·(exp(t/τ) − 1)`` (exponential,
slope r at t = 0) and ``h = t_s·(t/t_s)^p`` (power). With process noise, each increment
between two checks is multiplied by ``max(0, 1 + process_noise·ε)``, ε standard normal. The
true end of life of a fault is where its path reaches its limit (linear interpolation between
checks); of an actuator, the earliest over the limited faults.

Outputs in DIR: ``records/<actuator>/c<cycle>.csv`` (t, com, xu, p12, xs in SI; the checks
before the end of life), ``manifest.csv`` (actuator, cycle, record), ``truth.json``
(``{"unit", "limits", "seed", "actuators": {ID: {"eol", "driver", "eol_by_fault", "laws",
"checks": [{"cycle", "true": {...}, "record"}]}}}``), and ``eha.duckdb`` (the runs).
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.campaigns.files import name_problem
from eha.campaigns.jobs import JobKind
from eha.errors import InputError

LAWS = ("linear", "exponential", "power")
TOP_KEYS = ("name", "description", "seed", "actuators", "command", "t_end", "noise",
            "check_every", "first_check", "max_cycles", "format", "limits", "dispersion",
            "faults")
FAULT_KEYS = ("initial", "laws", "rate", "tau", "exponent", "t_scale", "process_noise")
FORMATS = ("csv", "parquet")


class FleetError(InputError):
    """A fleet file that cannot run; ``problems`` holds one line per problem."""

    def __init__(self, problems: list[str]):
        super().__init__(problems, message="\n".join(problems))


@dataclass(frozen=True)
class Degradation:
    """How one fault degrades across the fleet (see the module docstring); the fault itself
    is declared in :mod:`eha.models.faults` or is any LF parameter."""

    name: str
    initial: tuple[float, float]
    laws: tuple[str, ...]
    rate_median: float
    rate_sigma: float
    tau: tuple[float, float]
    exponent: tuple[float, float]
    t_scale: float
    process_noise: float


@dataclass(frozen=True)
class Fleet:
    """A validated fleet file."""

    name: str
    description: str
    seed: int
    actuators: int
    command: dict
    t_end: float
    noise: float
    check_every: float
    first_check: float
    max_cycles: float
    format: str
    limits: dict[str, float]
    dispersion: dict[str, float]
    faults: tuple[Degradation, ...]
    source: str = ""
    definition: dict = field(default_factory=dict)


def _num(where: str, value: Any, lo: float, hi: float, problems: list[str],
         unit: str = "", integer: bool = False) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (integer and not isinstance(value, int)) or not math.isfinite(float(value)) or \
            not lo <= float(value) <= hi:
        kind = "an integer" if integer else "a number"
        problems.append(f"{where}: {value!r}; allowed {kind} in [{lo:g}, {hi:g}]"
                        + (f" {unit}" if unit else ""))
        return None
    return float(value)


def _range(where: str, value: Any, lo: float, hi: float, problems: list[str],
           unit: str = "") -> tuple[float, float] | None:
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value, value]
    if not isinstance(value, list) or len(value) != 2:
        problems.append(f"{where}: {value!r}; expected a number or [lo, hi] within "
                        f"[{lo:g}, {hi:g}] {unit}".rstrip())
        return None
    a = _num(where, value[0], lo, hi, problems, unit)
    b = _num(where, value[1], lo, hi, problems, unit)
    if a is None or b is None:
        return None
    if a > b:
        problems.append(f"{where}: lower {a:g} above upper {b:g}")
        return None
    return (a, b)


def _fault_spec(fname: str, spec: Any, limits: Mapping[str, float],
                p: list[str]) -> Degradation | None:
    """One ``[faults.NAME]`` table of a fleet: its :class:`Degradation`, or None with its
    problems appended to ``p``."""
    from eha.models.params import SPECS

    where = f"faults.{fname}"
    if fname not in SPECS or "hf" not in SPECS[fname].models:
        p.append(f"{where}: unknown HF parameter (see `eha params --faults`)")
        return None
    if not isinstance(spec, Mapping):
        p.append(f"{where}: must be a table")
        return None
    for key in spec:
        if key not in FAULT_KEYS:
            p.append(f"{where}.{key}: unknown key; allowed: {', '.join(FAULT_KEYS)}")
    s = SPECS[fname]
    init = _range(f"{where}.initial", spec.get("initial", s.nominal), s.lo, s.hi, p,
                  s.unit)
    laws = spec.get("laws", list(LAWS))
    if isinstance(laws, str):
        laws = [laws]
    if not isinstance(laws, list) or not laws or any(law not in LAWS for law in laws):
        p.append(f"{where}.laws: {laws!r}; allowed a non-empty list from "
                 f"{', '.join(LAWS)}")
        laws = list(LAWS)
    rate = spec.get("rate")
    rm = rs = None
    if not isinstance(rate, Mapping) or "median" not in rate:
        p.append(f"{where}.rate: required, {{median = r, sigma = s}} (lognormal slope "
                 f"scale, {s.unit}/cycle)")
    else:
        rm = _num(f"{where}.rate.median", rate["median"], 0.0, s.hi, p,
                  f"{s.unit}/cycle")
        rs = _num(f"{where}.rate.sigma", rate.get("sigma", 0.0), 0.0, 3.0, p)
    tau = _range(f"{where}.tau", spec.get("tau", [500.0, 2000.0]), 1e-6, 1e9, p,
                 "cycles")
    expo = _range(f"{where}.exponent", spec.get("exponent", [1.5, 3.0]), 0.1, 10.0, p)
    ts = _num(f"{where}.t_scale", spec.get("t_scale", 1000.0), 1e-6, 1e9, p, "cycles")
    pn = _num(f"{where}.process_noise", spec.get("process_noise", 0.0), 0.0, 2.0, p)
    if None in (init, rm, rs, tau, expo, ts, pn):
        return None
    if fname in limits and init[1] >= limits[fname]:
        p.append(f"{where}.initial: upper value {init[1]:g} is not below the limit "
                 f"{limits[fname]:g} {s.unit}")
    return Degradation(fname, init, tuple(laws), rm, rs, tau, expo, ts, pn)


def parse_fleet(table: Mapping[str, Any], source: str = "<dict>") -> Fleet:
    """Validate a parsed fleet TOML; raises :class:`FleetError` with one line per problem."""
    from eha.models.commands import CommandError, make_command, pin_command
    from eha.models.params import ParameterError, SPECS, check_value

    p: list[str] = []
    for key in table:
        if key not in TOP_KEYS:
            p.append(f"{key}: unknown key; allowed: {', '.join(TOP_KEYS)}")
    name = table.get("name")
    if name_problem(name) is not None:  # the campaign's name, and its folder's
        p.append(name_problem(name))
    seed = _num("seed", table.get("seed", 0), 0, 2**32 - 1, p, integer=True)
    n = _num("actuators", table.get("actuators"), 1, 10000, p, integer=True)
    cmd = table.get("command", "chirp_1cm")
    command: dict = {}
    if isinstance(cmd, str):
        command = {"name": cmd, "set": {}}
    elif isinstance(cmd, Mapping) and isinstance(cmd.get("name"), str):
        command = {"name": cmd["name"], "set": {k: v for k, v in cmd.items() if k != "name"}}
    else:
        p.append(f"command: {cmd!r}; expected a preset name or a table with 'name' (see "
                 "`eha commands`)")
    if command:
        try:
            make_command(command["name"], **command["set"])
            command["name"] = pin_command(command["name"])  # a file by its content hash
        except CommandError as exc:
            p.append(f"command: {exc}")
        except TypeError:
            p.append(f"command: {cmd!r}: parameters must be numbers")
    t_end = _num("t_end", table.get("t_end", 1.0), 0.05, 60.0, p, "s")
    noise = _num("noise", table.get("noise", 2e-6), 0.0, 1e-3, p, "m")
    every = _num("check_every", table.get("check_every"), 1e-6, 1e9, p, "cycles")
    first = _num("first_check", table.get("first_check", 0), 0, 1e9, p, "cycles")
    max_c = _num("max_cycles", table.get("max_cycles", 20000), 1e-6, 1e9, p, "cycles")
    fmt = table.get("format", "csv")
    if fmt not in FORMATS:
        p.append(f"format: {fmt!r}; allowed: {', '.join(FORMATS)}")
    limits: dict[str, float] = {}
    lim_t = table.get("limits", {})
    if not isinstance(lim_t, Mapping) or not lim_t:
        p.append("limits: required, a table NAME = value of at least one degrading fault")
        lim_t = {}
    for k, v in lim_t.items():
        try:
            limits[k] = check_value(k, v, "hf")
        except ParameterError as exc:
            p.append(f"limits: {exc}")
    disp: dict[str, float] = {}
    d_t = table.get("dispersion", {})
    if not isinstance(d_t, Mapping):
        p.append("dispersion: must be a table NAME = relative std")
        d_t = {}
    for k, v in d_t.items():
        if k not in SPECS or "hf" not in SPECS[k].models:
            p.append(f"dispersion: {k}: unknown HF parameter (see `eha params --model hf`)")
            continue
        x = _num(f"dispersion.{k}", v, 0.0, 0.5, p, "(relative std)")
        if x is not None:
            disp[k] = x
    faults: list[Degradation] = []
    f_t = table.get("faults", {})
    if not isinstance(f_t, Mapping) or not f_t:
        p.append("faults: required, one table [faults.NAME] per degrading fault")
        f_t = {}
    for fname, spec in f_t.items():
        fault = _fault_spec(fname, spec, limits, p)
        if fault is not None:
            faults.append(fault)
    for k in limits:
        if k not in f_t:
            p.append(f"limits: {k} has a limit but no [faults.{k}] table (it never degrades)")
    if p:
        raise FleetError(list(dict.fromkeys(p)))
    return Fleet(str(name), str(table.get("description", "")), int(seed), int(n), command,
                 float(t_end), float(noise), float(every), float(first), float(max_c),
                 str(fmt), limits, disp, tuple(faults), source, dict(table))


def load_fleet(path: str | Path) -> Fleet:
    """Read and validate a fleet TOML file (:class:`FleetError` on any problem)."""
    path = Path(path)
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FleetError([f"{path}: cannot read the fleet file ({exc.strerror})"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise FleetError([f"{path}: not valid TOML ({exc})"]) from None
    return parse_fleet(table, str(path))


# =========================================================================== the truth
def _h(law: str, t: np.ndarray, tau: float, p: float, ts: float) -> np.ndarray:
    if law == "linear":
        return t
    if law == "exponential":
        return tau * np.expm1(t / tau)
    return ts * np.power(t / ts, p)


def draw_truth(fleet: Fleet) -> dict[str, Any]:
    """Draw every actuator's laws and paths; returns the truth (see the module docstring).

    Each actuator ``i`` uses ``numpy.random.default_rng([seed, i])``; its record ``k`` the
    seed :func:`record_seed` (HF dither and sensor noise).
    """
    from eha.models.params import SPECS

    width = len(str(fleet.actuators))
    out: dict[str, Any] = {}
    grid = np.arange(fleet.first_check, fleet.max_cycles + 0.5 * fleet.check_every,
                     fleet.check_every)
    for i in range(fleet.actuators):
        aid = f"A{i + 1:0{width}d}"
        rng = np.random.default_rng([fleet.seed, i])
        disp = {}
        for k, rel in fleet.dispersion.items():
            s = SPECS[k]
            disp[k] = float(np.clip(s.nominal * (1 + rel * rng.standard_normal()), s.lo, s.hi))
        laws, paths, eols = {}, {}, {}
        for f in fleet.faults:
            law = f.laws[int(rng.integers(len(f.laws)))]
            x0 = float(rng.uniform(*f.initial))
            r = float(f.rate_median * math.exp(f.rate_sigma * rng.standard_normal()))
            tau = float(rng.uniform(*f.tau))
            p = float(rng.uniform(*f.exponent))
            h = _h(law, grid, tau, p, f.t_scale)
            dh = np.diff(h, prepend=0.0) if grid[0] == 0 else np.diff(
                h, prepend=_h(law, np.array([0.0]), tau, p, f.t_scale)[0])
            mult = np.maximum(0.0, 1.0 + f.process_noise * rng.standard_normal(grid.size))
            if grid[0] == 0:
                mult[0] = 1.0
            x = x0 + r * np.cumsum(dh * mult)
            laws[f.name] = {"law": law, "x0": x0, "rate": r,
                            **({"tau": tau} if law == "exponential" else {}),
                            **({"exponent": p, "t_scale": f.t_scale} if law == "power"
                               else {}),
                            "process_noise": f.process_noise}
            paths[f.name] = x
            lim = fleet.limits.get(f.name)
            if lim is not None:
                above = np.flatnonzero(x >= lim)
                if above.size == 0:
                    eols[f.name] = None
                elif above[0] == 0:
                    eols[f.name] = float(grid[0])
                else:
                    j = above[0]
                    frac = (lim - x[j - 1]) / (x[j] - x[j - 1])
                    eols[f.name] = float(grid[j - 1] + frac * (grid[j] - grid[j - 1]))
        finite = {k: v for k, v in eols.items() if v is not None}
        eol = min(finite.values()) if finite else None
        driver = min(finite, key=finite.get) if finite else None
        checks = []
        for k, c in enumerate(grid):
            if eol is not None and c >= eol:
                break
            true = {f: float(paths[f][k]) for f in paths}
            ext = "csv" if fleet.format == "csv" else "parquet"
            checks.append({"cycle": float(c), "true": true,
                           "record": f"records/{aid}/c{c:g}.{ext}",
                           "seed": record_seed(fleet.seed, aid, k)})
        out[aid] = {"eol": eol, "driver": driver, "eol_by_fault": eols, "laws": laws,
                    "dispersion": disp, "checks": checks}
    return {"unit": "cycle", "fleet": fleet.name, "seed": fleet.seed,
            "limits": dict(fleet.limits), "command": fleet.command, "noise_m": fleet.noise,
            "t_end": fleet.t_end, "actuators": out}


def record_seed(seed: int, actuator: str, k: int) -> int:
    """Seed of record ``k`` of ``actuator`` (HF dither and noise), from the fleet seed."""
    text = json.dumps(["fleet-record", int(seed), actuator, int(k)])
    return int(hashlib.sha256(text.encode()).hexdigest()[:8], 16)


# =========================================================================== runner jobs
def fleet_campaign(fleet: Fleet, out: Path, truth: Mapping[str, Any]):
    """The records as a campaign of ``fleet_record`` jobs (one per check), made as a campaign
    file's jobs are (:func:`eha.campaigns.files.make_campaign`)."""
    from eha.campaigns.files import JobDraft, make_campaign
    from eha.models.simulate import MODEL_VERSION

    drafts = []
    for aid, act in truth["actuators"].items():
        for chk in act["checks"]:
            params = {**act["dispersion"], **chk["true"]}
            spec = {"record": str((out / chk["record"]).resolve()), "command": fleet.command,
                    "params": params, "t_end": fleet.t_end, "noise": fleet.noise,
                    "seed": chk["seed"], "format": fleet.format}
            cols = {"model": "hf", "command": fleet.command["name"], "faults": chk["true"],
                    "seed": chk["seed"], "t_end": fleet.t_end,
                    "fault_label": ",".join(f"{k}={v:g}" for k, v in chk["true"].items()),
                    "label": f"{aid} cycle {chk['cycle']:g}"}
            drafts.append(JobDraft("fleet_record", spec, columns=cols, version=MODEL_VERSION))
    return make_campaign(fleet.name, drafts, fleet.description, fleet.source,
                         fleet.definition)


def run_record_job(spec: Mapping[str, Any], run_key: str, campaign: str,
                   trace_file: str) -> dict[str, Any]:
    """Worker of a ``fleet_record`` job: one HF record with sensor noise, written to
    ``spec["record"]``. No trace or result row (the record is the output)."""
    import time

    from eha.campaigns.traces import write_table_file
    from eha.models.commands import make_command
    from eha.identification.measured import synthetic_record

    t0 = time.perf_counter()
    cmd = make_command(spec["command"]["name"], **spec["command"]["set"])
    frame = synthetic_record(cmd, spec["params"], t_end=float(spec["t_end"]),
                             noise=float(spec["noise"]), seed=int(spec["seed"]))
    if not np.all(np.isfinite(frame.to_numpy())):
        raise FloatingPointError("the HF run produced NaN/inf")
    write_table_file(frame, Path(spec["record"]), spec["format"])
    return {"rows": {}, "sim_s": time.perf_counter() - t0}


# =========================================================================== the command
@dataclass
class FleetResult:
    """What :func:`simulate_fleet` wrote."""

    out: Path
    manifest: Path
    truth: Path
    actuators: int
    records: int
    censored: int
    summary: Any


def simulate_fleet(fleet: Fleet | str | Path, out: str | Path, workers: int = 2,
                   progress: bool = True) -> FleetResult:
    """Simulate a fleet into ``out``: records (campaign runner), manifest.csv, truth.json.

    Re-running resumes (records already written are kept). Raises :class:`FleetError` for a
    bad file (nothing written) and the runner's errors (database locked, ...).
    """
    from eha.prognostics.manifest import write_manifest
    from eha.campaigns.runner import run_campaign

    fl = fleet if isinstance(fleet, Fleet) else load_fleet(fleet)
    out = Path(out)
    truth = draw_truth(fl)
    n_rec = sum(len(a["checks"]) for a in truth["actuators"].values())
    if n_rec == 0:
        raise FleetError(["fleet: no check before any end of life (first_check too late or "
                          "limits too low)"])
    out.mkdir(parents=True, exist_ok=True)
    camp = fleet_campaign(fl, out.resolve(), truth)
    if (out / "eha.duckdb").exists():
        # a record deleted since it was written is simulated again
        from eha.campaigns.store import ResultStore

        with ResultStore(out) as db:
            if db.campaign(camp.name) is not None:
                db.discard_runs(camp.name, {j.run_key for j in camp.jobs
                                            if Path(j.spec["record"]).is_file()})
    summary = run_campaign(camp, out, workers=workers, replace=True, progress=progress)
    rows = [(aid, c["cycle"], c["record"]) for aid, a in truth["actuators"].items()
            for c in a["checks"]]
    manifest = write_manifest(out / "manifest.csv", rows)
    truth_path = out / "truth.json"
    from eha.outputs import write_json

    write_json(truth_path, truth, indent=1)
    censored = sum(1 for a in truth["actuators"].values() if a["eol"] is None)
    return FleetResult(out, manifest, truth_path, len(truth["actuators"]), n_rec, censored,
                       summary)


#: The ``fleet_record`` job kind (entry point ``eha.job_kinds``): ``eha fleet simulate``'s
#: records, one per job.
FLEET_RECORD = JobKind("fleet_record", run_record_job)


__all__ = ["Fleet", "FleetError", "Degradation", "parse_fleet", "load_fleet", "draw_truth",
           "simulate_fleet", "run_record_job", "record_seed", "FleetResult"]
