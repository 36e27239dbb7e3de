"""Position commands (thesis §4.1, docs/model.md §5): step, ramp, sine, chirp, mixed, test, array.

A :class:`Command` is a kind plus its parameters; :meth:`Command.sample` evaluates it on a time
grid (vectorised NumPy, once per simulation, outside the kernels). Presets are named commands
whose parameters can be overridden (``make_command("chirp_1cm", A0=5e-3)``).
"""

from __future__ import annotations

import hashlib
import os
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numba import njit
from eha.errors import InputError


class CommandError(InputError):
    """Unknown command, unknown command parameter or bad value (message is one line)."""


@dataclass(frozen=True)
class CommandKind:
    """A command family: its parameters (name -> (default, unit, lo, hi)) and its meaning."""

    name: str
    params: Mapping[str, tuple[float, str, float, float]]
    description: str


KINDS: dict[str, CommandKind] = {
    k.name: k
    for k in (
        CommandKind("step", {"A": (1e-3, "m", -0.2, 0.2), "t0": (0.0, "s", 0.0, 1e4)},
                    "A for t >= t0"),
        CommandKind("ramp", {"slope": (0.01, "m/s", -10.0, 10.0), "t0": (0.0, "s", 0.0, 1e4)},
                    "slope*(t - t0) for t >= t0"),
        CommandKind("sine", {"A": (1e-2, "m", 0.0, 0.2), "f": (5.0, "Hz", 0.0, 1e3),
                             "phase": (0.0, "rad", -10.0, 10.0)},
                    "A*sin(2*pi*f*t + phase)"),
        CommandKind("chirp", {"A0": (1e-3, "m", 0.0, 0.2), "f0": (0.5, "Hz", 0.0, 1e3),
                              "f1": (10.0, "Hz", 0.0, 1e3), "T": (1.0, "s", 1e-3, 1e4)},
                    "A0*(1 - t/T)*sin(2*pi*(f0*t + (f1 - f0)*t^2/(2T))): amplitude falls, "
                    "frequency rises linearly"),
        CommandKind("mixed", {"scale": (1.0, "-", -100.0, 100.0)},
                    "EHA_Dat.m mixed command: ramp 0.03 m/s to 0.3 s, then two sine arcs"),
        CommandKind("test", {"scale": (1.0, "-", -100.0, 100.0)},
                    "EHA_Dat.m prognostic test sequence: steps, ramp, sine"),
        CommandKind("array", {}, "user samples (t, value), interpolated or held onto the grid"),
    )
}

#: Named presets: (kind, parameter overrides, description).
PRESETS: dict[str, tuple[str, dict[str, float], str]] = {
    "step_1mm": ("step", {"A": 1e-3}, "1 mm step at t = 0"),
    "step_1cm": ("step", {"A": 1e-2}, "1 cm step at t = 0 (saturates the spool)"),
    "ramp": ("ramp", {"slope": 0.01}, "ramp 0.01 m/s from t = 0"),
    "sine": ("sine", {"A": 1e-2, "f": 5.0}, "1 cm, 5 Hz sine"),
    "chirp_1mm": ("chirp", {"A0": 1e-3, "f0": 0.5, "f1": 10.0}, "1 mm chirp 0.5 -> 10 Hz"),
    "chirp_1cm": ("chirp", {"A0": 1e-2, "f0": 0.1, "f1": 1.5}, "1 cm chirp 0.1 -> 1.5 Hz"),
    "mixed": ("mixed", {}, "ramp then sine arcs (EHA_Dat.m)"),
    "test": ("test", {}, "prognostic test sequence (EHA_Dat.m)"),
}

#: The six nominal commands of thesis chapter 5.
NOMINAL_COMMANDS = ("step_1mm", "step_1cm", "ramp", "chirp_1mm", "chirp_1cm", "mixed")


