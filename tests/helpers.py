"""Plain helper functions of the test suite, imported by the tests (``from helpers import
error_line, invoke_eha``); the fixtures are in conftest.py, which no test imports.

- ``run_eha``: run the real command line (``python -m eha ...``) in a subprocess; returns the
  completed process (text stdout/stderr). ``invoke_eha``: the same in this process (typer's
  runner), for the many checks of one message each.
- ``error_line(proc, code)``: the single ``error:`` line a failing command printed, after
  checking its exit status and that no traceback reached the user.
- ``write_campaign(tmp_path, text)``: a campaign file from TOML text.
- ``close(a, b, rel=..., abs=...)``: element-wise tolerance check of arrays or scalars with a
  message that shows the worst element (``numpy.testing.assert_allclose``).
- ``files_under(folder)``: every file under a folder (to check that nothing was written).
- ``SMALL_FLEET``: the TOML of a two-actuator fleet (prognostics and report tests).
- ``Inline``: an executor of :func:`eha.campaigns.runner.run_campaign` that runs every task in
  this process, for tests of what a campaign writes rather than of the worker pool (a spawned
  worker costs 2-3 s of imports and kernel loading).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from eha.campaigns.executors import Executor


#: Under pytest-xdist, the folder where each kernel warm-up of the controller leaves its done
#: file (conftest.py).
KERNELS_READY = "EHA_TEST_KERNELS_READY"


#: Set once every warm-up is done: later waits return at once.
_KERNELS_DONE = False


def wait_for_kernels(names=None, timeout: float = 600.0) -> None:
    """Wait until the controller's warm-ups ``names`` (all by default) have compiled their
    kernels into numba's cache; at once outside pytest-xdist or when they are done."""
    import time

    global _KERNELS_DONE
    folder = os.environ.get(KERNELS_READY)
    if _KERNELS_DONE or not folder or not os.path.isdir(folder):
        return
    waiting = list(names or ("hf", "lf", "lf_batch"))
    deadline = time.monotonic() + timeout
    while waiting and time.monotonic() < deadline:
        # done, or its process gone without a word (killed): the kernel compiles on first use
        waiting = [n for n in waiting if not (Path(folder) / n).exists()
                   and _alive(Path(folder) / f"{n}.pid")]
        if waiting:
            time.sleep(0.05)
    _KERNELS_DONE = not names and not waiting


def _alive(pid_file: Path) -> bool:
    """Whether the process whose PID the file holds runs (a zombie does not); True while the
    file is not written yet."""
    try:
        pid = int(pid_file.read_text())
    except (OSError, ValueError):
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except OSError:
        pass
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    return True


def run_eha(*args: str, cwd: str | Path | None = None, env: dict | None = None,
            timeout: float = 300, **kwargs) -> subprocess.CompletedProcess:
    """``python -m eha ARGS`` in a subprocess (the installed package of this interpreter),
    started once the suite's kernels are in numba's cache (:func:`wait_for_kernels`)."""
    wait_for_kernels()
    # under pytest-xdist one numba thread, as the worker running the test (conftest.py)
    threads = {"NUMBA_NUM_THREADS": "1"} if os.environ.get("PYTEST_XDIST_WORKER") else {}
    full_env = {**os.environ, "COLUMNS": "200", **threads, **(env or {})}
    return subprocess.run([sys.executable, "-m", "eha", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, env=full_env, timeout=timeout, **kwargs)


def invoke_eha(*args: str, cwd: str | Path | None = None) -> subprocess.CompletedProcess:
    """The command line in this process (typer's runner: no interpreter start-up, so a test of
    a message costs milliseconds); same result type as :func:`run_eha`."""
    from typer.testing import CliRunner

    from eha.cli import app

    old = Path.cwd()
    if cwd is not None:
        os.chdir(cwd)
    try:
        res = CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "200"})
    finally:
        os.chdir(old)
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        raise res.exception
    return subprocess.CompletedProcess(list(args), res.exit_code, res.stdout, res.stderr)


def error_line(proc: subprocess.CompletedProcess, code: int | None = None) -> str:
    """The one ``error:`` line of a failed command; asserts the exit status (non-zero, or
    ``code``) and that nothing else, in particular no traceback, was printed to stderr."""
    assert proc.returncode != 0, (proc.stdout, proc.stderr)
    if code is not None:
        assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr and "Traceback" not in proc.stdout, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    return lines[0]


def write_campaign(folder: Path, text: str, name: str = "campaign.toml") -> Path:
    """Write a campaign file (TOML text, dedented) into ``folder``; returns its path."""
    path = Path(folder) / name
    path.write_text(textwrap.dedent(text))
    return path


def small_campaign(folder: Path, t_end: float = 0.05) -> Path:
    """``folder/small.toml``: 6 nominal runs (HF and LF on step_1mm, 3 seeds) of ``t_end`` s,
    the smallest real campaign a test of the store and its readers needs."""
    return write_campaign(folder, textwrap.dedent(f"""
        name = "small"
        models = ["hf", "lf"]
        commands = ["step_1mm"]
        seeds = [0, 1, 2]
        t_end = {t_end}
        [faults]
        nominal = true
    """), "small.toml")


def close(actual, expected, rel: float = 1e-9, abs: float = 0.0, what: str = "") -> None:
    """Assert ``|actual - expected| <= abs + rel*|expected|`` element-wise."""
    np.testing.assert_allclose(np.asarray(actual, dtype=float),
                               np.asarray(expected, dtype=float), rtol=rel, atol=abs,
                               err_msg=what)


def files_under(folder: Path) -> list[Path]:
    """Every file under ``folder`` (relative paths, sorted); [] when it does not exist."""
    folder = Path(folder)
    return sorted(p.relative_to(folder) for p in folder.rglob("*") if p.is_file()) \
        if folder.exists() else []


#: A two-actuator fleet whose friction (FDJ) grows linearly to its 1500 N limit on 0.3-s chirp
#: records: the small fleet of the prognostics and report tests (``eha fleet simulate``).
SMALL_FLEET = """
name = "t-fleet"
seed = 3
actuators = 2
command = "chirp_1cm"
t_end = 0.3
noise = 2e-6
check_every = 400
max_cycles = 6000
[limits]
FDJ = 1500
[faults.FDJ]
initial = 200
laws = ["linear"]
rate = {median = 1.0, sigma = 0.0}
"""


class Inline(Executor):
    """Runs every task in this process, in order (``run_campaign(..., executor=Inline())``)."""

    workers = 1

    def map_unordered(self, fn, payloads):
        for p in payloads:
            yield fn(p)
