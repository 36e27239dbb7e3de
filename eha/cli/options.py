"""Options several commands share, defaults read from the library, and the checks of output
paths done before any work starts.

Range checks of the library's settings are not repeated here: a command builds the library's
settings object (``LoopSettings``, ``RecordFile``, ...) and its error is printed by the guard.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer

from eha.cli.guard import fail

#: Plot file types the figures are written in (matplotlib infers the format from the suffix).
PLOT_SUFFIXES = (".png", ".pdf", ".svg")
#: Allowed seeds (numpy's generators take unsigned 32-bit seeds).
SEED_MAX = 2**32 - 1

#: Default results folder (database eha.duckdb, traces/, plots/, reports/).
RESULTS = Path("results")
ResultsOption = Annotated[Path, typer.Option(
    "--results", help="Results folder (eha.duckdb, traces/, plots/, reports/).")]
#: Default number of local worker processes.
WORKERS = 2
WorkersOption = Annotated[int, typer.Option("--workers", min=1,
                                            help="Local worker processes.")]
#: How a measured record's command is rebuilt between its samples (eha.identification.measured).
COMMAND_HOLD = "auto"
CommandHoldOption = Annotated[str, typer.Option(
    "--command-hold", help="How the record's command is rebuilt between its samples: zoh "
    "(held, as a digital controller's output), linear (interpolated) or auto (zoh when the "
    "command is flat between jumps, else linear).")]
#: A measured record as its user has it (eha.identification.columns.RecordFile).
ColumnsOption = Annotated[Optional[str], typer.Option(
    "--columns", help="Header of each signal of the record, SIGNAL=HEADER comma-separated "
    "(signals t, com, xu, p12, xs), e.g. t=time_s,com=command_mm,xu=position_mm; signals "
    "not named are found by their usual names. A unit in the header ('(mm)' or '_mm') is "
    "honoured.")]
UnitsOption = Annotated[Optional[str], typer.Option(
    "--units", help="Unit of the record's position and command columns (com, xu, xs) whose "
    "header declares none: m, mm or um (default m).")]


def record_file(path: Path, columns: Optional[str], units: Optional[str]):
    """The record ``path`` read with ``--columns`` and ``--units`` (checked by the library:
    an unknown signal or unit is one line naming the option, exit 2)."""
    from eha.identification.measured import RecordFile

    return RecordFile(path, columns, units)


def check_database(results: Path) -> None:
    """Before reading the result database: when the folder has none, one line that says so
    and how to name the folder that has one (a user who ran the campaign elsewhere), exit 2."""
    from eha.campaigns.schema import DB_NAME

    if not (results / DB_NAME).exists():
        fail(f"{results / DB_NAME}: no result database yet; run a campaign first (eha "
             f"campaign run FILE), or give the results folder that holds one with --results "
             f"DIR")


def split_names(text: str) -> list[str]:
    """``"BKL, FDJ"`` -> ``["BKL", "FDJ"]``."""
    return [n.strip() for n in text.split(",") if n.strip()]


def _writable_folder(folder: Path, option: str, shown: Path) -> None:
    """Fail unless ``folder`` is (or can be created as) a writable folder."""
    probe = folder.absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not probe.is_dir():
        fail(f"{option} {shown}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        fail(f"{option} {shown}: folder {probe} is not writable")


def check_out_file(path: Optional[Path], option: str,
                   suffixes: tuple[str, ...] | None = None) -> None:
    """Refuse an output file before any work starts: wrong type, a folder, or a place that
    cannot be written (a parent that is a file, a read-only folder)."""
    if path is None:
        return
    if suffixes and path.suffix.lower() not in suffixes:
        fail(f"{option} {path}: unsupported file type {path.suffix or '(none)'!r}; allowed: "
             f"{', '.join(suffixes)}")
    if path.is_dir():
        fail(f"{option} {path}: is a folder; give a file name")
    if path.exists() and not os.access(path, os.W_OK):
        fail(f"{option} {path}: the file exists and is not writable")
    _writable_folder(path.parent, option, path)


def check_out_dir(path: Optional[Path], option: str) -> None:
    """Refuse an output folder before any work starts: a file, or not writable."""
    if path is None:
        return
    if path.exists() and not path.is_dir():
        fail(f"{option} {path}: is a file, not a folder")
    _writable_folder(path, option, path)


def check_seed(seed: int, option: str = "--seed") -> None:
    if not 0 <= seed <= SEED_MAX:
        fail(f"{option} {seed}: allowed range [0, {SEED_MAX}]")


def check_names(text: str, option: str) -> None:
    """Refuse a comma-separated list that names a parameter twice (``--fit BKL,BKL``)."""
    names = [item.split("=")[0].strip() for item in text.split(",") if item.strip()]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        fail(f"{option} {text}: {', '.join(twice)} given twice; name each parameter once")


def write_json(path: Optional[Path], data: Any, indent: int = 2) -> None:
    """Write ``data`` as indented JSON to ``path``, whole (:func:`eha.outputs.write_json`;
    nothing when None)."""
    if path is None:
        return
    from eha.outputs import write_json as write

    write(path, data, indent=indent)


def print_paths(paths: dict, skip: tuple[str, ...] = ()) -> None:
    """``kind: path`` a line."""
    from eha.cli.guard import console

    for kind, path in paths.items():
        if kind not in skip:
            console.print(f"{kind}: {path}")