@dataclass(frozen=True)
class Command:
    """A position command.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    params : dict
        Parameters of the kind (units as declared there); missing ones take their defaults.
    name : str
        Label for reports (preset name or kind).
    samples : tuple of (t, value) arrays, optional
        Only for ``kind="array"``: times [s] (strictly increasing) and positions [m].
    hold : {"linear", "zoh"}
        Only for ``kind="array"``: how the samples are rebuilt between sample instants:
        ``"linear"`` interpolation, or ``"zoh"`` (zero-order hold: each sample holds until the
        next, as a digital controller's output; a step changes *at* a sample instant).
    """

    kind: str
    params: dict[str, float] = field(default_factory=dict)
    name: str = ""
    samples: tuple[np.ndarray, np.ndarray] | None = None
    hold: str = "linear"

    def sample(self, t: np.ndarray, uniform: bool = False) -> np.ndarray:
        """Command value [m] at times ``t`` [s].

        ``uniform=True`` promises an evenly spaced grid (the integration grid), on which the
        sinusoids are evaluated by a rotation recurrence instead of one ``sin`` per sample.
        """
        t = np.asarray(t, dtype=np.float64)
        sin = _sin_on_grid if uniform else _sin_anywhere
        if self.kind in ("mixed", "test") and np.any(np.diff(t) < 0):
            raise CommandError(f"command {self.name or self.kind}: times must be non-decreasing")
        p = {k: v[0] for k, v in KINDS[self.kind].params.items()} | self.params
        if self.kind == "step":
            return np.where(t >= p["t0"], p["A"], 0.0)
        if self.kind == "ramp":
            return p["slope"] * np.maximum(t - p["t0"], 0.0)
        if self.kind == "sine":
            return p["A"] * sin(t, p["phase"], 2 * np.pi * p["f"], 0.0)
        if self.kind == "chirp":
            T = p["T"]
            amp = p["A0"] * np.clip(1.0 - t / T, 0.0, None)
            return amp * sin(t, 0.0, 2 * np.pi * p["f0"], np.pi * (p["f1"] - p["f0"]) / T)
        if self.kind == "mixed":
            return p["scale"] * _mixed(t, sin)
        if self.kind == "test":
            return p["scale"] * _test(t, sin)
        if self.kind == "array":
            ts, xs = self.samples
            if self.hold == "zoh":
                # the sample at t_k holds on [t_k, t_k+1); a grid time within a millionth of a
                # sample period of t_k counts as t_k (k*DT and k*1e-3 differ by rounding)
                eps = 1e-6 * float(np.min(np.diff(ts)))
                idx = np.searchsorted(ts, t + eps, side="right") - 1
                return xs[np.clip(idx, 0, xs.size - 1)]
            return np.interp(t, ts, xs)
        raise CommandError(f"command: unknown kind {self.kind!r}")  # pragma: no cover

    def describe(self) -> dict[str, Any]:
        return {"name": self.name or self.kind, "kind": self.kind, **self.params}


def _piecewise(t: np.ndarray, edges: list[float], pieces: list) -> np.ndarray:
    """Evaluate ``pieces[i]`` only on ``edges[i-1] < t <= edges[i]`` (sin is the costly part)."""
    out = np.empty_like(t)
    bounds = np.searchsorted(t, edges, side="right")
    start = 0
    for stop, piece in zip(list(bounds) + [t.size], pieces):
        if stop > start:
            out[start:stop] = piece(t[start:stop])
        start = max(start, stop)
    return out


def _sin_anywhere(t: np.ndarray, c0: float, c1: float, c2: float) -> np.ndarray:
    """``sin(c0 + c1*t + c2*t**2)`` at arbitrary times."""
    return np.sin(c0 + c1 * t + c2 * t * t)


def _sin_on_grid(t: np.ndarray, c0: float, c1: float, c2: float) -> np.ndarray:
    """``sin(c0 + c1*t + c2*t**2)`` on an evenly spaced grid ``t``, by rotation recurrence."""
    if t.size < 3:
        return _sin_anywhere(t, c0, c1, c2)
    t0 = t[0]
    dt = (t[-1] - t0) / (t.size - 1)
    # phase(k) = a0 + a1*k + a2*k^2 with k the grid index
    a0 = c0 + c1 * t0 + c2 * t0 * t0
    a1 = (c1 + 2.0 * c2 * t0) * dt
    a2 = c2 * dt * dt
    return _sin_quadratic_phase(t.size, a0, a1, a2)


