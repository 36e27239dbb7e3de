"""Interactive figures of the HTML report (plotly figures as JSON-ready dicts).

Every figure aggregates what the database holds (no stored trace is embedded); hover labels
carry the unit of each value. Built with :mod:`plotly.graph_objects` (validated), returned as
``fig.to_plotly_json()`` dicts for :mod:`eha.reports.html.page` to embed.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Mapping, Sequence

import numpy as np

from eha.reports.html.data import Fleet, fault_key, unit_of

#: Colours of the report (plotly's default sequence, named where one has a meaning).
BLUE, ORANGE, GREEN, RED, GREY = "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#7f7f7f"
#: α of the α-λ cone (prognostic metrics, ±20 %).
ALPHA = 0.2


def _go():
    import plotly.graph_objects as go

    return go


#: The look of every figure: one plotly template, embedded once in the page and applied by its
#: script (not copied into each figure).
TEMPLATE = "plotly_white"


@contextmanager
def shared_template():
    """While building the report's figures: figures get no template of their own (plotly's
    default is deep-copied into every figure otherwise, a third of the build time); the page
    applies :data:`TEMPLATE` to each when it draws it."""
    import plotly.io as pio

    before = pio.templates.default
    pio.templates.default = "none"
    try:
        yield
    finally:
        pio.templates.default = before


def template_json() -> dict:
    """:data:`TEMPLATE` as JSON (the page's script sets it as each figure's template)."""
    import plotly.io as pio

    return pio.templates[TEMPLATE].to_plotly_json()


def _done(fig, title: str, height: int = 420) -> dict:
    fig.update_layout(title={"text": title, "font": {"size": 15}}, height=height,
                      margin={"l": 70, "r": 30, "t": 60, "b": 55},
                      hoverlabel={"namelength": -1}, legend={"font": {"size": 11}})
    return fig.to_plotly_json()


def _none(values) -> list:
    """Floats with NaN for None (plotly draws a gap)."""
    return [np.nan if v is None else float(v) for v in values]


# =========================================================================== fleet
def fleet_overview(rows: Sequence[Mapping[str, Any]], unit: str = "cycles") -> dict:
    """RUL at the last check of every actuator (median, 5-95 %), most urgent on top."""
    go = _go()
    rows = sorted(rows, key=lambda r: (r["rul"] is None, r["rul"] if r["rul"] is not None
                                       else 0.0), reverse=True)
    names = [r["actuator"] for r in rows]
    med = _none(r["rul"] for r in rows)
    lo = _none(r["rul_lo"] for r in rows)
    hi = _none(r["rul_hi"] for r in rows)
    colour = {"end of life": RED, "attention": ORANGE, "ok": BLUE, "no trend": GREY}
    fig = go.Figure(go.Scatter(
        x=med, y=names, mode="markers", marker={"size": 9, "color": [colour.get(r["status"],
                                                                            GREY) for r in rows]},
        error_x={"type": "data", "symmetric": False, "color": GREY,
                 "array": [h - m if np.isfinite(h) else 0 for h, m in zip(hi, med)],
                 "arrayminus": [m - v if np.isfinite(v) else 0 for v, m in zip(lo, med)]},
        customdata=np.array([[r["status"], r["driver"] or "-", r["last_cycle"], l_, h_]
                             for r, l_, h_ in zip(rows, lo, hi)], dtype=object),
        hovertemplate=("%{y}: RUL %{x:.0f} " + unit + " [%{customdata[3]:.0f}, "
                       "%{customdata[4]:.0f}] at cycle %{customdata[2]:.0f}<br>driver "
                       "%{customdata[1]}, %{customdata[0]}<extra></extra>"), name="RUL"))
    fig.update_xaxes(title_text=f"remaining useful life at the last check [{unit}] "
                                "(median, 5-95 %)", rangemode="tozero")
    fig.update_yaxes(title_text="actuator", type="category")
    return _done(fig, "Remaining useful life per actuator (colour: status)",
                 height=max(300, 60 + 22 * len(rows)))


def actuator_figure(fleet: Fleet, aid: str) -> dict:
    """One actuator: each fault's estimates with intervals, its limit and the predicted
    crossing (median, 5-95 %), then the RUL at every check with its interval; the true end of
    life, the true RUL and the α-cone when the truth is known."""
    go = _go()
    from plotly.subplots import make_subplots

    grp = fleet.predictions[fleet.predictions["actuator"] == aid].sort_values("cycle")
    faults = fleet.faults
    fig = make_subplots(rows=len(faults) + 1, cols=1, shared_xaxes=True,
                        vertical_spacing=0.06)
    cyc = grp["cycle"].to_numpy(float)
    last = grp.iloc[-1]
    eol = (fleet.truth or {}).get(aid)
    shown: set[str] = set()                  # legend entries already drawn
    for i, name in enumerate(faults, start=1):
        unit, f = unit_of(name)
        est = np.array(_none((e or {}).get(name) for e in grp["estimates"]))
        ivs = [(iv or {}).get(name) or (None, None) for iv in grp["intervals"]]
        lo, hi = np.array(_none(v[0] for v in ivs)), np.array(_none(v[1] for v in ivs))
        flagged = grp["flagged"].fillna(False).to_numpy(bool)
        fig.add_trace(go.Scatter(
            x=cyc, y=f * est, mode="markers+lines",
            name="identified (90 % interval; grey: flagged)",
            marker={"size": 6, "color": [GREY if fl else BLUE for fl in flagged]},
            line={"width": 1, "color": BLUE},
            error_y={"type": "data", "symmetric": False, "color": BLUE,
                     "array": np.nan_to_num(f * (hi - est)),
                     "arrayminus": np.nan_to_num(f * (est - lo))},
            customdata=np.c_[f * lo, f * hi, flagged.astype(float)],
            hovertemplate=(f"cycle %{{x:.0f}}: {name} %{{y:.4g}} {unit} "
                           f"[%{{customdata[0]:.4g}}, %{{customdata[1]:.4g}}] {unit}"
                           "<extra></extra>"), legendgroup="est", showlegend=i == 1),
            row=i, col=1)
        lim = fleet.limits.get(name)
        if lim is not None:
            fig.add_hline(y=f * lim, line={"color": RED, "dash": "dash", "width": 1.2},
                          annotation_text=f"limit {f * lim:.4g} {unit}",
                          annotation_position="top left", row=i, col=1)
            cr = (last["crossings"] or {}).get(name) or {}
            if cr.get("median") is not None:
                c_lo = cr.get("lo") if cr.get("lo") is not None else cr["median"]
                c_hi = cr.get("hi") if cr.get("hi") is not None else cr["median"]
                fig.add_trace(go.Scatter(
                    x=[cr["median"]], y=[f * lim], mode="markers",
                    name="predicted crossing (5-95 %)",
                    marker={"symbol": "diamond", "size": 11, "color": ORANGE},
                    error_x={"type": "data", "symmetric": False,
                             "array": [c_hi - cr["median"]],
                             "arrayminus": [cr["median"] - c_lo]},
                    hovertemplate=(f"{name} reaches {f * lim:.4g} {unit} at cycle "
                                   f"%{{x:.0f}} [{c_lo:.0f}, {c_hi:.0f}] (5-95 %)"
                                   "<extra></extra>"), legendgroup="cross",
                    showlegend="cross" not in shown), row=i, col=1)
                shown.add("cross")
        fig.update_yaxes(title_text=f"{name} [{unit}]", row=i, col=1)
    r = len(faults) + 1
    med, rlo, rhi = (np.array(_none(grp[k])) for k in ("rul", "rul_lo", "rul_hi"))
    fig.add_trace(go.Scatter(x=cyc, y=rhi, mode="lines", line={"width": 0}, showlegend=False,
                             hoverinfo="skip"), row=r, col=1)
    fig.add_trace(go.Scatter(x=cyc, y=rlo, mode="lines", line={"width": 0}, fill="tonexty",
                             fillcolor="rgba(31,119,180,0.2)", name="RUL 5-95 %",
                             hoverinfo="skip"), row=r, col=1)
    fig.add_trace(go.Scatter(
        x=cyc, y=med, mode="markers+lines", name="RUL median", marker={"color": BLUE},
        customdata=np.c_[rlo, rhi],
        hovertemplate=("cycle %{x:.0f}: RUL %{y:.0f} cycles [%{customdata[0]:.0f}, "
                       "%{customdata[1]:.0f}] cycles<extra></extra>")), row=r, col=1)
    if eol is not None:
        tt = np.linspace(cyc[0], eol, 30)
        fig.add_trace(go.Scatter(x=tt, y=(1 + ALPHA) * (eol - tt), mode="lines",
                                 line={"width": 0}, showlegend=False, hoverinfo="skip"),
                      row=r, col=1)
        fig.add_trace(go.Scatter(x=tt, y=(1 - ALPHA) * (eol - tt), mode="lines",
                                 line={"width": 0}, fill="tonexty",
                                 fillcolor="rgba(0,0,0,0.08)", name=f"α-cone ±{ALPHA:.0%}",
                                 hoverinfo="skip"), row=r, col=1)
        fig.add_trace(go.Scatter(x=tt, y=eol - tt, mode="lines", name="true RUL",
                                 line={"color": "black", "width": 1.2},
                                 hovertemplate="cycle %{x:.0f}: true RUL %{y:.0f} cycles"
                                               "<extra></extra>"), row=r, col=1)
        for i in range(1, r + 1):
            fig.add_vline(x=eol, line={"color": "black", "width": 1}, row=i, col=1)
    fig.update_yaxes(title_text="RUL [cycles]", rangemode="tozero", row=r, col=1)
    fig.update_xaxes(title_text="cycle", row=r, col=1)
    title = f"Actuator {aid}: fault trends and remaining useful life"
    if eol is not None:
        title += f" (true end of life {eol:.0f})"
    return _done(fig, title, height=230 * (len(faults) + 1) + 80)


def change_figure(fleet: Fleet, aid: str) -> dict:
    """One actuator on the change check: each tracked fault's change since the baseline with
    its interval at every check (red: the fault alarms and the check is isolated to it), and
    its first alarm."""
    go = _go()
    from plotly.subplots import make_subplots

    grp = fleet.changes[fleet.changes["actuator"] == aid].sort_values("cycle")
    faults = fleet.faults
    fig = make_subplots(rows=len(faults), cols=1, shared_xaxes=True, vertical_spacing=0.08)
    cyc = grp["cycle"].to_numpy(float)
    for i, name in enumerate(faults, start=1):
        unit, f = unit_of(name)
        ch = np.array(_none((c or {}).get(name) for c in grp["changes"]))
        ivs = [(iv or {}).get(name) or (None, None) for iv in grp["intervals"]]
        lo, hi = np.array(_none(v[0] for v in ivs)), np.array(_none(v[1] for v in ivs))
        alarm = [bool((d or {}).get(name)) and name in (iso or [])
                 for d, iso in zip(grp["degraded"], grp["isolated"])]
        fig.add_trace(go.Scatter(
            x=cyc, y=f * ch, mode="markers+lines", name="change (90 % interval; red: alarm)",
            marker={"size": 6, "color": [RED if a else BLUE for a in alarm]},
            line={"width": 1, "color": BLUE},
            error_y={"type": "data", "symmetric": False, "color": BLUE,
                     "array": np.nan_to_num(f * (hi - ch)),
                     "arrayminus": np.nan_to_num(f * (ch - lo))},
            customdata=np.c_[f * lo, f * hi],
            hovertemplate=(f"cycle %{{x:.0f}}: {name} changed by %{{y:.4g}} {unit} "
                           f"[%{{customdata[0]:.4g}}, %{{customdata[1]:.4g}}] {unit}"
                           "<extra></extra>"), legendgroup="ch", showlegend=i == 1),
            row=i, col=1)
        first = (fleet.alarms.get(aid, {}).get(name) or {}).get("first_alarm")
        if first is not None and np.isfinite(first):
            fig.add_vline(x=first, line={"color": RED, "dash": "dot", "width": 1.2},
                          annotation_text=f"first alarm {first:.0f}", row=i, col=1)
        fig.add_hline(y=0, line={"color": GREY, "width": 1}, row=i, col=1)
        fig.update_yaxes(title_text=f"Δ{name} [{unit}]", row=i, col=1)
    fig.update_xaxes(title_text="cycle", row=len(faults), col=1)
    return _done(fig, f"Actuator {aid}: change since its baseline (change check)",
                 height=200 * len(faults) + 100)


def alpha_lambda_figure(fleet: Fleet) -> dict | None:
    """Every actuator's RUL (median, 5-95 %) relative to its monitored life against λ, inside
    the α-cone; None without a truth."""
    if not fleet.truth:
        return None
    go = _go()
    fig = go.Figure()
    lam = np.linspace(0, 1, 30)
    fig.add_trace(go.Scatter(x=lam, y=(1 + ALPHA) * (1 - lam), mode="lines", line={"width": 0},
                             showlegend=False, hoverinfo="skip"))
    fig.add_trace(go.Scatter(x=lam, y=(1 - ALPHA) * (1 - lam), mode="lines", line={"width": 0},
                             fill="tonexty", fillcolor="rgba(0,0,0,0.1)",
                             name=f"α-cone ±{ALPHA:.0%}", hoverinfo="skip"))
    fig.add_trace(go.Scatter(x=lam, y=1 - lam, mode="lines", name="true RUL",
                             line={"color": "black"}, hoverinfo="skip"))
    drawn = 0
    for aid, grp in fleet.predictions.groupby("actuator", sort=True):
        eol = fleet.truth.get(str(aid))
        grp = grp.sort_values("cycle")
        t0 = float(grp["cycle"].iloc[0])
        if eol is None or eol <= t0:
            continue
        sel = grp[(grp["cycle"] < eol) & grp["rul"].notna()]
        if sel.empty:
            continue
        life = eol - t0
        x = (sel["cycle"].to_numpy(float) - t0) / life
        lo = np.array(_none(sel["rul_lo"])) / life
        hi = np.array(_none(sel["rul_hi"])) / life
        y = sel["rul"].to_numpy(float) / life
        fig.add_trace(go.Scatter(
            x=x, y=y, mode="markers+lines", name=str(aid), line={"width": 1},
            marker={"size": 5},
            error_y={"type": "data", "symmetric": False, "array": np.nan_to_num(hi - y),
                     "arrayminus": np.nan_to_num(y - lo), "thickness": 1, "width": 0},
            customdata=np.c_[sel["cycle"].to_numpy(float), sel["rul"].to_numpy(float),
                             np.full(len(sel), eol) - sel["cycle"].to_numpy(float)],
            hovertemplate=(f"{aid}, cycle %{{customdata[0]:.0f}} (λ %{{x:.2f}}): RUL "
                           "%{customdata[1]:.0f} cycles, true %{customdata[2]:.0f} cycles"
                           "<extra></extra>")))
        drawn += 1
    if not drawn:
        return None
    fig.add_vrect(x0=0.5, x1=0.95, fillcolor=GREEN, opacity=0.06, line_width=0)
    fig.update_xaxes(title_text="λ = (cycle − first check) / (true end of life − first check)",
                     range=[0, 1])
    fig.update_yaxes(title_text="RUL / monitored life", range=[0, 1.6])
    return _done(fig, "Alpha-lambda: every actuator's RUL predictions against the truth "
                      "(shaded: λ window 0.5-0.95)", height=460)


# =========================================================================== health
def verdict_figure(verdicts) -> dict:
    """Heat map of the health checks: per record and fault, the detection statistic over its
    threshold (≥ 1: degraded), the estimate and interval in the hover."""
    go = _go()
    checks = list(dict.fromkeys(verdicts["check_id"]))
    faults = list(dict.fromkeys(verdicts["fault"]))
    labels = []
    z = np.full((len(checks), len(faults)), np.nan)
    text = np.full((len(checks), len(faults)), "", dtype=object)
    for i, cid in enumerate(checks):
        sel = verdicts[verdicts["check_id"] == cid]
        rec = str(sel["record"].iloc[0]).replace("\\", "/").rsplit("/", 1)[-1]
        labels.append(f"{rec} ({cid[:6]})")
        for r in sel.itertuples():
            j = faults.index(r.fault)
            unit, f = unit_of(r.fault)
            if r.threshold is not None and np.isfinite(r.threshold) and r.threshold:
                z[i, j] = r.statistic / r.threshold
            # a change-check row (reference 'baseline'): the change since the baseline
            change = getattr(r, "reference", None) == "baseline"
            what = (f"change {f * r.estimate:+.4g} {unit}" if change
                    else f"{f * r.estimate:.4g} {unit}")
            base = ("since the baseline" if change or r.healthy is None
                    or not np.isfinite(r.healthy) else f"healthy {f * r.healthy:.4g} {unit}")
            text[i, j] = (f"{r.fault} {what} [{f * r.lo:.4g}, {f * r.hi:.4g}] {unit}; "
                          f"{base}; "
                          + ("degraded" if r.degraded is True else
                             "healthy" if r.degraded is False else "no calibration")
                          + ("; isolated" if r.isolated else ""))
    fig = go.Figure(go.Heatmap(
        z=z, x=faults, y=labels, text=text, zmin=0, zmax=2,
        colorscale=[[0, "#e8f1fa"], [0.5, "#9ecae1"], [0.5, "#fdae6b"], [1, "#d62728"]],
        colorbar={"title": {"text": "statistic / threshold"}},
        hovertemplate="%{y}<br>%{text}<br>statistic / threshold %{z:.2f}<extra></extra>"))
    fig.update_xaxes(title_text="fault")
    return _done(fig, "Health checks: deviation from healthy (or change since the baseline) "
                      "over the alarm threshold (≥ 1: degraded)",
                 height=max(280, 120 + 30 * len(checks)))


def roc_figure(perf: Mapping[str, Any], command: str, alpha: float) -> dict:
    """ROC curve of every fault level against the healthy fleet, one panel per fault."""
    go = _go()
    from plotly.subplots import make_subplots

    faults = list(perf["faults"])
    ncol = min(4, max(1, len(faults)))
    nrow = -(-len(faults) // ncol)
    fig = make_subplots(rows=nrow, cols=ncol, subplot_titles=faults, horizontal_spacing=0.06,
                        vertical_spacing=0.16)
    for k, name in enumerate(faults):
        r, c = k // ncol + 1, k % ncol + 1
        unit, f = unit_of(name)
        for lev in perf["faults"][name]["levels"]:
            roc = lev["roc"]
            fig.add_trace(go.Scatter(
                x=roc["pfa"], y=roc["pd"], mode="lines", line={"shape": "hv", "width": 1.5},
                name=f"{name} {f * lev['value']:.3g} {unit}", legendgroup=name,
                hovertemplate=(f"{name} = {f * lev['value']:.4g} {unit}: P_FA %{{x:.3f}}, "
                               f"P_D %{{y:.3f}} (at the threshold: P_D "
                               f"{lev['p_detect']:.2f}, n {lev['n']})<extra></extra>")),
                row=r, col=c)
        fig.add_vline(x=alpha, line={"color": GREY, "dash": "dot", "width": 1}, row=r, col=c)
        fig.update_xaxes(range=[-0.02, 1.02], row=r, col=c)
        fig.update_yaxes(range=[-0.02, 1.02], row=r, col=c)
    fig.update_xaxes(title_text="false-alarm probability", row=nrow)
    fig.update_yaxes(title_text="detection probability", col=1)
    return _done(fig, f"ROC per fault on {command} (healthy fleet vs each injected level; "
                      f"dotted: α = {alpha:g})", height=300 * nrow + 90)


def confusion_figure(confusion: Mapping[str, Mapping[str, int]], command: str) -> dict:
    """Isolation: rows the injected fault, columns the declared one (counts, row fractions)."""
    go = _go()
    rows = list(confusion)
    cols = list(dict.fromkeys([*rows, *[c for r in confusion.values() for c in r]]))
    m = np.array([[confusion[r].get(c, 0) for c in cols] for r in rows], dtype=float)
    frac = m / np.maximum(m.sum(axis=1, keepdims=True), 1)
    fig = go.Figure(go.Heatmap(
        z=frac, x=cols, y=rows, text=m.astype(int), texttemplate="%{text}", zmin=0, zmax=1,
        colorscale="Blues", colorbar={"title": {"text": "fraction of the row"}},
        hovertemplate="injected %{y}, declared %{x}: %{text} checks (%{z:.0%} of the row)"
                      "<extra></extra>"))
    fig.update_xaxes(title_text="declared")
    fig.update_yaxes(title_text="injected", autorange="reversed")
    return _done(fig, f"Isolation on {command}", height=120 + 40 * len(rows))


# =========================================================================== identification
def mean_error_figure(table, campaign: str) -> dict:
    """Mean error per case, ours (median, min-max over the seeds) against the thesis' (and the
    LF augmented by eha explain when run), log scale: the thesis' Figure 6.18."""
    go = _go()
    floor = 1e-3
    x = [f"{c} ({cmd})" for c, cmd in zip(table["case"], table["command"])]
    ours = table["mean_err_pct"].to_numpy(float)
    fig = go.Figure()
    if table["thesis_mean_err_pct"].notna().any():
        fig.add_trace(go.Scatter(x=x, y=np.maximum(table["thesis_mean_err_pct"], floor),
                                 mode="markers+lines", name="thesis (Matlab GA, one run)",
                                 marker={"symbol": "square", "color": RED},
                                 line={"dash": "dash", "width": 1},
                                 hovertemplate="case %{x}: thesis %{y:.3g} %<extra></extra>"))
    fig.add_trace(go.Scatter(
        x=x, y=np.maximum(ours, floor), mode="markers+lines",
        name=f"eha {table['method'].iloc[0]} (median, min-max of {int(table['seeds'].iloc[0])}"
             " seeds)", marker={"color": BLUE, "size": 8},
        error_y={"type": "data", "symmetric": False,
                 "array": table["mean_err_pct_max"].to_numpy(float) - ours,
                 "arrayminus": ours - np.maximum(table["mean_err_pct_min"].to_numpy(float),
                                                 floor * 0.999)},
        customdata=np.c_[table["mean_err_pct_min"], table["mean_err_pct_max"]],
        hovertemplate=("case %{x}: %{y:.3g} % (min %{customdata[0]:.3g} %, max "
                       "%{customdata[1]:.3g} %)<extra></extra>")))
    if "aug_mean_err_pct" in table:
        fig.add_trace(go.Scatter(x=x, y=np.maximum(table["aug_mean_err_pct"], floor),
                                 mode="markers+lines", name="eha, LF augmented by eha explain",
                                 marker={"symbol": "diamond", "color": GREEN},
                                 hovertemplate="case %{x}: augmented %{y:.3g} %<extra></extra>"))
    fig.update_yaxes(type="log", title_text="mean error [%] (|BKL err| + |FDJ err|)/2")
    fig.update_xaxes(title_text="case (command)", type="category")
    return _done(fig, f"{campaign}: mean identification error per case (thesis Figure 6.18)")


