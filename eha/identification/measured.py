"""Measured-data input of the residual loop (docs/model.md §8): read, validate, resample to 1 kHz.

A measured record is a CSV (or TSV/TXT) or Parquet table with at least the columns ``t`` [s],
``com`` [m] and ``xu`` [m], optionally ``p12`` [Pa] and ``xs`` [m]; SI units. Column names are
matched case-insensitively, through the aliases of :data:`ALIASES`; a trailing unit in
brackets (``"t [ms]"``, ``"xu (mm)"``) or after an underscore (``"time_ms"``,
``"position_mm"``) is honoured: values are converted to SI with :data:`UNITS`, and a bracketed
unit not listed there is refused.

Records as users have them (:class:`RecordFile`, ``--columns`` and ``--units`` of the
commands that read a record): ``columns`` names the header of any signal
(``"t=time_s,com=command_mm,xu=position_mm"``), whatever its name; the signals not named are
matched through the aliases. ``units`` (:data:`LENGTH_UNITS`: m, mm, um) is the unit of the
position and command columns (com, xu, xs) whose header declares none.

Validation (:func:`validate`) reports every problem at once, one line each:

- a required column is missing (or a column is claimed by two headers);
- a value is not a finite number (NaN, inf, text);
- time is not strictly increasing;
- sampling is irregular: an interval differs from the median interval by more than
  :data:`SAMPLING_TOLERANCE` (20 %), e.g. a gap of missing samples;
- fewer than :data:`MIN_SAMPLES` samples, or a record shorter than :data:`MIN_DURATION`;
- sampling the models cannot resolve: a median interval above :data:`MAX_PERIOD` (10 ms),
  e.g. time in milliseconds read as seconds;
- values outside physical ranges (:data:`PHYSICAL_RANGES`, e.g. |xu| <= 0.2 m, the jack end
  stop; a record in millimetres fails here, and the message says so).

Accepted records are shifted to start at t = 0 and resampled (linear interpolation) onto the
models' 1 kHz output grid; the command keeps its original samples and is rebuilt on the
integration step by :func:`eha.models.commands.array_command`, either interpolated (``linear``) or
held between samples (``zoh``, the output of a digital controller: a step changes *at* a sample
instant). ``command_hold="auto"`` (the default) decides from the command itself
(:func:`detect_hold`). Reading writes nothing.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.models.commands import Command, array_command
from eha.models.simulate import OUTPUT_DT
from eha.errors import InputError
from eha.identification.synthetic import synthetic_record

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
#: Largest allowed relative deviation of a sampling interval from the median interval.
SAMPLING_TOLERANCE = 0.2
#: Fewest samples and shortest record accepted.
MIN_SAMPLES = 50
MIN_DURATION = 0.05
#: Longest record accepted [s] (the simulator's limit).
MAX_DURATION = 3600.0
#: Coarsest sampling accepted [s]: the models output at 1 kHz and the actuator responds within
#: tens of ms; a slower record cannot be compared with them (and time in ms read as seconds
#: looks like a record sampled at 1 Hz).
MAX_PERIOD = 0.01
#: Units accepted in a header (``"xu [mm]"``), per column: unit (lower case) -> factor to SI.
_LENGTH = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6}
UNITS: dict[str, dict[str, float]] = {
    "t": {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6},
    "com": _LENGTH, "xu": _LENGTH, "xs": _LENGTH,
    "p12": {"pa": 1.0, "kpa": 1e3, "mpa": 1e6, "bar": 1e5, "psi": 6894.757293168},
}
#: Physical range of each column (SI): jack stroke, supply pressure, spool stroke.
PHYSICAL_RANGES: dict[str, tuple[float, float, str]] = {
    "com": (-0.2, 0.2, "m"),
    "xu": (-0.2, 0.2, "m"),
    "p12": (-1e8, 1e8, "Pa"),
    "xs": (-1e-2, 1e-2, "m"),
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


@dataclass(frozen=True)
class MeasuredData:
    """A validated record on the 1 kHz model grid.

    Attributes
    ----------
    t : float64 array
        Time [s] from 0 at 1 kHz (``len = round(duration/1e-3) + 1``).
    com, xu : float64 arrays
        Command and measured position [m] on ``t``.
    p12, xs : float64 arrays or None
        Optional load pressure [Pa] and spool position [m] on ``t``.
    command : Command
        The command as an array command on the original samples (for the simulator).
    source : str
        File name or label.
    info : dict
        Original sample count, sampling period, start time, whether it was resampled.
    """

    t: np.ndarray
    com: np.ndarray
    xu: np.ndarray
    command: Command
    p12: np.ndarray | None = None
    xs: np.ndarray | None = None
    source: str = ""
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def __len__(self) -> int:
        return self.t.size

    def head(self, n: int) -> "MeasuredData":
        """The first ``n`` samples (the command keeps its full samples)."""
        cut = {k: (None if v is None else v[:n]) for k, v in
               (("p12", self.p12), ("xs", self.xs))}
        return MeasuredData(self.t[:n], self.com[:n], self.xu[:n], self.command, cut["p12"],
                            cut["xs"], self.source, dict(self.info))


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
        item = f"--columns {signal}={header}"
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

    Path-like: the library's functions that take a record path (``eha.fdi.identify_source``,
    ``eha.monitoring.check_record``, ``eha.explain.outputs.explain_report``) take one too, and
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
            problems.append(f"--units {self.units!r}: allowed {', '.join(LENGTH_UNITS)} "
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
            problems.append(f"--columns {name}={given}: no column {given!r} in the file "
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
                            f"header: --columns {name}=HEADER)")
    return mapping, problems


def validate(columns: dict[str, Any], source: str = "data",
             scales: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """Check canonical columns (name -> values); return float64 arrays (SI) or raise.

    ``scales``: factor to SI of a column given in other units (from its header).

    Raises
    ------
    MeasuredDataError
        With one line per problem found.
    """
    problems: list[str] = []
    arrays: dict[str, np.ndarray] = {}
    for name, values in columns.items():
        numeric = _to_float(values) * (scales or {}).get(name, 1.0)
        bad = ~np.isfinite(numeric)
        if bad.any():
            first = int(np.argmax(bad))
            problems.append(f"column {name}: {int(bad.sum())} value(s) are not finite numbers "
                            f"(NaN/inf/text), first at row {first + 1}: {str(values[first])!r}")
        arrays[name] = numeric
    n = len(arrays["t"]) if "t" in arrays else 0
    if n < MIN_SAMPLES:
        problems.append(f"record: {n} samples; at least {MIN_SAMPLES} are required")
    t = arrays.get("t")
    if t is not None and n >= 2 and np.all(np.isfinite(t)):
        dt = np.diff(t)
        if np.any(dt <= 0):
            i = int(np.argmax(dt <= 0))
            problems.append(f"column t: time must be strictly increasing (row {i + 2}: "
                            f"{t[i + 1]:g} s after {t[i]:g} s)")
        else:
            med = float(np.median(dt))
            if med > MAX_PERIOD:
                problems.append(f"column t: sampling period {med:g} s ({1 / med:.3g} Hz) is "
                                f"coarser than the models resolve (at most {MAX_PERIOD:g} s); "
                                "time in milliseconds? declare it in the header, e.g. "
                                "'t [ms]'")
            dev = np.abs(dt - med) / med
            if dev.max() > SAMPLING_TOLERANCE:
                i = int(np.argmax(dev))
                problems.append(f"column t: irregular sampling, interval {dt[i]:g} s at row "
                                f"{i + 2} vs median {med:g} s (tolerance "
                                f"±{100 * SAMPLING_TOLERANCE:g} %)")
            duration = float(t[-1] - t[0])
            if duration < MIN_DURATION:
                problems.append(f"column t: record lasts {duration:g} s; at least "
                                f"{MIN_DURATION:g} s is required")
            if duration > MAX_DURATION:
                problems.append(f"column t: record lasts {duration:g} s; at most "
                                f"{MAX_DURATION:g} s is allowed")
    for name, (lo, hi, unit) in PHYSICAL_RANGES.items():
        values = arrays.get(name)
        if values is None or not np.all(np.isfinite(values)):
            continue
        out = (values < lo) | (values > hi)
        if out.any():
            worst = float(values[np.argmax(np.abs(values))])
            hint = (f" (SI units required: millimetres? declare them: '{name} [mm]' or "
                    f"--units mm)" if name in LENGTH_SIGNALS else "")
            problems.append(f"column {name}: {int(out.sum())} value(s) outside the physical "
                            f"range [{lo:g}, {hi:g}] {unit}, e.g. {worst:g}{hint}")
    if problems:
        raise MeasuredDataError(source, problems)
    return arrays


def noise_level(xu: np.ndarray) -> float:
    """Measurement-noise standard deviation [m] of a position record, from the record itself.

    Robust (median absolute deviation) spread of the fourth difference, divided by sqrt(70):
    white noise of std s gives fourth differences of std s*sqrt(70), while the actuator's
    position (a mass behind a valve) is smooth at 1 kHz: a 5 Hz, 1 cm sine contributes
    (2*pi*5e-3)**4 * 1 cm = 0.01 µm, and the few corners (steps, end stops) are outliers that
    the median ignores.
    """
    d4 = np.diff(np.asarray(xu, dtype=np.float64), 4)
    if d4.size < 5:
        return 0.0
    mad = np.median(np.abs(d4 - np.median(d4)))
    return float(1.4826 * mad / math.sqrt(70.0))


#: ``command_hold`` values: decide from the record, or force one rebuild of the command.
COMMAND_HOLDS = ("auto", "zoh", "linear")
#: A command is read as held (``auto`` -> ``zoh``) when at least this fraction of its sample
#: differences are exactly zero (flat runs between changes) and at least one change is an
#: isolated jump between flat runs.
HELD_FLAT_FRACTION = 0.2


def detect_hold(com: np.ndarray) -> tuple[str, str]:
    """How a recorded command was produced between its samples: ``"zoh"`` or ``"linear"``.

    A digital controller holds its output between samples, so a held command is piecewise
    constant on its samples: most sample differences are exactly zero and every change is a jump
    between flat runs. Interpolating such a record linearly drives the model up to one sample
    early at every step (the residual loop then "explains" that with a delay). A command that
    changes at every sample (a sine or chirp recorded at the controller's rate) carries no such
    evidence: it is rebuilt linearly, which is unbiased for a step at an unknown instant
    between samples.

    Parameters
    ----------
    com : float64 array
        Command samples [m] as recorded.

    Returns
    -------
    hold : {"zoh", "linear"}
    reason : str
        One line for reports, e.g. ``"held: 96 % of sample differences are zero, 4 jumps"``.
    """
    com = np.asarray(com, dtype=np.float64)
    d = np.diff(com)
    if d.size < 3:
        return "linear", "too few samples to tell; interpolated"
    span = float(np.max(com) - np.min(com))
    flat = np.abs(d) <= 1e-9 * span + 1e-15
    isolated = ~flat[1:-1] & flat[:-2] & flat[2:]
    jumps = int(np.count_nonzero(isolated)) + int(not flat[0] and flat[1]) \
        + int(not flat[-1] and flat[-2])
    fraction = float(np.mean(flat))
    if span > 0 and jumps >= 1 and fraction >= HELD_FLAT_FRACTION:
        return "zoh", (f"held: {fraction:.0%} of sample differences are zero, {jumps} jump"
                       f"{'s' if jumps != 1 else ''} between flat runs")
    return "linear", (f"interpolated: {fraction:.0%} of sample differences are zero, "
                      f"{jumps} isolated jump{'s' if jumps != 1 else ''}")


def resolve_hold(command_hold: str, com: np.ndarray, source: str = "data") -> tuple[str, str]:
    """``command_hold`` resolved for a record's command samples (``auto`` -> detected)."""
    if command_hold not in COMMAND_HOLDS:
        raise MeasuredDataError(source, [f"--command-hold {command_hold!r}: allowed: "
                                         f"{', '.join(COMMAND_HOLDS)}"])
    if command_hold == "auto":
        return detect_hold(com)
    return command_hold, f"{command_hold} (given)"


def _to_float(values: Any) -> np.ndarray:
    try:
        return np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        import pandas as pd

        return pd.to_numeric(pd.Series(values), errors="coerce").to_numpy(dtype=np.float64)


def from_arrays(t, com, xu, p12=None, xs=None, source: str = "data",
                scales: dict[str, float] | None = None,
                command_hold: str = "auto") -> MeasuredData:
    """Validate arrays and resample them onto the 1 kHz model grid.

    Parameters
    ----------
    t : array
        Time [s], strictly increasing, regular within :data:`SAMPLING_TOLERANCE`.
    com, xu : arrays
        Command and measured position [m].
    p12, xs : arrays, optional
        Load pressure [Pa], spool position [m].
    scales : dict, optional
        Factor to SI of columns given in other units (e.g. ``{"xu": 1e-3}`` for mm).
    command_hold : {"auto", "zoh", "linear"}
        How the command is rebuilt between its samples (:func:`detect_hold` for ``auto``).
    """
    columns = {"t": t, "com": com, "xu": xu}
    if p12 is not None:
        columns["p12"] = p12
    if xs is not None:
        columns["xs"] = xs
    lengths = {k: len(v) for k, v in columns.items()}
    if len(set(lengths.values())) > 1:
        raise MeasuredDataError(source, [f"columns have different lengths: {lengths}"])
    arrays = validate(columns, source, scales)
    t_raw = arrays["t"] - arrays["t"][0]
    n_out = int(np.floor(t_raw[-1] / OUTPUT_DT + 1e-9)) + 1
    grid = np.arange(n_out) * OUTPUT_DT
    period = float(np.median(np.diff(t_raw)))
    resampled = not (t_raw.size == n_out and np.allclose(t_raw, grid, atol=1e-3 * OUTPUT_DT))

    def on_grid(values):
        return values.copy() if not resampled else np.interp(grid, t_raw, values)

    hold, hold_reason = resolve_hold(command_hold, arrays["com"], source)
    command = array_command(t_raw, arrays["com"], name=f"array:{Path(source).name}", hold=hold)

    info = {"samples": int(t_raw.size), "period_s": period, "t0_s": float(arrays["t"][0]),
            "resampled": bool(resampled), "samples_1khz": int(n_out),
            # on the original samples: interpolation would smooth the noise away
            "noise_m": noise_level(arrays["xu"]),
            "command_hold": hold, "command_hold_reason": hold_reason}
    return MeasuredData(
        t=grid, com=command.sample(grid) if resampled else arrays["com"].copy(),
        xu=on_grid(arrays["xu"]), command=command,
        p12=on_grid(arrays["p12"]) if "p12" in arrays else None,
        xs=on_grid(arrays["xs"]) if "xs" in arrays else None,
        source=str(source), info=info)


def load(path: str | Path | RecordFile, command_hold: str = "auto",
         columns: Mapping[str, str] | str | None = None,
         units: str | None = None) -> MeasuredData:
    """Read, validate and resample a measured record (CSV/TSV/TXT or Parquet).

    ``command_hold`` says how the command is rebuilt between its samples
    (:data:`COMMAND_HOLDS`; ``auto`` decides from the command, :func:`detect_hold`).
    ``columns`` (signal -> header, or ``"com=command_mm,xu=position_mm"``) and ``units``
    (m, mm, um: of the length columns whose header has none) read a record as its user has
    it (:class:`RecordFile`; a ``RecordFile`` given as ``path`` brings its own).

    Raises
    ------
    MeasuredDataError
        File missing or unreadable, unsupported type, a bad ``columns`` or ``units``, or any
        validation problem.
    """
    from eha.campaigns.traces import read_table_file

    if isinstance(path, RecordFile):
        record = RecordFile(path.path, path.columns if columns is None else columns,
                            path.units if units is None else units)
    else:
        record = RecordFile(Path(path), columns, units)
    path = record.path
    source = str(path)
    if not path.is_file():
        raise MeasuredDataError(source, ["file not found"])
    if path.suffix.lower() not in FILE_TYPES:
        raise MeasuredDataError(source, [f"unsupported file type {path.suffix or '(none)'!r}; "
                                         f"allowed: {', '.join(FILE_TYPES)}"])
    try:
        frame = read_table_file(path)
    except Exception as exc:  # any parser error becomes one line naming the file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeasuredDataError(source, [f"cannot read the table: {first}"]) from None
    headers = [str(c) for c in frame.columns]
    mapping, problems = match_columns(headers, record.columns)
    scales, unit_problems = unit_scales(mapping, record.units)
    if problems or unit_problems:
        raise MeasuredDataError(source, problems + unit_problems)
    cols = {name: frame[header].to_numpy() for name, header in mapping.items()}
    return from_arrays(cols["t"], cols["com"], cols["xu"], cols.get("p12"), cols.get("xs"),
                       source=source, scales=scales, command_hold=command_hold)


__all__ = ["MeasuredData", "MeasuredDataError", "load", "from_arrays", "validate",
           "match_columns", "RecordFile", "same_format", "parse_columns", "SIGNALS",
           "LENGTH_UNITS", "ALIASES", "REQUIRED", "OPTIONAL", "SAMPLING_TOLERANCE",
           "MIN_SAMPLES", "MIN_DURATION", "PHYSICAL_RANGES", "synthetic_record", "noise_level",
           "COMMAND_HOLDS", "detect_hold", "resolve_hold"]

