"""Health-history manifests: which record of which actuator was taken at which cycle.

A manifest is a CSV file with (at least) the columns

``actuator``
    Actuator identifier (text, e.g. a serial number).
``cycle``
    Age at the check: flight cycles or flight hours (a number >= 0), strictly increasing per
    actuator. The unit is whatever the user counts; predictions come back in the same unit.
``record``
    Path of the check's record, a table ``eha fdi --data`` accepts (CSV/TSV/TXT or Parquet
    with t, com, xu in SI units), relative to the manifest's folder (or absolute).

Optional columns say how a record is read when its header or units are not the usual ones
(:class:`eha.identification.measured.RecordFile`, as ``--columns`` and ``--units`` of ``eha rul``
do for every record; a non-empty cell overrides the option for its row):

``columns``
    Header of each signal, ``SIGNAL=HEADER`` comma-separated, in quotes
    (``"t=time_s,com=command_mm,xu=lvdt"``).
``units``
    Unit (m, mm, um) of the record's length columns whose header declares none.

Other columns are kept (``extra``) and ignored. Column names are matched case-insensitively.
Rows may come in any order; :func:`read_manifest` returns them sorted by actuator (in order of
first appearance) and cycle.

:func:`read_manifest` reports every problem at once, one line each (:class:`ManifestError`):
missing columns, empty actuator names, non-numeric / negative / non-finite cycles, duplicate
or decreasing cycles of an actuator (in file order), records that do not exist or have an
unsupported file type, a bad ``columns`` or ``units`` cell. Reading writes nothing; record
contents are validated later, by the health assessment of each record.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from eha.errors import InputError

#: Required manifest columns.
COLUMNS = ("actuator", "cycle", "record")
#: Optional columns: how the row's record is read (``eha rul --columns``, ``--units``).
FORMAT_COLUMNS = ("columns", "units")
#: Record file types accepted (those of :mod:`eha.identification.measured`).
RECORD_TYPES = (".csv", ".tsv", ".txt", ".parquet", ".pq")


class ManifestError(InputError):
    """A manifest that cannot be used; ``problems`` holds one line per problem."""

    def __init__(self, source: str, problems: list[str]):
        super().__init__(problems, source=source,
                         message="\n".join(f"{source}: {p}" for p in problems))


@dataclass(frozen=True)
class Check:
    """One row of a manifest: a check of one actuator.

    Attributes
    ----------
    actuator : str
        Actuator identifier.
    cycle : float
        Age at the check [cycles or hours, the manifest's unit].
    record : Path
        Absolute path of the record.
    row : int
        Line number in the manifest file (header = line 1).
    extra : dict
        Other columns of the row, as text.
    columns, units : optional
        How the record is read (the row's ``columns``, signal -> header, and ``units``);
        None where the row gives none.
    """

    actuator: str
    cycle: float
    record: Path
    row: int
    extra: dict = field(default_factory=dict)
    columns: dict | None = None
    units: str | None = None


@dataclass(frozen=True)
class Manifest:
    """A validated manifest: its checks sorted by actuator (first appearance) then cycle."""

    source: Path
    checks: tuple[Check, ...]

    @property
    def actuators(self) -> list[str]:
        """Actuator identifiers in order of first appearance."""
        return list(dict.fromkeys(c.actuator for c in self.checks))

    def of(self, actuator: str) -> list[Check]:
        """The checks of one actuator in cycle order."""
        return [c for c in self.checks if c.actuator == actuator]


def read_manifest(path: str | Path, check_files: bool = True) -> Manifest:
    """Read and validate a manifest CSV.

    Parameters
    ----------
    path : path
        The manifest file.
    check_files : bool
        Also check that every record exists and has a supported file type.

    Returns
    -------
    Manifest

    Raises
    ------
    ManifestError
        With one line per problem (all problems of the file).
    """
    path = Path(path)
    if path.is_dir():
        hint = " (it holds manifest.csv: give that)" if (path / "manifest.csv").is_file() \
            else ""
        raise ManifestError(path, [f"a folder, not a manifest file{hint}"])
    if not path.is_file():
        raise ManifestError(path, ["file not found"])
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = [ln for ln in fh.read().splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        raise ManifestError(path, [f"cannot read the file ({exc})"]) from None
    body = [(i + 1, ln) for i, ln in enumerate(lines)
            if ln.strip() and not ln.lstrip().startswith("#")]
    if not body:
        raise ManifestError(path, ["empty file; expected a header with the columns "
                                   f"{', '.join(COLUMNS)}"])
    rows = list(csv.reader([ln for _, ln in body], skipinitialspace=True))
    numbers = [n for n, _ in body]
    header = [h.strip().lower() for h in rows[0]]
    problems: list[str] = []
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        problems.append(f"missing column(s) {', '.join(missing)}; required columns: "
                        f"{', '.join(COLUMNS)} (found: {', '.join(rows[0]) or 'none'})")
        raise ManifestError(path, problems)
    dup = sorted({h for h in header if header.count(h) > 1 and h in COLUMNS + FORMAT_COLUMNS})
    for h in dup:
        problems.append(f"column {h} given twice; keep one")
    idx = {c: header.index(c) for c in COLUMNS}
    folder = path.parent
    checks: list[Check] = []
    last: dict[str, tuple[float, int]] = {}
    if len(rows) == 1:
        problems.append("no checks: the manifest has a header but no rows")
    for raw, line in zip(rows[1:], numbers[1:]):
        check = _check_row(raw, line, header, idx, folder, check_files, last, problems)
        if check is not None:
            checks.append(check)
    if problems:
        raise ManifestError(path, problems)
    order = {a: i for i, a in enumerate(dict.fromkeys(c.actuator for c in checks))}
    checks.sort(key=lambda c: (order[c.actuator], c.cycle))
    return Manifest(path.resolve(), tuple(checks))


def _check_row(raw: list[str], line: int, header: list[str], idx: dict[str, int], folder: Path,
               check_files: bool, last: dict[str, tuple[float, int]],
               problems: list[str]) -> Check | None:
    """One row of the manifest: its check, or None with its problems appended to
    ``problems``; ``last`` (actuator -> last cycle and its line) is updated."""
    if len(raw) < len(header):
        raw = raw + [""] * (len(header) - len(raw))
    where = f"line {line}"
    actuator = raw[idx["actuator"]].strip()
    cycle_text = raw[idx["cycle"]].strip()
    record_text = raw[idx["record"]].strip()
    ok = True
    if not actuator:
        problems.append(f"{where}: column actuator is empty; give an identifier")
        ok = False
    try:
        cycle = float(cycle_text)
        if not math.isfinite(cycle):
            raise ValueError
    except ValueError:
        problems.append(f"{where}: column cycle {cycle_text!r} is not a number; allowed "
                        "a finite number >= 0 (cycles or hours)")
        cycle, ok = math.nan, False
    else:
        if cycle < 0:
            problems.append(f"{where}: column cycle {cycle_text} is negative; allowed a "
                            "finite number >= 0 (cycles or hours)")
            ok = False
    if actuator and ok:
        prev = last.get(actuator)
        if prev is not None and cycle == prev[0]:
            problems.append(f"{where}: actuator {actuator}: cycle {cycle:g} listed twice "
                            f"(also on line {prev[1]}); cycles must be strictly "
                            "increasing per actuator")
            ok = False
        elif prev is not None and cycle < prev[0]:
            problems.append(f"{where}: actuator {actuator}: cycle {cycle:g} comes after "
                            f"cycle {prev[0]:g} (line {prev[1]}); cycles must be strictly "
                            "increasing per actuator")
            ok = False
        if prev is None or cycle > prev[0]:
            last[actuator] = (cycle, line)
    if not record_text:
        problems.append(f"{where}: column record is empty; give the path of a record "
                        "(relative to the manifest's folder)")
        ok = False
        record = Path()
    else:
        record = Path(record_text)
        if not record.is_absolute():
            record = folder / record
        record = record.resolve()
        if check_files:
            if record.suffix.lower() not in RECORD_TYPES:
                problems.append(f"{where}: record {record_text}: unsupported file type "
                                f"{record.suffix or '(none)'!r}; allowed: "
                                f"{', '.join(RECORD_TYPES)}")
                ok = False
            elif not record.is_file():
                problems.append(f"{where}: record {record_text}: file not found "
                                f"(looked for {record})")
                ok = False
    fmt = _record_format(raw, header, where, problems)
    if not ok or fmt is None:
        return None
    extra = {h: v for h, v in zip(header, raw) if h not in COLUMNS + FORMAT_COLUMNS}
    return Check(actuator, cycle, record, line, extra, *fmt)


def _record_format(raw: list[str], header: list[str], where: str, problems: list[str]
                   ) -> tuple[dict | None, str | None] | None:
    """The row's ``columns`` and ``units`` (None where empty), checked by the record loader
    (:class:`eha.identification.measured.RecordFile`); None with the problems appended."""
    cells = {h: v.strip() for h, v in zip(header, raw) if h in FORMAT_COLUMNS and v.strip()}
    if not cells:
        return None, None
    from eha.identification.measured import MeasuredDataError, RecordFile

    try:
        fmt = RecordFile(Path(), cells.get("columns"), cells.get("units"))
    except MeasuredDataError as exc:
        # the loader names its options ("--units 'inch': allowed ..."): here they are columns
        for problem in exc.problems:
            detail = problem.split(": ", 1)[-1]
            name = "columns" if problem.startswith("`columns`") else "units"
            problems.append(f"{where}: {name} {cells[name]!r}: {detail}")
        return None
    return (fmt.columns or None), fmt.units


def write_manifest(path: str | Path, rows: list[tuple[str, float, str]]) -> Path:
    """Write a manifest CSV (``actuator, cycle, record``; records relative to its folder)."""
    path = Path(path)
    from eha.outputs import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for actuator, cycle, record in rows:
            w.writerow([actuator, f"{cycle:g}", record])
    return path


__all__ = ["Check", "Manifest", "ManifestError", "read_manifest", "write_manifest", "COLUMNS",
           "FORMAT_COLUMNS"]
