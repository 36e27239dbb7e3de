"""Measured-data input of the residual loop (docs/model.md §8): read, validate, resample to 1 kHz.

A measured record is a CSV (or TSV/TXT) or Parquet table with at least the columns ``t`` [s],
``com`` [m] and ``xu`` [m], optionally ``p12`` [Pa] and ``xs`` [m]; SI units. Column names are
matched case-insensitively, through the aliases of :data:`ALIASES`; a trailing unit in
brackets (``"t [ms]"``, ``"xu (mm)"``) or after an underscore (``"time_ms"``,
``"position_mm"``) is honoured: values are converted to SI with :data:`UNITS`, and a bracketed
unit not listed there is refused.

Records as users have them (:class:`RecordFile`, ``--columns`` and ``--units`` of the
commands that read a record; :mod:`eha.identification.columns` with the aliases and units):
``columns`` names the header of any signal
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.models.commands import Command, array_command
from eha.models.simulate import OUTPUT_DT
from eha.identification.columns import (ALIASES, FILE_TYPES, LENGTH_SIGNALS, LENGTH_UNITS,
                                        OPTIONAL, REQUIRED, SIGNALS, UNITS, MeasuredDataError,
                                        RecordFile, match_columns, parse_columns, same_format,
                                        unit_scales)
from eha.identification.holds import COMMAND_HOLDS, HELD_FLAT_FRACTION, detect_hold, resolve_hold
from eha.identification.synthetic import synthetic_record

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
#: Physical range of each column (SI): jack stroke, supply pressure, spool stroke.
PHYSICAL_RANGES: dict[str, tuple[float, float, str]] = {
    "com": (-0.2, 0.2, "m"),
    "xu": (-0.2, 0.2, "m"),
    "p12": (-1e8, 1e8, "Pa"),
    "xs": (-1e-2, 1e-2, "m"),
}
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
                    f"`units` mm)" if name in LENGTH_SIGNALS else "")
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
    if path.is_dir():
        raise MeasuredDataError(source, ["a folder, not a record file (give one CSV, TSV or "
                                         "Parquet file of it)"])
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

