"""The sections of the HTML report: Fleet, Health, Identification, Residual loop, Campaigns.

Each function takes what :mod:`eha.reports.html.data` read and returns the section's HTML (the
:class:`~eha.reports.html.page.Page` keeps the figures' ids); the caller leaves out a section
whose data is None.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from eha.reports.html import figures as F
from eha.reports.html.data import Fleet, Health, Identification, _json, fleet_table, unit_of
from eha.reports.html.fits import fit_figures
from eha.reports.html.page import Column, Page, esc, fmt_int, fmt_num, tag


# =========================================================================== fleet
def fleet_section(page: Page, fleets: list[Fleet]) -> str:
    """Per ``eha rul`` run: the RUL overview, the actuator table (click a row: its figure),
    the actuator figure with a selector, the α-λ plot with a truth."""
    parts = []
    for fleet in fleets:
        rows = fleet_table(fleet)
        for r in rows:                       # estimate and interval in one cell, as shown
            for name in fleet.faults:
                unit, f = unit_of(name)
                est, lo, hi = r.get(name), r.get(f"{name}_lo"), r.get(f"{name}_hi")
                r[f"{name}_text"] = "-" if est is None else (
                    f"{f * est:.4g} [{fmt_num()(lo and f * lo)}, {fmt_num()(hi and f * hi)}]")
        order = {"end of life": 0, "attention": 1, "no trend": 2, "ok": 3}
        rows.sort(key=lambda r: (order.get(r["status"], 9), r["rul"] if r["rul"] is not None
                                 else np.inf, r["actuator"]))
        cols = [Column("actuator", "actuator", text=True), Column("status", "status", tag),
                Column("checks", "checks", fmt_int), Column("last_cycle", "last check", fmt_int)]
        for name in fleet.faults:
            unit, _ = unit_of(name)
            cols += [Column(name, f"{name} [{unit}] (90 % interval)", show=f"{name}_text"),
                     Column(f"{name}_verdict", f"{name} verdict", tag)]
        cols += [Column("rul", "RUL median", fmt_int), Column("rul_lo", "RUL 5 %", fmt_int),
                 Column("rul_hi", "RUL 95 %", fmt_int), Column("driver", "driver", text=True),
                 Column("predicted_eol", "predicted end of life", fmt_int),
                 Column("flagged", "last check flagged", lambda v: tag("flagged") if v else "")]
        if fleet.truth is not None:
            cols.append(Column("true_eol", "true end of life", fmt_int))
        by_aid = {r["actuator"]: r for r in rows}
        figs = {aid: F.actuator_figure(fleet, aid) for aid in by_aid}
        choice_html, pid = page.choice("Actuator:", figs, selected=rows[0]["actuator"])
        limits = ", ".join(f"{n} = {unit_of(n)[1] * v:.4g} {unit_of(n)[0]}"
                           for n, v in fleet.limits.items())
        parts.append(
            f"<h3>{esc(fleet.run_id)}"
            + (" (change check: baseline + change)" if fleet.reference == "baseline" else "")
            + "</h3>"
            f'<p class="note">{len(rows)} actuators, limits {esc(limits)}; units: cycles of '
            "the manifest. Status: <i>end of life</i> a fault beyond its limit, <i>attention"
            "</i> the 5 % RUL within two check spacings, <i>no trend</i> no predicted "
            "crossing. Click a row to show its actuator below."
            + (f" Truth: {esc(fleet.truth_source)}." if fleet.truth_source else "") + "</p>"
            + page.plot(F.fleet_overview(rows))
            + page.table(cols, rows, f"fleet {fleet.run_id}", choice=(pid, "actuator"))
            + choice_html)
        al = F.alpha_lambda_figure(fleet)
        if al is not None:
            parts.append(page.plot(al))
        if fleet.changes is not None:
            parts.append(_changes(page, fleet))
    return "".join(parts)


def _changes(page: Page, fleet: Fleet) -> str:
    """An ``eha rul --check change`` run: per actuator the change of each fault since its
    baseline at the last check with its interval, its first alarm; the changes' figure."""
    rows = []
    for aid, grp in fleet.changes.groupby("actuator", sort=True):
        last = grp.sort_values("cycle").iloc[-1]
        row = {"actuator": str(aid), "baseline": str(last["baseline"]).replace(
            "\\", "/").rsplit("/", 1)[-1], "last_cycle": float(last["cycle"]),
            "isolated": ", ".join(last["isolated"] or []) or "-"}
        for name in fleet.faults:
            unit, f = unit_of(name)
            ch = (last["changes"] or {}).get(name)
            lo, hi = (last["intervals"] or {}).get(name) or (None, None)
            row[name] = ch
            # an open end: the change is beyond its response's growing range (a bound)
            ends = ["open" if v is None else fmt_num()(f * v) for v in (lo, hi)]
            row[f"{name}_text"] = "-" if ch is None else f"{f * ch:+.4g} [{ends[0]}, {ends[1]}]"
            first = (fleet.alarms.get(str(aid), {}).get(name) or {})
            row[f"{name}_alarm"] = _num_or_none(first.get("first_alarm"))
            row[f"{name}_alarm_text"] = fmt_int(row[f"{name}_alarm"]) + (
                " (baseline)" if row[f"{name}_alarm"] is not None and first.get("at_baseline")
                else "")
        beside = _decoded(last.get("beside"), dict)
        row["beside"] = "; ".join(_beside_text(name, beside.get(name) or {})
                                  for name in _decoded(last.get("also"), list)) or "-"
        rows.append(row)
    cols = [Column("actuator", "actuator", text=True),
            Column("baseline", "baseline record", text=True),
            Column("last_cycle", "last check", fmt_int)]
    for name in fleet.faults:
        unit, _ = unit_of(name)
        cols += [Column(name, f"Δ{name} since baseline [{unit}] (90 % interval)",
                        show=f"{name}_text"),
                 Column(f"{name}_alarm", f"{name} first alarm [cycle]",
                        show=f"{name}_alarm_text")]
    cols.append(Column("isolated", "last check isolated to", text=True))
    cols.append(Column("beside", "changed beside it (90 % interval)", text=True))
    figs = {r["actuator"]: F.change_figure(fleet, r["actuator"]) for r in rows}
    choice_html, pid = page.choice("Actuator:", figs, selected=rows[0]["actuator"])
    return ("<h4>Change check: each record against its actuator's baseline</h4>"
            '<p class="note">Change of each fault since the baseline record (later minus '
            "earlier, eha health check --baseline), with its 90 % interval (<i>open</i>: "
            "beyond the range where the fault's response grows, the change only bounded on "
            "that side); first alarm: the "
            "first check at which the fault alarms and the change is isolated to it, or the "
            "baseline's own cycle, marked <i>(baseline)</i>, where the baseline record itself "
            "is unlike the healthy fleet, farthest in that fault; changed "
            "beside it: a second fault's change read jointly with the isolated one's (the "
            "two-fault reading). Click a row to show its actuator below.</p>"
            + page.table(cols, rows, f"changes {fleet.run_id}", choice=(pid, "actuator"))
            + choice_html)


