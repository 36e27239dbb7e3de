"""The family of test commands ``eha design`` searches: segments of holds, sines, triangles and
chirps within a test's limits.

A command of the family is ``N_SEGMENTS`` segments, each a vector of five numbers in [0, 1]
(:data:`GENES`): its shape (hold, sine, triangle or chirp), its share of the test's duration,
its centre and amplitude (fractions of the stroke) and its frequency (log scale between
:data:`F_MIN` and the limits' ``max_freq``). The samples are then held within the stroke,
slew-limited to the rate the servo loop can follow, and the test ends with a rest at zero
(:func:`rest_length`: long enough to return from anywhere at the largest rate), so every member
starts and ends at rest and respects the limits by construction.

Why this family: each shape is what one kind of fault needs (holds show offsets and
leakage-driven drift, constant-rate ramps of triangles show friction and backlash at each
reversal, sines and chirps show the loop's gain and the first stage's dynamics), and a
sequence of them lets the search trade one against another within the time budget; the
parameters are few (20) so a population search converges in a few hundred candidates.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from eha.errors import InputError

#: Segments of a command.
N_SEGMENTS = 4
#: Genes of one segment, each in [0, 1].
GENES = ("shape", "share", "centre", "amplitude", "frequency")
#: Segment shapes, in gene order.
SHAPES = ("hold", "sine", "triangle", "chirp")
#: Lowest segment frequency [Hz].
F_MIN = 0.1
#: Share gene below which a segment is left out (so that one segment can fill the test).
MIN_SHARE = 0.05
#: Share of the duration the closing rest takes, and its least length [s].
REST_SHARE, MIN_REST_S = 0.08, 0.05
#: Sampling of a command file [s] (1 kHz, the records').
COMMAND_DT = 1e-3


class DesignError(InputError):
    """Bad test-design input (limits, faults, pairs); the message is one line."""


@dataclass(frozen=True)
class Limits:
    """What a test may do.

    Attributes
    ----------
    duration : float
        Length of the test [s], 0.2 to 10.
    max_stroke : float
        Largest command away from zero [m], 1e-4 to 0.2.
    max_rate : float
        Largest command rate [m/s] (what the servo loop can follow; the jack's no-load speed
        is about 0.15 m/s), 1e-4 to 1.
    max_freq : float
        Highest segment frequency [Hz], 1 to 100.
    """

    duration: float = 1.0
    max_stroke: float = 0.01
    max_rate: float = 0.1
    max_freq: float = 20.0

    def check(self) -> "Limits":
        for name, lo, hi, unit in (("duration", 0.2, 10.0, "s"), ("max_stroke", 1e-4, 0.2, "m"),
                                   ("max_rate", 1e-4, 1.0, "m/s"),
                                   ("max_freq", 1.0, 100.0, "Hz")):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or not lo <= value <= hi:
                raise DesignError(f"{name}={value!r}: allowed range [{lo:g}, {hi:g}] {unit}")
        return self

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def rest_length(limits: Limits) -> float:
    """The closing rest [s]: :data:`REST_SHARE` of the test, at least :data:`MIN_REST_S` and
    long enough to come back from the full stroke at the largest rate (plus 20 ms still)."""
    return max(REST_SHARE * limits.duration, MIN_REST_S,
               limits.max_stroke / limits.max_rate + 0.02)


def n_genes() -> int:
    return N_SEGMENTS * len(GENES)


def _segment(shape: str, tau: np.ndarray, length: float, centre: float, amp: float,
             freq: float) -> np.ndarray:
    if shape == "hold":
        return np.full_like(tau, centre)
    if shape == "sine":
        return centre + amp * np.sin(2 * np.pi * freq * tau)
    if shape == "triangle":                       # constant rate between reversals
        return centre + amp * (2.0 / np.pi) * np.arcsin(np.sin(2 * np.pi * freq * tau))
    f0 = freq / 4.0                               # chirp: f/4 -> f over the segment
    return centre + amp * np.sin(2 * np.pi * (f0 * tau + (freq - f0) * tau ** 2 /
                                              (2.0 * max(length, 1e-9))))


def genes(segments: list[dict[str, float | str]], limits: Limits) -> np.ndarray:
    """The gene vector of up to :data:`N_SEGMENTS` segments given as ``shape``, ``share``,
    ``centre`` and ``amplitude`` (fractions of the stroke, centre in [-1, 1]) and
    ``frequency`` [Hz]; the rest left out (a search's starting points)."""
    x = np.zeros((N_SEGMENTS, len(GENES)))
    for k, seg in enumerate(segments[:N_SEGMENTS]):
        f = min(max(float(seg.get("frequency", 1.0)), F_MIN), limits.max_freq)
        x[k] = [(SHAPES.index(str(seg["shape"])) + 0.5) / len(SHAPES),
                float(seg.get("share", 1.0)), (float(seg.get("centre", 0.0)) + 1.0) / 2.0,
                float(seg.get("amplitude", 0.0)),
                math.log(f / F_MIN) / math.log(limits.max_freq / F_MIN)]
    return np.clip(x.ravel(), 0.0, 1.0)


def slew_limit(values: np.ndarray, max_step: float) -> np.ndarray:
    """``values`` followed by a slew-rate limiter that starts at rest at 0 (at most
    ``max_step`` per sample)."""
    out = np.zeros_like(values)
    prev = 0.0
    for i in range(1, values.size):
        prev += min(max(values[i] - prev, -max_step), max_step)
        out[i] = prev
    return out


def decode(x: np.ndarray, limits: Limits) -> list[dict[str, float | str]]:
    """The segments a gene vector stands for (shape, start and length [s], centre and
    amplitude [m], frequency [Hz])."""
    x = np.clip(np.asarray(x, dtype=np.float64).reshape(N_SEGMENTS, len(GENES)), 0.0, 1.0)
    rest = rest_length(limits)
    shares = np.where(x[:, 1] < MIN_SHARE, 0.0, x[:, 1])
    if not shares.sum() > 0:
        shares = np.ones(N_SEGMENTS)
    lengths = (limits.duration - rest) * shares / shares.sum()
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    s = limits.max_stroke
    segs = []
    for k in range(N_SEGMENTS):
        shape = SHAPES[min(int(x[k, 0] * len(SHAPES)), len(SHAPES) - 1)]
        amp = 0.0 if shape == "hold" else float(x[k, 3]) * s
        centre = (2.0 * float(x[k, 2]) - 1.0) * (s - amp)
        freq = F_MIN * (limits.max_freq / F_MIN) ** float(x[k, 4])
        segs.append({"shape": shape, "start": float(starts[k]), "length": float(lengths[k]),
                     "centre": centre, "amplitude": amp, "frequency": float(freq)})
    return segs


def command_samples(x: np.ndarray, limits: Limits) -> tuple[np.ndarray, np.ndarray]:
    """``(t, com)`` at 1 kHz of the family member ``x`` within ``limits``: the segments, held
    within the stroke, slew-limited from rest and ending at rest at zero."""
    return segment_samples(decode(x, limits), limits)


def segment_samples(segments: list[dict[str, float | str]], limits: Limits
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``(t, com)`` at 1 kHz of decoded ``segments`` (:func:`decode`'s, or a design JSON's
    ``segments``) within ``limits``: held within the stroke and slew-limited from rest."""
    t = np.round(np.arange(0.0, limits.duration + COMMAND_DT / 2, COMMAND_DT), 9)
    raw = np.zeros_like(t)
    for seg in segments:
        if seg["length"] <= 0:
            continue
        mask = (t >= seg["start"]) & (t < seg["start"] + seg["length"])
        raw[mask] = _segment(seg["shape"], t[mask] - seg["start"], seg["length"], seg["centre"],
                             seg["amplitude"], seg["frequency"])
    raw = np.clip(raw, -limits.max_stroke, limits.max_stroke)
    return t, slew_limit(raw, limits.max_rate * COMMAND_DT)


def at_rest_at_the_end(com: np.ndarray, limits: Limits) -> bool:
    """Does the slew-limited command reach zero and stay there before the test ends?"""
    tail = max(3, int(0.02 * com.size))
    return bool(np.all(np.abs(com[-tail:]) <= 1e-9 * max(1.0, limits.max_stroke * 1e3)))


def outside_limits(com: np.ndarray, limits: Limits) -> str | None:
    """Why a command sampled at 1 kHz over the test is outside ``limits`` (a library command
    offered as the design), or None: beyond the stroke, faster than the rate, not at rest at
    the start or the end, or with more than 1 % of its energy above ``max_freq``."""
    stroke = limits.max_stroke * (1.0 + 1e-6)
    if np.max(np.abs(com)) > stroke:
        return f"reaches {np.max(np.abs(com)) * 1e3:.3g} mm (stroke {limits.max_stroke * 1e3:g} mm)"
    rate = np.max(np.abs(np.diff(com))) / COMMAND_DT if com.size > 1 else 0.0
    if rate > limits.max_rate * 1.001:
        return f"moves at {rate:.3g} m/s (rate {limits.max_rate:g} m/s)"
    if abs(com[0]) > 1e-9 or not at_rest_at_the_end(com, limits):
        return "does not start and end at rest"
    power = np.abs(np.fft.rfft(com - com.mean())) ** 2
    freq = np.fft.rfftfreq(com.size, COMMAND_DT)
    if power.sum() > 0 and power[freq > limits.max_freq].sum() > 0.01 * power.sum():
        return f"has more than 1 % of its energy above {limits.max_freq:g} Hz"
    return None


__all__ = ["Limits", "DesignError", "N_SEGMENTS", "GENES", "SHAPES", "n_genes", "decode", "genes",
           "command_samples", "segment_samples", "slew_limit", "at_rest_at_the_end",
           "outside_limits"]
