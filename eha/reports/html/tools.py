"""The report's sections of the single-run tools: ``eha fdi --results`` (Fault identification)
and ``eha design --results`` (Test design), from the ``fdi_runs`` and ``design_runs`` rows
that :mod:`eha.reports.html.data` read.
"""

from __future__ import annotations

import math
from typing import Any

from eha.reports.html.data import unit_of
from eha.reports.html.page import Column, Page, fmt_int, fmt_num, tag


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
    return ('<p class="note">Each <code>eha fdi --results</code> run (table '
            "<code>fdi_runs</code>), newest first. Mean error = mean of |injected − "
            "identified| / injected × 100 (HF references only); <i>flagged</i>: the residual "
            "stays well above the record's noise, the intervals are widened.</p>"
            + page.table(cols, rows, "fdi runs"))


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
            "Health).</p>" + page.table(cols, rows, "designs"))


__all__ = ["fdi_section", "design_section"]