def _decoded(value: Any, kind: type) -> Any:
    """A JSON cell decoded, or an empty ``kind`` where it is NULL (an older row)."""
    value = _json(value)
    return value if isinstance(value, kind) else kind()


def _beside_text(name: str, beside: dict) -> str:
    """``BKL +8.47 µm [7.01, 9.95]``: a fault's change read beside the isolated one."""
    if beside.get("change") is None:
        return name
    unit, f = unit_of(name)
    ends = ["open" if v is None else fmt_num()(f * v)
            for v in (beside.get("interval") or [None, None])]
    return f"{name} {f * beside['change']:+.4g} {unit} [{ends[0]}, {ends[1]}]"


def _num_or_none(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


# =========================================================================== health
def health_section(page: Page, health: Health) -> str:
    parts = []
    if health.verdicts is not None:
        v = health.verdicts
        rows = []
        for cid, grp in v.groupby("check_id", sort=False):
            first = grp.iloc[0]
            degraded = [r.fault for r in grp.itertuples() if r.degraded is True]
            isolated = [r.fault for r in grp.itertuples() if r.isolated]
            calibrated = grp["degraded"].notna().any()
            change = first.get("reference") == "baseline"
            beside = [(r["fault"], _decoded(r.get("beside"), dict))
                      for r in grp.to_dict("records")] if "beside" in grp else []
            rows.append({"beside": "; ".join(_beside_text(n, b) for n, b in beside
                                             if b.get("named")) or "-",
                         "check": "change since " + _base_name(first.get("baseline"))
                         if change else "fleet",
                         "record": str(first["record"]), "check_id": cid,
                         "created_at": str(first["created_at"])[:19],
                         "verdict": ("degraded" if degraded else "healthy") if calibrated
                         else "no calibration",
                         "degraded": ", ".join(degraded) or "-",
                         "isolated": ", ".join(isolated) or "-",
                         "flagged": bool(grp["flagged"].fillna(False).any())})
        cols = [Column("record", "record", text=True), Column("check", "check", text=True),
                Column("created_at", "checked", text=True),
                Column("verdict", "verdict", tag), Column("degraded", "degraded faults",
                                                          text=True),
                Column("isolated", "isolated fault", text=True),
                Column("beside", "changed beside it (90 % interval)", text=True),
                Column("flagged", "flagged", lambda x: tag("flagged") if x else "")]
        parts.append("<h3>Health checks (eha health check)</h3>"
                     + page.table(cols, rows, "health checks") + page.plot(F.verdict_figure(v)))
    if health.thresholds is not None:
        parts.append(_calibrations(page, health))
    elif health.calibrations:
        parts.append("<h3>Healthy fleets (eha health calibrate)</h3>"
                     + '<p class="note">' + esc("; ".join(
                         f"{c}: {n} healthy actuators" for c, n in health.calibrations.items()))
                     + ". Their thresholds are in the calibration files.</p>")
    for camp, why in health.skipped.items():
        parts.append(f'<p class="note">Detection campaign {esc(camp)}: not shown ({esc(why)}'
                     ").</p>")
    for camp, perf in health.campaigns.items():
        change = any(c.get("check") == "change" for c in perf.values())
        parts.append(f"<h3>Detection campaign {esc(camp)}"
                     + (" (change check: pairs of records)" if change else "") + "</h3>"
                     f'<p class="note">Thresholds from each command\'s healthy '
                     + ("pairs" if change else "group") + " for a false-alarm probability "
                     f"α = {health.alpha:g} (as eha report health)"
                     + ("; each level is a change since the earlier record" if change else "")
                     + ".</p>")
        for command, c in perf.items():
            rows = []
            for name, f in c["faults"].items():
                unit, k = unit_of(name)
                md = f.get("min_detectable_deviation")
                rows.append({"fault": name, "unit": unit, "threshold": f["threshold"],
                             "min_detectable": None if md is None else k * md,
                             "levels": ", ".join(f"{k * lev['value']:.3g}: "
                                                 f"{lev['p_detect']:.2f}"
                                                 for lev in f["levels"])})
            fa = c["false_alarms"]
            cols = [Column("fault", "fault", text=True), Column("unit", "unit", text=True),
                    Column("min_detectable", "minimum detectable deviation (P_D ≥ 0.95)",
                           fmt_num(3)),
                    Column("levels", "injected value: detection probability", text=True)]
            parts.append(f"<h3>{esc(command)}</h3>"
                         f'<p class="note">{fa.get("n", "-")} healthy checks, any alarm on '
                         f'{fmt_num(3)(fa.get("any"))} of them (in sample).</p>'
                         + page.table(cols, rows, f"detection {camp} {command}",
                                      filter_box=False)
                         + '<div class="row"><div>' + page.plot(F.roc_figure(c, command,
                                                                           health.alpha))
                         + "</div><div>" + page.plot(F.confusion_figure(c["confusion"],
                                                                         command))
                         + "</div></div>")
    return "".join(parts)


def _calibrations(page: Page, health: Health) -> str:
    """The thresholds of each calibration (``health_thresholds``), in each fault's display
    unit: the healthy fleet's statistic (a deviation from the nominal value, in the direction
    of degradation) and the alarm threshold of that same statistic."""
    rows = []
    for r in health.thresholds.to_dict("records"):
        unit, k = unit_of(str(r["fault"]))
        reference = r.get("reference")
        rows.append({"calibration": str(r["calibration"]), "command": str(r["command"]),
                     "check": reference if isinstance(reference, str) else "fleet",
                     "fault": str(r["fault"]), "unit": unit or "-",
                     "mean": None if r["mean"] is None else k * r["mean"],
                     "std": None if r["std"] is None else k * r["std"],
                     "threshold": None if r["threshold"] is None else k * r["threshold"],
                     "n": r["n"], "alpha": r["alpha"]})
    cols = [Column("calibration", "calibration file", text=True),
            Column("command", "command", text=True), Column("check", "check", text=True),
            Column("fault", "fault", text=True), Column("unit", "unit", text=True),
            Column("mean", "healthy mean of the deviation", fmt_num(4)),
            Column("std", "healthy std", fmt_num(3)),
            Column("threshold", "alarm when the deviation exceeds", fmt_num(4)),
            Column("n", "healthy actuators", fmt_int), Column("alpha", "α (any alarm)",
                                                              fmt_num(3))]
    fleets = "".join(f"; {esc(c)}: {n} healthy actuators" for c, n in
                     health.calibrations.items())
    return ("<h3>Calibrations (eha health calibrate)</h3>"
            '<p class="note">Per fault, the detection statistic is the deviation from the '
            "nominal value in the direction of degradation (check <i>fleet</i>), or the "
            "change since the actuator's own earlier record (check <i>baseline</i>), in the "
            "display unit of the fault"
            f"{fleets}.</p>" + page.table(cols, rows, "calibrations"))


# =========================================================================== identification
def identification_section(page: Page, ident: Identification) -> str:
    parts = []
    for name, table in ident.tables.items():
        camp = ident.campaigns[name]
        rows = table.to_dict("records")
        fits = list(camp.fit)
        has_thesis = bool(table["thesis_mean_err_pct"].notna().any())
        # the comparison first (in view at 1400 px), the per-fault detail after it
        cols = [Column("case", "case", fmt_int), Column("command", "command", text=True),
                Column("mean_err_pct", "mean err [%]", fmt_num(3))]
        if has_thesis:
            cols += [Column("thesis_mean_err_pct", "thesis mean err [%]", fmt_num(3)),
                     Column("at_least_as_accurate", "≤ thesis",
                            lambda v: tag("yes" if v else "no"))]
        if "aug_mean_err_pct" in table:
            cols += [Column("aug_mean_err_pct", "augmented LF mean err [%]", fmt_num(3))]
        for n in fits:
            unit, k = unit_of(n)
            ln = n.lower()
            cols += [Column(f"{ln}_in", f"{n} in [{unit}]", fmt_num(4, k)),
                     Column(f"{ln}_out", f"{n} out [{unit}]", fmt_num(4, k)),
                     Column(f"err_{ln}_pct", f"{n} err [%]", fmt_num(3)),
                     Column(f"{ln}_int_lo", f"{n} 90 % lo [{unit}]", fmt_num(4, k)),
                     Column(f"{ln}_int_hi", f"{n} 90 % hi [{unit}]", fmt_num(4, k))]
        cols += [Column("mean_err_pct_min", "min [%]", fmt_num(3)),
                 Column("mean_err_pct_max", "max [%]", fmt_num(3)),
                 Column("seeds", "seeds", fmt_int), Column("seconds", "time [s]", fmt_num(3))]
        better = int(table["at_least_as_accurate"].sum()) if has_thesis else None
        note = (f"Method {esc(table['method'].iloc[0])}, objective "
                f"{esc(table['objective'].iloc[0])}; medians over the seeds (the intervals: "
                "median of each bound). Error = (in − out) / in × 100 (positive: the fit "
                "reads low; 0 when nothing was injected); mean err is the mean of the "
                "faults' |error|, as the thesis' Figure 6.17."
                + (f" At least as accurate as the thesis on <b>{better}/{len(table)}</b> "
                   "cases." if has_thesis else ""))
        note += _bounds_note(ident.rows[name], fits)
        parts.append(f"<h3>{esc(name)}</h3><p class=\"note\">{note}</p>"
                     + page.table(cols, rows, f"fdi {name}")
                     + page.plot(F.mean_error_figure(table, name)))
        fits = fit_figures(ident.rows[name], camp)
        if fits:
            parts.append('<p class="note">Fit of record vs model: the HF reference of a case '
                         "against the LF model with the identified faults (lowest seed, "
                         "re-simulated).</p>" + page.choice("Case:", fits)[0])
    return "".join(parts)


def _bounds_note(rows, fits) -> str:
    """Why some cases' 90 % interval is their search bounds (the thesis' cases 1 and 2): the
    interval of a parameter the record does not constrain, or of a flagged fit (residual well
    above the noise), is widened to the bounds searched; said once, with the cases."""
    cases: dict[int, bool] = {}
    for r in rows:
        for n in fits:
            lo, hi = (r.intervals or {}).get(n, (None, None))
            b = (r.bounds or {}).get(n)
            if lo is None or hi is None or not b:
                continue
            span = abs(float(b[1]) - float(b[0])) or 1.0
            if lo <= float(b[0]) + 1e-6 * span and hi >= float(b[1]) - 1e-6 * span:
                cases[int(r.case)] = cases.get(int(r.case), False) or bool(r.flagged)
    if not cases:
        return ""
    listed = ", ".join(str(c) for c in sorted(cases))
    flagged = [c for c, f in sorted(cases.items()) if f]
    why = (f" (flagged on case{'s' if len(flagged) > 1 else ''} "
           f"{', '.join(map(str, flagged))}: the residual stays well above the noise)"
           if flagged else "")
    return (f" On case{'s' if len(cases) > 1 else ''} {esc(listed)} the 90 % interval is the "
            "search bounds: the record does not constrain the parameter there" + esc(why)
            + ", so the interval is widened to all it could be.")


# =========================================================================== residual loop
def _explain_state(run: dict[str, Any]) -> str:
    """The tag of the residual (:mod:`eha.explain.verdict`'s facts): "explained" (at the
    noise or the found model's own level, whether or not a rival fits as well: the verdict
    kind says that), "above noise"
    (within what healthy actuators leave on the command) or "unexplained" (beyond it). A
    database from before the facts: ``unexplained`` then meant "not at the noise or not
    unique", and one from before the healthy band (no ``beyond_healthy``) called only the
    last unexplained."""
    def known(value) -> bool:
        return value is not None and not (isinstance(value, float) and value != value)

    if known(run.get("at_noise")):
        at_level = run.get("at_model_level")
        if bool(run["at_noise"]) or (known(at_level) and bool(at_level)):
            return "explained"
        return "above noise" if bool(run.get("within_healthy_band")) else "unexplained"
    if not run.get("unexplained"):
        return "explained"
    beyond = run.get("beyond_healthy")
    return "above noise" if known(beyond) and not bool(beyond) else "unexplained"


def explain_key(run: dict[str, Any]) -> str:
    """The one key of a residual-loop run in the report: its table row and its figure in
    the selector (a record given with a folder, ``data/run1.csv``, is shown by its name)."""
    return f"{_base_name(run['source'])} ({str(run['run_id'])[:6]})"


def _base_name(source: Any) -> str:
    return str(source).replace("\\", "/").rsplit("/", 1)[-1]


def explain_section(page: Page, data: dict[str, Any]) -> str:
    from eha.models.units import show

    runs, steps = data["runs"], data["steps"]
    rows = []
    for r in runs.to_dict("records"):
        verdict = r.get("verdict")
        rows.append({"source": _base_name(r["source"]), "key": explain_key(r),
                     "run_id": r["run_id"], "created_at": str(r["created_at"])[:19],
                     "fit": ", ".join(r["fit"] or {}),
                     "effects": ", ".join(r["effects"] or []) or "-",
                     "rmse_before": r["rmse_before"], "rmse_after": r["rmse_after"],
                     "noise_rmse": r["noise_rmse"],
                     "state": _explain_state(r),
                     "kind": r.get("verdict_kind") if isinstance(r.get("verdict_kind"), str)
                     else "-",
                     "verdict": verdict if isinstance(verdict, str) else "-",
                     "stop_reason": r.get("stop_reason") or "-"})
    cols = [Column("source", "record", text=True), Column("created_at", "run", text=True),
            Column("fit", "declared faults", text=True),
            Column("effects", "added effects", text=True),
            Column("rmse_before", "RMSE before [µm]", fmt_num(3, 1e6)),
            Column("rmse_after", "RMSE after [µm]", fmt_num(3, 1e6)),
            Column("noise_rmse", "noise [µm]", fmt_num(3, 1e6)),
            Column("state", "residual", tag), Column("kind", "verdict kind", text=True),
            Column("verdict", "verdict", text=True)]
    key = explain_key
    figs = {}
    step_tables = []
    for r in runs.to_dict("records"):
        mine = steps[steps["run_id"] == r["run_id"]]
        figs[key(r)] = F.steps_figure(mine, r)
        srows = [{"step": s["step"], "effect": s["effect"],
                  "params": ", ".join(f"{k} {show(k, v, 4)}"
                                      for k, v in (s["params"] or {}).items()),
                  "rmse_before": s["rmse_before"], "rmse_after": s["rmse_after"],
                  "rmse_hold_before": s["rmse_hold_before"],
                  "rmse_hold_after": s["rmse_hold_after"], "gain": s["gain"],
                  "score": s["score"]} for s in mine.to_dict("records")]
        scols = [Column("step", "step", fmt_int), Column("effect", "effect", text=True),
                 Column("params", "parameters", text=True),
                 Column("rmse_before", "RMSE before [µm]", fmt_num(3, 1e6)),
                 Column("rmse_after", "RMSE after [µm]", fmt_num(3, 1e6)),
                 Column("rmse_hold_before", "held-out before [µm]", fmt_num(3, 1e6)),
                 Column("rmse_hold_after", "held-out after [µm]", fmt_num(3, 1e6)),
                 Column("gain", "gain", fmt_num(3)), Column("score", "score", fmt_num(3))]
        body = (page.table(scols, srows, f"steps {r['run_id']}", filter_box=False) if srows
                else '<p class="note">no effect added</p>')
        step_tables.append(f"<details><summary>{esc(key(r))}: {len(srows)} steps — "
                           f"{esc(r.get('verdict') or r.get('stop_reason') or '')}</summary>"
                           f"{body}</details>")
    choice_html, pid = page.choice("Record:", figs)
    return ('<p class="note">Every eha explain run in the database: the error of the LF model '
            "with the declared faults only, then with the effects the loop added (whole "
            "record), against the record's noise. Click a row to show its steps.</p>"
            + page.plot(F.explain_figure(runs))
            + page.table(cols, rows, "explain runs", choice=(pid, "key"))
            + choice_html + "<h3>Steps</h3>" + "".join(step_tables))


# =========================================================================== campaigns
def campaigns_section(page: Page, data: dict[str, Any]) -> str:
    status = data["status"]
    rows = []
    for camp, grp in status.groupby("campaign", sort=True):
        n = {s: int(grp[grp["status"] == s]["n"].sum()) for s in ("done", "failed",
                                                                  "pending")}
        rows.append({"campaign": camp, "kind": ", ".join(sorted(set(grp["kind"]))),
                     "runs": int(grp["n"].sum()), **n,
                     "description": grp["description"].dropna().iloc[0]
                     if grp["description"].notna().any() else "-"})
    cols = [Column("campaign", "campaign", text=True), Column("kind", "kind", text=True),
            Column("runs", "runs", fmt_int), Column("done", "done", fmt_int),
            Column("failed", "failed", fmt_int), Column("pending", "pending", fmt_int),
            Column("description", "description", text=True)]
    parts = [page.table(cols, rows, "campaigns"), page.plot(F.status_figure(status))]
    hf_lf = data["hf_lf"]
    for camp, grp in hf_lf.groupby("campaign", sort=True):
        parts.append(page.plot(F.hf_lf_figure(grp, str(camp))))
    return "".join(parts)
