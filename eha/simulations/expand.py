"""The ``simulate`` kind's part of a campaign file: models × commands × fault sets × seeds.

:func:`_expand_simulations` validates the top-level keys (:data:`KEYS`) ``models``,
``commands``, ``seeds``, ``t_end``, ``signals``, ``params`` and ``faults`` of a campaign file
(the format: :mod:`eha.campaigns.files`) through the same validators the models use
(:func:`eha.models.params.resolve`, :func:`eha.models.params.check_value`,
:func:`eha.models.commands.make_command`, :func:`eha.models.simulate.check_grid`) and returns the
drafts of its ``simulate`` jobs, one per model, fault set, command and seed. Every problem is
appended to ``problems``, one line each. The kind's declaration names the keys and their
expander (:data:`eha.simulations.batch.SIMULATE`); each draft
carries the models' version (:data:`eha.models.simulate.MODEL_VERSION`), hashed into its run
key.
"""

from __future__ import annotations

import itertools
import json
from typing import Any, Callable, Mapping

from eha.campaigns.drafts import MAX_JOBS, JobDraft, _did_you_mean, _hash
from eha.models import OUTPUTS
from eha.models import simulate as models_simulate
from eha.models.commands import Command, CommandError, make_command, pin_command
from eha.models.params import MODELS, ParameterError, check_value, resolve

#: Top-level keys of a campaign file that are the ``simulate`` kind's.
KEYS = ("models", "commands", "seeds", "t_end", "signals", "params", "faults")

#: Signals every stored trace must keep (metrics, pairing and plots read them).
REQUIRED_SIGNALS = ("t", "com", "xu")
#: Most integration steps of one run: the worker holds the command and the time of every step
#: (16 bytes each), so 4e8 steps (t_end = 3600 s at the nominal DT = 1e-5 s) need about 6.4 GB.
MAX_STEPS = 400_000_000
FAULT_KEYS = ("nominal", "grid", "single", "points")


def _model_version() -> str:
    """The models' version, read when a file is expanded (a test may patch it)."""
    return models_simulate.MODEL_VERSION


def expand(table: Mapping[str, Any], name: str, problems: list[str],
           chosen: bool) -> list[JobDraft]:
    """The ``simulate`` jobs of a campaign file: those of :func:`_expand_simulations` when the
    file's kind is ``simulate`` (``chosen``) or it names models or commands, else none."""
    if not (chosen or "models" in table or "commands" in table):
        return []
    return _expand_simulations(table, name, problems)


