"""Low-fidelity ("monitoring") model (docs/model.md §6) with its optional effects as data.

Proportional controller, static first stage, first-order spool with Karnopp friction, linear
P12 law, jack with Karnopp friction, output backlash. The optional effects are parameters of
the same kernel whose "off" value makes them vanish (``orifice_law = 0``, ``Clk = 0``,
``FRC = 0``, ``Kaer = 0``, ``Ofs = 0``, ``His = 0``, ``SNF = 0`` for a static first stage, ...),
so any combination runs in the one compiled kernel.
"""

import math

from numba import njit, prange

from eha.models.friction import (clamp, dithered_play, end_stop, karnopp_velocity,
                                 karnopp_velocity_first_order, play, record)
from eha.models.params import LF

#: State variables of the LF model (SI; cor in mA).
STATES = ("xu", "xj", "dxj", "xs", "dxs", "xf", "dxf", "xsb", "cor")
#: Inputs: the position command [m] on the DT grid.
INPUTS = ("com",)
#: Interval between the dither's draws [s] (the HF's zero-order hold, docs/model.md §2).
DITHER_PERIOD = 1e-3


@njit(cache=True, fastmath=True)
def run_lf(p, com, steps_per_out, out):
    """Integrate the LF model.

    Parameters
    ----------
    p : float64[:]
        Parameter vector in :class:`eha.models.params.LFParams` order (index with ``LF``).
    com : float64[:]
        Command [m] at every step, ``len = (out.shape[0] - 1)*steps_per_out + 1``.
    steps_per_out : int
        Integration steps per recorded sample.
    out : float64[:, :]
        Recorded outputs, shape ``(n_out, len(OUTPUTS))``; row 0 is the initial state.
    """
    orifice = p[LF.orifice_law] != 0.0
    dynamic_flapper = p[LF.SNF] > 0.0
    # One loop per structural switch, so that the hot loop holds no branch on them.
    if orifice:
        if dynamic_flapper:
            _lf_loop(p, com, steps_per_out, out, True, True)
        else:
            _lf_loop(p, com, steps_per_out, out, True, False)
    elif dynamic_flapper:
        _lf_loop(p, com, steps_per_out, out, False, True)
    else:
        _lf_loop(p, com, steps_per_out, out, False, False)


@njit(cache=True, fastmath=True, inline="always")
def _lf_loop(p, com, steps_per_out, out, orifice, dynamic_flapper):
    dt = p[LF.DT]
    gap = p[LF.GAP]; corm = p[LF.CorM]; his = p[LF.His]; ofs = p[LF.Ofs]; gm = p[LF.GM]
    kf = p[LF.KF]; ksf = p[LF.KSF]
    inv_kf_ksf = 1.0 / (kf + ksf)
    snf = p[LF.SNF]
    mf = (ksf + kf) / (snf * snf) if dynamic_flapper else 1.0
    cf = 2.0 * p[LF.ZF] * math.sqrt(mf * (ksf + kf))
    dt_over_mf = dt / mf
    xfm = p[LF.XFM]; gioco = p[LF.gioco]
    asv = p[LF.ASV]; gpfe = p[LF.GPF] * (1.0 - p[LF.Kintas])
    fatt_s_gain = asv * gpfe
    inv_cs = 1.0 / (p[LF.CSV] + asv * asv * gpfe / p[LF.GQF])
    xsm = p[LF.XSM]; fss = p[LF.FSS]; fds = fss / p[LF.FSDS]; eps = p[LF.eps]
    psr = p[LF.PSR]; gp = p[LF.GP]; gq = p[LF.GQ]; clk = p[LF.Clk]
    # the saturation opening's law in the supply pressure (the thesis' listing: PSR0/GP,
    # its text: PSR/GP; XSSK interpolates, docs/model.md)
    xss = p[LF.PSR0] / gp * (psr / p[LF.PSR0]) ** p[LF.XSSK]
    gpq_xss = gp / gq * xss
    den0 = gpq_xss * clk
    # linear law with leakage = small-opening limit of the orifice law (docs/model.md)
    lin_gain = gp / (1.0 + gp / gq * clk)
    inv_gq = 1.0 / gq
    if orifice:
        pi0 = 0.5 * (psr + 2.0 * p[LF.PRV])
        p12_max = 2.0 * min(psr + p[LF.PRV] - pi0, pi0 - p[LF.PVap])
    else:
        p12_max = psr
    frc = p[LF.FRC]; kaer = p[LF.Kaer]
    aj = p[LF.AJ]; cj = p[LF.CJ]; dt_over_mj = dt / p[LF.MJ]; xjm = p[LF.XJM]
    fdj = p[LF.FDJ]; fsj = p[LF.FSD] * fdj
    half_bkl = 0.5 * p[LF.BKL]
    # the dither (a fresh draw every DITHER_PERIOD, as in the HF) acts on the hysteresis only
    # through its expectation: the mean-field dithered play at each draw, the plain play on
    # the steps between draws
    sigma = p[LF.dither_ma]
    dithered = his > 0.0 and sigma > 0.0
    steps_per_draw = max(1, int(round(DITHER_PERIOD / dt)))

    xj = p[LF.XJ0]; xu = xj; dxj = 0.0
    xs = 0.0; dxs = 0.0; xf = 0.0; dxf = 0.0; xsb = 0.0; cor = 0.0; p12 = 0.0

    n_out = out.shape[0]
    record(out, 0, 0.0, com[0], xu, xj, 0.0, 0.0, 0.0, 0.0, 0.0)
    k = 0
    for i in range(1, n_out):
        for _ in range(steps_per_out):
            current = gap * (com[k] - xu) + ofs
            if dithered and k % steps_per_draw == 0:
                cor = clamp(dithered_play(current, cor, his, sigma), -corm, corm)
            else:
                cor = clamp(play(current, cor, his), -corm, corm)
            xsb = play(xs, xsb, gioco)
            if dynamic_flapper:
                dxf += (gm * cor - cf * dxf - kf * xf - ksf * (xf + xsb)) * dt_over_mf
                xf += dxf * dt
            else:
                xf = (gm * cor - ksf * xsb) * inv_kf_ksf
            xf, dxf = end_stop(xf, dxf, xfm)
            dxs = karnopp_velocity_first_order(dxs, fatt_s_gain * xf, fds, fss, eps, inv_cs)
            xs += dxs * dt
            xs, dxs = end_stop(xs, dxs, xsm)
            qj = aj * dxj
            if orifice:
                p12 = (psr * xs - gpq_xss * qj) / (max(abs(xs), xss) + den0)
            else:
                p12 = lin_gain * (xs - qj * inv_gq)
            p12 = clamp(p12, -p12_max, p12_max)
            fatt = aj * p12 - frc - kaer * xj - cj * dxj
            dxj = karnopp_velocity(dxj, fatt, fdj, fsj, eps, dt_over_mj)
            xj += dxj * dt
            xj, dxj = end_stop(xj, dxj, xjm)
            xu = play(xj, xu, half_bkl)
            k += 1
        record(out, i, k * dt, com[k], xu, xj, dxj, xs, xf, p12, cor)


@njit(cache=True, parallel=True)
def run_lf_batch(params, com, steps_per_out, out):
    """Run the LF model for every row of ``params`` (shape ``(n, n_par)``), in parallel.

    ``out`` has shape ``(n, n_out, len(OUTPUTS))``. One call per GA generation.
    """
    for j in prange(params.shape[0]):
        run_lf(params[j], com, steps_per_out, out[j])
