"""Shared fixtures of the test suite.

- ``eha``: the real command line in a subprocess (``helpers.run_eha``).
- the residual loop's null cache, in a temporary folder for the session (autouse); each null
  is calibrated once even when both xdist workers need it at once (a lock per cache key).
- ``slow``: marker of the end-to-end tests that take more than a second or two
  (``pytest -m "not slow"`` skips them; CI runs everything; markers are strict).

Under pytest-xdist (``-n 2``) the tests of each module in :data:`ONE_WORKER` run on one worker,
so that its module fixtures (results folders that commands wrote, calibrations) are built once,
not once per worker that gets one of its tests (:func:`pytest_xdist_make_scheduler`); the
``slow`` tests are sent first (:func:`pytest_collection_modifyitems`).

Plain helper functions (``run_eha``, ``invoke_eha``, ``error_line``, ``write_campaign``,
``close``, ``files_under``) are in tests/helpers.py: tests import them from there, never
from this file (pytest imports conftest itself).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import KERNELS_READY, run_eha, wait_for_kernels

# Rich sizes tables to the terminal: a wide one in every process of the suite (pytest-xdist's
# workers have none), so that no check of printed text depends on where the tests run.
os.environ["COLUMNS"] = "200"

#: Under pytest-xdist the workers already fill the cores: each runs the parallel model kernels
#: on one numba thread (and ``run_eha``'s commands too, helpers.py), as a campaign's pool
#: workers do. Two threads per worker on two cores cost up to twice the CPU for the same work
#: (measured: the quick explain_settle and explain_replicates tests, 45 s of CPU against 25 s).
#: The pool keeps its size (``numba.config.NUMBA_NUM_THREADS``), so a test can still run the
#: kernels on every thread (tests/test_models.py); a serial run keeps numba's default.
if os.environ.get("PYTEST_XDIST_WORKER"):
    import numba

    numba.set_num_threads(1)


def _build_each_cli_once() -> None:
    """typer's test runner turns the app into its click command on every ``invoke`` (about
    30 ms for eha's command tree, as a real command line pays once per process): the suite
    invokes the CLI in-process some thousand times, so each app's command is built once per
    process and built again only when a command or group was added to the app since."""
    import typer.testing

    real, built = typer.testing._get_command, {}

    def get_command(app):
        shape = (len(app.registered_commands), len(app.registered_groups))
        hit = built.get(id(app))
        if hit is None or hit[0] is not app or hit[1] != shape:
            hit = built[id(app)] = (app, shape, real(app))
        return hit[2]

    typer.testing._get_command = get_command


_build_each_cli_once()


#: Test modules whose module-scoped fixtures cost seconds: under pytest-xdist each runs on one
#: worker. xdist's default distribution sent their tests to both workers, and each worker built
#: the fixtures again (``--dist loadgroup`` would do this with marks, but it stopped grouping
#: with pytest 9.2: pytest-xdist issue 1386).
ONE_WORKER = ("test_results_matrix.py", "test_reports_html.py", "test_health_change.py",
              "test_prognostics_change.py", "test_exit_codes.py", "test_identification_cases.py",
              "test_reliability_processes.py", "test_explain_settle.py",
              "test_explain_replicates.py")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """xdist's scheduler for ``-n N`` (its default ``load``; an explicit ``--dist`` is kept):
    one work unit per test, as ``load``, except the tests of a module in :data:`ONE_WORKER`,
    one unit for the module (units with the most tests are sent first)."""
    if config.getoption("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class OneWorkerModules(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module.rsplit("/", 1)[-1] in ONE_WORKER else nodeid

    return OneWorkerModules(config, log)


def pytest_collection_modifyitems(config, items):
    """Under pytest-xdist, each worker lists the ``slow`` tests first (in their order; the
    rest after them, in theirs): the controller sends single tests in the workers' order, so
    the long end-to-end tests start while the other worker runs short ones, and the run ends
    on short tests, not on one worker finishing a long test alone while the other idles. (Both
    workers sort alike, so their collections stay identical, as xdist requires.) A serial run
    keeps the file order, so that a module's fixtures are built once."""
    if hasattr(config, "workerinput"):
        cold = bool(os.environ.get(COLD_KERNELS))
        items.sort(key=lambda item: (cold and not _kernel_free(item),
                                     item.get_closest_marker("slow") is None))


