"""Campaign files (TOML) → validated, expanded jobs with run keys.

A campaign is a named batch of simulations: models × commands × fault sets × seeds, all run
for ``t_end`` seconds. Everything is validated before anything runs; every problem found is
reported on its own line (:class:`CampaignError`), through the same validators the models use
(:func:`eha.models.params.resolve`, :func:`eha.models.params.check_value`,
:func:`eha.models.commands.make_command`; the ``simulate`` kind's keys:
:mod:`eha.simulations.expand`).

File format
-----------
::

    name = "thesis-matrix"              # [A-Za-z0-9_.-]+, also the trace folder
    description = "..."
    kind = "simulate"                    # default; other kinds: see "Other job kinds"
    models = ["hf", "lf"]
    commands = ["mixed", {name = "chirp_1cm", A0 = 5e-3}]   # presets or kinds, overrides
    seeds = [0]                          # HF dither seeds (default [0])
    t_end = 1.0                          # simulated seconds per run
    signals = ["t", "com", "xu", "p12"]  # stored trace columns (default all; t, com, xu needed)

    [params]                             # fixed overrides of every run (SI units)
    DT = 1e-5
    [params.hf]                          # ... of the HF runs only (also [params.lf])
    dither_ma = 0.0

    [faults]
    nominal = true                       # include the healthy case (default: only if no faults)
    grid = {BKL = [1e-4, 5e-4], FDJ = [400, 800]}   # Cartesian product (4 fault sets)
    single = {BKL = [1e-4, 1e-3]}        # one parameter at a time, others nominal (2 sets)
    points = [{name = "worn", BKL = 1e-3, FDJ = 3200}]   # named single points

The fault sets are the union of ``nominal``, ``grid``, ``single`` and ``points`` (duplicates
kept once, in that order).

Run keys
--------
Each job's ``run_key`` is the first 16 hex digits of the SHA-256 of its *resolved* spec: the
campaign name, job kind, model, the full parameter set after :func:`eha.models.params.resolve` (so a
change of a nominal value changes the key), the resolved command, seed, ``t_end``, stored
signals, and the version of the code that computes it (:attr:`JobDraft.version`: a simulation's
is :data:`eha.models.simulate.MODEL_VERSION`). A campaign's ``spec_hash`` is the hash of
its sorted run keys: a campaign file edited under the same name (or a model-version bump) gives
a different ``spec_hash``, which the runner detects.

Job kinds
---------
A job has a ``kind``. Each kind's part of a file is declared with the kind
(:class:`eha.campaigns.jobs.JobKind`, found through the ``eha.job_kinds`` entry points): the
``simulate`` kind's is the top-level keys above (its ``keys``, expanded by
:func:`eha.simulations.expand.expand`); another kind (e.g. fault identification) plugs in
through a top-level TOML table (its ``section``, ``[fdi]``) whose expander is its ``drafts``:
``drafts(section, campaign_table, problems) -> list[JobDraft]`` validates its section
(appending one line per problem to ``problems``) and returns the job specs. A file with
``kind = "fdi"`` (and no ``models``/``commands``) has only the jobs of its ``[fdi]`` section; a
simulation file may also carry such a section (both kinds in one campaign). The same
declaration holds the kind's worker function and its result tables.
"""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence
from eha.errors import InputError
from eha.campaigns.drafts import MAX_JOBS, JobDraft, _did_you_mean, _dumps, _hash, _hash_text

#: Top-level keys of every campaign file; job kinds add their own keys and sections
#: (:attr:`eha.campaigns.jobs.JobKind.keys`, :attr:`eha.campaigns.jobs.JobKind.section`).
TOP_KEYS = ("name", "description", "kind")
#: The kind of a file that names none: a simulation campaign (:mod:`eha.simulations.expand`).
DEFAULT_KIND = "simulate"
# The name is also a folder under traces/: it starts with a letter or digit, so "." and ".."
# (which would put traces outside that folder) and hidden names are refused, as is any path
# separator. The one rule of every campaign name (files, fleets, programs): name_problem.
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,79}$")
#: The rule, as the messages state it.
NAME_RULE = ("1-80 characters from letters, digits, '_', '.', '-', starting with a letter or "
             "digit")


def name_problem(name: Any, field: str = "name") -> str | None:
    """Why ``name`` cannot name a campaign (it becomes the folder ``traces/<name>/``), as one
    line starting with ``field``; None when it can."""
    if isinstance(name, str) and _NAME_RE.match(name):
        return None
    return f"{field}: {name!r} is not a valid campaign name; required, {NAME_RULE}"


class CampaignError(InputError):
    """A campaign file that cannot run; ``problems`` holds one line per problem."""

    def __init__(self, problems: list[str]):
        super().__init__(problems, message="\n".join(problems))


