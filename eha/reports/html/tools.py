"""The report's sections of the single-run tools: ``eha fdi --results`` (Fault identification)
and ``eha design --results`` (Test design), from the ``fdi_runs`` and ``design_runs`` rows
that :mod:`eha.reports.html.data` read.
"""

from __future__ import annotations

import math
from typing import Any

from eha.reports.html.data import unit_of
from eha.reports.html.figures import BLUE, RED, _done, _go
from eha.reports.html.page import Column, Page, fmt_int, fmt_num, tag

#: At most this many parameters get a figure of their identified values (one figure each).
MAX_FDI_FIGURES = 4


def _value(name: str, v: Any, digits: int = 4) -> str:
    """``v`` (SI) in the display unit of parameter ``name``, with the unit."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    unit, k = unit_of(name)
    return f"{k * float(v):.{digits}g} {unit}".strip()


def fdi_section(page: Page, runs) -> str:
    """One row per ``eha fdi --results``: the reference, the LF model and method, each
    identified parameter with its interval in its display unit, the injected values (HF
    reference), the error and the fit's RMSE."""
    rows = []
    for r in runs.to_dict("records"):
        names = list(r["names"] or [])
        est, ivs, truth = r["estimates"] or {}, r["intervals"] or {}, r["truth"] or {}
        level = r.get("level")
        shown = []
        for n in names:
            lo, hi = (ivs.get(n) or (None, None))
            iv = (f" [{_value(n, lo)}, {_value(n, hi)}]" if lo is not None and hi is not None
                  else "")
            shown.append(f"{n} = {_value(n, est.get(n))}{iv}")
        rows.append({"run_id": str(r["run_id"]), "created_at": str(r["created_at"])[:19],
                     "source": str(r["source"]), "model": str(r["base_model"]),
                     "method": str(r["method"]), "estimates": "; ".join(shown),
                     "truth": "; ".join(f"{n} = {_value(n, truth.get(n))}" for n in names)
                     if truth else "-",
                     "mean_err_pct": r.get("mean_err_pct"),
                     "rmse_um": None if r.get("objective") is None else 1e6 * r["objective"],
                     "flagged": bool(r.get("flagged")), "seconds": r.get("seconds"),
                     "level": level})
    level = next((r["level"] for r in rows if r["level"] is not None), None)
    pct = f"{100 * level:g} % interval" if level is not None else "interval"
    cols = [Column("created_at", "fitted", text=True), Column("source", "reference", text=True),
            Column("model", "LF model", text=True), Column("method", "method", text=True),
            Column("estimates", f"identified [{pct}]", text=True),
            Column("truth", "injected", text=True),
            Column("mean_err_pct", "mean error [%]", fmt_num(3)),
            Column("rmse_um", "fit objective [µm]", fmt_num(3)),
            Column("flagged", "flagged", lambda v: tag("flagged") if v else ""),
            Column("seconds", "time [s]", fmt_num(3))]
    names = list(dict.fromkeys(n for r in runs["names"] for n in (r or [])))
    figures = "".join(page.plot(fdi_figure(runs, n)) for n in names[:MAX_FDI_FIGURES])
    return ('<p class="note">Each <code>eha fdi --results</code> run (table '
            "<code>fdi_runs</code>), newest first. Mean error = mean of |injected − "
            "identified| / injected × 100 (HF references only); <i>flagged</i>: the residual "
            "stays well above the record's noise, the intervals are widened.</p>"
            + page.table(cols, rows, "fdi runs") + figures)


def _run_label(r) -> str:
    source = str(r["source"]).replace("\\", "/").rsplit("/", 1)[-1]
    return f"{source[:40]} ({str(r['run_id'])[:6]})"