# =========================================================================== residual loop
def explain_figure(runs) -> dict:
    """Whole-record RMSE of every residual-loop run before and after the added effects,
    against the record's noise (µm)."""
    go = _go()
    labels = [f"{str(s).replace(chr(92), '/').rsplit('/', 1)[-1]} ({rid[:6]})"
              for s, rid in zip(runs["source"], runs["run_id"])]
    eff = [", ".join(e or []) or "nothing added" for e in runs["effects"]]
    fig = go.Figure()
    for col, name, colour in (("rmse_before", "declared faults only", GREY),
                              ("rmse_after", "with the added effects", BLUE)):
        fig.add_trace(go.Bar(x=labels, y=1e6 * runs[col].to_numpy(float), name=name,
                             marker_color=colour, customdata=eff,
                             hovertemplate=("%{x}: RMSE %{y:.3g} µm (" + name + "; added: "
                                            "%{customdata})<extra></extra>")))
    fig.add_trace(go.Scatter(x=labels, y=1e6 * runs["noise_rmse"].to_numpy(float),
                             mode="markers", name="record noise",
                             marker={"symbol": "line-ew-open", "size": 30, "color": "black",
                                     "line": {"width": 2}},
                             hovertemplate="%{x}: noise %{y:.3g} µm<extra></extra>"))
    fig.update_yaxes(rangemode="tozero", title_text="RMSE measured − LF, whole record [µm]")
    fig.update_layout(barmode="group")
    return _done(fig, "Residual loop: error before and after, against the record's noise")