@njit(cache=True)
def _sin_quadratic_phase(n, a0, a1, a2):
    """``sin(a0 + a1*k + a2*k**2)`` for k = 0..n-1.

    Complex rotation z <- z*w, w <- w*r (r the constant second difference), re-anchored with
    exact sin/cos every 64 samples so the rounding error stays at a few ulps.
    """
    out = np.empty(n)
    rr = math.cos(2.0 * a2)
    ri = math.sin(2.0 * a2)
    k = 0
    while k < n:
        th = a0 + a1 * k + a2 * k * k
        zr = math.cos(th)
        zi = math.sin(th)
        d = a1 + a2 * (2 * k + 1)
        wr = math.cos(d)
        wi = math.sin(d)
        stop = min(n, k + 64)
        for j in range(k, stop):
            out[j] = zi
            zr, zi = zr * wr - zi * wi, zr * wi + zi * wr
            wr, wi = wr * rr - wi * ri, wr * ri + wi * rr
        k = stop
    return out


def _mixed(t: np.ndarray, sin=_sin_anywhere) -> np.ndarray:
    # EHA_Dat.m, verbatim (docs/model.md §5); t <= 0.3 is the ramp, t <= 0.65 the first arc.
    return _piecewise(t, [0.3, 0.65], [
        lambda s: 0.03 * s,
        lambda s: 0.005 + 0.004 * sin(s, -2 * np.pi / 0.35 * 0.3 + np.pi / 2, 2 * np.pi / 0.35,
                                      0.0),
        lambda s: 0.005 + 0.004 * sin(s, -3 * np.pi / 0.35 * 0.65 + np.pi / 2, 3 * np.pi / 0.35,
                                      0.0),
    ])


def _test(t: np.ndarray, sin=_sin_anywhere) -> np.ndarray:
    # 0 until 0.01 s; 3 mm until 0.2 s; 0 until 0.4 s; ramp 0.01 m/s to 0.6 s; then a sine.
    out = np.zeros_like(t)
    out[(t >= 0.01) & (t < 0.2)] = 3e-3
    ramp = (t >= 0.4) & (t < 0.6)
    out[ramp] = 0.01 * (t[ramp] - 0.4)
    tail = t >= 0.6
    out[tail] = 0.003 * sin(t[tail], -10 * np.pi * 0.6 + np.pi / 2, 10 * np.pi, 0.0)
    return out


def make_command(name: str, **overrides: float) -> Command:
    """A preset or a kind by name, with its parameters overridden and validated.

    ``name`` may also be a command file (``FILE.csv``, :func:`load_command_file`).

    Raises
    ------
    CommandError
        Unknown name, unknown parameter of that kind, or value outside its range; a bad
        command file.
    """
    if is_command_file(name):
        if overrides:
            raise CommandError(f"command file {name}: takes no parameters (got "
                               f"{', '.join(overrides)})")
        return load_command_file(name)
    if name in PRESETS:
        kind, params, _ = PRESETS[name]
    elif isinstance(name, str) and Path(name).is_dir():
        raise CommandError(f"command {name}: a folder, not a command file (give a FILE.csv "
                           "with columns t,com)")
    elif name in KINDS and name != "array":
        kind, params = name, {}
    else:
        allowed = ", ".join(list(PRESETS) + [k for k in KINDS if k not in PRESETS and k != "array"])
        raise CommandError(f"command: unknown command {name!r}; allowed: {allowed}")
    spec = KINDS[kind].params
    merged = dict(params)
    for key, value in overrides.items():
        if key not in spec:
            allowed = ", ".join(spec) or "none"
            raise CommandError(f"command {name}: unknown parameter {key!r}; allowed: {allowed}")
        default, unit, lo, hi = spec[key]
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise CommandError(f"command {name}.{key}: {value!r} is not a number") from None
        if not math.isfinite(value) or not lo <= value <= hi:
            raise CommandError(f"command {name}.{key}={value:g} is out of range; "
                               f"allowed range [{lo:g}, {hi:g}] {unit}")
        merged[key] = value
    return Command(kind, merged, name)


#: How an array command is rebuilt between its samples (see :class:`Command`).
HOLDS = ("linear", "zoh")