def fdi_figure(runs, name: str) -> dict:
    """Parameter ``name`` of every run that fitted it: the identified value with its interval
    and, for an HF reference, the injected value, in the parameter's display unit."""
    go = _go()
    unit, k = unit_of(name)
    rows = [r for r in runs.to_dict("records") if name in (r["names"] or [])]
    x = [_run_label(r) for r in rows]
    est = [k * float((r["estimates"] or {}).get(name, math.nan)) for r in rows]
    ivs = [(r["intervals"] or {}).get(name) or (math.nan, math.nan) for r in rows]
    lo = [e - k * float(iv[0]) for e, iv in zip(est, ivs)]
    hi = [k * float(iv[1]) - e for e, iv in zip(est, ivs)]
    fig = go.Figure()
    fig.add_trace(go.Scatter(x=x, y=est, mode="markers", name="identified (interval)",
                             marker={"color": BLUE, "size": 9},
                             error_y={"type": "data", "symmetric": False, "array": hi,
                                      "arrayminus": lo},
                             hovertemplate=f"%{{x}}: %{{y:.4g}} {unit}<extra></extra>"))
    truth = [k * float(t[name]) if t and name in t else math.nan
             for t in (r["truth"] for r in rows)]
    if any(math.isfinite(v) for v in truth):
        fig.add_trace(go.Scatter(x=x, y=truth, mode="markers", name="injected",
                                 marker={"color": RED, "symbol": "x", "size": 10},
                                 hovertemplate=f"%{{x}}: injected %{{y:.4g}} {unit}"
                                               "<extra></extra>"))
    fig.update_yaxes(title_text=f"{name} [{unit}]" if unit else name)
    fig.update_xaxes(title_text="identification (reference, run)", type="category")
    return _done(fig, f"{name}: identified value with its interval, per eha fdi run", 380)


def design_section(page: Page, runs) -> str:
    """One row per ``eha design --results``: the command file, its length, how many targets
    it shows and, per target, the predicted minimum detectable size against the best
    library command's."""
    rows = []
    for r in runs.to_dict("records"):
        targets = r["targets"] or {}
        per = []
        for name, t in targets.items():
            k, unit = t.get("display_factor", 1.0), t.get("display_unit") or t.get("unit", "")
            size = t.get("min_detectable")
            best = t.get("best_library") or {}
            ref = best.get("min_detectable")
            text = (f"{name}: {k * size:.3g} {unit}" if size is not None and t.get("detectable")
                    else f"{name}: not detectable")
            if ref is not None and math.isfinite(ref) and ref < t.get("limit", math.inf):
                text += f" (best library {k * ref:.3g} {unit}, {best.get('command')})"
            per.append(text)
        rows.append({"created_at": str(r["created_at"])[:19], "name": str(r["name"]),
                     "command_file": str(r["command_file"]), "duration": r["duration"],
                     "shown": f"{int(r['detectable'])} of {int(r['n_targets'])}",
                     "targets": "; ".join(per), "model_form": r.get("model_form"),
                     "seconds": r.get("seconds")})
    cols = [Column("created_at", "designed", text=True), Column("name", "name", text=True),
            Column("command_file", "command file", text=True),
            Column("duration", "length [s]", fmt_num(3)),
            Column("shown", "targets detectable", text=True),
            Column("targets", "predicted minimum detectable size", text=True),
            Column("model_form", "LF model-form residual [noise stds]", fmt_num(2)),
            Column("seconds", "time [s]", fmt_int)]
    return ('<p class="note">Each <code>eha design --results</code> run (table '
            "<code>design_runs</code>), newest first: sizes predicted from the HF model's "
            "signatures (<code>eha design verify</code> measures them: its campaign is under "
            "Health).</p>" + page.table(cols, rows, "designs")
            + page.plot(design_figure(runs)))


def design_figure(runs) -> dict:
    """Per design and target, the predicted minimum detectable size on the design over the
    best library command's (log scale; below 1: the design shows the target at a smaller
    size)."""
    go = _go()
    fig = go.Figure()
    for r in runs.to_dict("records"):
        targets = r["targets"] or {}
        names = list(targets)
        ratio = [targets[n].get("ratio_to_best_library") for n in names]
        y = [math.nan if v is None else float(v) for v in ratio]
        # markers, not bars: a bar on a log axis starts at an arbitrary floor
        fig.add_trace(go.Scatter(x=names, y=y, mode="markers+text", marker={"size": 12},
                                 text=[f"{v:.2f}x" if math.isfinite(v) else "" for v in y],
                                 textposition="middle right",
                                 name=f"{r['name']} ({str(r['run_id'])[:6]})",
                                 hovertemplate="%{x}: %{y:.3g}x the best library command's "
                                               "size<extra></extra>"))
    fig.add_hline(y=1.0, line={"dash": "dash", "color": "#7f7f7f"})
    fig.update_yaxes(type="log", title_text="design / best library command (detectable size)")
    fig.update_xaxes(title_text="target", type="category")
    return _done(fig, "Predicted minimum detectable size, design over the best library command",
                 380)


__all__ = ["fdi_section", "design_section", "fdi_figure", "design_figure"]
