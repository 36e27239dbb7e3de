"""The residual loop's null: how far each effect's fit goes on *healthy* actuators driven by
the record's own command.

An effect is added by the loop (:mod:`eha.explain.loop`) only when the refit moves its
parameter further from its off value than healthy actuators move it on the same command,
sampled and noised like the record: a fixed tolerance would be the worst case over every
command (a viscous friction of 1.2e4 N·s/m hides a real one on a chirp that a healthy jack
never fits above a few hundred). The null is

1. a **healthy fleet simulated** on the record's command (:func:`simulated_null`): HF
   actuators with the manufacturing scatter of ``eha health calibrate``
   (:data:`eha.identification.healthy.DISPERSION`), the declared faults drawn over a typical range
   (:data:`DECLARED_DRAW`), the HF's dither, the record's noise level (position and, when the
   record has one, P12), sampling and command hold; or the user's own **healthy records**
   (:func:`records_null`, ``eha explain --healthy DIR``: commissioning tests of their
   actuators, whose scatter is the better null);
2. on each healthy record, the loop's own candidate test (:func:`eha.explain.healthy_fleet.healthy_statistics`): the
   declared faults and the model's known structure fitted (the state of the loop once it has
   added the structure), then each library effect refitted on top by the loop's local test
   (:meth:`eha.explain.fitting.Fitter.local_test`: least squares from the effect off and
   from its probe, the better fit); the statistic is the parameter's distance from its off value
   (:meth:`eha.explain.effects.Effect.shift`), or for an effect whose parameters trade (the
   supply pressure and its law) its footprint on the record, the RMS change of the position
   it makes (:attr:`eha.explain.effects.Effect.footprint`);
3. per effect, the threshold of the shared detection engine
   (:func:`eha.identification.healthy.tail_threshold`): a normal tail with probability ``alpha /
   m`` for ``m`` effects, so that a healthy record passes *any* effect's gate with probability at
   most ``alpha`` (union bound) — the same rule as ``eha health calibrate``'s thresholds.

Simulated nulls are cached on disk (:func:`cache_dir`), keyed by the command's samples, the
sampling, the noise, the declared faults, the loop's fit settings and the model version
(:data:`eha.models.simulate.MODEL_VERSION`); the statistics are stored, so any ``alpha`` reuses
them. Those of the command presets, logged as eha logs them, are shipped with eha
(:func:`shipped_null`, :mod:`eha.explain.library_nulls`). The null's constants (:data:`DECLARED_DRAW`, ...) are in :mod:`eha.explain.settings`.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from multiprocessing import get_context
from pathlib import Path
from statistics import NormalDist
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from eha.explain.settings import (DECLARED_DRAW, DEFAULT_ACTUATORS, DETECTION_POWER,
                                  FOOTPRINT_RESOLUTION,
                                  MIN_RECORDS, RATIO_SPREAD,
                                  RESOLUTION, STRUCTURAL)
from eha.errors import InputError
from eha.models import use_one_numba_thread
from eha.explain.healthy_fleet import _fleet_member, healthy_statistics
from eha.explain.replicates import started_effects
from eha.explain.simulated_record import noise_class
from eha.identification.healthy import command_signature, tail_threshold

#: Version of the cached null's format (and of the procedure: a change invalidates caches).
NULL_FORMAT = 8   # 8: the supply pressure's footprint and PSR shift; 6: its law (XSSK)


class NullError(InputError):
    """Bad null input (``--healthy`` folder, too few records); one-line message."""


def cache_dir() -> Path:
    """Folder of cached nulls: ``$EHA_CACHE_DIR/explain-null`` or
    ``~/.cache/eha/explain-null``."""
    root = os.environ.get("EHA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache"), "eha")
    return Path(root) / "explain-null"


@dataclass
class Null:
    """Healthy statistics of each effect on one command (see the module docstring).

    Attributes
    ----------
    source : str
        What the healthy records were (``"simulated healthy fleet (20 actuators, seed 0)"``
        or ``"healthy records in DIR (12)"``).
    key : str
        Cache key (empty for user records).
    statistics : dict of str to list of float
        Per effect, its :meth:`~eha.explain.effects.Effect.shift` on each healthy record (the
        parameter's unit).
    gains : dict of str to list of float
        Per effect, the relative RMSE reduction its refit brought on each healthy record.
    residual_ratios : list of float
        Per healthy record, the residual of its faults and structure over its noise.
    resolution : dict of str to float
        Per effect, the smallest spread of its statistic (:data:`RESOLUTION` of its range).
    units : dict of str to str
        Per effect, the unit of its statistic.
    seconds : float
        Wall time of the calibration [s].
    """

    source: str
    key: str
    statistics: dict[str, list[float]]
    gains: dict[str, list[float]]
    resolution: dict[str, float]
    units: dict[str, str]
    records: int
    seconds: float
    residual_ratios: list[float] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    model_version: str = ""
    created_at: str = ""
    format: int = NULL_FORMAT

    def thresholds(self, alpha: float) -> dict[str, float]:
        """Per statistic (an effect's, and the second of one tested by its footprint: its
        :attr:`~eha.explain.effects.Effect.shift_key`), the value a healthy record exceeds
        with probability ``alpha / m`` (``m`` statistics;
        :func:`eha.identification.healthy.tail_threshold`)."""
        m = max(len(self.statistics), 1)
        return {name: tail_threshold(values, alpha / m, self.resolution.get(name, 0.0))[0]
                for name, values in self.statistics.items()}

    def detectable(self, alpha: float, power: float = DETECTION_POWER) -> dict[str, float]:
        """Per effect, the shift from off that its fit exceeds the threshold with probability
        ``power``, assuming the fit scatters about a real effect as about a healthy one: the
        threshold plus the ``power`` quantile of the healthy spread. An estimate of the
        loop's minimum detectable effect on this command; ``validation/explain_power.py``
        measures it."""
        z = NormalDist().inv_cdf(power)
        m = max(len(self.statistics), 1)
        out = {}
        for name, values in self.statistics.items():
            threshold, summary = tail_threshold(values, alpha / m,
                                                self.resolution.get(name, 0.0))
            out[name] = threshold + z * summary["scale"]
        return out

    def residual_limit(self, alpha: float) -> float:
        """The residual-to-noise ratio that faults and structure leave on a healthy record of
        this command with probability ``alpha`` (:func:`eha.identification.healthy.tail_threshold`,
        spread :data:`RATIO_SPREAD`), at most :data:`eha.identification.intervals.FLAG_RATIO`: a
        record whose final model leaves more is unexplained. Without ratios (an older null): the
        flag ratio."""
        from eha.identification.intervals import FLAG_RATIO

        if len(self.residual_ratios) < 2:
            return FLAG_RATIO
        return min(FLAG_RATIO, tail_threshold(self.residual_ratios, alpha, RATIO_SPREAD)[0])

    def summary(self, alpha: float) -> dict[str, Any]:
        """The JSON of the null for a report: source, thresholds, detectable sizes."""
        thr, det = self.thresholds(alpha), self.detectable(alpha)
        effects = {name: {"threshold": thr[name], "detectable": det[name],
                          "unit": self.units.get(name, ""),
                          "healthy_max": float(np.max(v)) if v else math.nan}
                   for name, v in self.statistics.items() if "." not in name}
        for key, v in self.statistics.items():
            if "." in key and key.split(".")[0] in effects:
                name, param = key.split(".", 1)
                effects[name]["shift"] = {"param": param, "threshold": thr[key],
                                          "detectable": det[key],
                                          "unit": self.units.get(key, ""),
                                          "healthy_max": float(np.max(v)) if v else math.nan}
        return {"source": self.source, "key": self.key, "records": self.records,
                "alpha": alpha, "seconds": self.seconds,
                "healthy_residual_ratio": [float(np.min(self.residual_ratios)),
                                           float(np.max(self.residual_ratios))]
                if self.residual_ratios else None,
                "residual_limit": self.residual_limit(alpha),
                "effects": effects}

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(asdict(self), indent=1))
        tmp.replace(path)           # atomic: two processes calibrating alike both succeed
        return path


#: Nulls calibrated in advance for the command presets (:mod:`eha.explain.library_nulls`).
SHIPPED_DIR = Path(__file__).resolve().parent / "nulls"


def shipped_null(key: str) -> Null | None:
    """The null of cache key ``key`` shipped with eha (:mod:`eha.explain.library_nulls`), or
    None (none shipped, or stale: :func:`load_null` checks its format and model version)."""
    null = load_null(SHIPPED_DIR / f"{key}.json") if key else None
    if null is not None:
        null.source += (f", calibrated in advance for the preset "
                        f"{null.settings.get('library_command', '?')} and shipped with eha")
    return null


def load_null(path: str | Path) -> Null | None:
    """A cached null, or None when the file is missing, damaged or of another format."""
    from eha.models.simulate import MODEL_VERSION

    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        null = Null(**data)
    except (OSError, ValueError, TypeError):
        return None
    if null.format != NULL_FORMAT or null.model_version != MODEL_VERSION:
        return None
    return null


def null_key(data, fit: Mapping[str, tuple[float, float]], effects: Sequence[str], settings,
             actuators: int, seed: int, base=None, fixed: Sequence[str] = (),
             fdi_options: Mapping[str, float] | None = None) -> str:
    """Cache key of a simulated null for ``data``'s command, sampling and noise."""
    from eha.identification.measured import noise_level
    from eha.models.simulate import MODEL_VERSION

    noise = noise_class(float(data.info.get("noise_m", noise_level(data.xu))))
    parts = {
        "format": NULL_FORMAT, "model": MODEL_VERSION,
        "command": command_signature(np.asarray(data.command.samples[1])),
        "command_t": command_signature(np.asarray(data.command.samples[0]) * 1e4),
        "hold": data.info.get("command_hold", ""),
        "noise": f"{noise:.4g}",
        "p12_noise": f"{noise_class(noise_level(data.p12)):.4g}" if data.p12 is not None
        else "",
        "fit": {k: [float(v[0]), float(v[1])] for k, v in sorted(fit.items())},
        "effects": sorted(effects),
        "settings": {k: getattr(settings, k) for k in ("holdout", "p12_weight", "method",
                                                          "pop", "seed", "penalty",
                                                          "flow_gain_spread")},
        "actuators": actuators, "fleet_seed": seed,
        "declared": DECLARED_DRAW,
        "base": _changed(base), "fixed": sorted(fixed),
        "fdi_options": dict(sorted((fdi_options or {}).items())),
    }
    started = started_effects(base, fit)
    if started:
        # the fleet carries the effects the base starts with (healthy_fleet.fleet_actuator)
        parts["started"] = started
    blob = json.dumps(parts, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:20]


def _changed(base) -> dict[str, float]:
    """The parameters of an LF base that differ from nominal (a prior's effects)."""
    if base is None:
        return {}
    from dataclasses import fields as dc_fields

    from eha.models.params import LFParams

    nominal = LFParams()
    return {f.name: getattr(base, f.name) for f in dc_fields(base)
            if f.name != "XJ0" and getattr(base, f.name) != getattr(nominal, f.name)}


def statistic_keys(effects: Sequence[str]) -> list[str]:
    """The null's statistics of ``effects``: each effect's name, and for one tested by its
    footprint also its parameter's shift (:attr:`~eha.explain.effects.Effect.shift_key`)."""
    from eha.explain.effects import EFFECTS

    keys = []
    for name in effects:
        keys.append(name)
        if EFFECTS[name].shift_key:
            keys.append(EFFECTS[name].shift_key)
    return keys


def _units(effects: Sequence[str]) -> tuple[dict[str, str], dict[str, float]]:
    from eha.explain.effects import EFFECTS

    units, resolution = {}, {}
    for name in effects:
        effect = EFFECTS[name]
        param = effect.tested
        lo, hi = effect.bounds[param]
        units[name] = effect.statistic_unit
        resolution[name] = FOOTPRINT_RESOLUTION if effect.footprint else RESOLUTION * (hi - lo)
        if effect.shift_key:
            units[effect.shift_key] = effect.units()[param]
            resolution[effect.shift_key] = RESOLUTION * (hi - lo)
    return units, resolution


def covered_effects(effects: Sequence[str]) -> list[str]:
    """The effects a null covers: those with a tested parameter
    (:attr:`~eha.explain.effects.Effect.tested`) that are not the model's known structure."""
    from eha.explain.effects import EFFECTS

    return [n for n in effects if n not in STRUCTURAL and EFFECTS[n].tested is not None]


def simulated_null(data, fit: Mapping[str, tuple[float, float]], effects: Sequence[str],
                   settings, actuators: int = DEFAULT_ACTUATORS, seed: int = 0,
                   workers: int | None = None, use_cache: bool = True, base=None,
                   fixed: Sequence[str] = (), fdi_options: Mapping[str, float] | None = None,
                   on_progress: Callable[[str], None] | None = None) -> Null:
    """The null of ``data``'s command from a simulated healthy fleet (cached).

    Parameters
    ----------
    data : MeasuredData
        The record whose command, sampling and noise the fleet copies.
    fit : mapping
        The declared faults and their bounds (fitted on every healthy record).
    effects : names
        The candidate effects (those :func:`covered_effects` get statistics).
    settings : LoopSettings
        The loop's settings (the fits of the null are the loop's).
    actuators : int
        Healthy actuators; actuator ``k`` has seed ``1000 * seed + k``.
    workers : int, optional
        Processes (default: the machine's cores, at most 2 per calibration).
    base, fixed : optional
        The loop's starting LF parameters and its known ones: every actuator carries the
        known test conditions and the effects ``base`` starts with (a prior's:
        :func:`eha.explain.healthy_fleet.fleet_actuator`), and is fitted from ``base``.
    """
    from eha.models.simulate import MODEL_VERSION

    names = covered_effects(effects)
    if actuators < MIN_RECORDS:
        raise NullError(f"`null_actuators` {actuators}: allowed range [{MIN_RECORDS}, ...]")
    key = null_key(data, fit, names, settings, actuators, seed, base, fixed, fdi_options)
    path = cache_dir() / f"{key}.json"
    if use_cache:
        cached = load_null(path) or shipped_null(key)
        if cached is not None:
            return cached
    t0 = time.perf_counter()
    seeds = [1000 * seed + k for k in range(actuators)]
    jobs = [(data, dict(fit), names, settings, s, base, tuple(fixed), dict(fdi_options or {}))
            for s in seeds]
    workers = workers or min(2, os.cpu_count() or 1)
    results = []
    say = _fleet_progress(on_progress, actuators, t0)
    say(0)
    if workers <= 1:
        for job in jobs:
            results.append(_fleet_member(job))
            say(len(results))
    else:
        # spawned workers with one numba thread each (the LF batch kernel is parallel, and a
        # forked copy of an initialised threading layer is not safe), set in each worker
        # before numba is imported there: the parent's environment is not touched, so a
        # parent whose threading layer is already up never sees the variable change
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"),
                                 initializer=use_one_numba_thread) as pool:
            for res in pool.map(_fleet_member, jobs):
                results.append(res)
                say(len(results))
    null = _assemble(f"simulated healthy fleet ({actuators} actuators, seed {seed})", key,
                     names, results, time.perf_counter() - t0)
    null.settings = {"actuators": actuators, "seed": seed, "seeds": seeds,
                     "declared": {k: list(v) for k, v in DECLARED_DRAW.items()}}
    null.model_version = MODEL_VERSION
    if use_cache:
        null.save(path)
    return null