#: Test modules whose quick tests run no model kernel, in their process or in one they start
#: (found with a probe on the kernels' entry points, less the modules that start commands,
#: pools or kernels in scripts): they do not wait for the kernels' warm-up
#: (:func:`_kernels_compiled`; their ``slow`` tests do), and from an empty numba cache they are
#: sent first, while the kernels compile.
NO_KERNELS = ("test_code_size.py", "test_docs.py", "test_estimate.py", "test_explain_decide.py",
              "test_explain_leads.py", "test_explain_report.py",
              "test_explain_unexplained.py", "test_explain_verdict.py", "test_keywords.py",
              "test_layering.py", "test_null_match.py", "test_progress_phases.py")
#: Set by the controller for its workers when numba's cache lacks the LF batch kernel.
COLD_KERNELS = "EHA_TEST_COLD_KERNELS"


def _kernels_cached() -> bool:
    """Whether numba's cache holds the LF batch kernel (its index file; a stale one counts:
    numba then compiles as before)."""
    cache = os.environ.get("NUMBA_CACHE_DIR")
    if cache:
        return any(Path(cache).rglob("lf._run_groups-*.nbi"))
    import eha.models.lf as lf

    return any((Path(lf.__file__).parent / "__pycache__").glob("lf._run_groups-*.nbi"))


#: What compiles the model kernels into numba's cache (``cache=True``), one process each: the
#: HF kernels with the chirp phase and the metrics (about 2 s of CPU from an empty cache), the
#: LF kernel (about 6 s), the LF batch kernel (about 11 s: four specializations).
WARM_UP = {
    "hf": "from eha.models.simulate import simulate, simulate_hf_batch\n"
          "from eha.models.run_metrics import trace_metrics\n"
          "trace_metrics(simulate('hf', 'chirp_1cm', t_end=0.01))\n"
          "simulate_hf_batch([{}, {}], 'chirp_1cm', 0.01, [0, 1])",
    "lf": "from eha.models.simulate import simulate\nsimulate('lf', 'chirp_1cm', t_end=0.01)",
    "lf_batch": "from eha.models.simulate import simulate_lf_rows\n"
                "simulate_lf_rows([{}, {}], 'chirp_1cm', t_end=0.01)",
}
_WARMING: dict[str, subprocess.Popen] = {}