def steps_figure(steps, run: Mapping[str, Any]) -> dict:
    """One run: RMSE after each added effect (whole record, fitted part, held-out part)."""
    go = _go()
    x = ["declared faults"] + [f"{s}. + {e}" for s, e in zip(steps["step"], steps["effect"])]
    fig = go.Figure()
    for pre, name in (("", "whole record"), ("fit_", "fitted part"), ("hold_", "held-out part")):
        if steps.empty:
            y = [run["rmse_before"]] if not pre else []
        else:
            y = [steps[f"rmse_{pre}before"].iloc[0]] + list(steps[f"rmse_{pre}after"])
        if len(y):
            fig.add_trace(go.Scatter(x=x[:len(y)], y=1e6 * np.array(_none(y)),
                                     mode="markers+lines", name=name,
                                     hovertemplate="%{x}: %{y:.3g} µm (" + name + ")"
                                                   "<extra></extra>"))
    noise = run.get("noise_rmse")
    if noise is not None and np.isfinite(noise):
        fig.add_hline(y=1e6 * noise, line={"color": "black", "dash": "dot"},
                      annotation_text=f"noise {1e6 * noise:.3g} µm")
    fig.update_yaxes(rangemode="tozero", title_text="RMSE [µm]")
    src = str(run["source"]).replace("\\", "/").rsplit("/", 1)[-1]
    return _done(fig, f"{src}: error after each step", height=360)


