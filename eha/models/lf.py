"""Low-fidelity ("monitoring") model (docs/model.md §6) with its optional effects as data.

Proportional controller, static first stage, first-order spool with Karnopp friction, linear
P12 law, jack with Karnopp friction, output backlash. The optional effects are parameters of
the same kernel whose "off" value makes them vanish (``orifice_law = 0``, ``Clk = 0``,
``FRC = 0``, ``Kaer = 0``, ``Ofs = 0``, ``His = 0``, ``SNF = 0`` for a static first stage, ...),
so any combination runs in the one compiled kernel.
"""

import math

import numpy as np
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


#: Most runs of a batch that one thread integrates interleaved (:func:`_lf_group`).
GROUP = 8
#: Rows of a group's constants (:func:`_group_constants`), in the order of its ``K`` rows.
_K = ("gap", "corm", "his", "ofs", "gm", "kf", "ksf", "inv_kf_ksf", "cf", "dt_over_mf", "xfm",
      "gioco", "fatt_s_gain", "inv_cs", "xsm", "fss", "fds", "eps", "psr", "gpq_xss", "xss",
      "den0", "lin_gain", "inv_gq", "p12_max", "frc", "kaer", "aj", "cj", "dt_over_mj", "xjm",
      "fdj", "fsj", "half_bkl", "sigma", "dithered", "xj0")


@njit(cache=True, fastmath=True)
def _group_constants(P, idx, orifice, dynamic_flapper):
    """The constants of :func:`_lf_loop` for the runs ``P[idx]``: shape ``(len(_K), g)``."""
    K = np.empty((37, idx.size))
    for a in range(idx.size):
        p = P[idx[a]]
        dt = p[LF.DT]
        kf = p[LF.KF]; ksf = p[LF.KSF]; snf = p[LF.SNF]
        mf = (ksf + kf) / (snf * snf) if dynamic_flapper else 1.0
        asv = p[LF.ASV]; gpfe = p[LF.GPF] * (1.0 - p[LF.Kintas])
        psr = p[LF.PSR]; gp = p[LF.GP]; gq = p[LF.GQ]; clk = p[LF.Clk]
        xss = p[LF.PSR0] / gp * (psr / p[LF.PSR0]) ** p[LF.XSSK]
        if orifice:
            pi0 = 0.5 * (psr + 2.0 * p[LF.PRV])
            p12_max = 2.0 * min(psr + p[LF.PRV] - pi0, pi0 - p[LF.PVap])
        else:
            p12_max = psr
        fss = p[LF.FSS]; fdj = p[LF.FDJ]; his = p[LF.His]; sigma = p[LF.dither_ma]
        K[0, a] = p[LF.GAP]; K[1, a] = p[LF.CorM]; K[2, a] = his; K[3, a] = p[LF.Ofs]
        K[4, a] = p[LF.GM]; K[5, a] = kf; K[6, a] = ksf; K[7, a] = 1.0 / (kf + ksf)
        K[8, a] = 2.0 * p[LF.ZF] * math.sqrt(mf * (ksf + kf)); K[9, a] = dt / mf
        K[10, a] = p[LF.XFM]; K[11, a] = p[LF.gioco]; K[12, a] = asv * gpfe
        K[13, a] = 1.0 / (p[LF.CSV] + asv * asv * gpfe / p[LF.GQF]); K[14, a] = p[LF.XSM]
        K[15, a] = fss; K[16, a] = fss / p[LF.FSDS]; K[17, a] = p[LF.eps]; K[18, a] = psr
        K[19, a] = gp / gq * xss; K[20, a] = xss; K[21, a] = gp / gq * xss * clk
        K[22, a] = gp / (1.0 + gp / gq * clk); K[23, a] = 1.0 / gq; K[24, a] = p12_max
        K[25, a] = p[LF.FRC]; K[26, a] = p[LF.Kaer]; K[27, a] = p[LF.AJ]; K[28, a] = p[LF.CJ]
        K[29, a] = dt / p[LF.MJ]; K[30, a] = p[LF.XJM]; K[31, a] = fdj
        K[32, a] = p[LF.FSD] * fdj; K[33, a] = 0.5 * p[LF.BKL]; K[34, a] = sigma
        K[35, a] = 1.0 if his > 0.0 and sigma > 0.0 else 0.0; K[36, a] = p[LF.XJ0]
    return K