def pytest_sessionstart(session):
    """Under pytest-xdist the kernels are compiled into numba's cache once, side by side
    (:data:`WARM_UP`), while the workers start, collect and run the first tests. From a fresh
    clone (CI) both workers, and the command lines the first tests run, otherwise compiled the
    same kernels at once, each for itself (about 20 s of CPU each); with a cache they load it
    in a second. Each warm-up leaves a done file in the folder named by
    ``helpers.KERNELS_READY`` (the workers inherit it), also when it failed (the tests then
    show the failure). From an empty cache the modules of :data:`NO_KERNELS` go first."""
    import tempfile
    import textwrap

    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    folder = Path(tempfile.mkdtemp(prefix="eha-kernels-"))
    os.environ[KERNELS_READY] = str(folder)
    if not _kernels_cached():
        # the workers send the tests without kernels first (pytest_collection_modifyitems) and
        # the controller keeps that order (xdist sorts its units by size otherwise)
        os.environ[COLD_KERNELS] = "1"
        config.option.loadscopereorder = False
    for name, code in WARM_UP.items():
        wrapped = (f"try:\n{textwrap.indent(code, '    ')}\nfinally:\n"
                   f"    open({str(folder / name)!r}, 'w').close()\n")
        _WARMING[name] = subprocess.Popen([sys.executable, "-c", wrapped],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        (folder / f"{name}.pid").write_text(str(_WARMING[name].pid))


def pytest_sessionfinish(session):
    if not _WARMING:          # a worker, or a run that started no warm-up
        return
    for proc in _WARMING.values():   # a run that ended before the kernels were compiled
        proc.wait(timeout=600)
    _WARMING.clear()
    folder = os.environ.pop(KERNELS_READY, None)
    os.environ.pop(COLD_KERNELS, None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(autouse=True)
def _kernels_compiled(request):
    """Under pytest-xdist a test of a module not in :data:`NO_KERNELS` starts once the
    controller's warm-ups have compiled every kernel into numba's cache (at once when they
    have), so that neither it nor a process it starts compiles them a second time."""
    if not _kernel_free(request.node):
        wait_for_kernels()


def _kernel_free(item) -> bool:
    """A quick test of a module of :data:`NO_KERNELS`."""
    return item.path.name in NO_KERNELS and item.get_closest_marker("slow") is None


@pytest.fixture(autouse=True, scope="session")
def _explain_null_cache(tmp_path_factory):
    """The residual loop's healthy nulls (eha.explain.null) are cached for the session in a
    temporary folder: never in the user's cache, shared by the tests of one command. Under
    pytest-xdist (CI's ``-n 2``) the workers share one folder (the run's base folder, above
    each worker's own): a null one worker calibrated is read by the other (the cache file is
    written atomically, so two calibrating alike both succeed)."""
    old = os.environ.get("EHA_CACHE_DIR")
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = tmp_path_factory.getbasetemp().parent / "eha-cache"
        shared.mkdir(exist_ok=True)
        os.environ["EHA_CACHE_DIR"] = str(shared)
    else:
        os.environ["EHA_CACHE_DIR"] = str(tmp_path_factory.mktemp("eha-cache"))
    _seed_nulls()
    with _one_calibration_per_null():
        yield
    if old is None:
        os.environ.pop("EHA_CACHE_DIR", None)
    else:
        os.environ["EHA_CACHE_DIR"] = old


#: The healthy nulls of the suite's end-to-end records, as the suite calibrated them (one file
#: per cache key; tests/data/explain-nulls/README.md says how to refresh them).
SEEDED_NULLS = Path(__file__).parent / "data" / "explain-nulls"


def _seed_nulls() -> None:
    """The session's null cache starts with :data:`SEEDED_NULLS`, as a user's cache starts
    with the nulls eha ships for its presets: an end-to-end test reads its record's null
    instead of calibrating it (about 20 s of two processes each, 12 in the full suite). A file
    is keyed by its record, fit, effects and settings, and read only when its format and model
    version are the current ones (:func:`eha.explain.null.load_null`): a changed procedure
    (a new ``NULL_FORMAT``) or model calibrates afresh. The calibration itself is tested with
    an empty cache (tests/test_explain_null.py)."""
    from eha.explain.null import cache_dir

    folder = cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    for path in SEEDED_NULLS.glob("*.json"):
        target = folder / path.name
        if not target.exists():       # both xdist workers seed: each file lands whole once
            tmp = folder / f".{path.name}.{os.getpid()}.tmp"
            shutil.copyfile(path, tmp)
            os.replace(tmp, target)


@contextlib.contextmanager
def _one_calibration_per_null():
    """While it is open, a null is calibrated once for the session even when both workers
    need it at once: :func:`eha.explain.null.simulated_null` (as the loop calls it in this
    process) holds a lock on its cache key (``KEY.lock`` beside the cache file) while it
    reads or calibrates it, so the second worker waits for the first's file and reads it.
    (Tests that share a null often run side by side: the slow ones are sent in file order, so
    the four injected-effect tests on one record started two calibrations of their null, at
    about 40 s of CPU each.)"""
    import fcntl
    import inspect

    import eha.explain.api as api
    import eha.explain.null as null

    real = null.simulated_null
    signature = inspect.signature(real)

    def simulated_null(*args, **kwargs):
        a = signature.bind(*args, **kwargs)
        a.apply_defaults()
        a = a.arguments
        if not a["use_cache"]:
            return real(*args, **kwargs)
        key = null.null_key(a["data"], a["fit"], null.covered_effects(a["effects"]),
                            a["settings"], a["actuators"], a["seed"], a["base"], a["fixed"],
                            a["fdi_options"])
        folder = null.cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / f"{key}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)     # released when the file closes
            return real(*args, **kwargs)

    null.simulated_null = api.simulated_null = simulated_null
    try:
        yield
    finally:
        null.simulated_null, api.simulated_null = real, real


@pytest.fixture
def eha():
    """The command line in a subprocess: ``eha("simulate", "--out", path)``."""
    return run_eha
