"""Columns of a measured record as its user has it: signal names and their aliases, units in
headers (``"xu [mm]"``, ``"position_mm"``), ``--columns`` and ``--units`` (:class:`RecordFile`).

Matching and unit parsing only; reading, validation and resampling are in
:mod:`eha.identification.measured`. Every problem is one line naming the column or the option.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from eha.errors import InputError

#: Required columns, then optional ones.
REQUIRED = ("t", "com", "xu")
OPTIONAL = ("p12", "xs")
#: Accepted header names of each column (lower case, unit suffix stripped).
ALIASES: dict[str, tuple[str, ...]] = {
    "t": ("t", "time", "t_s", "time_s", "timestamp_s", "seconds"),
    "com": ("com", "command", "cmd", "xc", "x_cmd", "xcom", "com_m", "command_m", "setpoint",
            "reference", "ref", "demand", "x_ref", "xref"),
    "xu": ("xu", "position", "pos", "x", "xu_m", "position_m", "surface", "y", "output",
           "measured", "x_meas", "xmeas", "feedback"),
    "p12": ("p12", "dp", "delta_p", "p12_pa", "load_pressure", "differential_pressure"),
    "xs": ("xs", "spool", "xs_m", "spool_position"),
}
#: Units accepted in a header (``"xu [mm]"``), per column: unit (lower case) -> factor to SI.
_LENGTH = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6}
UNITS: dict[str, dict[str, float]] = {
    "t": {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6},
    "com": _LENGTH, "xu": _LENGTH, "xs": _LENGTH,
    "p12": {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "bar": 1e5, "psi": 6894.757293168},
}
FILE_TYPES = (".csv", ".tsv", ".txt", ".parquet", ".pq")
#: Signals a record may carry, the names of ``--columns SIGNAL=HEADER``.
SIGNALS = REQUIRED + OPTIONAL
#: ``--units``: the unit of the length columns (:data:`LENGTH_SIGNALS`) whose header declares
#: none -> factor to SI.
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3, "um": 1e-6}
LENGTH_SIGNALS = ("com", "xu", "xs")


class MeasuredDataError(InputError):
    """A measured record that cannot be used; ``problems`` holds one line per problem (the
    command line prints each as ``SOURCE: problem``)."""

    def __init__(self, source: str, problems: list[str]):
        super().__init__(problems, source=source,
                         message=f"{source}: " + "; ".join(problems))


def header_unit(header: str) -> str | None:
    """The unit declared at the end of a header in brackets (``"xu [mm]"`` -> ``"mm"``)."""
    match = re.search(r"[\[(]\s*([^\])]*?)\s*[\])]\s*$", str(header))
    return match.group(1) if match else None


def suffix_unit(header: str, name: str) -> str | None:
    """A unit of column ``name`` (:data:`UNITS`) after the header's last underscore
    (``"position_mm"`` -> ``"mm"``), or None (``"x_ref"``: not a unit)."""
    match = re.search(r"_([^\W_\d]+)\s*$", str(header))
    if match and match.group(1).lower() in UNITS.get(name, {}):
        return match.group(1)
    return None


def unit_scales(mapping: dict[str, str], units: str | None = None
                ) -> tuple[dict[str, float], list[str]]:
    """Factor to SI of each mapped column from its header's unit (in brackets, or after an
    underscore), else, for a length column, from ``units`` (:data:`LENGTH_UNITS`);
    ``(scales, problems)``."""
    scales: dict[str, float] = {}
    problems: list[str] = []
    for name, header in mapping.items():
        unit = header_unit(header)
        allowed = UNITS.get(name, {})
        if unit is None:
            unit = suffix_unit(header, name)
        if unit is None:
            if units is not None and name in LENGTH_SIGNALS:
                scales[name] = LENGTH_UNITS[units]
            continue
        factor = allowed.get(unit.lower())
        if factor is None:
            problems.append(f"column {name}: unit {unit!r} in header {header!r} is not "
                            f"supported; allowed: {', '.join(dict.fromkeys(allowed))}")
        else:
            scales[name] = factor
    return scales, problems


def parse_columns(spec: str | Mapping[str, str] | None) -> tuple[dict[str, str], list[str]]:
    """``--columns``: ``"com=command_mm,xu=position_mm"`` (or a mapping) -> signal -> header,
    and one problem line per bad item (unknown signal, no header, a signal or a header given
    twice)."""
    if spec is None:
        return {}, []
    items = (list(spec.items()) if isinstance(spec, Mapping) else
             [tuple(part.partition("=")[::2]) if "=" in part else (part, "")
              for part in (p.strip() for p in str(spec).split(",")) if part])
    columns: dict[str, str] = {}
    problems: list[str] = []
    for signal, header in items:
        signal, header = str(signal).strip(), str(header).strip()
        item = f"`columns` {signal}={header}"
        if signal.lower() not in SIGNALS:
            problems.append(f"{item}: unknown signal {signal!r}; allowed: "
                            f"{', '.join(SIGNALS)} (SIGNAL=HEADER, e.g. com=command_mm)")
        elif not header:
            problems.append(f"{item}: no header; give SIGNAL=HEADER, e.g. com=command_mm")
        elif signal.lower() in columns:
            problems.append(f"{item}: {signal} given twice; name each signal once")
        elif header.lower() in (h.lower() for h in columns.values()):
            problems.append(f"{item}: header {header!r} given for two signals")
        else:
            columns[signal.lower()] = header
    return columns, problems


@dataclass(frozen=True)
class RecordFile:
    """A measured record file as its user has it: the path, the header of any signal
    (``columns``, signal -> header, e.g. ``{"com": "command_mm"}``) and the unit of length
    columns whose header declares none (``units``, :data:`LENGTH_UNITS`).

    Path-like: the library's functions that take a record path (``eha.identification.fdi.identify_source``,
    ``eha.health.monitoring.check_record``, ``eha.explain.from_file.explain_file``) take one too, and
    :func:`load` reads it with its columns and units.

    Raises
    ------
    MeasuredDataError
        An unknown signal, a malformed item of ``columns`` or a ``units`` not allowed, one
        line each naming the option (``--columns``, ``--units``).
    """

    path: Path
    columns: Mapping[str, str] | str | None = None
    units: str | None = None

    def __post_init__(self):
        columns, problems = parse_columns(self.columns)
        units = None if self.units is None else str(self.units).strip().lower()
        if units is not None and units not in LENGTH_UNITS:
            problems.append(f"`units` {self.units!r}: allowed {', '.join(LENGTH_UNITS)} "
                            f"(the unit of com, xu and xs columns whose header has none)")
        if problems:
            raise MeasuredDataError(str(self.path), problems)
        object.__setattr__(self, "path", Path(self.path))
        object.__setattr__(self, "columns", columns)
        object.__setattr__(self, "units", units)

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __str__(self) -> str:
        return str(self.path)

    def at(self, path: str | Path) -> "RecordFile":
        """Another file of the same format (a folder of records)."""
        return RecordFile(Path(path), dict(self.columns), self.units)


def same_format(record: Any, path: str | Path) -> "RecordFile | Path":
    """``path`` read as ``record`` is (its columns and units), when ``record`` is a
    :class:`RecordFile`; else ``path`` as it is."""
    return record.at(path) if isinstance(record, RecordFile) else Path(path)


def _canonical(header: str) -> str:
    name = re.sub(r"\s*[\[(].*?[\])]\s*$", "", str(header)).strip().lower()
    return re.sub(r"[\s\-]+", "_", name)


def _find_header(headers: list[str], given: str) -> str | None:
    """The file's header named ``given``: the same text, else the same but for case and
    surrounding spaces."""
    if given in headers:
        return given
    folded = [h for h in headers if h.strip().lower() == given.strip().lower()]
    return folded[0] if len(folded) == 1 else None


def match_columns(headers: list[str], columns: Mapping[str, str] | None = None
                  ) -> tuple[dict[str, str], list[str]]:
    """Map canonical names to the file's headers; returns ``(mapping, problems)``.

    ``columns`` (signal -> header, ``--columns``) names headers explicitly; the other signals
    are matched through :data:`ALIASES` among the headers not named."""
    mapping: dict[str, str] = {}
    problems: list[str] = []
    found = ", ".join(map(str, headers)) or "none"
    for name, given in (columns or {}).items():
        header = _find_header(headers, given)
        if header is None:
            problems.append(f"`columns` {name}={given}: no column {given!r} in the file "
                            f"(found: {found})")
        mapping[name] = header if header is not None else given
    claimed = set(mapping.values())
    for header in headers:
        if header in claimed:
            continue
        key = _canonical(header)
        for name, aliases in ALIASES.items():
            if name in (columns or {}):
                continue
            if key in aliases:
                if name in mapping:
                    problems.append(f"column {name}: given twice ({mapping[name]!r} and "
                                    f"{header!r}); keep one")
                else:
                    mapping[name] = header
    for name in REQUIRED:
        if name not in mapping:
            problems.append(f"column {name}: missing (accepted names: "
                            f"{', '.join(ALIASES[name])}; found: {found}; or name its "
                            f"header: `columns` {name}=HEADER)")
    return mapping, problems