@dataclass(frozen=True)
class Job:
    """One unit of work of a campaign, with its run key.

    Attributes
    ----------
    campaign : str
    kind : str
    run_key : str
        16 hex digits; unique across campaigns (the campaign name is hashed too).
    spec : dict
        What the worker executes (JSON-serialisable).
    columns : dict
        Descriptive columns of the ``runs`` table (model, command, faults, seed, t_end, label,
        case_key).
    """

    campaign: str
    kind: str
    run_key: str
    spec: dict
    columns: dict

    @property
    def label(self) -> str:
        return self.columns.get("label", self.run_key)


@dataclass(frozen=True)
class Campaign:
    """A validated campaign: its definition and its expanded jobs."""

    name: str
    description: str
    source: str
    definition: dict
    jobs: tuple[Job, ...]
    #: Version of the code that computes its jobs (:attr:`JobDraft.version`), recorded.
    model_version: str | None = None

    @property
    def spec_hash(self) -> str:
        """Hash of the sorted run keys: changes whenever any run of the campaign changes."""
        return _hash(sorted(j.run_key for j in self.jobs))

    def count_by(self, column: str) -> dict[Any, int]:
        out: dict[Any, int] = {}
        for j in self.jobs:
            value = j.columns.get(column, j.kind if column == "kind" else None)
            out[value] = out.get(value, 0) + 1
        return out


def _run_key(name: str, draft: "JobDraft", version: str, identity_text: str | None) -> str:
    """``_hash({"campaign", "kind", "spec", "identity", "model_version"})`` with the identity's
    JSON text given when it is shared by many jobs: the same text (keys sorted), so the same
    key, without serialising the ~60 resolved parameters once per job (that took 63 µs a job,
    most of the validation of a 10^5-job campaign)."""
    if identity_text is None:
        identity_text = _dumps(draft.identity)
    return _hash_text('{"campaign":' + _dumps(name) + ',"identity":' + identity_text +
                      ',"kind":' + _dumps(draft.kind) + ',"model_version":' + _dumps(version) +
                      ',"spec":' + _dumps(draft.spec) + "}")


# --------------------------------------------------------------------------- loading
def campaigns_dir() -> Path:
    """The campaign files shipped in the package (``eha/campaigns/data/``; ``campaigns/`` at
    the repository root links to them), so that a non-editable install runs ``eha reproduce``
    from any folder."""
    return Path(__file__).resolve().parent / "data"


