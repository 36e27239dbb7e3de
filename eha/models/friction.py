"""Friction laws and the play operator, each written once (docs/model.md §3).

All functions are scalar ``@njit`` helpers inlined into the model kernels. Velocities in m/s,
forces in N. ``fs`` is the static (break-away) force, ``fd`` the dynamic one.
"""

import math

from numba import njit


@njit(cache=True, fastmath=True, inline="always")
def play(x, y, half_width):
    """Play (backlash) operator: output ``y`` follows ``x`` once ``|x - y|`` exceeds the half-width.

    Also the play-type hysteresis of the torque motor (``half_width`` = His).
    """
    # Branches rather than min/max keep the dependency chain short; the first one is constant
    # within a run (no play), so it never mispredicts on a signal that changes direction.
    if half_width == 0.0:
        return x
    if y < x - half_width:
        return x - half_width
    if y > x + half_width:
        return x + half_width
    return y


_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@njit(cache=True, fastmath=True, inline="always")
def normal_loss(z):
    """``E[(Z - z)+]`` for a standard normal ``Z`` (the normal loss function)."""
    return _INV_SQRT_2PI * math.exp(-0.5 * z * z) - 0.5 * z * math.erfc(z / _SQRT2)


@njit(cache=True, fastmath=True, inline="always")
def dithered_play(x, y, half_width, sigma):
    """Expected output of the play when its input ``x`` carries a fresh Gaussian draw of
    standard deviation ``sigma`` (> 0): the mean-field dithered play (docs/model.md §6).

    The play pushes its output up by ``(x + d - half_width - y)+`` and down by
    ``(y - x - d - half_width)+``; their expectations over ``d`` are ``sigma * normal_loss``
    of the distances to the band's edges in units of ``sigma``. With ``sigma -> 0`` it is
    :func:`play`; with ``half_width = 0`` it returns ``x``.
    """
    e = x - y
    return y + sigma * (normal_loss((half_width - e) / sigma)
                        - normal_loss((half_width + e) / sigma))


@njit(cache=True, fastmath=True, inline="always")
def clamp(x, lo, hi):
    if x > hi:
        return hi
    if x < lo:
        return lo
    return x


@njit(cache=True, fastmath=True, inline="always")
def borello_velocity(v, fatt, fd, fs, dt_over_m):
    """Borello dry friction on a mass: new velocity after one semi-implicit Euler step.

    Stuck (``v == 0``) is an exact state: the body stays at rest while ``|fatt| <= fs``,
    otherwise it breaks away against ``fd``. A moving body feels ``fd*sign(v)``; when its
    velocity would change sign in the step, it stops (``v = 0``).
    """
    if v == 0.0:
        if abs(fatt) <= fs:
            return 0.0
        return (fatt - fd if fatt > 0.0 else fatt + fd) * dt_over_m
    v_new = v + (fatt - fd if v > 0.0 else fatt + fd) * dt_over_m
    if v_new * v <= 0.0:
        return 0.0
    return v_new


@njit(cache=True, fastmath=True, inline="always")
def borello_velocity_first_order(v, fatt, fd, fs, inv_c):
    """Borello dry friction on a first-order (massless, viscous) body: its velocity.

    At rest it breaks away only when ``|fatt| > fs``; once moving it keeps moving while the
    active force beats ``fd`` in the same direction, and stops otherwise.
    """
    if v == 0.0:
        if abs(fatt) <= fs:
            return 0.0
        return (fatt - fd if fatt > 0.0 else fatt + fd) * inv_c
    if v > 0.0:
        return (fatt - fd) * inv_c if fatt > fd else 0.0
    return (fatt + fd) * inv_c if fatt < -fd else 0.0


@njit(cache=True, fastmath=True, inline="always")
def karnopp_velocity(v, fatt, fd, fs, eps, dt_over_m):
    """Karnopp friction on a mass: new velocity after one step.

    Inside the dead band ``|v| < eps`` the body sticks (``v = 0``) while ``|fatt| <= fs``,
    else friction is ``fd*sign(fatt)``; outside it friction is ``fd*sign(v)``.
    """
    if abs(v) < eps:
        if abs(fatt) <= fs:
            return 0.0
        return v + (fatt - fd if fatt > 0.0 else fatt + fd) * dt_over_m
    return v + (fatt - fd if v > 0.0 else fatt + fd) * dt_over_m


@njit(cache=True, fastmath=True, inline="always")
def karnopp_velocity_first_order(v, fatt, fd, fs, eps, inv_c):
    """Karnopp friction on a first-order body: its velocity given the previous one ``v``."""
    if abs(v) < eps:
        if abs(fatt) <= fs:
            return 0.0
        return (fatt - fd if fatt > 0.0 else fatt + fd) * inv_c
    return (fatt - fd if v > 0.0 else fatt + fd) * inv_c


@njit(cache=True, fastmath=True, inline="always")
def end_stop(x, v, limit):
    """End stop at ``±limit``: position clamped, velocity zeroed (completely inelastic impact)."""
    # One return point: numba's multiple tuple returns cost ~70 % of the LF loop's speed.
    if x > limit:
        x = limit
        v = 0.0
    elif x < -limit:
        x = -limit
        v = 0.0
    return x, v


@njit(cache=True, inline="always")
def record(out, i, t, com, xu, xj, dxj, xs, xf, p12, cor):
    """Write one row of the recorded outputs (column order of ``eha.models.OUTPUTS``)."""
    out[i, 0] = t
    out[i, 1] = com
    out[i, 2] = xu
    out[i, 3] = xj
    out[i, 4] = dxj
    out[i, 5] = xs
    out[i, 6] = xf
    out[i, 7] = p12
    out[i, 8] = cor
