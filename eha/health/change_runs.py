"""The change calibration's HF runs: a pair's records, a fault grown on an actuator, and the
runs that measure how each fault's linear estimate responds to the true change (the gain
curves), what one fault leaves in the others' readings beside it (the leaks) and how far a
second fault's reading beside the first strays when both have grown (the interactions).

Every run is the later record of one of the calibration's first :data:`GAIN_ACTUATORS`
actuators with faults grown, minus the same record without them (the same noise and dither
seed: the noise cancels), so the figures are the faults' own responses.
"""

from __future__ import annotations

from itertools import product
from typing import Mapping, Sequence

import numpy as np

from eha.health.change import GAIN_SIZES, GainCurve, Signatures, draw_test_day, probe
from eha.identification.healthy import draw_actuator
from eha.models.faults import FAULTS

#: Actuators on which each fault's HF gain is measured (the first of the calibration's).
GAIN_ACTUATORS = 8
#: The later record of actuator ``s`` is recorded with noise and dither seed ``s + SHIFT``.
LATER_SEED_SHIFT = 2**30


def later_seed(seed: int) -> int:
    """Noise and dither seed of the later record of the actuator of ``seed``."""
    return (int(seed) + LATER_SEED_SHIFT) % 2**31


def sign_of(name: str) -> float:
    """+1 or -1: the direction of degradation of fault ``name`` (+1 for the offset)."""
    return -1.0 if FAULTS[name].direction < 0 else 1.0


def _record(command, hf: Mapping[str, float], t_end: float, noise: float, seed: int):
    from eha.identification.measured import from_arrays
    from eha.identification.synthetic import synthetic_record

    df = synthetic_record(command, dict(hf), t_end=t_end, noise=noise, seed=seed)
    return from_arrays(df["t"].to_numpy(), df["com"].to_numpy(), df["xu"].to_numpy(),
                       source="calibration")


def _positions(command, runs: Sequence[tuple[Mapping[str, float], int]], t_end: float,
               noise: float) -> np.ndarray:
    """The recorded positions of many ``(hf, seed)`` runs (rows in order), each what
    ``_record(command, hf, t_end, noise, seed).xu`` is, in parallel numba calls."""
    from eha.identification.healthy import DetectionError
    from eha.identification.synthetic import synthetic_positions

    xs = synthetic_positions(command, [hf for hf, _ in runs], t_end, noise,
                             [s for _, s in runs])
    bad = ~np.isfinite(xs).all(axis=1)
    if bad.any():   # as a record that is not finite numbers is refused
        hf = runs[int(np.argmax(bad))][0]
        raise DetectionError(f"`command`: an HF run of the calibration diverged (parameters "
                             f"{ {k: v for k, v in hf.items() if k in FAULTS} }); its "
                             "positions are not finite")
    return xs


def _faulted(hf: Mapping[str, float], name: str, change: float) -> tuple[dict, float]:
    """``hf`` with fault ``name`` changed by ``change`` from its own value, within the
    parameter's range; the change applied."""
    from eha.models.params import SPECS

    spec = SPECS[name]
    v0 = float(hf.get(name, FAULTS[name].healthy))
    v = min(max(v0 + change, spec.lo), spec.hi)
    return {**hf, name: v}, v - v0


def _gains(cmd, sig: Signatures, widths: Mapping[str, float], actuators: int, seed: int,
           t_end: float, noise: float, at: Mapping[str, float]) -> dict[str, dict[str, list]]:
    """Per fault, the HF gain curve of its estimate (:class:`GainCurve`): the later record
    with the fault grown by each size of :data:`GAIN_SIZES` x its probe minus the same record
    without it (same noise and dither seed: the noise cancels), over the first
    :data:`GAIN_ACTUATORS` actuators; and per fault ``f`` and other fault ``g`` the ``leak``
    (``g``'s reading beside ``f`` when only ``f`` grew: mean and std by ``f``'s size) and the
    ``interaction`` (:func:`_interactions`)."""
    out, leaks = {}, {}
    k_max = min(actuators, GAIN_ACTUATORS)
    runs = [(draw_test_day({**draw_actuator(seed + k), **at}, widths, seed + k),
             later_seed(seed + k)) for k in range(k_max)]
    later = [(hf, s, xb) for (hf, s), xb in zip(runs, _positions(cmd, runs, t_end, noise))]
    signs = np.array([sign_of(n) for n in sig.faults])
    # every run first (one batch of parallel HF runs), then the readings
    grown = {(name, mult, k): _faulted(hf, name, mult * probe(name))
             for name in sig.faults for mult in GAIN_SIZES for k, (hf, _, _) in enumerate(later)}
    keys = [key for key, (_, change) in grown.items() if change != 0]
    xs = dict(zip(keys, _positions(cmd, [(grown[key][0], later[key[2]][1]) for key in keys],
                                   t_end, noise)))
    for i, name in enumerate(sig.faults):
        sizes, gains, spread = [], [], []
        cond = sig.conditional(i)
        leak: dict[str, dict[str, list]] = {n: {"sizes": [], "mean": [], "std": []}
                                            for j, n in enumerate(sig.faults) if j != i}
        for mult in GAIN_SIZES:
            g, applied, other = [], [], []
            for k, (hf, s, xb) in enumerate(later):
                change = grown[(name, mult, k)][1]
                if change == 0:
                    continue
                xf = xs[(name, mult, k)]
                g.append(sig.estimate(xf - xb)[i] / change)
                other.append(signs * (cond @ (xf - xb)))
                applied.append(change)
            if len(g) < 2 or abs(np.mean(applied)) < 0.5 * abs(mult * probe(name)):
                continue                           # clipped at the parameter's range
            sizes.append(float(np.mean(applied)))
            gains.append(float(np.mean(g)))
            spread.append(float(np.std(g, ddof=1)))
            other = np.array(other)
            for j, n in enumerate(sig.faults):
                if j != i:
                    leak[n]["sizes"].append(sizes[-1])
                    leak[n]["mean"].append(float(other[:, j].mean()))
                    leak[n]["std"].append(float(other[:, j].std(ddof=1)))
        out[name] = {"sizes": sizes, "gains": gains, "spread": spread}
        leaks[name] = {n: {"leak": v} for n, v in leak.items()}
    for name, per in _interactions(cmd, sig, later[:INTERACTION_ACTUATORS], out, leaks, t_end,
                                   noise).items():
        for other, figures in per.items():
            leaks[name][other]["interaction"] = figures
    return out, leaks