def _fleet_progress(on_progress: Callable[[str], None] | None, actuators: int, t0: float
                    ) -> Callable[[int], None]:
    """``say(k)``: the healthy fleet's progress after ``k`` actuators, with an estimate of the
    time left (``healthy null of this command (once, then cached): actuator 4 of 12 done,
    about 1 min 20 s left``)."""
    from eha.models.units import duration

    def say(done: int) -> None:
        if on_progress is None:
            return
        head = "healthy null of this command (once, then cached)"
        if done == 0:
            on_progress(f"{head}: simulating and fitting {actuators} healthy actuators")
            return
        left = (time.perf_counter() - t0) / done * (actuators - done)
        on_progress(f"{head}: actuator {done} of {actuators} done"
                    + (f", about {duration(left)} left" if done < actuators else ""))
    return say


def _assemble(source: str, key: str, names: Sequence[str],
              results: Sequence[tuple[dict[str, float], dict[str, float], float]],
              seconds: float) -> Null:
    units, resolution = _units(names)
    keys = statistic_keys(names)
    stats = {n: [float(r[0][n]) for r in results if n in r[0]] for n in keys}
    gains = {n: [float(r[1][n]) for r in results if n in r[1]] for n in names}
    return Null(source=source, key=key, statistics=stats, gains=gains, resolution=resolution,
                units=units, records=len(results), seconds=seconds,
                residual_ratios=[float(r[2]) for r in results],
                created_at=datetime.now(timezone.utc).isoformat(timespec="seconds"))


