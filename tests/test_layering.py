"""Layering: eha.campaigns is the infrastructure below the domain (it imports no domain module,
only the error hierarchy and the trace columns; job kinds reach the runner through the
registry, one module at a time, and every layer may use it); the domain's packages import one
way, models -> simulations, identification -> explain -> health, prognostics -> design ->
reports -> cli (the import-graph tests at the end)."""

import ast
import functools
import json
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "eha" / "campaigns"
INFRA = tuple(sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"))
#: What the infrastructure may import besides itself: the error hierarchy, the trace's
#: columns (constants and a numpy dataclass; nothing of the domain) and the writer of whole
#: output files (eha.outputs: imports only the error hierarchy).
BELOW = ("eha.errors", "eha.trace", "eha.outputs")
#: Job kinds and campaign sections the domain declares (what the runner once imported itself).
KINDS = {"simulate", "fdi", "health_assessment", "health_change", "change_record",
         "change_calibration", "health", "fleet_record"}
SECTIONS = {"fdi", "health"}


def _fresh(code: str) -> dict:
    """Run ``code`` in a new interpreter; it prints one JSON value."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_importing_the_infrastructure_loads_no_domain_module_and_no_numba():
    loaded = _fresh("import json, sys\n"
                    + "".join(f"import eha.campaigns.{m}\n" for m in INFRA)
                    + "print(json.dumps(sorted(sys.modules)))")
    eha = [m for m in loaded if m == "eha" or m.startswith("eha.")]
    # eha.trace: the output columns of a trace (constants, a dataclass);
    # eha.errors: the error hierarchy every layer derives its errors from (imports nothing)
    foreign = [m for m in eha if m not in ("eha", "eha.campaigns", *BELOW)
               and not m.startswith("eha.campaigns.")]
    assert foreign == [], foreign
    assert "numba" not in loaded and "eha.models.simulate" not in loaded


@pytest.mark.parametrize("module", INFRA)
def test_infrastructure_modules_name_no_domain_module(module):
    """No import of a module outside eha.campaigns, not even inside a function, but the
    trace columns (eha.trace) and the error hierarchy (eha.errors): the runner and its workers
    reach a job kind's module through the registry only."""
    tree = ast.parse((PACKAGE / f"{module}.py").read_text(encoding="utf-8"))
    named = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
    named += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    domain = [m for m in named if m.split(".")[0] == "eha"
              and not (m in ("eha.campaigns", *BELOW) or m.startswith("eha.campaigns."))]
    assert domain == [], f"eha/campaigns/{module}.py imports {domain}"


def test_job_kinds_and_sections_register_through_the_entry_points():
    from eha.campaigns import jobs

    assert KINDS <= set(jobs._entry_points(jobs.KIND_GROUP))
    assert SECTIONS <= set(jobs.section_names())
    for kind in KINDS:
        assert jobs.job_kind(kind).name == kind
    for name in SECTIONS:
        assert callable(jobs.section(name))
    assert jobs.job_kind("simulate").run_chunk is not None
    assert callable(jobs.job_kind("simulate").warm_up)
    # the [health] section makes health_assessment jobs: said by that kind's declaration
    assert jobs.job_kind("health_assessment").section == "health"
    assert jobs.job_kind("health").section is None


def test_job_kinds_take_at_most_two_entry_point_groups():
    """One entry point per kind (its JobKind), plus the tables of writers that are not kinds."""
    import tomllib

    table = tomllib.loads((PACKAGE.parents[1] / "pyproject.toml").read_text(encoding="utf-8"))
    groups = set(table["project"]["entry-points"])
    assert groups == {"eha.job_kinds", "eha.tables"}
    kinds = table["project"]["entry-points"]["eha.job_kinds"]
    assert all(":" in v for v in kinds.values())  # each names a JobKind, not a module


def test_a_worker_imports_only_the_module_of_the_kind_it_runs():
    loaded = _fresh("import json, sys\n"
                    "from eha.campaigns.jobs import job_kind\n"
                    "job_kind('fleet_record')\n"
                    "print(json.dumps(sorted(sys.modules)))")
    assert "eha.prognostics.fleet" in loaded
    assert not {"eha.identification.cases", "eha.health.detection", "eha.prognostics.jobs",
                "eha.simulations.batch"} & set(loaded)


def test_an_unregistered_kind_fails_its_job_with_one_line(tmp_path):
    from eha.campaigns.jobs import execute_job

    res = execute_job({"kind": "no-such-kind", "spec": {}, "run_key": "0" * 16,
                       "campaign": "x", "trace_file": str(tmp_path / "x.parquet"),
                       "trace_path": "traces/x/x.parquet"})
    assert res["status"] == "failed" and res["rows"] == {}
    assert res["error"].startswith("UnknownJobKind: 'no-such-kind' is not registered")


# --------------------------------------------------------------------------------------------
# the import graph of the whole package: data flows one way (docs/decisions.md)

ROOT = PACKAGE.parent
#: Layer of each package (and of the flat modules): a module imports only from its own layer
#: or below, at module level or inside a function. health and prognostics share a layer and
#: do not import each other.
LAYERS = {"errors": -3, "trace": -2, "outputs": -2, "campaigns": -1, "models": 0,
          "figures": 0, "simulations": 1, "identification": 1, "explain": 2, "health": 3,
          "prognostics": 3, "design": 4, "reports": 5, "cli": 6, "docgen": 7, "__main__": 7}


def _eha_imports(path: Path) -> set[str]:
    """The eha modules ``path`` imports (anywhere in it)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out |= {f"{node.module}.{a.name}" for a in node.names} | {node.module}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return {m for m in out if m.split(".")[0] == "eha"}


def _part(module: str) -> str | None:
    """The package (or flat module) right under eha of a dotted name (None for eha itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


@functools.lru_cache(maxsize=1)
def _graph() -> dict[str, set[str]]:
    """``eha/<part>/...py`` -> the parts under eha it imports (parsed once per session: the
    tests only read it)."""
    graph = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        graph["/".join(rel.parts)] = {p for p in map(_part, _eha_imports(path)) if p}
    return graph


def test_every_package_and_flat_module_has_a_layer():
    parts = {p.name if p.is_dir() else p.stem for p in ROOT.iterdir()
             if (p.is_dir() and (p / "__init__.py").exists()) or p.suffix == ".py"}
    assert parts - {"__init__"} == set(LAYERS), sorted(parts)


def test_no_module_imports_a_layer_above_its_own():
    """campaigns -> models -> identification -> explain -> health, prognostics -> reports ->
    cli: no arrow back (health <-> prognostics neither), not even inside a function; no
    exemption: every layer may use the infrastructure because it is below them all."""
    backward = []
    for module, parts in _graph().items():
        own = module.split("/")[1]
        if own == "__init__":
            continue
        backward += [f"{module} -> eha.{part}" for part in sorted(parts - {own})
                     if LAYERS[part] >= LAYERS[own]]
    assert backward == [], backward


def test_the_infrastructure_imports_nothing_of_the_domain():
    """eha.campaigns: the error hierarchy, the trace columns and the writer of whole output
    files (eha.outputs, below it) only; a job kind's part of a campaign file, its worker and
    its tables are its own module's (e.g. eha.simulations)."""
    found = {f"{module} -> eha.{part}" for module, parts in _graph().items()
             if module.startswith("eha/campaigns/")
             for part in parts - {"campaigns", "errors", "trace", "outputs"}}
    assert found == set(), sorted(found)


def test_no_dynamic_import_of_eha_modules():
    """Modules are imported by name (plain imports, inside a function where start-up time
    needs it), never by a computed string: no ``importlib.import_module`` and no
    ``__import__`` in eha/. (Job kinds are found through their entry points,
    :mod:`eha.campaigns.jobs`: the packaging metadata's plug-in mechanism.)"""
    found = []
    for path in sorted(ROOT.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        for needle in ("import_module(", "__import__("):
            if needle in text:
                found.append(f"{path.relative_to(ROOT.parent)}: {needle}")
    assert found == [], found


def _module_graph() -> dict[str, set[str]]:
    """``eha.x.y`` -> the eha modules it imports, at module level or inside a function."""
    mods = {}
    for path in sorted(ROOT.rglob("*.py")):
        name = ".".join(path.relative_to(ROOT.parent).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = path
    graph = {}
    for name, path in mods.items():
        found = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                # `from eha.x import y`: the module eha.x.y if there is one, else eha.x
                refs = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in mods
                        else node.module for a in node.names]
            elif isinstance(node, ast.Import):
                refs = [a.name for a in node.names]
            else:
                continue
            found |= {r for r in refs if r in mods and r != name}
        graph[name] = found
    return graph


def test_no_import_circle_between_files():
    """Issue 40: no two files import each other, directly or through others, not even inside
    a function (a circle hides which one is below)."""
    graph = _module_graph()
    circles, state = [], {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                circles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    assert circles == [], circles
