"""High-fidelity ("detailed") actuator model, one semi-implicit Euler step per DT (docs/model.md §2).

Signal flow per step: command -> PID -> torque motor (offset, dither, play hysteresis,
saturation) -> flapper (2nd order, end stops, feedback-spring ball play) -> spool (1st order,
Borello friction, end stops, quantizer) -> nonlinear P12 with leakage and chamber-pressure
limits -> jack (2nd order, Borello friction, loads, end stops) -> output backlash.
"""

import math

import numpy as np
from numba import njit, prange

from eha.models import OUTPUTS
from eha.models.friction import (borello_velocity, borello_velocity_first_order, clamp,
                                 end_stop, play, record)
from eha.models.params import HF

#: State variables of the HF model (SI; cor in mA; ierr in m*s).
STATES = ("xu", "xj", "dxj", "xs", "dxs", "xf", "dxf", "xsb", "cor", "ierr", "er_prev")
#: Inputs: the position command [m] on the DT grid and the dither current [mA] per output step.
INPUTS = ("com", "dither")


@njit(cache=True, fastmath=True)
def run_hf(p, com, dither, steps_per_out, out):
    """Integrate the HF model.

    Parameters
    ----------
    p : float64[:]
        Parameter vector in :class:`eha.models.params.HFParams` order (index with ``HF``).
    com : float64[:]
        Command [m] at every step, ``len = n_out_intervals*steps_per_out + 1``.
    dither : float64[:]
        Dither current [mA], one zero-order-held value per output interval.
    steps_per_out : int
        Integration steps per recorded sample (1 ms / DT).
    out : float64[:, :]
        Recorded outputs, shape ``(n_out, len(OUTPUTS))``; row 0 is the initial state.
    """
    # Derived constants, once (docs/model.md §1); reciprocals so the loop only multiplies.
    dt = p[HF.DT]
    gap = p[HF.GAP]; gai = p[HF.GAI]; gad = p[HF.GAD]; erim = p[HF.ErIM]; gas = p[HF.GAS]
    corm = p[HF.CorM]; his = p[HF.His]; ofs = p[HF.Ofs]; gm = p[HF.GM]
    kf = p[HF.KF]; ksf = p[HF.KSF]; snf = p[HF.SNF]; zf = p[HF.ZF]
    mf = (ksf + kf) / (snf * snf)
    cf = 2.0 * zf * math.sqrt(mf * (ksf + kf))
    dt_over_mf = dt / mf
    xfm = p[HF.XFM]; gioco = p[HF.gioco]
    asv = p[HF.ASV]; gpfe = p[HF.GPF] * (1.0 - p[HF.Kintas])
    fatt_s_gain = asv * gpfe
    inv_cs = 1.0 / (p[HF.CSV] + asv * asv * gpfe / p[HF.GQF])
    xsm = p[HF.XSM]
    fss = p[HF.FSS]; fds = fss / p[HF.FSDS]
    q_xs = p[HF.q_xs]
    inv_q = 1.0 / q_xs if q_xs > 0.0 else 0.0
    psr = p[HF.PSR]; prv = p[HF.PRV]; pvap = p[HF.PVap]
    gp = p[HF.GP]; gq = p[HF.GQ]
    xss = p[HF.PSR0] / gp * (psr / p[HF.PSR0]) ** p[HF.XSSK]   # docs/model.md
    gpq_xss = gp / gq * xss
    den0 = gpq_xss * p[HF.Clk]
    pi0 = 0.5 * (psr + 2.0 * prv)
    # chamber pressures P1,2 = Pi +- P12/2 within [PVap, PSR + PRV]
    p12_max = 2.0 * min(psr + prv - pi0, pi0 - pvap)
    p12_min = -p12_max
    frc = p[HF.FRC]; frr = p[HF.FRR]; fr_t = p[HF.FR_time]
    frsa = p[HF.FRSA]; frsf = p[HF.FRSF]; kaer = p[HF.Kaer]
    aj = p[HF.AJ]; cj = p[HF.CJ]; dt_over_mj = dt / p[HF.MJ]; xjm = p[HF.XJM]
    fdj = p[HF.FDJ]; fsj = p[HF.FSD] * fdj
    half_bkl = 0.5 * p[HF.BKL]
    inv_dt = 1.0 / dt

    xj = p[HF.XJ0]; xu = xj; dxj = 0.0
    xs = 0.0; dxs = 0.0; xf = 0.0; dxf = 0.0; xsb = 0.0
    cor = 0.0; ierr = 0.0; er_prev = com[0] - xu
    p12 = 0.0

    n_out = out.shape[0]
    record(out, 0, 0.0, com[0], xu, xj, 0.0, 0.0, 0.0, 0.0, 0.0)
    k = 0
    for i in range(1, n_out):
        dith = dither[i - 1]
        for _ in range(steps_per_out):
            t = k * dt
            # controller
            er = com[k] - xu
            ierr = clamp(ierr + er * dt, -erim, erim)
            coer = gap * er + gai * ierr + gad * (er - er_prev) * inv_dt - gas * dxj
            er_prev = er
            # torque motor
            cor = clamp(play(coer + ofs + dith, cor, his), -corm, corm)
            # first stage
            xsb = play(xs, xsb, gioco)
            dxf += (gm * cor - cf * dxf - kf * xf - ksf * (xf + xsb)) * dt_over_mf
            xf += dxf * dt
            xf, dxf = end_stop(xf, dxf, xfm)
            # second stage
            dxs = borello_velocity_first_order(dxs, fatt_s_gain * xf, fds, fss, inv_cs)
            xs += dxs * dt
            xs, dxs = end_stop(xs, dxs, xsm)
            xsq = xs if q_xs == 0.0 else q_xs * math.floor(xs * inv_q + 0.5)
            # fluid dynamics
            p12 = (psr * xsq - gpq_xss * aj * dxj) / (max(abs(xsq), xss) + den0)
            p12 = clamp(p12, p12_min, p12_max)
            # jack
            fr = 0.0
            if t >= fr_t:
                fr = frc + frr * (t - fr_t)
            if frsa != 0.0:
                fr += frsa * math.sin(frsf * t)
            fatt = aj * p12 - fr - kaer * xj - cj * dxj
            dxj = borello_velocity(dxj, fatt, fdj, fsj, dt_over_mj)
            xj += dxj * dt
            xj, dxj = end_stop(xj, dxj, xjm)
            xu = play(xj, xu, half_bkl)
            k += 1
        record(out, i, k * dt, com[k], xu, xj, dxj, xs, xf, p12, cor)


@njit(cache=True, parallel=True)
def run_hf_batch(params, com, dithers, steps_per_out, out):
    """Run the HF model for every row of ``params`` (shape ``(n, n_par)``) with the dither
    row of the same index (``dithers``, shape ``(n, n_out - 1)``), in parallel; ``out`` has
    shape ``(n, n_out, len(OUTPUTS))``. The test design's many actuators on one command."""
    for j in prange(params.shape[0]):
        run_hf(params[j], com, dithers[j], steps_per_out, out[j])


def dither_samples(sigma_ma, n, seed):
    """Zero-order-held Gaussian dither [mA], one sample per output interval, from ``seed``."""
    if sigma_ma == 0.0:
        return np.zeros(n)
    return np.random.default_rng(seed).normal(0.0, sigma_ma, n)


assert len(OUTPUTS) == 9
