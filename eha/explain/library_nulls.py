"""Healthy nulls shipped with eha for the library's command presets (issue 42, item 6).

A record's first run on a new command calibrates that command's healthy null
(:func:`eha.explain.null.simulated_null`: 12 healthy actuators simulated and fitted, about a
minute on 2 cores, then cached). For the command presets (:data:`eha.models.commands.PRESETS`)
logged as eha logs them, the null is calibrated in advance and shipped in ``eha/explain/nulls/``:
one file per preset, for a record of :data:`LIBRARY_T_END` seconds at 1 kHz with a position noise
in the class of :data:`LIBRARY_NOISE` (0.79-1.26 µm, :func:`eha.explain.simulated_record.noise_class`),
the loop's default settings, declared faults and candidate effects, and no P12. The shipped file
is the null such a record would calibrate (the same key, :func:`eha.explain.null.null_key`, the
same procedure and seeds): a record that differs in any of these calibrates its own as before.

Regenerate them after a change of the null's procedure or of the model (:data:`NULL_FORMAT`,
``MODEL_VERSION``; a test fails while a shipped null is stale)::

    python -m eha.explain.library_nulls            # all presets (about 1 min each on 2 cores)
    python -m eha.explain.library_nulls mixed ramp
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path
from typing import Sequence

from eha.explain.null import NULL_FORMAT, SHIPPED_DIR

#: Length [s] and position noise [m] of the records the shipped nulls are for.
LIBRARY_T_END = 1.0
LIBRARY_NOISE = 1e-6


def library_record(command: str):
    """A healthy record of the preset ``command`` as the shipped nulls assume it: the HF at
    nominal, :data:`LIBRARY_T_END` s at 1 kHz, white noise of :data:`LIBRARY_NOISE` (seed 0),
    written to CSV and read back as ``eha explain`` reads a record."""
    from eha.identification.measured import load
    from eha.identification.synthetic import synthetic_record

    frame = synthetic_record(command, {}, t_end=LIBRARY_T_END, noise=LIBRARY_NOISE, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{command}.csv"
        frame.to_csv(path, index=False)
        return load(path)


def _null_arguments(data):
    """``(fit, effects)`` of :func:`eha.explain.api.healthy_null` for ``data`` at the loop's
    defaults."""
    from eha.explain.problem import Problem

    problem = Problem.build(data)
    return problem.bounds, [e.name for e in problem.pool]


def library_key(command: str) -> str:
    """The cache key of the null of :func:`library_record` ``(command)``."""
    from eha.explain.null import covered_effects, null_key
    from eha.explain.settings import LoopSettings

    data = library_record(command)
    fit, names = _null_arguments(data)
    settings = LoopSettings()
    return null_key(data, fit, covered_effects(names), settings, settings.null_actuators, 0,
                    None, [], {})


def calibrate(commands: Sequence[str], say=print) -> list[Path]:
    """Calibrate the null of each preset of ``commands`` afresh and write it to
    :data:`SHIPPED_DIR`; returns the files written."""
    from eha.explain.null import simulated_null
    from eha.explain.settings import LoopSettings

    settings = LoopSettings()
    SHIPPED_DIR.mkdir(parents=True, exist_ok=True)
    written = []
    for command in commands:
        data = library_record(command)
        fit, names = _null_arguments(data)
        null = simulated_null(data, fit, names, settings, actuators=settings.null_actuators,
                              fixed=[], fdi_options={}, use_cache=False)
        null.settings["library_command"] = command
        written.append(null.save(SHIPPED_DIR / f"{null.key}.json"))
        say(f"{command}: {null.key} ({null.seconds:.0f} s, format {NULL_FORMAT})")
    return written


def main(argv: Sequence[str] | None = None) -> None:
    from eha.models.commands import PRESETS

    names = list(argv if argv is not None else sys.argv[1:]) or list(PRESETS)
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        raise SystemExit(f"not a command preset: {', '.join(unknown)} (presets: "
                         f"{', '.join(PRESETS)})")
    keep = {library_key(n) for n in PRESETS if n not in names}
    for old in SHIPPED_DIR.glob("*.json"):       # a preset's older null (another key) goes
        if old.stem not in keep:
            old.unlink()
    calibrate(names)


if __name__ == "__main__":
    main()