#: How far a user's healthy record may be from the record it is the null of (issue 43): its
#: duration [relative], sampling period [relative], command [RMS difference on the common
#: 1 kHz grid, relative to the record's command peak] and noise [factor, either way].
MATCH_DURATION = 0.02
MATCH_PERIOD = 0.2
MATCH_COMMAND = 0.05
MATCH_NOISE = 2.0
#: Noise below which two records' noise is not compared [m] (noise-free simulations).
NOISE_FLOOR = 1e-8


def record_mismatch(healthy, record) -> str | None:
    """Why the healthy record ``healthy`` is not a null of ``record`` (both
    :class:`~eha.identification.measured.MeasuredData`), naming the field; None when it
    matches: the same length, sampling, command and noise class (within :data:`MATCH_*`).
    The null's thresholds and detectable sizes hold for the command, length and noise it was
    built on only."""
    d_rec, d_h = record.t_end, healthy.t_end
    if abs(d_h - d_rec) > MATCH_DURATION * d_rec + 1e-3:
        return (f"length {d_h:g} s, the record {d_rec:g} s (allowed within "
                f"{100 * MATCH_DURATION:g} %)")
    p_rec, p_h = record.info.get("period_s"), healthy.info.get("period_s")
    if p_rec and p_h and abs(p_h / p_rec - 1) > MATCH_PERIOD:
        return (f"sampling {1 / p_h:.4g} Hz, the record {1 / p_rec:.4g} Hz (allowed within "
                f"{100 * MATCH_PERIOD:g} %)")
    n = min(len(record), len(healthy))
    peak = float(np.max(np.abs(record.com[:n]))) or 1.0
    diff = float(np.sqrt(np.mean((healthy.com[:n] - record.com[:n]) ** 2))) / peak
    if diff > MATCH_COMMAND:
        return (f"command differs from the record's by {100 * diff:.3g} % RMS of its peak "
                f"(allowed {100 * MATCH_COMMAND:g} %): another command")
    n_rec = float(record.info.get("noise_m", 0.0))
    n_h = float(healthy.info.get("noise_m", 0.0))
    if max(n_rec, n_h) > NOISE_FLOOR and not (n_rec / MATCH_NOISE <= n_h <= n_rec * MATCH_NOISE):
        return (f"noise {1e6 * n_h:.3g} µm, the record {1e6 * n_rec:.3g} µm (another noise "
                f"class; allowed within a factor {MATCH_NOISE:g})")
    return None


