"""Figures and tables of simulations: traces overlaid (PNG), the figures of a simulation
campaign (HF vs LF per fault set, the RMSE between them) and its table of runs (CSV).

The thesis report (:mod:`eha.reports.thesis`) and the CLI (``eha simulate --plot``, ``eha
plot``) draw with these.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from eha.figures import pyplot as _pyplot
from eha.figures import save as _save
from eha.models.simulate import Trace


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
        # a record without P12 or the spool (NaN throughout) draws nothing: no legend entry
        for ax, key, k in ((axes[2], "p12", 1e-5), (axes[3], "xs", 1e3)):
            if np.isfinite(tr[key]).any():
                ax.plot(tr.t, k * tr[key], ls, lw=1.2, label=_label(tr))
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
    return _save(fig, path, dpi=110)

def _fmt_value(name: str, value: float) -> str:
    """``BKL 100 µm``: a fault in its display unit (eha.models.units), as everywhere else."""
    from eha.models.units import show

    return f"{name} {show(name, value, 4)}"


def fault_text(faults: dict) -> str:
    return ", ".join(_fmt_value(k, v) for k, v in faults.items()) or "nominal"


def campaign_runs(results: str | Path, campaign: str):
    """Done simulation runs of a campaign joined with their metrics (pandas DataFrame)."""
    from eha.campaigns.query import query

    frame = query(results, """
        SELECT r.*, m.* EXCLUDE (run_key) FROM runs r LEFT JOIN metrics m USING (run_key)
        WHERE r.campaign = ? AND r.kind = 'simulate'
          AND r.status = 'done' ORDER BY r.command, r.fault_label, r.model, r.seed""",
                  [campaign])
    frame["faults"] = frame["faults"].map(lambda s: json.loads(s) if isinstance(s, str) else {})
    return frame


def fault_order(faults: dict) -> tuple:
    """Sort key of fault sets: fewer faults first, then by parameter names and values."""
    return (len(faults), sorted(faults), [faults[k] for k in sorted(faults)])


def _layout(fault_sets: list[dict]) -> tuple[list[str], list[str], dict[str, tuple[int, int]]]:
    """Panel grid for fault sets: a 2-parameter product as rows x columns, single faults as one
    row per parameter, anything else wrapped in rows of four."""
    keys = [json.dumps(f, sort_keys=True) for f in fault_sets]
    names = sorted({k for f in fault_sets for k in f})
    if len(names) == 2 and all(len(f) == 2 for f in fault_sets):
        a = sorted({f[names[0]] for f in fault_sets})
        b = sorted({f[names[1]] for f in fault_sets})
        pos = {k: (a.index(f[names[0]]), b.index(f[names[1]])) for k, f in zip(keys, fault_sets)}
        return ([_fmt_value(names[0], v) for v in a], [_fmt_value(names[1], v) for v in b], pos)
    if fault_sets and all(len(f) == 1 for f in fault_sets):
        by_name: dict[str, list[float]] = {}
        for f in fault_sets:
            (n, v), = f.items()
            by_name.setdefault(n, []).append(v)
        rows = sorted(by_name)
        pos = {}
        for k, f in zip(keys, fault_sets):
            (n, v), = f.items()
            pos[k] = (rows.index(n), sorted(by_name[n]).index(v))
        ncol = max(len(v) for v in by_name.values())
        return rows, [""] * ncol, pos
    ncol = min(4, max(1, len(fault_sets)))
    pos = {k: (i // ncol, i % ncol) for i, k in enumerate(keys)}
    return [""] * (-(-len(fault_sets) // ncol)), [""] * ncol, pos


def plot_campaign(results: str | Path = "results", campaign: str = "thesis-matrix",
                  out: str | Path | None = None) -> list[Path]:
    """Campaign figures (PNG): HF vs LF xu and P12 per fault set, and the HF-vs-LF RMSE.

    For each command, one figure of xu (command, HF, LF) and one of P12, with a panel per fault
    set (the matrix gives a BKL x FDJ grid, like the thesis' figures 5.28-5.37), and one summary
    figure of the RMSE of xu between HF and LF. With a single fault set the panels are the
    commands instead. Only the first seed is drawn.

    Returns
    -------
    list of Path
        The PNGs written under ``out`` (default ``DIR/plots/<campaign>/``).
    """
    from eha.campaigns.query import check_trace_files
    from eha.campaigns.traces import read_trace

    results = Path(results)
    runs = campaign_runs(results, campaign)
    if runs.empty:
        from eha.campaigns.store import StoreError

        raise StoreError(f"plot: campaign {campaign!r} has no finished runs in "
                         f"{results / 'eha.duckdb'}")
    out = Path(out) if out is not None else results / "plots" / campaign
    runs = runs[runs["seed"] == runs["seed"].min()]
    # the checksums of the files drawn, as every reader of traces (a flipped byte is a spike)
    check_trace_files(results, set(runs["trace_path"]), "plot")
    traces = {rk: read_trace(results / p, rk)
              for rk, p in zip(runs["run_key"], runs["trace_path"])}
    fault_sets = sorted({json.dumps(f, sort_keys=True): f for f in runs["faults"]}.values(),
                        key=fault_order)
    fault_keys = [json.dumps(f, sort_keys=True) for f in fault_sets]
    commands = list(dict.fromkeys(runs["command"]))
    written = []
    if len(fault_sets) == 1:  # e.g. the nominal campaign: one panel per command
        panels = [(c, fault_keys[0], c) for c in commands]
        ncol = min(3, len(commands))
        layout = ([""] * -(-len(commands) // ncol), [""] * ncol,
                  {c: (i // ncol, i % ncol) for i, c in enumerate(commands)})
        written += _overlay_figures(runs, traces, panels, layout, out, campaign, "commands",
                                    by_command=True)
    else:
        layout = _layout(fault_sets)
        for cmd in commands:
            panels = [(cmd, k, fault_text(json.loads(k))) for k in fault_keys]
            written += _overlay_figures(runs, traces, panels, layout, out, campaign, cmd)
    written.append(_rmse_figure(runs, fault_sets, commands, out, campaign))
    return written


def _overlay_figures(runs, traces, panels, layout, out: Path, campaign: str, tag: str,
                     by_command: bool = False) -> list[Path]:
    plt = _pyplot()
    rows, cols, pos = layout
    paths = []
    for signal, scale, unit in (("xu", 1e3, "mm"), ("p12", 1e-5, "bar")):
        fig, axes = plt.subplots(len(rows), len(cols), figsize=(3.6 * len(cols) + 0.8,
                                                                2.6 * len(rows) + 0.9),
                                 sharex=True, squeeze=False)
        used = set()
        for cmd, fkey, title in panels:
            r, c = pos[cmd if by_command else fkey]
            ax = axes[r][c]
            used.add((r, c))
            sel = runs[(runs["command"] == cmd) &
                       (runs["faults"].map(lambda f: json.dumps(f, sort_keys=True)) == fkey)]
            first = True
            for model, style in (("hf", "-"), ("lf", "--")):
                for rk in sel.loc[sel["model"] == model, "run_key"]:
                    tr = traces[rk]
                    if signal == "xu" and first:
                        ax.plot(tr.t, scale * tr["com"], color="0.6", lw=2.2, label="command")
                        first = False
                    ax.plot(tr.t, scale * tr[signal], style, lw=1.2, label=model.upper())
            ax.set_title(title, fontsize=9)
            ax.grid(True, alpha=0.3)
            if c == 0:
                ax.set_ylabel(f"{rows[r] + chr(10) if rows[r] else ''}{signal} [{unit}]",
                              fontsize=8)
            if r == len(rows) - 1:
                ax.set_xlabel("time [s]", fontsize=8)
            ax.tick_params(labelsize=7)
        for r in range(len(rows)):
            for c in range(len(cols)):
                if (r, c) not in used:
                    axes[r][c].set_visible(False)
        handles, labels = next(((h, lb) for h, lb in (a.get_legend_handles_labels()
                                                     for a in axes.flat) if h), ([], []))
        if handles:
            fig.legend(handles, labels, loc="upper right", fontsize=8, ncol=len(handles))
        what = "position xu" if signal == "xu" else "differential pressure P12"
        fig.suptitle(f"{campaign}: HF vs LF {what}" + ("" if by_command else f" — {tag}"),
                     fontsize=11, x=0.02, ha="left")
        fig.tight_layout(rect=(0, 0, 1, 0.96))
        paths.append(_save(fig, out / f"{tag}_{signal}.png"))
    return paths


def _rmse_figure(runs, fault_sets, commands, out: Path, campaign: str) -> Path:
    plt = _pyplot()
    hf = runs[runs["model"] == "hf"]
    key = hf["faults"].map(lambda f: json.dumps(f, sort_keys=True))
    value = {(c, k): 1e6 * v for c, k, v in zip(hf["command"], key, hf["rmse_xu_hf_lf"])}
    names = sorted({k for f in fault_sets for k in f})
    grid2 = len(names) == 2 and all(len(f) == 2 for f in fault_sets)
    if grid2:
        a = sorted({f[names[0]] for f in fault_sets})
        b = sorted({f[names[1]] for f in fault_sets})
        fig, axes = plt.subplots(1, len(commands), figsize=(5.2 * len(commands), 3.8),
                                 squeeze=False)
        for ax, cmd in zip(axes[0], commands):
            m = np.full((len(a), len(b)), np.nan)
            for f in fault_sets:
                v = value.get((cmd, json.dumps(f, sort_keys=True)))
                if v is not None:
                    m[a.index(f[names[0]]), b.index(f[names[1]])] = v
            from matplotlib.colors import LogNorm

            finite = m[np.isfinite(m) & (m > 0)]
            norm = LogNorm(finite.min(), finite.max()) if finite.size > 1 else None
            im = ax.imshow(m, cmap="viridis", aspect="auto", origin="lower", norm=norm)
            for (i, j), v in np.ndenumerate(m):
                if np.isfinite(v):
                    dark = finite.size > 1 and np.log(v / finite.min()) < 0.6 * np.log(
                        finite.max() / finite.min())
                    ax.text(j, i, f"{v:.3g}", ha="center", va="center", fontsize=8,
                            color="w" if dark else "k")
            ax.set_xticks(range(len(b)), [_fmt_value(names[1], v).split(" ", 1)[1] for v in b])
            ax.set_yticks(range(len(a)), [_fmt_value(names[0], v).split(" ", 1)[1] for v in a])
            ax.set_xlabel(names[1])
            ax.set_ylabel(names[0])
            ax.set_title(cmd)
            fig.colorbar(im, ax=ax, label="RMSE xu HF vs LF [µm]")
    elif len(fault_sets) == 1:  # one case per command: a bar per command, values written
        key = json.dumps(fault_sets[0], sort_keys=True)
        ys = [value.get((c, key), np.nan) for c in commands]
        fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(commands)), 4))
        bars = ax.bar(commands, ys, color="tab:blue")
        ax.bar_label(bars, labels=[f"{y:.3g}" for y in ys], fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel("RMSE xu HF vs LF [µm]")
        ax.set_title(fault_text(fault_sets[0]), fontsize=9)
        ax.grid(True, axis="y", alpha=0.3)
    else:
        fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(fault_sets) * len(commands)), 4))
        labels = [fault_text(f) for f in fault_sets]
        width = 0.8 / max(1, len(commands))
        for i, cmd in enumerate(commands):
            ys = [value.get((cmd, json.dumps(f, sort_keys=True)), np.nan) for f in fault_sets]
            ax.bar(np.arange(len(fault_sets)) + i * width, ys, width, label=cmd)
        ax.set_xticks(np.arange(len(fault_sets)) + 0.4 - width / 2, labels, rotation=30,
                      ha="right", fontsize=8)
        ax.set_ylabel("RMSE xu HF vs LF [µm]")
        ax.set_yscale("log")
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{campaign}: HF vs LF position error", fontsize=11)
    fig.tight_layout()
    return _save(fig, out / "rmse_hf_lf.png")


def campaign_report(results: str | Path, campaign: str) -> Path:
    """``DIR/reports/<campaign>.csv``: every done run of the campaign with its metrics."""
    frame = campaign_runs(results, campaign)
    frame["faults"] = frame["faults"].map(lambda f: json.dumps(f, sort_keys=True))
    path = Path(results) / "reports" / f"{campaign}.csv"
    from eha.outputs import atomic_path

    with atomic_path(path) as tmp:
        frame.drop(columns=["spec"]).to_csv(tmp, index=False)
    return path
