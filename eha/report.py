"""Figures and tables for people: PNG plots of traces, CSV tables."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from eha.figures import pyplot as _pyplot
from eha.figures import save as _save
from eha.simulate import Trace


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
    return _save(fig, path, dpi=110)


from eha.runner import rmse  # noqa: E402  (one definition; re-exported for report users)


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


# =========================================================================== campaigns
#: Thesis chapter-5 campaigns run by :func:`reproduce_thesis` (files ``campaigns/<name>.toml``).
THESIS_CAMPAIGNS = ["thesis-nominal", "thesis-single-fault", "thesis-matrix"]


def campaigns_dir() -> Path:
    """The thesis campaign files, shipped in the package (``campaigns/`` links to them)."""
    return Path(__file__).resolve().parent / "campaigns"


def _fmt_value(name: str, value: float) -> str:
    from eha.params import SPECS

    unit = SPECS[name].unit if name in SPECS else ""
    if unit == "m" and abs(value) < 0.1:
        return f"{name} {1e3 * value:g} mm"
    return f"{name} {value:g} {unit}".rstrip()


def _fault_text(faults: dict) -> str:
    return ", ".join(_fmt_value(k, v) for k, v in faults.items()) or "nominal"


def campaign_runs(results: str | Path, campaign: str):
    """Done simulation runs of a campaign joined with their metrics (pandas DataFrame)."""
    from eha.store import query

    frame = query(results, f"""
        SELECT r.*, m.* EXCLUDE (run_key) FROM runs r LEFT JOIN metrics m USING (run_key)
        WHERE r.campaign = '{campaign.replace("'", "''")}' AND r.kind = 'simulate'
          AND r.status = 'done' ORDER BY r.command, r.fault_label, r.model, r.seed""")
    frame["faults"] = frame["faults"].map(lambda s: json.loads(s) if isinstance(s, str) else {})
    return frame


def _fault_order(faults: dict) -> tuple:
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
    from eha.store import read_trace

    results = Path(results)
    runs = campaign_runs(results, campaign)
    if runs.empty:
        from eha.store import StoreError

        raise StoreError(f"plot: campaign {campaign!r} has no finished runs in "
                         f"{results / 'eha.duckdb'}")
    out = Path(out) if out is not None else results / "plots" / campaign
    runs = runs[runs["seed"] == runs["seed"].min()]
    traces = {rk: read_trace(results / p) for rk, p in zip(runs["run_key"], runs["trace_path"])}
    fault_sets = sorted({json.dumps(f, sort_keys=True): f for f in runs["faults"]}.values(),
                        key=_fault_order)
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
            panels = [(cmd, k, _fault_text(json.loads(k))) for k in fault_keys]
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
        ax.set_title(_fault_text(fault_sets[0]), fontsize=9)
        ax.grid(True, axis="y", alpha=0.3)
    else:
        fig, ax = plt.subplots(figsize=(max(6, 0.5 * len(fault_sets) * len(commands)), 4))
        labels = [_fault_text(f) for f in fault_sets]
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
    path.parent.mkdir(parents=True, exist_ok=True)
    frame.drop(columns=["spec"]).to_csv(path, index=False)
    return path


def _markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def reproduce_thesis(results: str | Path = "results", workers: int = 2,
                     progress: bool = True) -> dict:
    """Thesis chapters 5 and 6 end to end: run :data:`THESIS_CAMPAIGNS` and the FDI campaign
    :data:`FDI_CAMPAIGN`, then figures and reports (the FDI ones by :func:`thesis_report`).

    Runs each ``campaigns/<name>.toml`` into ``results`` on one pool of ``workers`` processes
    (resuming runs already done; a thesis campaign whose file changed is re-run from scratch),
    then writes ``plots/nominal_<command>.png`` (HF vs LF, every signal), the campaign figures
    of :func:`plot_campaign` under ``plots/<campaign>/``, ``reports/<campaign>.csv`` and
    ``reports/summary.md``.

    Returns
    -------
    dict
        ``summaries`` (one :class:`eha.runner.RunSummary` per campaign), ``nominal`` (rows:
        command, RMSE of xu HF vs LF [m], as % of the command peak), ``plots``, ``reports``.
    """
    from eha.runner import LocalPoolExecutor, run_campaign
    from eha.store import read_trace

    results = Path(results)
    summaries = []
    with LocalPoolExecutor(workers) as pool:
        # chapter 5, then chapter 6 (FDI), then FDI with the LF augmented by eha explain
        for name in THESIS_CAMPAIGNS + [FDI_CAMPAIGN, AUGMENTED_CAMPAIGN]:
            path = campaigns_dir() / f"{name}.toml"
            summaries.append(run_campaign(path, results, replace=True, progress=progress,
                                          executor=pool))
    plots: list[Path] = []
    nominal = []
    runs = campaign_runs(results, "thesis-nominal")
    for cmd in dict.fromkeys(runs["command"]):
        sel = runs[runs["command"] == cmd].set_index("model")
        hf = read_trace(results / sel.loc["hf", "trace_path"])
        lf = read_trace(results / sel.loc["lf", "trace_path"])
        plots.append(plot_traces([hf, lf], results / "plots" / f"nominal_{cmd}.png",
                                 title=f"Nominal HF vs LF — {cmd}"))
        err = float(sel.loc["hf", "rmse_xu_hf_lf"])
        peak = float(np.max(np.abs(hf["com"])))
        nominal.append({"command": cmd, "rmse_xu_m": err, "rmse_pct_of_peak": 100 * err / peak})
    reports = []
    for name in THESIS_CAMPAIGNS:
        plots += plot_campaign(results, name)
        reports.append(campaign_report(results, name))
    reports.append(_summary_markdown(results, summaries, nominal))
    fdi = thesis_report(results)        # reports/thesis: fdi_table.csv, mean_error.png, summary
    plots.append(fdi["plot"])
    reports += [fdi["table"], fdi["summary"]]
    return {"summaries": summaries, "nominal": nominal, "plots": plots, "reports": reports,
            "fdi": fdi}


def _summary_markdown(results: Path, summaries, nominal: list[dict]) -> Path:
    parts = ["# Thesis chapter 5 reproduction", "",
             "Generated by `eha reproduce`. Query everything with `eha query`, e.g. "
             "`eha query \"SELECT * FROM runs JOIN metrics USING (run_key) LIMIT 5\"`.", "",
             "## Campaigns", "",
             _markdown_table(["campaign", "runs", "run now", "already done", "failed", "wall [s]"],
                             [[s.campaign, str(s.total), str(s.done), str(s.skipped),
                               str(s.failed), f"{s.wall_s:.1f}"] for s in summaries]),
             "", "## Nominal: HF vs LF position (RMSE of xu)", "",
             _markdown_table(["command", "RMSE [µm]", "% of command peak"],
                             [[r["command"], f"{1e6 * r['rmse_xu_m']:.2f}",
                               f"{r['rmse_pct_of_peak']:.3f}"] for r in nominal])]
    for name in THESIS_CAMPAIGNS[1:]:
        runs = campaign_runs(results, name)
        hf = runs[runs["model"] == "hf"]
        commands = list(dict.fromkeys(hf["command"]))
        table: dict[str, dict[str, float]] = {}
        for f, c, v in sorted(zip(hf["faults"], hf["command"], hf["rmse_xu_hf_lf"]),
                              key=lambda x: _fault_order(x[0])):
            table.setdefault(_fault_text(f), {})[c] = v
        parts += ["", f"## {name}: RMSE of xu, HF vs LF [µm]", "",
                  _markdown_table(["faults"] + commands,
                                  [[k] + [f"{1e6 * v[c]:.3g}" if c in v else "-"
                                          for c in commands] for k, v in table.items()])]
    path = results / "reports" / "summary.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(parts) + "\n", encoding="utf-8")
    return path


# =========================================================================== thesis FDI report
def fdi_table(rows: Sequence[dict], campaign, augmented: Sequence[dict] | None = None
              ) -> "pd.DataFrame":
    """The thesis' Figure 6.17 with our results beside the thesis' own, one row per case.

    Parameters
    ----------
    rows : sequence of dict
        FDI results (:class:`eha.fdi_cases.FDIRow` rows, or rows of the ``fdi_results`` table
        through :func:`eha.store.fdi_rows`), any number of seeds per case.
    campaign : eha.fdi_cases.FDICampaign
        The cases: injected faults, bounds, population and the thesis' values.

    Returns
    -------
    pandas.DataFrame
        ``case, command, <p>_in, <p>_out, population, <p>_lb, <p>_ub, err_<p>_pct,
        mean_err_pct`` (medians over the seeds, ``p`` = bkl, fdj; bounds of the search), the
        spread ``mean_err_pct_min/max``, ``seeds``,
        ``seconds`` (median), ``evaluations``, ``method``, ``objective``, then
        ``thesis_<p>_out, thesis_err_<p>_pct, thesis_mean_err_pct, thesis_seconds`` and
        ``at_least_as_accurate`` (our median mean error <= the thesis'); with ``augmented``
        (rows of the same cases run with the LF model augmented by ``eha explain``, campaign
        :data:`AUGMENTED_CAMPAIGN`) also ``aug_<p>_out, aug_err_<p>_pct, aug_mean_err_pct``,
        ``aug_mean_err_pct_max`` and ``aug_at_least_as_accurate``.
    """
    import pandas as pd

    out = []
    for case in campaign.cases:
        rs = [r for r in rows if int(r["case"]) == case.case]
        if not rs:
            continue
        names = list(rs[0]["estimates"])
        med = lambda values: float(np.median(list(values)))  # noqa: E731
        row = {"case": case.case, "command": case.command}
        for n in names:
            row[f"{n.lower()}_in"] = float(rs[0]["truth"][n])
        for n in names:
            row[f"{n.lower()}_out"] = med(r["estimates"][n] for r in rs)
        row["population"] = case.pop
        for n in names:
            row[f"{n.lower()}_lb"], row[f"{n.lower()}_ub"] = case.bounds[n]
        for n in names:
            row[f"err_{n.lower()}_pct"] = med(r["errors_pct"][n] for r in rs)
        errs = [float(r["mean_err_pct"]) for r in rs]
        row.update({"mean_err_pct": med(errs), "mean_err_pct_min": min(errs),
                    "mean_err_pct_max": max(errs), "seeds": len(rs),
                    "seconds": med(r["seconds"] for r in rs),
                    "evaluations": med(r["evaluations"] for r in rs),
                    "method": rs[0]["method"], "objective": rs[0]["objective_name"]})
        th = case.thesis
        for n in names:
            row[f"thesis_{n.lower()}_out"] = th.get(n, np.nan)
        for n in names:
            row[f"thesis_err_{n.lower()}_pct"] = th.get(f"err_{n}_pct", np.nan)
        row["thesis_mean_err_pct"] = th.get("mean_err_pct", np.nan)
        row["thesis_seconds"] = th.get("seconds", np.nan)
        row["at_least_as_accurate"] = bool(row["mean_err_pct"] <= row["thesis_mean_err_pct"])
        aug = [r for r in augmented or () if int(r["case"]) == case.case]
        if aug:
            for n in names:
                row[f"aug_{n.lower()}_out"] = med(r["estimates"][n] for r in aug)
            for n in names:
                row[f"aug_err_{n.lower()}_pct"] = med(r["errors_pct"][n] for r in aug)
            row["aug_mean_err_pct"] = med(float(r["mean_err_pct"]) for r in aug)
            row["aug_mean_err_pct_max"] = max(float(r["mean_err_pct"]) for r in aug)
            row["aug_at_least_as_accurate"] = bool(
                row["aug_mean_err_pct"] <= row["thesis_mean_err_pct"])
        out.append(row)
    return pd.DataFrame(out)


def plot_fdi_mean_error(table, path: str | Path) -> Path:
    """Mean error per case, ours (median, min-max over seeds) against the thesis', log scale
    (the thesis' Figure 6.18)."""
    plt = _pyplot()
    cases = table["case"].to_numpy()
    x = np.arange(len(cases))
    ours = table["mean_err_pct"].to_numpy()
    lo = ours - table["mean_err_pct_min"].to_numpy()
    hi = table["mean_err_pct_max"].to_numpy() - ours
    floor = 1e-3   # a perfect fit (0 %) is drawn at the floor of the log axis
    fig, ax = plt.subplots(figsize=(9, 4.8))
    ax.plot(x, np.maximum(table["thesis_mean_err_pct"], floor), "s--", color="tab:red",
            ms=7, lw=1, label="thesis (Matlab GA, one run)")
    ax.errorbar(x, np.maximum(ours, floor), yerr=[lo, hi], fmt="o-", color="tab:blue",
                ms=7, lw=1.5, capsize=4,
                label=f"eha {table['method'].iloc[0]} (median, min–max of "
                      f"{int(table['seeds'].iloc[0])} seeds)")
    if "aug_mean_err_pct" in table:
        ax.plot(x, np.maximum(table["aug_mean_err_pct"], floor), "D-", color="tab:green",
                ms=6, lw=1.2, label="eha, LF augmented by eha explain (median)")
    ax.set_yscale("log")
    ax.set_xticks(x, [str(c) for c in cases])
    commands = list(table["command"])
    start, group = 0, 0
    for i in range(1, len(commands) + 1):       # one shaded, labelled span per command
        if i == len(commands) or commands[i] != commands[start]:
            ax.axvspan(start - 0.5, i - 0.5, color=("0.92", "0.97")[group % 2], zorder=0)
            group += 1
            ax.text((start + i - 1) / 2, 0.02, f"{commands[start]} command",
                    transform=ax.get_xaxis_transform(), ha="center", fontsize=9, color="0.3")
            start = i
    ax.set_xlim(-0.5, len(cases) - 0.5)
    ax.set_xlabel("case")
    ax.set_ylabel("mean error [%]  (|BKL err| + |FDJ err|)/2")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=9)
    ax.set_title("Fault identification: mean error per case, eha vs thesis (Figure 6.18)")
    return _save(fig, Path(path))


def write_thesis_report(rows: Sequence[dict], campaign, out: str | Path,
                        augmented: Sequence[dict] | None = None) -> dict[str, Path]:
    """``fdi_table.csv``, ``mean_error.png`` and ``fdi_summary.md`` under ``out`` (with the
    augmented-LF columns when ``augmented`` rows are given)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    table = fdi_table(rows, campaign, augmented)
    if table.empty:
        raise ValueError(f"no FDI results of campaign {campaign.name!r} to report")
    csv_path = out / "fdi_table.csv"
    table.to_csv(csv_path, index=False, float_format="%.6g")
    png = plot_fdi_mean_error(table, out / "mean_error.png")
    better = int(table["at_least_as_accurate"].sum())
    fmt = lambda v: f"{v:.3g}"  # noqa: E731
    body = [[str(r.case), r.command, fmt(r.bkl_out), fmt(r.fdj_out), fmt(r.mean_err_pct),
             f"[{fmt(r.mean_err_pct_min)}, {fmt(r.mean_err_pct_max)}]",
             fmt(r.thesis_mean_err_pct), "yes" if r.at_least_as_accurate else "no",
             f"{r.seconds:.2f}", "-" if np.isnan(r.thesis_seconds) else f"{r.thesis_seconds:g}"]
            for r in table.itertuples()]
    lines = [
        "# Thesis fault identification (Figure 6.17) — eha against the thesis", "",
        f"Method `{table['method'].iloc[0]}`, objective `{table['objective'].iloc[0]}`, "
        f"{int(table['seeds'].iloc[0])} seeds per case (each seed: HF dither and optimizer). "
        "Percent error = (input − output)/input·100 (0 when the input is 0), mean error = "
        "(|BKL err| + |FDJ err|)/2, as in the thesis.", "",
        f"- cases at least as accurate as the thesis (median over seeds): **{better}/"
        f"{len(table)}**",
        f"- median time per case run: **{table['seconds'].median():.2f} s**" + (
            f" (thesis: median {np.nanmedian(table['thesis_seconds']):.0f} s over the cases "
            "where it reports one)" if table["thesis_seconds"].notna().any() else ""),
        f"- sum of the median times over the cases: {table['seconds'].sum():.1f} s", "",
        _markdown_table(["case", "command", "BKL out [m]", "FDJ out [N]", "mean err [%]",
                         "min–max [%]", "thesis [%]", "≤ thesis", "time [s]", "thesis [s]"],
                        body), "",
        "Where a case is less accurate than the thesis, the limit is the LF model, not the "
        "search: the plain LF model (linear P12 law, no leakage) has its best fit a few percent "
        "away from the injected FDJ (see docs/fdi.md).",
        "", f"![mean error]({png.name})", ""]
    if "aug_mean_err_pct" in table:
        lines += _augmented_markdown(table)
    cases = plot_fdi_cases(rows, campaign, out / "cases")
    lines += ["## Each case: HF reference against the identified LF model (first seed)", ""]
    lines += [f"![case {c}](cases/{path.name})" for c, path in cases.items()] + [""]
    md = out / "fdi_summary.md"
    md.write_text("\n".join(lines), encoding="utf-8")
    return {"table": csv_path, "plot": png, "summary": md, "cases": out / "cases"}


def plot_fdi_cases(rows: Sequence[dict], campaign, out: str | Path) -> dict[int, Path]:
    """One figure per case, like the thesis' Figures 6.4–6.16: the HF reference with the
    injected faults against the LF model with the identified ones, for the case's first seed
    (both re-simulated: the runs are deterministic). Returns ``case -> PNG path``."""
    from eha.fdi import hf_reference
    from eha.params import resolve
    from eha.simulate import simulate

    base = resolve("lf", campaign.base)
    paths = {}
    for case in campaign.cases:
        rs = sorted((r for r in rows if int(r["case"]) == case.case), key=lambda r: r["seed"])
        if not rs:
            continue
        r = rs[0]
        hf = hf_reference(case.command, case.faults, seed=r["seed"], t_end=campaign.t_end)
        lf = simulate("lf", case.command, base.replace(**r["estimates"]), t_end=campaign.t_end)
        truth = ", ".join(f"{k}={v:.4g}" for k, v in r["truth"].items())
        est = ", ".join(f"{k}={v:.4g}" for k, v in r["estimates"].items())
        paths[case.case] = plot_traces(
            [hf, lf], Path(out) / f"case_{case.case:02d}.png",
            title=f"Case {case.case} ({case.command}, seed {r['seed']}): HF with {truth}\n"
                  f"vs LF with the identified {est} (mean error {r['mean_err_pct']:.3g} %)")
    return paths


#: The campaign of the thesis' fault-identification cases (campaigns/thesis-fdi.toml).
FDI_CAMPAIGN = "thesis-fdi"


def fdi_results(results: str | Path = "results", campaign: str = FDI_CAMPAIGN):
    """The ``fdi_results`` rows of a campaign and its definition, from ``DIR/eha.duckdb``.

    Returns
    -------
    (list of dict, eha.fdi_cases.FDICampaign)
        Rows as :func:`eha.fdi_cases.run_case` returns them; the campaign as it was run (its stored
        definition, so the thesis' values travel with the results).

    Raises
    ------
    eha.store.StoreError
        No database, or no FDI result of that campaign in it.
    """
    from eha.fdi_cases import parse_fdi_campaign, rows_from_results
    from eha.store import StoreError, query

    name = campaign.replace("'", "''")
    frame = query(results, f"""
        SELECT f.* FROM fdi_results f JOIN runs r USING (run_key)
        WHERE r.campaign = '{name}' AND r.status = 'done' ORDER BY f.case_id, f.seed""")
    definition = query(results, f"SELECT definition FROM campaigns WHERE name = '{name}'")
    if frame.empty or definition.empty:
        raise StoreError(f"{Path(results) / 'eha.duckdb'}: no FDI results of campaign "
                         f"{campaign!r}; run `eha campaign run campaigns/{campaign}.toml` "
                         "(or `eha reproduce`) first")
    camp = parse_fdi_campaign(json.loads(definition["definition"].iloc[0]), campaign)
    return rows_from_results(frame), camp


def thesis_report(results: str | Path = "results", out: str | Path | None = None,
                  campaign: str = FDI_CAMPAIGN) -> dict[str, Path]:
    """``eha report thesis``: the FDI table, figure and summary of ``campaign`` from the
    database in ``results``, written to ``out`` (default ``results/reports/thesis``)."""
    from eha.store import StoreError

    rows, camp = fdi_results(results, campaign)
    try:
        augmented, _ = fdi_results(results, AUGMENTED_CAMPAIGN)
    except StoreError:      # not run (yet): the report has the plain columns only
        augmented = None
    return write_thesis_report(rows, camp, Path(out) if out else
                               Path(results) / "reports" / "thesis", augmented)


#: The thesis FDI cases with the LF model augmented by ``eha explain`` on nominal HF data
#: (campaigns/thesis-fdi-augmented.toml; issue 5, item 6).
AUGMENTED_CAMPAIGN = "thesis-fdi-augmented"


def _augmented_markdown(table) -> list[str]:
    """Summary section of the augmented-LF columns (goal: mean error <= 1 % on cases 3-12,
    <= 5 % on case 2)."""
    fmt = lambda v: f"{v:.3g}"  # noqa: E731
    body = [[str(r.case), r.command, fmt(r.mean_err_pct), fmt(r.aug_bkl_out), fmt(r.aug_fdj_out),
             fmt(r.aug_err_bkl_pct), fmt(r.aug_err_fdj_pct), fmt(r.aug_mean_err_pct),
             fmt(r.thesis_mean_err_pct),
             "yes" if r.aug_at_least_as_accurate == True else "no"]  # noqa: E712 (NaN: no)
            for r in table.itertuples()]
    late = table[table["case"] >= 3]
    case2 = table[table["case"] == 2]
    lines = ["## LF model augmented by `eha explain` (campaign thesis-fdi-augmented)", "",
             "The same cases with the LF model augmented by the effects `eha explain` adds on "
             "nominal HF data (the base and how it was found: campaigns/thesis-fdi-augmented.toml"
             ", docs/explain.md). Medians over the seeds.", "",
             f"- cases at least as accurate as the thesis (median over seeds): **"
             f"{int((table['aug_at_least_as_accurate'] == True).sum())}/{len(table)}**"]  # noqa: E712
    if not late.empty:
        lines.append(f"- mean error, cases 3–12: plain **{late['mean_err_pct'].mean():.3g} %**"
                     f" → augmented **{late['aug_mean_err_pct'].mean():.3g} %** (goal ≤ 1 %); "
                     f"worst case {late['aug_mean_err_pct'].max():.3g} %")
    if not case2.empty:
        lines.append(f"- case 2: plain {case2['mean_err_pct'].iloc[0]:.3g} % → augmented "
                     f"**{case2['aug_mean_err_pct'].iloc[0]:.3g} %** (goal ≤ 5 %)")
    return lines + ["", _markdown_table(
        ["case", "command", "plain mean err [%]", "aug. BKL out [m]", "aug. FDJ out [N]",
         "aug. BKL err [%]", "aug. FDJ err [%]", "aug. mean err [%]", "thesis [%]",
         "aug. ≤ thesis"], body), ""]


# =========================================================================== residual loop
def plot_explain_residuals(result, path: str | Path) -> Path:
    """Measured vs LF before/after, and the residual before/after the added effects (PNG).

    ``result`` is an :class:`eha.explain.ExplainResult`; the held-out part is shaded.
    """
    plt = _pyplot()
    t = result.t
    fig, axes = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True,
                             gridspec_kw={"height_ratios": [3, 2]})
    added = ", ".join(result.effects) or "nothing added"
    axes[0].plot(t, 1e3 * result.measured, color="0.6", lw=2.2, label="measured xu")
    axes[0].plot(t, 1e3 * result.before.xu, "--", lw=1.2,
                 label=f"LF, declared faults (RMSE {1e6 * result.rmse_before:.3g} µm)")
    axes[0].plot(t, 1e3 * result.after.xu, lw=1.2,
                 label=f"LF + {added} (RMSE {1e6 * result.rmse_after:.3g} µm)")
    axes[0].set_ylabel("position [mm]")
    axes[1].plot(t, 1e6 * (result.measured - result.before.xu), lw=0.9,
                 label="residual before")
    axes[1].plot(t, 1e6 * (result.measured - result.after.xu), lw=0.9, label="residual after")
    noise = 1e6 * result.noise_rmse
    axes[1].axhspan(-noise, noise, color="0.85", zorder=0,
                    label=f"±noise level ({noise:.2g} µm)")
    axes[1].set_ylabel("measured − LF [µm]")
    axes[1].set_xlabel("time [s]")
    n_fit = result.settings.get("n_fit", len(t))
    for ax in axes:
        if n_fit < len(t):
            ax.axvspan(t[n_fit], t[-1], color="tab:orange", alpha=0.08, lw=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    if n_fit < len(t):
        axes[0].text(t[n_fit], axes[0].get_ylim()[1], " held out", va="top", fontsize=8,
                     color="tab:orange")
    fig.suptitle(f"Residual loop — {Path(result.source).name}: RMSE "
                 f"{1e6 * result.rmse_before:.3g} → {1e6 * result.rmse_after:.3g} µm")
    return _save(fig, Path(path))


def plot_explain_trace(result, path: str | Path) -> Path:
    """How the first residual traces to effects: signature correlation, the fraction each
    effect's linearised fit explains, held-out gain of the refits, and signal correlations."""
    plt = _pyplot()
    if not result.rounds:
        fig, ax = plt.subplots(figsize=(7, 2))
        ax.axis("off")
        ax.text(0.5, 0.5, f"Residual not traced: {result.stop_reason}", ha="center",
                va="center", wrap=True, fontsize=9)
        return _save(fig, Path(path))
    rnd = result.rounds[0]
    cands = sorted((c for c in rnd.candidates if "+" not in c.effect),  # single effects
                   key=lambda c: c.explained)
    names = [c.effect for c in cands]
    y = np.arange(len(cands))
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 0.32 * len(cands) + 2.2),
                                  gridspec_kw={"width_ratios": [3, 1.4]})
    ax.barh(y - 0.2, [c.explained for c in cands], 0.4, label="explained by signature (lin.)")
    ax.barh(y + 0.2, [abs(c.signature_corr) for c in cands], 0.4,
            label="|corr(residual, signature)|")
    gains = [max(c.gain, 0.0) if c.refit else np.nan for c in cands]
    ax.plot(gains, y, "k^", label="held-out gain of the refit")
    ax.set_yticks(y, names)
    ax.set_xlim(0, 1.05)
    ax.set_xlabel("fraction")
    ax.grid(True, axis="x", alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("Effects (round 1)", fontsize=10)
    sig = list(rnd.signals.items())
    ax2.barh(range(len(sig)), [v for _, v in sig], color="tab:gray")
    ax2.set_yticks(range(len(sig)), [k for k, _ in sig])
    ax2.set_xlim(-1, 1)
    ax2.axvline(0, color="k", lw=0.6)
    ax2.set_xlabel("correlation with the residual")
    ax2.set_title("Signals", fontsize=10)
    ax2.grid(True, axis="x", alpha=0.3)
    fig.suptitle(f"Tracing the residual ({1e6 * rnd.residual_rmse:.3g} µm RMS on the fitted "
                 f"part) — {Path(result.source).name}")
    return _save(fig, Path(path))


def explain_report(data: str | Path, fit: str | None = None, effects: str | None = None,
                   holdout: float | None = None, validate: str | Path | None = None,
                   prior: str | Path | None = None, json_path: str | Path | None = None,
                   out: str | Path | None = None, results: str | Path = "results",
                   on_progress=None, known: dict[str, float] | None = None,
                   **options) -> dict:
    """``eha explain``: run the residual loop on a measured file and write its outputs.

    Everything is read and validated before anything is written. Writes, under ``out``
    (default ``results/explain/<file stem>``): ``steps.csv`` (the steps table),
    ``candidates.csv`` (every candidate of every round), ``residuals.png``, ``trace.png``,
    ``explain.json`` (everything); the rows of ``explain_runs``/``explain_steps`` in
    ``results/eha.duckdb``; and, when given, ``json_path`` with the contract of issue 5.
    ``known`` holds LF parameters fixed at known values (test conditions such as a test load
    ``{"FRC": 4000}``), on top of the ``prior``'s effects; they are not candidates.

    Returns
    -------
    dict
        ``result`` (:class:`eha.explain.ExplainResult`), ``paths`` (name -> Path),
        ``run_id``, ``db_error`` (None, or why the database could not be written).
    """
    import datetime
    import hashlib

    import pandas as pd

    from eha.explain import ExplainError, augmented_base, explain
    from eha.measured import load
    from eha.store import StoreError, save_explain

    record = load(data)
    check = load(validate) if validate is not None else None
    base = None
    if prior is not None:
        try:
            base = augmented_base(json.loads(Path(prior).read_text()))
        except (OSError, ValueError) as exc:
            raise ExplainError(f"--prior {prior}: {str(exc).splitlines()[0]}") from None
    if known:
        from eha.params import ParameterError, resolve

        try:
            base = resolve("lf", dict(known), base=base)
        except ParameterError as exc:
            raise ExplainError(f"--set {exc}") from None
    result = explain(record, fit=fit, effects=effects, holdout=holdout, validate=check,
                     base=base, on_progress=on_progress, fixed=tuple(known or ()), **options)

    out = Path(out) if out is not None else Path(results) / "explain" / Path(data).stem
    out.mkdir(parents=True, exist_ok=True)
    digest = hashlib.sha1(Path(data).read_bytes())
    digest.update(json.dumps([str(validate), str(prior), dict(known or {}), result.settings,
                              {k: list(v) for k, v in result.fit_bounds.items()}],
                             sort_keys=True, default=str).encode())
    run_id = digest.hexdigest()[:16]
    paths = {"steps": out / "steps.csv", "candidates": out / "candidates.csv",
             "residuals": out / "residuals.png", "trace": out / "trace.png",
             "details": out / "explain.json"}
    pd.DataFrame(result.steps_table()).to_csv(paths["steps"], index=False)
    pd.DataFrame([{"round": i + 1, **{k: v for k, v in vars(c).items()
                                      if not k.startswith("_")}}
                  for i, rnd in enumerate(result.rounds) for c in rnd.candidates]
                 ).to_csv(paths["candidates"], index=False)
    plot_explain_residuals(result, paths["residuals"])
    plot_explain_trace(result, paths["trace"])
    details = {**result.to_json(), "run_id": run_id, "source": result.source,
               "noise_rmse": result.noise_rmse, "unexplained_rmse": result.unexplained_rmse,
               "stop_reason": result.stop_reason, "holdout": result.holdout,
               "steps_table": result.steps_table(), "settings": result.settings,
               "signals": [r.signals for r in result.rounds], "seconds": result.seconds}
    paths["details"].write_text(json.dumps(details, indent=2, default=float))
    if json_path is not None:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(json.dumps(result.to_json(), indent=2))
        paths["json"] = Path(json_path)
    run_row = {"run_id": run_id, "source": str(data), "created_at": datetime.datetime.now(),
               "fit": {k: list(v) for k, v in result.fit_bounds.items()},
               "holdout": result.holdout, "settings": result.settings,
               "rmse_before": result.rmse_before, "rmse_after": result.rmse_after,
               "noise_rmse": result.noise_rmse, "unexplained_rmse": result.unexplained_rmse,
               "faults_before": result.faults_before, "faults_after": result.faults_after,
               "effects": result.effects, "stop_reason": result.stop_reason,
               "seconds": result.seconds}
    step_rows = [{"run_id": run_id, "step": i + 1, "effect": s.effect,
                  "params": result.final_params(s),
                  "rmse_before": s.rmse_before, "rmse_after": s.rmse_after,
                  "rmse_fit_before": s.rmse_fit_before, "rmse_fit_after": s.rmse_fit_after,
                  "rmse_hold_before": s.rmse_hold_before, "rmse_hold_after": s.rmse_hold_after,
                  "faults_before": s.faults_before, "faults_after": s.faults_after,
                  "gain": s.gain, "score": s.score} for i, s in enumerate(result.steps)]
    db_error = None
    try:
        paths["database"] = save_explain(results, run_row, step_rows)
    except StoreError as exc:
        db_error = str(exc)
    return {"result": result, "paths": paths, "run_id": run_id, "db_error": db_error}