def load_campaign(path: str | Path) -> Campaign:
    """Read, validate and expand a campaign file.

    Raises
    ------
    CampaignError
        Unreadable file, bad TOML, or any validation problem (all of them, one per line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CampaignError([f"{path}: cannot read the campaign file ({exc.strerror})"]) from None
    except UnicodeDecodeError as exc:
        raise CampaignError([f"{path}: not UTF-8 text (byte {exc.start}); a campaign file is "
                             "TOML text"]) from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CampaignError([f"{path}: not valid TOML ({exc})"]) from None
    return build_campaign(table, source=str(path))


def build_campaign(table: Mapping[str, Any], source: str = "<dict>") -> Campaign:
    """Validate and expand a campaign given as a mapping (the parsed TOML).

    The definition stored is a copy of ``table`` in which a kind's expansion may name a file it
    reads by its absolute path and content hash (a command file), so that the campaign can be
    rebuilt from the database in any folder (``eha campaign verify --repair``)."""
    import copy

    from eha.campaigns import jobs as registry

    table = copy.deepcopy(dict(table))

    owners = registry.file_keys()
    sections = registry.section_names()
    problems: list[str] = []
    allowed = TOP_KEYS + tuple(k for o in owners.values() for k in o.keys) + sections
    for key in table:
        if key not in allowed:
            problems.append(f"{key}: unknown key{_did_you_mean(key, allowed)}; allowed: "
                            f"{', '.join(allowed)}")
    name = table.get("name")
    if name is None:
        problems.append(f"name: missing; required, {NAME_RULE}")
        name = "?"
    elif name_problem(name) is not None:
        problems.append(name_problem(name))
        name = "?"
    description = table.get("description", "")
    if not isinstance(description, str):
        problems.append("description: must be a string")
        description = ""

    kind = table.get("kind", DEFAULT_KIND)
    if kind not in owners and kind not in sections:
        problems.append(f"kind: {kind!r} is not a campaign kind here; allowed: "
                        f"{', '.join([*owners, *sections])}")
    drafts: list[JobDraft] = []
    others = [k for k in sections if k in table]
    for owner in owners.values():
        drafts += owner.drafts(table, name, problems, kind == owner.name)
    for key in others:
        section = table[key]
        if not isinstance(section, Mapping):
            problems.append(f"{key}: must be a table ([{key}])")
            continue
        drafts += registry.section(key)(section, table, problems)

    if not problems and not drafts:
        problems.append("campaign: expands to no jobs")
    if len(drafts) > MAX_JOBS:
        problems.append(f"campaign: expands to {len(drafts)} jobs; the limit is {MAX_JOBS} "
                        "(split it into several campaigns)")
    if problems:
        raise CampaignError(_unique(problems))
    return make_campaign(name, drafts, description, source, dict(table))


def make_campaign(name: str, drafts: Sequence[JobDraft], description: str = "",
                  source: str = "<code>", definition: Mapping[str, Any] | None = None
                  ) -> Campaign:
    """A campaign of the jobs ``drafts`` (what a kind's expander returns, or what a program
    builds: a fleet's records): the run keys, the de-duplication and the recorded version of
    a campaign file's jobs (:func:`build_campaign`, which ends here).

    Raises
    ------
    CampaignError
        ``name`` breaks the campaign-name rule (:func:`name_problem`): it becomes a folder.
    """
    problem = name_problem(name)
    if problem is not None:
        raise CampaignError([problem])
    jobs: list[Job] = []
    seen: dict[str, Job] = {}
    shared: dict[int, str] = {}
    for d in drafts:
        ident = id(d.identity)
        if ident not in shared:  # drafts of one model, fault set and command share it
            shared[ident] = _dumps(d.identity)
        key = _run_key(name, d, d.version, shared[ident])
        job = Job(name, d.kind, key, d.spec, dict(d.columns))
        if key in seen:
            continue  # the same run reached twice (e.g. a point equal to a grid point)
        seen[key] = job
        jobs.append(job)
    versions = sorted({d.version for d in drafts if d.version})
    return Campaign(name, description, source, dict(definition or {}), tuple(jobs),
                    ",".join(versions) or None)


def _unique(items: list[str]) -> list[str]:
    return list(dict.fromkeys(items))


# --------------------------------------------------------------------------- plan
def plan(campaign: Campaign, workers: int = 2,
         results: str | Path | None = None) -> dict[str, Any]:
    """Counts and an estimated wall time for running ``campaign`` on ``workers`` processes.

    The estimate uses measured per-run costs on this project's reference machine: a job kind's
    own estimate where it registers one (simulations: HF about 5 ms and LF about 3 ms per
    simulated second at DT = 1e-5 s, :data:`eha.simulations.batch.SIM_COST`, plus about 0.5 ms per run
    for metrics, its share of a chunk file and the commit), else the job's ``estimated_s`` column,
    and about 2 s to start the worker pool; it is a guide, not a promise. With ``results``, the
    runs its database already holds as done (``done``) are not run again and count for
    nothing in ``estimated_s`` (``estimated_all_s``: every job).
    """
    from eha.campaigns.jobs import find_job_kind

    done = _done_keys(results, {j.run_key for j in campaign.jobs})
    work = todo = 0.0
    estimate: dict[str, Callable | None] = {}  # kind -> its estimate, looked up once
    for j in campaign.jobs:
        if j.kind not in estimate:
            found = find_job_kind(j.kind)
            estimate[j.kind] = found.estimate_s if found is not None else None
        if estimate[j.kind] is not None:
            cost = estimate[j.kind](j.spec)
        else:
            cost = float(j.columns.get("estimated_s", 1.0))
        work += cost
        todo += 0.0 if j.run_key in done else cost
    workers = max(1, int(workers))
    return {"campaign": campaign.name, "jobs": len(campaign.jobs), "done": len(done),
            "by_kind": campaign.count_by("kind"), "by_model": campaign.count_by("model"),
            "by_command": campaign.count_by("command"),
            "fault_sets": len({json.dumps(j.columns.get("faults"), sort_keys=True)
                               for j in campaign.jobs}),
            "workers": workers,
            "estimated_s": 0.0 if len(done) == len(campaign.jobs) else 2.0 + todo / workers,
            "estimated_all_s": 2.0 + work / workers}


def _done_keys(results: str | Path | None, keys: set[str]) -> set[str]:
    """The run keys among ``keys`` that the database under ``results`` holds as done (none
    without a database)."""
    from eha.campaigns.schema import DB_NAME
    from eha.campaigns.store import connect

    if results is None or not (Path(results) / DB_NAME).exists():
        return set()
    con = connect(results, read_only=True)
    try:
        if not con.execute("SELECT count(*) FROM information_schema.tables WHERE table_name = "
                           "'runs'").fetchone()[0]:
            return set()
        done = {k for (k,) in con.execute("SELECT run_key FROM runs WHERE status = 'done'"
                                          ).fetchall()}
    finally:
        con.close()
    return done & keys


__all__ = ["Campaign", "CampaignError", "Job", "JobDraft", "load_campaign", "build_campaign",
           "make_campaign", "plan", "campaigns_dir", "MAX_JOBS"]
