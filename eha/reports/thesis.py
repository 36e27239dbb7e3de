"""The thesis reproduction: chapter-5 campaigns and their report, and the chapter-6 fault
identification table against the thesis' own values (``eha reproduce``,
``eha report thesis``).

Reads what the runner stored in ``DIR/eha.duckdb``; draws with :mod:`eha.reports.plots`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from eha.campaigns.files import campaigns_dir
from eha.figures import pyplot as _pyplot
from eha.figures import save as _save
from eha.reports.fdi_table import AUGMENTED_CAMPAIGN, FDI_CAMPAIGN, fdi_table
from eha.reports.plots import (campaign_report, campaign_runs, fault_order, fault_text,
                               plot_campaign, plot_traces)

if TYPE_CHECKING:      # for the annotations only: pandas is imported where a table is built
    import pandas as pd

#: Thesis chapter-5 campaigns run by :func:`reproduce_thesis` (files ``campaigns/<name>.toml``).
THESIS_CAMPAIGNS = ["thesis-nominal", "thesis-single-fault", "thesis-matrix"]


def _markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


@dataclass
class Reproduction:
    """What :func:`reproduce_thesis` did: the campaigns' :class:`eha.campaigns.runner.RunSummary`
    (``summaries``), the nominal HF-vs-LF error per command (``nominal``: ``rmse_xu_m`` in m,
    ``rmse_pct_of_peak`` in % of the command's peak), the figures and reports written, the
    FDI report's paths (``fdi``) and the HTML report (``html``)."""

    summaries: list
    nominal: list[dict]
    plots: list[Path]
    reports: list[Path]
    fdi: dict
    html: Any

    def to_pandas(self) -> "pd.DataFrame":
        """The nominal HF-vs-LF error, one row per command (``rmse_xu_m`` in m)."""
        import pandas as pd

        return pd.DataFrame(self.nominal, columns=["command", "rmse_xu_m",
                                                   "rmse_pct_of_peak"])


def reproduce_thesis(results: str | Path = "results", *, workers: int = 2,
                     progress: bool = True, on_phase=None) -> Reproduction:
    """Thesis chapters 5 and 6 end to end: run :data:`THESIS_CAMPAIGNS` and the FDI campaign
    :data:`FDI_CAMPAIGN`, then figures and reports (the FDI ones by :func:`thesis_report`).

    Runs each ``campaigns/<name>.toml`` into ``results`` on one pool of ``workers`` processes
    (resuming runs already done; a thesis campaign whose file changed is re-run from scratch),
    then writes ``plots/nominal_<command>.png`` (HF vs LF, every signal), the campaign figures
    of :func:`plot_campaign` under ``plots/<campaign>/``, ``reports/<campaign>.csv`` and
    ``reports/summary.md``. ``on_phase(message)`` is told each phase after the campaigns
    (the figures, the reports, the HTML page: 20 s and more on 2 cores).

    Returns
    -------
    dict
        ``summaries`` (one :class:`eha.campaigns.runner.RunSummary` per campaign), ``nominal`` (rows:
        command, RMSE of xu HF vs LF [m], as % of the command peak), ``plots``, ``reports``,
        ``fdi`` (:func:`thesis_report`'s paths), ``html`` (:class:`eha.reports.html.ReportResult`).
    """
    from eha.campaigns.executors import LocalPoolExecutor
    from eha.campaigns.runner import run_campaign
    from eha.campaigns.query import check_trace_files
    from eha.campaigns.traces import read_trace

    results = Path(results)
    summaries = []
    with LocalPoolExecutor(workers) as pool:
        # chapter 5, then chapter 6 (FDI), then FDI with the LF augmented by eha explain
        for name in THESIS_CAMPAIGNS + [FDI_CAMPAIGN, AUGMENTED_CAMPAIGN]:
            path = campaigns_dir() / f"{name}.toml"
            summaries.append(run_campaign(path, results, replace=True, progress=progress,
                                          executor=pool))
    say = on_phase or (lambda message: None)
    plots: list[Path] = []
    nominal = []
    runs = campaign_runs(results, "thesis-nominal")
    check_trace_files(results, set(runs["trace_path"]), "report")
    commands = list(dict.fromkeys(runs["command"]))
    for k, cmd in enumerate(commands):
        say(f"figures: nominal HF vs LF, {cmd} ({k + 1} of {len(commands)})")
        sel = runs[runs["command"] == cmd].set_index("model")
        hf = read_trace(results / sel.loc["hf", "trace_path"], sel.loc["hf", "run_key"])
        lf = read_trace(results / sel.loc["lf", "trace_path"], sel.loc["lf", "run_key"])
        plots.append(plot_traces([hf, lf], results / "plots" / f"nominal_{cmd}.png",
                                 title=f"Nominal HF vs LF — {cmd}"))
        err = float(sel.loc["hf", "rmse_xu_hf_lf"])
        peak = float(np.max(np.abs(hf["com"])))
        nominal.append({"command": cmd, "rmse_xu_m": err, "rmse_pct_of_peak": 100 * err / peak})
    reports = []
    for k, name in enumerate(THESIS_CAMPAIGNS):
        say(f"figures and CSV of campaign {name} ({k + 1} of {len(THESIS_CAMPAIGNS)})")
        plots += plot_campaign(results, name)
        reports.append(campaign_report(results, name))
    reports.append(_summary_markdown(results, summaries, nominal))
    say("thesis fault identification report (Figure 6.17)")
    fdi = thesis_report(results)        # reports/thesis: fdi_table.csv, mean_error.png, summary
    plots.append(fdi["plot"])
    reports += [fdi["table"], fdi["summary"]]
    # imported here: eha.reports.html.data reads this module's FDI table (a cycle at import)
    from eha.reports.html import build_report

    say("HTML report of the folder (reports/report.html)")
    html = build_report(results, results / "reports" / "report.html")   # one page of it all
    reports.append(html.path)
    return Reproduction(summaries, nominal, plots, reports, fdi, html)


#: per campaign, the call of eha reproduce that ran its runs (kept across calls)
WORK_RECORD = "reports/campaign_work.json"


def _work_record(results: Path, summaries) -> list[dict]:
    """Per summary, the record of the call that did the campaign's work: this call's when it
    ran anything (or nothing is recorded yet), else the one recorded in
    :data:`WORK_RECORD`, which is updated."""
    import datetime
    import json

    path = results / WORK_RECORD
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        record = record if isinstance(record, dict) else {}
    except (OSError, ValueError):
        record = {}
    now = datetime.datetime.now().isoformat(timespec="seconds")
    out = []
    for s in summaries:
        old = record.get(s.campaign)
        if s.done or s.failed or not isinstance(old, dict):
            old = record[s.campaign] = {"done": s.done, "failed": s.failed,
                                        "wall_s": s.wall_s, "at": now}
        out.append(old)
    from eha.outputs import write_json

    write_json(path, record, indent=1)
    return out


def _summary_markdown(results: Path, summaries, nominal: list[dict]) -> Path:
    parts = ["# Thesis chapter 5 reproduction", "",
             "Generated by `eha reproduce`. Query everything with `eha query`, e.g. "
             "`eha query \"SELECT * FROM runs JOIN metrics USING (run_key) LIMIT 5\"`.", "",
             "## Campaigns", "",
             "The run that did each campaign's work (a later call that found every run done "
             "does not replace it); the last call in the last columns.", "",
             _markdown_table(["campaign", "runs", "run by the work", "failed", "wall [s]",
                              "work done at", "last call: run now", "already done"],
                             [[s.campaign, str(s.total), str(w["done"]), str(w["failed"]),
                               f"{w['wall_s']:.1f}", w["at"], str(s.done), str(s.skipped)]
                              for s, w in zip(summaries, _work_record(results, summaries))]),
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
                              key=lambda x: fault_order(x[0])):
            table.setdefault(fault_text(f), {})[c] = v
        parts += ["", f"## {name}: RMSE of xu, HF vs LF [µm]", "",
                  _markdown_table(["faults"] + commands,
                                  [[k] + [f"{1e6 * v[c]:.3g}" if c in v else "-"
                                          for c in commands] for k, v in table.items()])]
    path = results / "reports" / "summary.md"
    from eha.outputs import write_atomic

    write_atomic(path, "\n".join(parts) + "\n")
    return path

# =========================================================================== thesis FDI report
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
    from eha.outputs import atomic_path, write_atomic

    with atomic_path(csv_path) as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")
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
    write_atomic(md, "\n".join(lines))
    return {"table": csv_path, "plot": png, "summary": md, "cases": out / "cases"}


def plot_fdi_cases(rows: Sequence[dict], campaign, out: str | Path) -> dict[int, Path]:
    """One figure per case, like the thesis' Figures 6.4–6.16: the HF reference with the
    injected faults against the LF model with the identified ones, for the case's first seed
    (both re-simulated: the runs are deterministic). Returns ``case -> PNG path``."""
    from eha.identification.fdi import hf_reference
    from eha.models.params import resolve
    from eha.models.simulate import simulate

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

def fdi_results(results: str | Path = "results", campaign: str = FDI_CAMPAIGN):
    """The ``fdi_results`` rows of a campaign and its definition, from ``DIR/eha.duckdb``.

    Returns
    -------
    (list of dict, eha.identification.cases.FDICampaign)
        Rows as :func:`eha.identification.cases.run_case` returns them; the campaign as it was run
        (its stored definition, so the thesis' values travel with the results).

    Raises
    ------
    eha.campaigns.store.StoreError
        No database, or no FDI result of that campaign in it.
    """
    from eha.identification.cases import parse_fdi_campaign, rows_from_results
    from eha.campaigns.query import query
    from eha.campaigns.store import StoreError

    definition = query(results, "SELECT definition FROM campaigns WHERE name = ?", [campaign])
    # the fdi kind's table exists once an fdi campaign has written to the database
    frame = query(results, """
        SELECT f.* FROM fdi_results f JOIN runs r USING (run_key)
        WHERE r.campaign = ? AND r.status = 'done' ORDER BY f.case_id, f.seed""",
                  [campaign]) if not definition.empty else None
    if frame is None or frame.empty:
        raise StoreError(f"{Path(results) / 'eha.duckdb'}: no FDI results of campaign "
                         f"{campaign!r}; run `eha campaign run campaigns/{campaign}.toml` "
                         "(or `eha reproduce`) first")
    camp = parse_fdi_campaign(json.loads(definition["definition"].iloc[0]), campaign)
    return rows_from_results(frame), camp


def thesis_report(results: str | Path = "results", out: str | Path | None = None,
                  campaign: str = FDI_CAMPAIGN) -> dict[str, Path]:
    """``eha report thesis``: the FDI table, figure and summary of ``campaign`` from the
    database in ``results``, written to ``out`` (default ``results/reports/thesis``)."""
    from eha.campaigns.store import StoreError

    rows, camp = fdi_results(results, campaign)
    try:
        augmented, _ = fdi_results(results, AUGMENTED_CAMPAIGN)
    except StoreError:      # not run (yet): the report has the plain columns only
        augmented = None
    return write_thesis_report(rows, camp, Path(out) if out else
                               Path(results) / "reports" / "thesis", augmented)

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