def _expand_simulations(table: Mapping[str, Any], name: str,
                        problems: list[str]) -> list[JobDraft]:
    n_before = len(problems)
    models = _models(table.get("models"), problems)
    commands = _commands(table.get("commands"), problems)
    _pin_in_definition(table, commands)
    seeds = _seeds(table.get("seeds", [0]), problems)
    signals = _signals(table.get("signals", list(OUTPUTS)), problems)
    fixed = _fixed_params(table.get("params", {}), models, problems)
    t_end = _t_end(table.get("t_end", 1.0), models, problems, fixed)
    # The job limit is checked on the counts, before a fault set or a job is built.
    per_set = max(1, len(models) * len(commands) * len(seeds))
    fault_sets = _fault_sets(table.get("faults", {}), models, problems,
                             limit=max(1, MAX_JOBS // per_set))
    if fault_sets is None:
        n_jobs = _fault_set_bound(table.get("faults", {})) * per_set
        problems.append(f"campaign: expands to up to {n_jobs} jobs; the limit is {MAX_JOBS} "
                        "(split it into several campaigns)")
        return []
    if len(problems) > n_before:
        return []

    # Cross-field checks (e.g. XJ0 within XJM) need the complete parameter set of each run.
    resolved: dict[tuple[str, int], dict[str, float]] = {}
    for model in models:
        for i, (_, faults) in enumerate(fault_sets):
            overrides = fixed["all"] | fixed[model] | faults
            try:
                resolved[model, i] = resolve(model, overrides).as_dict()
            except ParameterError as exc:
                problems.append(f"faults: {_describe_faults(faults)} ({model.upper()}): {exc}")
    if len(problems) > n_before:
        return []

    drafts = []
    version = _model_version()
    for i, (label, faults) in enumerate(fault_sets):
        for cmd_name, cmd_set, cmd in commands:
            identities = {m: {"params": resolved[m, i], "command": cmd.describe()}
                          for m in models}  # one object per model: hashed once (_run_key)
            for seed in seeds:
                case = {"command": cmd.describe(), "faults": faults, "seed": seed,
                        "t_end": t_end, "fixed": fixed["all"]}
                case_key = _hash(case)
                for model in models:
                    overrides = fixed["all"] | fixed[model] | faults
                    spec = {"model": model, "command": {"name": cmd_name, "set": cmd_set},
                            "params": overrides, "seed": seed, "t_end": t_end,
                            "signals": signals}
                    identity = identities[model]
                    columns = {"model": model, "command": cmd.describe()["name"],
                               "faults": faults, "fault_label": label, "seed": seed,
                               "t_end": t_end, "case_key": case_key,
                               "label": f"{model.upper()} {cmd_name} {label} seed={seed}"}
                    drafts.append(JobDraft("simulate", spec, identity, columns, version))
    return drafts


def _distinct(key: str, value: Any, what: str, ok: Callable[[Any], bool],
              bad: Callable[[Any], str], problems: list[str]) -> list:
    """A non-empty list of distinct valid items (a single item counts as a list of one)."""
    if not isinstance(value, list):
        value = [value] if isinstance(value, (str, int)) and not isinstance(value, bool) else []
    if not value:
        problems.append(f"{key}: must be a non-empty list of {what}")
        return []
    out: list = []
    seen: set = set()  # membership in a set: a list of 10^5 seeds is checked in linear time
    for item in value:
        if not ok(item):
            problems.append(f"{key}: {bad(item)}")
        elif item in seen:
            problems.append(f"{key}: {item!r} listed twice")
        else:
            seen.add(item)
            out.append(item)
    return out


def _models(value: Any, problems: list[str]) -> list[str]:
    if value is None:
        problems.append("models: required, a list from: hf, lf")
        return []
    return _distinct("models", value, "models from: hf, lf", lambda m: m in MODELS,
                     lambda m: f"unknown model {m!r}; allowed: hf, lf", problems)


def _pin_in_definition(table: Mapping[str, Any], commands: list) -> None:
    """Name each command file of the definition (``build_campaign``'s own copy) by its
    absolute path and content hash, as the run keys do: ``eha campaign verify --repair``
    rebuilds the campaign from the stored definition in any folder, and refuses a file edited
    since (:func:`eha.models.commands.load_command_file`)."""
    value = table.get("commands")
    entries = value if isinstance(value, list) else [value]
    if not isinstance(table, dict) or len(entries) != len(commands):
        return  # a bad entry was left out: nothing is stored
    pinned = [name if isinstance(entry, str) else {**entry, "name": name}
              for entry, (name, _, _) in zip(entries, commands)]
    table["commands"] = pinned if isinstance(value, list) else pinned[0]


def _commands(value: Any, problems: list[str]) -> list[tuple[str, dict, Command]]:
    if value is None:
        problems.append("commands: required, a list of presets or kinds (see `eha commands`)")
        return []
    if isinstance(value, (str, Mapping)):
        value = [value]
    if not isinstance(value, list) or not value:
        problems.append("commands: must be a non-empty list of presets or kinds "
                        "(see `eha commands`)")
        return []
    out: list[tuple[str, dict, Command]] = []
    labels: set[str] = set()
    for i, entry in enumerate(value):
        if isinstance(entry, str):
            cmd_name, overrides = entry, {}
        elif isinstance(entry, Mapping) and isinstance(entry.get("name"), str):
            cmd_name = entry["name"]
            overrides = {k: v for k, v in entry.items() if k != "name"}
        else:
            problems.append(f"commands[{i}]: expected a preset name or a table with a 'name' "
                            f"key, got {entry!r}")
            continue
        try:
            cmd = make_command(cmd_name, **overrides)
            cmd_name = pin_command(cmd_name)  # a command file by its content hash
        except CommandError as exc:
            problems.append(f"commands[{i}]: {exc}")
            continue
        key = json.dumps(cmd.describe(), sort_keys=True)
        if key in labels:
            problems.append(f"commands[{i}]: {cmd_name} listed twice with the same parameters")
            continue
        labels.add(key)
        out.append((cmd_name, {k: float(v) for k, v in overrides.items()}, cmd))
    return out


def _seeds(value: Any, problems: list[str]) -> list[int]:
    return _distinct("seeds", value, "integers in [0, 2**32-1]",
                     lambda s: isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32,
                     lambda s: f"{s!r} is out of range; allowed integers in [0, 2**32-1]",
                     problems)


def _t_end(value: Any, models: list[str], problems: list[str],
           fixed: Mapping[str, dict] | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        problems.append(f"t_end: {value!r} is not a number of seconds")
        return 1.0
    fixed = fixed or {}
    for model in models or ["hf"]:
        try:  # the campaign's own parameters (its DT), not the nominal ones
            params = resolve(model, dict(fixed.get("all", {})) | dict(fixed.get(model, {})))
        except ParameterError:
            continue  # reported by the fault-set check with its context
        try:  # the simulator's own range check, without allocating the step grid
            n_steps = models_simulate.check_grid(params, float(value))[2]
        except ParameterError as exc:
            problems.append(str(exc))
            break
        if n_steps > MAX_STEPS:
            problems.append(f"t_end: {float(value):g} s at DT={params.DT:g} s ({model.upper()}) "
                            f"is {n_steps:.3g} integration steps per run; at most "
                            f"{MAX_STEPS:.3g} (about {16 * MAX_STEPS / 1e9:.1f} GB); shorten "
                            "t_end or raise DT")
            break
    return float(value)


def _signals(value: Any, problems: list[str]) -> list[str]:
    if not isinstance(value, list) or not value:
        problems.append(f"signals: must be a non-empty list from: {', '.join(OUTPUTS)}")
        return list(OUTPUTS)
    for s in value:
        if s not in OUTPUTS:
            problems.append(f"signals: unknown signal {s!r}; allowed: {', '.join(OUTPUTS)}")
    for s in REQUIRED_SIGNALS:
        if s not in value:
            problems.append(f"signals: {s!r} is required (metrics and plots use "
                            f"{', '.join(REQUIRED_SIGNALS)})")
    return [s for s in OUTPUTS if s in value]  # canonical order


def _fixed_params(value: Any, models: list[str], problems: list[str]) -> dict[str, dict]:
    fixed: dict[str, dict] = {"all": {}, **{m: {} for m in MODELS}}
    if not isinstance(value, Mapping):
        problems.append("params: must be a table of NAME = value")
        return fixed
    for key, v in value.items():
        if key in MODELS:
            if not isinstance(v, Mapping):
                problems.append(f"params.{key}: must be a table of NAME = value")
                continue
            if key not in models:
                problems.append(f"params.{key}: the campaign has no {key.upper()} runs")
                continue
            for name, x in v.items():
                _check(f"params.{key}", name, x, [key], problems, fixed[key])
        else:
            _check("params", key, v, models, problems, fixed["all"])
    return fixed


def _check(where: str, name: str, value: Any, models: list[str], problems: list[str],
           into: dict) -> None:
    try:
        for m in models or [None]:
            into[name] = check_value(name, value, m)
    except ParameterError as exc:
        problems.append(f"{where}: {exc}")


def _fault_set_bound(value: Any) -> int:
    """Most fault sets ``value`` (the ``[faults]`` table) can expand to, from its counts alone
    (nothing is built: a 10^7-point grid is refused in microseconds)."""
    import math

    if not isinstance(value, Mapping):
        return 0

    def sizes(axes: Any) -> list[int]:
        if not isinstance(axes, Mapping):
            return []
        return [len(v) if isinstance(v, list) else 1 for v in axes.values()]

    grid = math.prod(sizes(value["grid"])) if sizes(value.get("grid")) else 0
    points = value.get("points", [])
    return (1 + grid + sum(sizes(value.get("single"))) +
            (len(points) if isinstance(points, list) else 0))


def _fault_sets(value: Any, models: list[str], problems: list[str],
                limit: int | None = None) -> list[tuple[str, dict[str, float]]] | None:
    """The fault sets of ``[faults]``; None (nothing built) when they could exceed ``limit``."""
    if not isinstance(value, Mapping):
        problems.append("faults: must be a table with keys " + ", ".join(FAULT_KEYS))
        return []
    if limit is not None and _fault_set_bound(value) > limit:
        return None
    for key in value:
        if key not in FAULT_KEYS:
            problems.append(f"faults.{key}: unknown key{_did_you_mean(key, FAULT_KEYS)}; "
                            f"allowed: {', '.join(FAULT_KEYS)}")
    sets: list[dict[str, float]] = []
    labels: list[str] = []
    known: set[tuple] = set()  # the sets seen, as sorted items: de-duplication in linear time

    def add(faults: dict[str, float], label: str | None = None) -> None:
        key = tuple(sorted(faults.items()))
        if key not in known:
            known.add(key)
            sets.append(faults)
            labels.append(label or _describe_faults(faults))

    nominal = value.get("nominal", not any(k in value for k in ("grid", "single", "points")))
    if not isinstance(nominal, bool):
        problems.append(f"faults.nominal: must be true or false, got {nominal!r}")
    elif nominal:
        add({}, "nominal")
    for mode in ("grid", "single"):
        if mode not in value:
            continue
        axes = _fault_axes(f"faults.{mode}", value[mode], models, problems)
        if axes is None:
            continue
        if mode == "grid":
            names = list(axes)
            for combo in itertools.product(*(axes[n] for n in names)):
                add(dict(zip(names, combo)))
        else:
            for n, values in axes.items():
                for x in values:
                    add({n: x})
    points = value.get("points", [])
    if not isinstance(points, list):
        problems.append("faults.points: must be a list of tables, e.g. "
                        "[{name = \"worn\", BKL = 1e-3}]")
        points = []
    named: dict[str, int] = {}
    for i, point in enumerate(points):
        if not isinstance(point, Mapping):
            problems.append(f"faults.points[{i}]: must be a table of NAME = value")
            continue
        label = point.get("name")
        if label is not None and not isinstance(label, str):
            problems.append(f"faults.points[{i}].name: must be a string")
            label = None
        if label is not None:
            if label in named:  # one label would name two fault sets in tables and plots
                problems.append(f"faults.points[{i}].name: {label!r} is also the name of "
                                f"faults.points[{named[label]}]; point names must be unique")
            named.setdefault(label, i)
        faults: dict[str, float] = {}
        for n, x in point.items():
            if n != "name":
                _check(f"faults.points[{i}]", n, x, models, problems, faults)
        add(faults, label)
    if not sets and not problems:
        problems.append("faults: no fault set (set nominal = true, or give grid, single or "
                        "points)")
    return list(zip(labels, sets))


def _fault_axes(where: str, value: Any, models: list[str],
                problems: list[str]) -> dict[str, list[float]] | None:
    if not isinstance(value, Mapping) or not value:
        problems.append(f"{where}: must be a non-empty table NAME = [values], e.g. "
                        "{BKL = [1e-4, 5e-4]}")
        return None
    axes: dict[str, list[float]] = {}
    ok = True
    for n, values in value.items():
        if not isinstance(values, list):
            values = [values]
        if not values:
            problems.append(f"{where}.{n}: empty list; give at least one value")
            ok = False
            continue
        checked: list[float] = []
        seen: set[float] = set()
        for x in values:
            holder: dict[str, float] = {}
            _check(where, n, x, models, problems, holder)
            if n not in holder:
                ok = False
            elif holder[n] in seen:
                problems.append(f"{where}.{n}: value {holder[n]:g} listed twice")
                ok = False
            else:
                seen.add(holder[n])
                checked.append(holder[n])
        axes[n] = checked
    return axes if ok else None


def _describe_faults(faults: Mapping[str, float]) -> str:
    return ",".join(f"{k}={v:g}" for k, v in faults.items()) or "nominal"


__all__ = ["KEYS", "REQUIRED_SIGNALS", "MAX_STEPS", "FAULT_KEYS", "expand"]