def records_null(folder: str | Path, fit: Mapping[str, tuple[float, float]],
                 effects: Sequence[str], settings, command_hold: str = "auto", base=None,
                 fixed: Sequence[str] = (), fdi_options: Mapping[str, float] | None = None,
                 on_progress: Callable[[str], None] | None = None, record=None) -> Null:
    """The null from the user's own healthy records (every CSV/TSV/TXT/Parquet file in
    ``folder``): each is fitted as :func:`healthy_statistics` fits a simulated one.
    Not cached (the files are the user's). A :class:`eha.identification.columns.RecordFile` folder reads
    its records with its columns and units. With ``record`` (the record the null is for),
    each healthy record must match it (:func:`record_mismatch`), checked before any fit."""
    from eha.identification.measured import FILE_TYPES, MeasuredDataError, load, same_format
    from eha.models.simulate import MODEL_VERSION

    spec, folder = folder, Path(folder)
    if not folder.is_dir():
        raise NullError(f"`null` {folder}: not a folder")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in FILE_TYPES)
    if len(files) < MIN_RECORDS:
        raise NullError(f"`null` {folder}: {len(files)} records; at least {MIN_RECORDS} "
                        f"healthy records are needed")
    records = []
    for path in files:
        try:
            records.append(load(same_format(spec, path), command_hold))
        except MeasuredDataError as exc:
            raise NullError(f"`null` {path}: {'; '.join(exc.problems)}") from None
        why = None if record is None else record_mismatch(records[-1], record)
        if why is not None:
            raise NullError(f"`null` {path}: {why}; a healthy null must be records of the "
                            f"same test as {Path(str(record.source)).name}") from None
    names = covered_effects(effects)
    t0 = time.perf_counter()
    results = []
    for k, record in enumerate(records):
        if on_progress:
            on_progress(f"healthy null: record {k + 1} of {len(records)}")
        results.append(healthy_statistics(record, fit, names, settings, base, fixed,
                                          fdi_options))
    null = _assemble(f"healthy records in {folder} ({len(records)})", "", names, results,
                     time.perf_counter() - t0)
    null.settings = {"files": [p.name for p in files]}
    null.model_version = MODEL_VERSION
    return null


__all__ = ["Null", "NullError", "simulated_null", "records_null", "statistic_keys",
           "load_null", "shipped_null", "cache_dir", "null_key", "covered_effects", "NULL_FORMAT"]
