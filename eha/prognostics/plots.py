"""Plots and the fleet summary table of ``eha rul --plots DIR``.

- ``actuator_<ID>.png``: per limited or tracked fault, the identified values with their
  intervals against cycle, the posterior trend (median and 5-95 % band) at the last check
  extended to the predicted crossing, the limit line and the predicted crossing (median and
  5-95 % span; the true end of life when known); below, the RUL against cycle with its
  interval, the true RUL and the α-cone (±20 %) when the truth is known.
- ``alpha_lambda.png``: every actuator's RUL prediction relative to the true RUL against λ,
  inside the α-cone (needs the truth).
- ``fleet_summary.csv`` / ``fleet_summary.md``: one row per actuator.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from eha.prognostics.degradation import LAWS, fault_scale, fit_degradation

def _unit(name: str) -> tuple[str, float]:
    """Display unit (:func:`eha.models.units.display_unit`; ``-`` when dimensionless, for an
    axis label) and the factor from SI."""
    from eha.models.units import display_unit

    unit, factor = display_unit(name)
    return (unit or "-", factor)


def _fmt(v, digits: int = 0) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else \
        f"{v:.{digits}f}"


def plot_actuator(path: Path, aid: str, hist: Mapping[str, Any], preds: Sequence[Any],
                  limits: Mapping[str, float], eol: float | None, seed: int = 0,
                  laws: Sequence[str] = LAWS, alpha: float = 0.2) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(hist)
    fig, axes = plt.subplots(len(names) + 1, 1, figsize=(9, 3.0 * (len(names) + 1)),
                             sharex=True, constrained_layout=True)
    last = preds[-1]
    c_last = last.cycle
    horizon = c_last
    for cr in last.crossings.values():
        for k in ("median", "hi"):
            v = cr.get(k)
            if v is not None:
                horizon = max(horizon, min(v, 3 * c_last))
    if eol is not None:
        horizon = max(horizon, eol)
    horizon *= 1.08
    for ax, name in zip(axes, names):
        h = hist[name]
        unit, f = _unit(name)
        cyc = h.cycles
        lo = np.where(np.isfinite(h.lo), h.lo, h.values) if h.lo is not None else h.values
        hi = np.where(np.isfinite(h.hi), h.hi, h.values) if h.hi is not None else h.values
        used = h.used
        ax.errorbar(cyc[used], f * h.values[used],
                    yerr=[f * (h.values - lo)[used], f * (hi - h.values)[used]], fmt="o",
                    ms=4, color="tab:blue", capsize=2, label="identified (90 % interval)")
        if (~used).any():
            ax.plot(cyc[~used], f * h.values[~used], "x", color="grey",
                    label="flagged (not used)")
        lim = limits.get(name)
        if used.sum() >= 3 and c_last > 0:
            sel = used
            fit = fit_degradation(cyc[sel], h.values[sel], h.sigma[sel],
                                  fault_scale(h.values[sel], lim), laws)
            tt = np.linspace(0, horizon, 200)
            traj = fit.trajectories(np.random.default_rng(seed), tt, 400)
            q = np.quantile(traj, [0.05, 0.5, 0.95], axis=0)
            ax.fill_between(tt, f * q[0], f * q[2], color="tab:orange", alpha=0.2,
                            label="trend 5-95 % (last check)")
            ax.plot(tt, f * q[1], color="tab:orange", lw=1.5, label="trend median")
            top = max(abs(f * lim) * 1.3 if lim is not None else 0, np.max(np.abs(f * hi)) * 1.2)
            ax.set_ylim(min(0.0, np.min(f * lo)), top)
        if lim is not None:
            ax.axhline(f * lim, color="red", ls="--", lw=1.2, label=f"limit {f * lim:g} {unit}")
            cr = last.crossings.get(name, {})
            if cr.get("median") is not None:
                ax.axvline(cr["median"], color="tab:orange", ls=":", lw=1.5,
                           label=f"predicted crossing {cr['median']:.0f}")
                ax.axvspan(cr["lo"] if cr.get("lo") is not None else cr["median"],
                           cr["hi"] if cr.get("hi") is not None else horizon,
                           color="tab:orange", alpha=0.08)
        if eol is not None:
            ax.axvline(eol, color="k", lw=1.0, label=f"true end of life {eol:.0f}")
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    ax = axes[-1]
    cyc = np.array([p.cycle for p in preds])
    med = np.array([np.nan if p.rul is None else p.rul for p in preds])
    lo = np.array([np.nan if p.rul_lo is None else p.rul_lo for p in preds])
    hi = np.array([np.nan if p.rul_hi is None else p.rul_hi for p in preds])
    ax.fill_between(cyc, lo, np.where(np.isnan(hi) & ~np.isnan(lo), np.nanmax(
        np.r_[hi, lo, 1.0]) * 1.5, hi), color="tab:blue", alpha=0.2, step=None,
        label="RUL 5-95 %")
    ax.plot(cyc, med, "o-", color="tab:blue", ms=4, label="RUL median")
    if eol is not None:
        tt = np.linspace(cyc[0], eol, 50)
        ax.plot(tt, eol - tt, "k-", lw=1.2, label="true RUL")
        ax.fill_between(tt, (1 - alpha) * (eol - tt), (1 + alpha) * (eol - tt), color="k",
                        alpha=0.08, label=f"α-cone ±{alpha:.0%}")
    ax.set_ylim(0, max(np.nanmax(np.r_[med, lo, 1.0]) * 1.5,
                       (eol - cyc[0]) * 1.3 if eol is not None else 0))
    ax.set_xlim(0, horizon)
    ax.set_xlabel("cycle")
    ax.set_ylabel("RUL [cycles]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"Actuator {aid}: health history and remaining useful life")
    from eha.outputs import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def plot_alpha_lambda(path: Path, preds_all: Mapping[str, Sequence[Any]],
                      truth: Mapping[str, float | None], alpha: float = 0.2) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5), constrained_layout=True)
    lam = np.linspace(0, 1, 50)
    ax.plot(lam, 1 - lam, "k-", lw=1.5, label="true RUL")
    ax.fill_between(lam, (1 - alpha) * (1 - lam), (1 + alpha) * (1 - lam), color="k",
                    alpha=0.1, label=f"α-cone ±{alpha:.0%}")
    ax.axvspan(0.5, 0.95, color="tab:green", alpha=0.05, label="λ window [0.5, 0.95]")
    for aid, preds in preds_all.items():
        eol = truth.get(aid)
        if eol is None or not preds or eol <= preds[0].cycle:
            continue
        t0 = preds[0].cycle
        life = eol - t0
        x, y, ylo, yhi = [], [], [], []
        for p in preds:
            if p.cycle >= eol or p.rul is None:
                continue
            x.append((p.cycle - t0) / life)
            y.append(p.rul / life)
            ylo.append(p.rul_lo / life if p.rul_lo is not None else np.nan)
            yhi.append(p.rul_hi / life if p.rul_hi is not None else np.nan)
        if x:
            line, = ax.plot(x, y, "o-", ms=3, lw=0.8, alpha=0.8)
            ax.vlines(x, ylo, yhi, color=line.get_color(), alpha=0.25, lw=2)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.6)
    ax.set_xlabel("λ = (cycle − first check) / (true end of life − first check)")
    ax.set_ylabel("RUL / monitored life (median and 5-95 %)")
    ax.set_title("Alpha-lambda plot: every actuator's RUL predictions")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    from eha.outputs import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def summary_rows(preds_all, truth, metrics) -> list[dict[str, Any]]:
    rows = []
    per = (metrics or {}).get("actuators", {})
    for aid, preds in preds_all.items():
        last = preds[-1] if preds else None
        m = per.get(aid, {})
        rows.append({
            "actuator": aid, "checks": len(preds),
            "last_cycle": None if last is None else last.cycle,
            "rul": None if last is None else last.rul,
            "rul_lo": None if last is None else last.rul_lo,
            "rul_hi": None if last is None else last.rul_hi,
            "driver": None if last is None else last.driver,
            "predicted_eol": None if last is None or last.rul is None else last.cycle + last.rul,
            "true_eol": (truth or {}).get(aid),
            "alpha_lambda_0.5": (m.get("alpha_lambda") or {}).get("0.5"),
            "alpha_lambda_0.75": (m.get("alpha_lambda") or {}).get("0.75"),
            "alpha_lambda_fraction": m.get("alpha_lambda_fraction"),
            "coverage": m.get("coverage"),
            "prognostic_horizon": m.get("prognostic_horizon"),
            "cra": m.get("cra"),
        })
    return rows


def write_summary(folder: Path, rows: list[dict[str, Any]], fleet: Mapping[str, Any] | None
                  ) -> tuple[Path, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    csv_path = folder / "fleet_summary.csv"
    from eha.outputs import atomic_path, write_atomic

    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["actuator"])
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    md = ["| actuator | checks | last cycle | RUL median [5 %, 95 %] | driver | predicted EOL "
          "| true EOL | α-λ 0.5 | α-λ 0.75 | α-λ [0.5,0.95] | coverage | PH | CRA |",
          "|---|---:|---:|---|---|---:|---:|---|---|---:|---:|---:|---:|"]
    yn = lambda v: "-" if v is None else ("yes" if v else "no")  # noqa: E731
    pc = lambda v: "-" if v is None else f"{100 * v:.0f} %"  # noqa: E731
    for r in rows:
        md.append(f"| {r['actuator']} | {r['checks']} | {_fmt(r['last_cycle'])} | "
                  f"{_fmt(r['rul'])} [{_fmt(r['rul_lo'])}, {_fmt(r['rul_hi'])}] | "
                  f"{r['driver'] or '-'} | {_fmt(r['predicted_eol'])} | {_fmt(r['true_eol'])} | "
                  f"{yn(r['alpha_lambda_0.5'])} | {yn(r['alpha_lambda_0.75'])} | "
                  f"{pc(r['alpha_lambda_fraction'])} | {pc(r['coverage'])} | "
                  f"{_fmt(r['prognostic_horizon'])} | {_fmt(r['cra'], 2)} |")
    if fleet:
        md += ["", "Fleet: " + ", ".join(f"{k} = {v}" for k, v in fleet.items())]
    md_path = folder / "fleet_summary.md"
    write_atomic(md_path, "\n".join(md) + "\n")
    return csv_path, md_path


def write_plots(folder: Path, hist, preds_all, limits, truth, metrics, seed: int = 0,
                laws: Sequence[str] = LAWS) -> dict[str, Path]:
    """Every plot and the summary table into ``folder``; returns ``{kind: path}``."""
    out: dict[str, Path] = {}
    for aid, preds in preds_all.items():
        if aid in hist and preds:
            out[f"plot {aid}"] = plot_actuator(folder / f"actuator_{aid}.png", aid, hist[aid],
                                               preds, limits, (truth or {}).get(aid), seed,
                                               laws)
    if truth:
        out["alpha-lambda plot"] = plot_alpha_lambda(folder / "alpha_lambda.png", preds_all,
                                                     truth)
    csv_path, md_path = write_summary(folder, summary_rows(preds_all, truth, metrics),
                                      (metrics or {}).get("fleet"))
    out["summary"] = md_path
    out["summary csv"] = csv_path
    return out