def array_command(t: np.ndarray, values: np.ndarray, name: str = "array",
                  hold: str = "linear") -> Command:
    """A command from samples (e.g. a measured-data file); checked finite and increasing.

    ``hold`` is ``"linear"`` (interpolated between samples) or ``"zoh"`` (each sample held
    until the next one).
    """
    if hold not in HOLDS:
        raise CommandError(f"array command: hold {hold!r}; allowed: {', '.join(HOLDS)}")
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if t.ndim != 1 or t.shape != values.shape or t.size < 2:
        raise CommandError("array command: t and values must be 1-D, equal length, >= 2 samples")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(values))):
        raise CommandError("array command: t and values must be finite (no NaN/inf)")
    if np.any(np.diff(t) <= 0):
        raise CommandError("array command: t must be strictly increasing")
    return Command("array", {}, name, (t, values), hold)


def as_command(command: "Command | str") -> Command:
    """Accept a :class:`Command`, a preset/kind name or a command file (``FILE.csv``)."""
    return command if isinstance(command, Command) else make_command(command)


# -- command files: a designed or hand-made command as samples (t, com) in SI

#: Suffix of a command file (``eha design`` writes them).
COMMAND_FILE_SUFFIX = ".csv"
#: The largest command a file may hold [m]: the jack's end stop (``XJM``).
MAX_FILE_STROKE = 0.2
_PIN = "#sha="


def is_command_file(name: str) -> bool:
    """Does ``name`` name a command file (``FILE.csv``, optionally pinned ``FILE.csv#sha=H``)?"""
    return isinstance(name, str) and name.split(_PIN)[0].lower().endswith(COMMAND_FILE_SUFFIX)


def _file_digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def pin_command(name: str) -> str:
    """A command reference that names its content: a command file becomes
    ``ABSOLUTE_PATH#sha=HASH`` (what run keys, caches and calibrations store, so that a changed
    file is a new command and a moved one is found by its content hash), other names are
    returned unchanged."""
    if not is_command_file(name):
        return name
    path = Path(name.split(_PIN)[0])
    return f"{path.resolve()}{_PIN}{_file_digest(_read_bytes(path))}"


#: The largest command file read [bytes]: 64 MiB, some 2.5 million samples (40 min at
#: 1 kHz); a larger file, or a file that is not a regular one (``/dev/zero``, a pipe), is
#: refused before it is read.
MAX_COMMAND_FILE_BYTES = 64 * 1024 * 1024