# =========================================================================== campaigns
def status_figure(status) -> dict:
    """Runs of every campaign by status (stacked bars)."""
    go = _go()
    camps = list(dict.fromkeys(status["campaign"]))
    fig = go.Figure()
    colours = {"done": GREEN, "failed": RED, "pending": GREY}
    for st in sorted(set(status["status"]), key=lambda s: ("done", "failed", "pending").index(s)
                     if s in colours else 9):
        n = [int(status[(status["campaign"] == c) & (status["status"] == st)]["n"].sum())
             for c in camps]
        fig.add_trace(go.Bar(y=camps, x=n, name=st, orientation="h",
                             marker_color=colours.get(st, ORANGE),
                             hovertemplate="%{y}: %{x} runs " + st + "<extra></extra>"))
    fig.update_layout(barmode="stack")
    fig.update_xaxes(title_text="runs")
    fig.update_yaxes(type="category", autorange="reversed")
    return _done(fig, "Runs by status", height=max(260, 90 + 28 * len(camps)))


def hf_lf_figure(runs, campaign: str) -> dict:
    """HF-vs-LF position error (RMSE of xu, median over seeds) over a campaign's fault grid:
    a BKL × FDJ-like grid per command when the faults form a two-parameter product, else one
    row per fault set and one column per command (log colour)."""
    go = _go()
    from plotly.subplots import make_subplots

    from eha.reports.plots import fault_order, fault_text

    med = (runs.assign(key=runs["faults"].map(fault_key))
           .groupby(["command", "key"])["rmse_xu_hf_lf"].median())
    commands = list(dict.fromkeys(runs["command"]))
    sets = sorted({fault_key(f): f for f in runs["faults"]}.values(), key=fault_order)
    names = sorted({k for f in sets for k in f})
    grid2 = len(names) == 2 and all(len(f) == 2 for f in sets) and len(sets) > 1
    log = lambda v: np.log10(1e6 * v) if v is not None and v > 0 else np.nan  # noqa: E731
    if grid2:
        (ua, fa), (ub, fb) = unit_of(names[0]), unit_of(names[1])
        a = sorted({f[names[0]] for f in sets})
        b = sorted({f[names[1]] for f in sets})
        fig = make_subplots(rows=1, cols=len(commands), subplot_titles=commands,
                            horizontal_spacing=0.08)
        for k, cmd in enumerate(commands, start=1):
            z = np.full((len(a), len(b)), np.nan)
            for f in sets:
                v = med.get((cmd, fault_key(f)))
                z[a.index(f[names[0]]), b.index(f[names[1]])] = log(v)
            fig.add_trace(go.Heatmap(
                z=z, x=[f"{fb * v:.4g}" for v in b], y=[f"{fa * v:.4g}" for v in a],
                coloraxis="coloraxis", text=_sig3(z),
                texttemplate="%{text}",
                hovertemplate=(f"{cmd}: {names[0]} %{{y}} {ua}, {names[1]} %{{x}} {ub}: RMSE "
                               "xu HF vs LF %{text} µm<extra></extra>")), row=1, col=k)
            fig.update_xaxes(title_text=f"{names[1]} [{ub}]", type="category", row=1, col=k)
        fig.update_yaxes(title_text=f"{names[0]} [{ua}]", type="category", col=1)
        height = 420
    else:
        labels = [fault_text(f) for f in sets]
        z = np.array([[log(med.get((c, fault_key(f)))) for c in commands] for f in sets])
        fig = go.Figure(go.Heatmap(
            z=z, x=commands, y=labels, coloraxis="coloraxis",
            text=_sig3(z), texttemplate="%{text}",
            hovertemplate="%{x}, %{y}: RMSE xu HF vs LF %{text} µm<extra></extra>"))
        fig.update_yaxes(type="category", autorange="reversed")
        fig.update_xaxes(title_text="command")
        height = max(300, 110 + 24 * len(sets))
    fig.update_layout(coloraxis={"colorscale": "Viridis", "colorbar": {
        "title": {"text": "RMSE xu [µm]"},
        "tickvals": list(range(-3, 5)), "ticktext": [f"{10.0 ** p:g}" for p in range(-3, 5)]}})
    return _done(fig, f"{campaign}: HF vs LF position error (RMSE of xu, median over seeds)",
                 height=height)