@njit(cache=True, fastmath=True)
def _lf_group(P, com, steps_per_out, out, idx, orifice, dynamic_flapper):
    """:func:`_lf_loop` for the runs ``P[idx]`` (one structural switch setting, one DT),
    integrated together: each step advances every run of the group in turn. The runs are
    independent chains of dependent operations, so a core overlaps them (about 1.4x the
    runs per second of one run at a time on the development machine)."""
    K = _group_constants(P, idx, orifice, dynamic_flapper)
    gap = K[0]; corm = K[1]; his = K[2]; ofs = K[3]; gm = K[4]; kf = K[5]; ksf = K[6]
    inv_kf_ksf = K[7]; cf = K[8]; dt_over_mf = K[9]; xfm = K[10]; gioco = K[11]
    fatt_s_gain = K[12]; inv_cs = K[13]; xsm = K[14]; fss = K[15]; fds = K[16]; eps = K[17]
    psr = K[18]; gpq_xss = K[19]; xss = K[20]; den0 = K[21]; lin_gain = K[22]; inv_gq = K[23]
    p12_max = K[24]; frc = K[25]; kaer = K[26]; aj = K[27]; cj = K[28]; dt_over_mj = K[29]
    xjm = K[30]; fdj = K[31]; fsj = K[32]; half_bkl = K[33]; sigma = K[34]; dithered = K[35]
    xj0 = K[36]
    g = idx.size
    dt = P[idx[0], LF.DT]
    steps_per_draw = max(1, int(round(DITHER_PERIOD / dt)))
    xj = xj0.copy(); xu = xj0.copy(); dxj = np.zeros(g); xs = np.zeros(g); dxs = np.zeros(g)
    xf = np.zeros(g); dxf = np.zeros(g); xsb = np.zeros(g); cor = np.zeros(g); p12 = np.zeros(g)
    for a in range(g):
        record(out[idx[a]], 0, 0.0, com[0], xu[a], xj[a], 0.0, 0.0, 0.0, 0.0, 0.0)
    k = 0
    for i in range(1, out.shape[1]):
        for _ in range(steps_per_out):
            draw = k % steps_per_draw == 0
            for a in range(g):
                current = gap[a] * (com[k] - xu[a]) + ofs[a]
                if dithered[a] != 0.0 and draw:
                    c = clamp(dithered_play(current, cor[a], his[a], sigma[a]), -corm[a],
                              corm[a])
                else:
                    c = clamp(play(current, cor[a], his[a]), -corm[a], corm[a])
                b = play(xs[a], xsb[a], gioco[a])
                if dynamic_flapper:
                    v = dxf[a] + (gm[a] * c - cf[a] * dxf[a] - kf[a] * xf[a]
                                  - ksf[a] * (xf[a] + b)) * dt_over_mf[a]
                    x = xf[a] + v * dt
                else:
                    v = dxf[a]
                    x = (gm[a] * c - ksf[a] * b) * inv_kf_ksf[a]
                x, v = end_stop(x, v, xfm[a])
                cor[a] = c; xsb[a] = b; xf[a] = x; dxf[a] = v
                v = karnopp_velocity_first_order(dxs[a], fatt_s_gain[a] * x, fds[a], fss[a],
                                                 eps[a], inv_cs[a])
                x = xs[a] + v * dt
                x, v = end_stop(x, v, xsm[a])
                xs[a] = x; dxs[a] = v
                qj = aj[a] * dxj[a]
                if orifice:
                    q = (psr[a] * x - gpq_xss[a] * qj) / (max(abs(x), xss[a]) + den0[a])
                else:
                    q = lin_gain[a] * (x - qj * inv_gq[a])
                q = clamp(q, -p12_max[a], p12_max[a])
                p12[a] = q
                fatt = aj[a] * q - frc[a] - kaer[a] * xj[a] - cj[a] * dxj[a]
                v = karnopp_velocity(dxj[a], fatt, fdj[a], fsj[a], eps[a], dt_over_mj[a])
                x = xj[a] + v * dt
                x, v = end_stop(x, v, xjm[a])
                xj[a] = x; dxj[a] = v
                xu[a] = play(x, xu[a], half_bkl[a])
            k += 1
        for a in range(g):
            record(out[idx[a]], i, k * dt, com[k], xu[a], xj[a], dxj[a], xs[a], xf[a],
                   p12[a], cor[a])


@njit(cache=True)
def batch_groups(params, threads, most):
    """The groups :func:`run_lf_batch` integrates: ``(order, bounds)``, the rows sorted by
    their structural switches and the ``[start, end)`` of each group in ``order``. A batch of
    ``n`` rows is cut into a multiple of ``threads`` groups of at most ``most`` rows, as
    equal as the switches allow (a group has one switch setting)."""
    n = params.shape[0]
    keys = np.empty(n, np.int64)
    for j in range(n):
        keys[j] = (2 if params[j, LF.orifice_law] != 0.0 else 0) + \
            (1 if params[j, LF.SNF] > 0.0 else 0)
    order = np.argsort(keys, kind="mergesort")
    per_thread = -(-n // (threads * most))
    size = max(1, -(-n // (threads * per_thread)))
    bounds = np.empty((n, 2), np.int64)
    count = 0
    start = 0
    while start < n:
        end = start
        while end < n and keys[order[end]] == keys[order[start]]:
            end += 1
        m = end - start
        parts = -(-m // size)
        for q in range(parts):
            bounds[count, 0] = start + q * m // parts
            bounds[count, 1] = start + (q + 1) * m // parts
            count += 1
        start = end
    return order, bounds[:count]


def run_lf_batch(params, com, steps_per_out, out):
    """Run the LF model for every row of ``params`` (shape ``(n, n_par)``), in parallel.

    ``out`` has shape ``(n, n_out, len(OUTPUTS))``. One call per GA generation. The rows are
    integrated in groups (:func:`batch_groups`, :func:`_lf_group`), one group per thread at a
    time; a row's trace does not depend on the group it is in nor on the number of threads.
    """
    import numba

    order, bounds = batch_groups(params, numba.get_num_threads(), GROUP)
    _run_groups(params, com, steps_per_out, out, order, bounds)


@njit(cache=True, parallel=True)
def _run_groups(params, com, steps_per_out, out, order, bounds):
    for c in prange(bounds.shape[0]):
        idx = order[bounds[c, 0]:bounds[c, 1]]
        orifice = params[idx[0], LF.orifice_law] != 0.0
        dynamic_flapper = params[idx[0], LF.SNF] > 0.0
        if orifice:
            if dynamic_flapper:
                _lf_group(params, com, steps_per_out, out, idx, True, True)
            else:
                _lf_group(params, com, steps_per_out, out, idx, True, False)
        elif dynamic_flapper:
            _lf_group(params, com, steps_per_out, out, idx, False, True)
        else:
            _lf_group(params, com, steps_per_out, out, idx, False, False)