#: Sizes of the first fault, in multiples of its probe, at which the interactions are measured.
INTERACTION_FIRST = (0.5, 2.0, 8.0)
#: Sizes of the second fault, in multiples of its probe (about 1x and 4x its detectable change
#: on ``chirp_1cm``).
INTERACTION_SECOND = (1.0, 4.0)
#: Actuators on which the interactions are measured (the first of the gain curves'; with 2
#: the second fault's interval covers as with 4, 299 of 319 pairs, at half the HF runs).
INTERACTION_ACTUATORS = 2


def _interactions(cmd, sig: Signatures, later, curves: Mapping[str, dict],
                  leaks: Mapping[str, Mapping[str, dict]], t_end: float, noise: float
                  ) -> dict[str, dict[str, dict[str, list]]]:
    """Per fault ``f`` and other fault ``g``: how far ``g``'s change read beside ``f`` (as
    :func:`eha.health.change_second.judge_second` reads it: the joint estimate less ``f``'s
    leak, through ``g``'s gain curve) strays from ``g``'s true change when both have grown,
    relative to it: the root mean square over :data:`INTERACTION_SECOND` and the actuators,
    by ``f``'s size (:data:`INTERACTION_FIRST`). A fault's signature bends with the faults
    already there; this is what the single-fault gain curves and leaks leave out."""
    signs = np.array([sign_of(n) for n in sig.faults])
    # every run first (one batch of parallel HF runs), then the readings
    grown: dict[tuple, tuple] = {}
    for i, f in enumerate(sig.faults):
        for j, g in enumerate(sig.faults):
            leak = (leaks.get(f, {}).get(g) or {}).get("leak") or {}
            if j == i or not leak.get("sizes"):
                continue
            top = abs(float(leak["sizes"][-1]))        # the largest size its leak was read at
            for mult_f, (k, (hf, s, _)), mult_g in product(INTERACTION_FIRST, enumerate(later),
                                                           INTERACTION_SECOND):
                first, change_f = _faulted(hf, f, mult_f * probe(f))
                both, change_g = _faulted(first, g, mult_g * probe(g))
                if change_f != 0 and abs(change_f) <= top and change_g != 0:
                    grown[(i, j, mult_f, k, mult_g)] = (both, s, change_f, change_g)
    positions = dict(zip(grown, _positions(cmd, [v[:2] for v in grown.values()], t_end,
                                           noise)))
    by_first: dict[tuple, list] = {}     # the runs of each (f, g, f's size), in their order
    for key, (_, _, change_f, change_g) in grown.items():
        by_first.setdefault(key[:3], []).append((key, change_f, change_g))
    out: dict[str, dict[str, dict[str, list]]] = {f: {} for f in sig.faults}
    for i, f in enumerate(sig.faults):
        cond = sig.conditional(i)
        for j, g in enumerate(sig.faults):
            leak = (leaks.get(f, {}).get(g) or {}).get("leak") or {}
            if j == i or not leak.get("sizes"):
                continue
            curve = GainCurve(*(tuple(curves[g][k]) for k in ("sizes", "gains", "spread")))
            xs = np.abs(np.array(leak["sizes"], dtype=float))
            sizes, rel = [], []
            for mult_f in INTERACTION_FIRST:
                errors, applied_f = [], []
                for key, change_f, change_g in by_first.get((i, j, mult_f), []):
                    d = signs[j] * float(cond[j] @ (positions[key] - later[key[3]][2])) - \
                        float(np.interp(abs(change_f), np.r_[0.0, xs], np.r_[0.0, leak["mean"]]))
                    read = curve.invert(signs[j] * d, signs[j])
                    errors.append((read - change_g) / change_g)
                    applied_f.append(abs(change_f))
                if len(errors) >= 2:
                    sizes.append(float(np.mean(applied_f)))
                    rel.append(float(np.sqrt(np.mean(np.square(errors)))))
            out[f][g] = {"sizes": sizes, "rel": rel}
    return out


__all__ = ["GAIN_ACTUATORS", "LATER_SEED_SHIFT", "INTERACTION_FIRST", "INTERACTION_SECOND",
           "INTERACTION_ACTUATORS", "later_seed", "sign_of"]
