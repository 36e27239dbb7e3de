"""Figures and tables for people: PNG plots of traces, CSV tables."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from eha.simulate import Trace


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _label(trace: Trace) -> str:
    meta = trace.meta
    faults = ", ".join(f"{k}={v:g}" for k, v in sorted(meta.get("params", {}).items()))
    return meta.get("model", "?").upper() + (f" ({faults})" if faults else "")


def plot_traces(traces: Sequence[Trace], path: str | Path, title: str | None = None) -> Path:
    """Command and position, spool position, P12 and current of one or more traces, as PNG.

    Traces are overlaid (e.g. HF against LF on the same command); the position panel also
    shows the difference of each trace from the first.
    """
    plt = _pyplot()
    ratios = [3, 1.4, 2, 1.4] if len(traces) > 1 else [3, 2, 1.4]
    fig, axes = plt.subplots(len(ratios), 1, figsize=(9, 2.5 * len(ratios)), sharex=True,
                             gridspec_kw={"height_ratios": ratios})
    if len(traces) == 1:
        axes = [axes[0], None, axes[1], axes[2]]
    first = traces[0]
    t = first.t
    axes[0].plot(t, 1e3 * first["com"], color="0.55", lw=2.5, label="command")
    styles = ["-", "--", "-.", ":"]
    for i, tr in enumerate(traces):
        ls = styles[i % len(styles)]
        axes[0].plot(tr.t, 1e3 * tr.xu, ls, lw=1.4, label=f"xu {_label(tr)}")
        if i > 0 and len(tr) == len(first):
            axes[1].plot(tr.t, 1e6 * (tr.xu - first.xu), ls, lw=1.2,
                         label=f"{_label(tr)} − {_label(first)}")
        axes[2].plot(tr.t, 1e-5 * tr["p12"], ls, lw=1.2, label=_label(tr))
        axes[3].plot(tr.t, 1e3 * tr["xs"], ls, lw=1.2, label=_label(tr))
    axes[0].set_ylabel("position [mm]")
    if axes[1] is not None:
        axes[1].set_ylabel("Δxu [µm]")
    axes[2].set_ylabel("P12 [bar]")
    axes[3].set_ylabel("spool xs [mm]")
    axes[3].set_xlabel("time [s]")
    for ax in [a for a in axes if a is not None]:
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="best")
    cmd = first.meta.get("command", {}).get("name", "")
    fig.suptitle(title or f"EHA response — command {cmd}")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root-mean-square difference of two equally sampled signals."""
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def nominal_comparison(results: str | Path = "results", t_end: float = 1.0,
                       seed: int = 0) -> list[dict]:
    """Every nominal command through HF and LF: Parquet traces, one PNG per command, RMSE rows.

    Writes ``results/traces/nominal/{model}_{command}.parquet`` and
    ``results/plots/nominal_{command}.png``; returns one row per command with the RMSE of xu
    (HF vs LF) in metres and as a percentage of the command peak.
    """
    from eha.commands import NOMINAL_COMMANDS
    from eha.simulate import simulate
    from eha.store import write_trace

    results = Path(results)
    rows = []
    for name in NOMINAL_COMMANDS:
        hf = simulate("hf", name, t_end=t_end, seed=seed)
        lf = simulate("lf", name, t_end=t_end, seed=seed)
        for tr in (hf, lf):
            model = tr.meta["model"]
            write_trace(tr, results / "traces" / "nominal" / f"{model}_{name}.parquet")
        plot_traces([hf, lf], results / "plots" / f"nominal_{name}.png",
                    title=f"Nominal HF vs LF — {name}")
        err = rmse(hf.xu, lf.xu)
        peak = float(np.max(np.abs(hf["com"])))
        rows.append({"command": name, "rmse_xu_m": err, "rmse_pct_of_peak": 100 * err / peak})
    return rows