def _read_bytes(path: Path) -> bytes:
    import stat

    try:
        with open(path, "rb") as fh:
            st = os.fstat(fh.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise CommandError(f"command file {path}: not a regular file (a device, a "
                                   "pipe or a socket)")
            if st.st_size > MAX_COMMAND_FILE_BYTES:
                raise CommandError(f"command file {path}: {st.st_size} bytes; allowed at most "
                                   f"{MAX_COMMAND_FILE_BYTES} bytes (64 MiB)")
            data = fh.read(MAX_COMMAND_FILE_BYTES + 1)
        if len(data) > MAX_COMMAND_FILE_BYTES:  # grew while it was read
            raise CommandError(f"command file {path}: more than {MAX_COMMAND_FILE_BYTES} "
                               "bytes; allowed at most 64 MiB")
        return data
    except FileNotFoundError:
        raise CommandError(f"command file {path}: no such file") from None
    except IsADirectoryError:
        raise CommandError(f"command file {path}: a folder, not a file") from None
    except OSError as exc:
        raise CommandError(f"command file {path}: cannot be read ({exc.strerror})") from None


def command_label(name: str) -> str:
    """A short name of a command for tables, file and campaign names: a command file's
    ``STEM-HASH``, else ``name`` itself."""
    return load_command_file(name).name if is_command_file(name) else name


def command_file_settings(text: str) -> dict[str, str]:
    """The ``# key = value`` lines of a command file's header comment."""
    out = {}
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        key, sep, value = line[1:].partition("=")
        if sep:
            out[key.strip()] = value.strip()
    return out


def load_command_file(name: str) -> Command:
    """A command from a CSV file: header comment lines (``# key = value``), then columns ``t``
    [s] and ``com`` [m]; ``t`` starts at 0 and strictly increases, every value finite and
    ``|com| <= MAX_FILE_STROKE``. Linear between samples; after the last sample the command
    holds its last value. A pinned name (:func:`pin_command`) must still have its content.

    Its :attr:`Command.name` is ``STEM-HASH`` (the first 8 hex digits of the content's hash).
    """
    text_path, _, pinned = name.partition(_PIN)
    path = Path(text_path)
    raw = _read_bytes(path)
    digest = _file_digest(raw)
    if pinned and pinned != digest:
        raise CommandError(f"command file {path}: changed since it was pinned (content "
                           f"{digest}, expected {pinned}); plan the campaign again")
    where = f"command file {path}"
    try:
        text = raw.decode("utf-8").removeprefix("\ufeff")  # a BOM (spreadsheets write one)
    except UnicodeDecodeError:
        raise CommandError(f"{where}: not UTF-8 text") from None
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    # any record's t and com columns (a record t,com,xu is its own command); others ignored
    header = [c.strip().lower() for c in rows[0].split(",")] if rows else []
    if "t" not in header or "com" not in header:
        raise CommandError(f"{where}: the first line after the comments must be a header "
                           "with the columns t and com (time [s], command [m]), e.g. 't,com' "
                           "or a record's 't,com,xu'")
    it, ic = header.index("t"), header.index("com")
    values = []
    for i, line in enumerate(rows[1:], start=1):
        cells = line.split(",")
        try:
            if len(cells) != len(header) or "_" in line:  # float() reads 1_0e-4 as 1e-3
                raise ValueError
            values.append((float(cells[it]), float(cells[ic])))
        except ValueError:
            raise CommandError(f"{where}: data row {i}: expected {len(header)} numbers "
                               f"({','.join(header)}), got {line[:40]!r}") from None
    arr = np.array(values, dtype=np.float64).reshape(-1, 2)
    t, com = arr[:, 0], arr[:, 1]
    if t.size < 2:
        raise CommandError(f"{where}: at least 2 samples needed, got {t.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(com))):
        bad = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(com)))[0]) + 1
        raise CommandError(f"{where}: data row {bad}: not a finite number (NaN or inf)")
    if abs(t[0]) > 1e-9:
        raise CommandError(f"{where}: t must start at 0 s, starts at {t[0]:g} s")
    steps = np.diff(t)
    if np.any(steps <= 0):
        bad = int(np.flatnonzero(steps <= 0)[0]) + 2
        raise CommandError(f"{where}: data row {bad}: t must increase strictly "
                           f"({t[bad - 2]:g} then {t[bad - 1]:g} s)")
    worst = int(np.argmax(np.abs(com)))
    if abs(com[worst]) > MAX_FILE_STROKE:
        raise CommandError(f"{where}: data row {worst + 1}: com = {com[worst]:g} m is beyond "
                           f"the stroke; allowed range [-{MAX_FILE_STROKE:g}, "
                           f"{MAX_FILE_STROKE:g}] m")
    return Command("array", {}, f"{path.stem}-{digest[:8]}", (t, com), "linear")


def default_duration(command: "Command | str", fallback: float = 1.0) -> float:
    """How long to run ``command`` when no duration is given [s]: a command file's own length
    (a 0.5-s design is simulated and checked for 0.5 s, not half of it at rest), else
    ``fallback``."""
    if isinstance(command, str) and not is_command_file(command):
        return fallback
    cmd = as_command(command)
    if cmd.kind == "array" and cmd.samples is not None:
        return float(cmd.samples[0][-1])
    return fallback


def write_command_file(path: str | Path, t: np.ndarray, com: np.ndarray,
                       settings: Mapping[str, Any] | None = None) -> Path:
    """Write a command file (:func:`load_command_file`'s format), whole or not at all."""
    from eha.outputs import write_atomic

    path = Path(path)
    lines = [f"# {k} = {v}" for k, v in (settings or {}).items()]
    lines.append("t,com")
    lines += [f"{a:.6f},{b:.9g}" for a, b in zip(np.asarray(t), np.asarray(com))]
    return write_atomic(path, "\n".join(lines) + "\n")  # a temporary name of its own