def _sig3(logz: np.ndarray) -> np.ndarray:
    """Text of 10**logz with 3 significant digits, no exponent below 1e6 ('' where NaN):
    one format for every cell (``1720`` beside ``158``, not ``1.72e+03``)."""
    from eha.models.units import plain

    return np.vectorize(lambda v: "" if not np.isfinite(v) else plain(10.0 ** v, 3),
                        otypes=[object])(logz)


def script_json(text: str) -> str:
    """JSON text safe inside a ``<script>`` element, whatever its strings hold: ``<``, ``>``
    and ``&`` written as ``\\u003c``, ``\\u003e``, ``\\u0026`` (the same JSON value; none
    of them is JSON syntax outside a string), so no ``</script``, ``<!--`` or ``<script`` of
    a record name or an actuator id can end the element or change how HTML parses it."""
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def figure_json(fig: dict) -> str:
    """A figure as JSON text safe inside a ``<script>`` element (numpy arrays converted;
    :func:`script_json`)."""
    from plotly.io.json import to_json_plotly

    return script_json(to_json_plotly(fig) if not isinstance(fig, str) else fig)


__all__ = ["fleet_overview", "actuator_figure", "alpha_lambda_figure", "verdict_figure",
           "roc_figure", "confusion_figure", "mean_error_figure", "explain_figure",
           "steps_figure", "status_figure", "hf_lf_figure", "figure_json"]
