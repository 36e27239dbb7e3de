"""Python API of the models: :func:`simulate` returns a :class:`Trace` at 1 kHz
(docs/model.md §8)."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from eha.models.commands import Command, as_command
from eha.models import O_COM, O_P12, O_T, O_XU, OUTPUTS
from eha.trace import Trace
from eha.models.hf import dither_samples, run_hf, run_hf_batch
from eha.models.lf import run_lf, run_lf_batch
from eha.models.params import ModelParams, ParameterError, resolve

#: Recorded sample period [s] (thesis: 100*DT).
OUTPUT_DT = 1e-3
#: Bumped whenever a kernel's equations change; part of every campaign run key.
MODEL_VERSION = "2"   # 2: XSSK, the supply-pressure law


def check_grid(params: ModelParams, t_end: float) -> tuple[int, int, int]:
    """``(steps_per_out, n_out, n_steps)`` of a run, checked but not allocated (a campaign
    validates t_end = 3600 s without building its 3.6e8-step grid)."""
    if not np.isfinite(t_end) or not 1e-3 <= t_end <= 3600.0:
        raise ParameterError(f"t_end={t_end:g} is out of range; allowed range [0.001, 3600] s")
    steps_per_out = int(round(OUTPUT_DT / params.DT))
    n_intervals = int(round(t_end / OUTPUT_DT))
    return steps_per_out, n_intervals + 1, n_intervals * steps_per_out + 1


def _grid(params: ModelParams, t_end: float) -> tuple[int, int, np.ndarray]:
    steps_per_out, n_out, n_steps = check_grid(params, t_end)
    return steps_per_out, n_out, np.arange(n_steps) * params.DT


def measure(t: np.ndarray, xu: np.ndarray, params: ModelParams) -> np.ndarray:
    """Recorded position: ``gain*XU(t - delay) + bias`` (sensor effects, docs/model.md §6)."""
    y = xu
    if params.sensor_delay > 0.0:
        y = np.interp(t - params.sensor_delay, t, xu, left=xu[0])
    if params.sensor_gain != 1.0:
        y = params.sensor_gain * y
    if params.sensor_bias != 0.0:
        y = y + params.sensor_bias
    return y


def _params(model: str, params: ModelParams | Mapping[str, float] | None) -> ModelParams:
    if isinstance(params, ModelParams):
        if params.model != model:
            raise ParameterError(f"params: a {params.model.upper()} parameter set was given to "
                                 f"the {model.upper()} model")
        return params
    return resolve(model, params or {})


def command_on_grid(command: Command | str, t_steps: np.ndarray) -> np.ndarray:
    """The command sampled at every integration step (contiguous float64)."""
    return np.ascontiguousarray(as_command(command).sample(t_steps, uniform=True),
                                dtype=np.float64)


def simulate(model: str, command: Command | str = "mixed",
             params: ModelParams | Mapping[str, float] | None = None,
             t_end: float = 1.0, seed: int = 0) -> Trace:
    """Simulate the HF or LF model.

    Parameters
    ----------
    model : {"hf", "lf"}
    command : Command or str
        A :class:`~eha.models.commands.Command` or a preset name (``eha commands``).
    params : ModelParams or mapping, optional
        Parameter set, or overrides of the nominal one by name (``{"BKL": 1e-4}``).
    t_end : float
        Simulated time [s]; the trace has ``round(t_end/1e-3) + 1`` samples.
    seed : int
        Seed of the HF dither (the only random input); recorded in ``Trace.meta``.

    Returns
    -------
    Trace
    """
    p = _params(model, params)
    cmd = as_command(command)
    steps_per_out, n_out, t_steps = _grid(p, t_end)
    com = command_on_grid(cmd, t_steps)
    out = np.empty((n_out, len(OUTPUTS)))
    vec = p.to_array()
    if model == "hf":
        run_hf(vec, com, dither_samples(p.dither_ma, n_out - 1, seed), steps_per_out, out)
    else:
        run_lf(vec, com, steps_per_out, out)
    out[:, O_XU] = measure(out[:, O_T], out[:, O_XU], p)
    nominal = type(p)()
    changed = {k: v for k, v in p.as_dict().items() if getattr(nominal, k) != v}
    meta = {"model": model, "command": cmd.describe(), "params": changed, "seed": int(seed),
            "t_end": float(t_end), "model_version": MODEL_VERSION}
    return Trace(out, meta)


def simulate_hf_batch(params: Sequence[Mapping[str, float]], command: Command | str,
                      t_end: float, seeds: Sequence[int]) -> np.ndarray:
    """The HF model for many parameter sets on one command, in one parallel numba call.

    Parameters
    ----------
    params : sequence of mappings
        Overrides of the nominal HF parameters, one per run (the same integration step DT).
    seeds : sequence of int
        Dither seed of each run.

    Returns
    -------
    float64 array, shape (n, n_out, len(OUTPUTS)): what :func:`simulate` records for each run
    (the position through the sensor).
    """
    sets = [_params("hf", p) for p in params]
    if len(sets) != len(seeds) or not sets:
        raise ParameterError("simulate_hf_batch: one seed per parameter set, at least one")
    if len({p.DT for p in sets}) != 1:
        raise ParameterError("simulate_hf_batch: every run needs the same integration step DT")
    steps_per_out, n_out, t_steps = _grid(sets[0], t_end)
    com = command_on_grid(as_command(command), t_steps)
    rows = np.stack([p.to_array() for p in sets])
    dithers = np.stack([dither_samples(p.dither_ma, n_out - 1, int(s))
                        for p, s in zip(sets, seeds)])
    out = np.empty((len(sets), n_out, len(OUTPUTS)))
    run_hf_batch(rows, com, dithers, steps_per_out, out)
    for j, p in enumerate(sets):
        out[j, :, O_XU] = measure(out[j, :, O_T], out[j, :, O_XU], p)
    return out


def simulate_lf_rows(params: Sequence[Mapping[str, float]], command: Command | str,
                     t_end: float) -> np.ndarray:
    """The LF model for many parameter sets on one command, in one parallel numba call:
    what :func:`simulate` records for each (shape ``(n, n_out, len(OUTPUTS))``)."""
    sets = [_params("lf", p) for p in params]
    if not sets or len({p.DT for p in sets}) != 1:
        raise ParameterError("simulate_lf_rows: at least one run, every run with the same DT")
    steps_per_out, n_out, t_steps = _grid(sets[0], t_end)
    com = command_on_grid(as_command(command), t_steps)
    out = np.empty((len(sets), n_out, len(OUTPUTS)))
    run_lf_batch(np.stack([p.to_array() for p in sets]), com, steps_per_out, out)
    for j, p in enumerate(sets):
        out[j, :, O_XU] = measure(out[j, :, O_T], out[j, :, O_XU], p)
    return out


def xj0_for_recorded(recorded_start: float, sensor_bias, sensor_gain, XJM):
    """Initial jack position [m] at which the *recorded* position (``gain*XU + bias``) equals
    ``recorded_start``, within the stroke ``±XJM`` (scalars or arrays)."""
    return np.clip((recorded_start - np.asarray(sensor_bias)) / np.asarray(sensor_gain),
                   -np.asarray(XJM), np.asarray(XJM))


def simulate_lf_batch(param_rows: np.ndarray, com: np.ndarray, steps_per_out: int,
                      n_out: int, base: ModelParams,
                      recorded_start: float | None = None, with_p12: bool = False):
    """Recorded LF position for many parameter vectors in one parallel numba call.

    Parameters
    ----------
    param_rows : float64 array, shape (n, n_par)
        LF parameter vectors (``LFParams.to_array`` order).
    com : float64 array
        Command on the step grid (:func:`command_on_grid`).
    base : LFParams
        Source of the sensor parameters when they are not varied (they are read per row).
    recorded_start : float, optional
        Start each row at rest where its recorded position is this value [m] (XJ0 from the
        row's sensor bias and gain, :func:`xj0_for_recorded`) instead of at its XJ0: a record
        that starts away from its command starts at its measured position.

    with_p12 : bool
        Also return the load pressure P12 of each row (the sensor does not touch it).

    Returns
    -------
    float64 array, shape (n, n_out): recorded xu of each row; with ``with_p12`` the pair
    ``(xu, p12)``, P12 in Pa.
    """
    from eha.models.params import LF

    out = np.empty((param_rows.shape[0], n_out, len(OUTPUTS)))
    if recorded_start is not None:
        param_rows = np.array(param_rows, dtype=np.float64)
        param_rows[:, LF.XJ0] = xj0_for_recorded(recorded_start, param_rows[:, LF.sensor_bias],
                                                 param_rows[:, LF.sensor_gain],
                                                 param_rows[:, LF.XJM])
    run_lf_batch(np.ascontiguousarray(param_rows), com, steps_per_out, out)

    xu = out[:, :, O_XU]
    t = out[0, :, O_T]
    for j in range(param_rows.shape[0]):
        row = param_rows[j]
        if row[LF.sensor_delay] or row[LF.sensor_gain] != 1.0 or row[LF.sensor_bias]:
            xu[j] = measure(t, xu[j], base.replace(
                sensor_delay=row[LF.sensor_delay], sensor_gain=row[LF.sensor_gain],
                sensor_bias=row[LF.sensor_bias]))
    if with_p12:
        return np.ascontiguousarray(xu), np.ascontiguousarray(out[:, :, O_P12])
    return np.ascontiguousarray(xu)


def grid(params: ModelParams, t_end: float) -> tuple[int, int, np.ndarray]:
    """``(steps_per_out, n_out, t_steps)`` of a run: the step grid for :func:`command_on_grid`."""
    return _grid(params, t_end)


__all__ = ["Trace", "simulate", "simulate_lf_batch", "command_on_grid", "grid", "measure",
           "xj0_for_recorded",
           "OUTPUT_DT", "MODEL_VERSION", "O_COM"]
