"""What the HTML report shows, read from a results folder (``eha report html``).

One read-only connection to ``DIR/eha.duckdb`` (:func:`eha.campaigns.store.connect`); each reader returns
plain tables (pandas DataFrames, dicts) for one section, or None when the folder holds nothing
for it, so that the section is left out. Nothing here draws or writes.

Units are SI as stored; the figures scale them for display (:func:`unit_of`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.models.params import SPECS
from eha.models.units import display_unit


def unit_of(name: str) -> tuple[str, float]:
    """Display unit and scale factor of a parameter (:func:`eha.models.units.display_unit`;
    ``-`` for a dimensionless one, so that a column head reads ``[-]``)."""
    unit, factor = display_unit(name)
    return (unit or ("-" if name in SPECS else ""), factor)


def _json(value: Any) -> Any:
    """A JSON column as read (text) back to Python; NULL stays None."""
    if isinstance(value, str):
        return json.loads(value)
    return value


def _tables(con) -> set[str]:
    return {r[0] for r in con.execute("SELECT table_name FROM information_schema.tables")
            .fetchall()}


def _count(con, table: str) -> int:
    return int(con.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0])


# =========================================================================== fleet
@dataclass
class Fleet:
    """One ``eha rul`` run: its predictions at every check and, when found, the truth.

    Attributes
    ----------
    run_id : str
        The health campaign of the run (``rul-<manifest>-<hash>``).
    predictions : pandas.DataFrame
        The ``rul_predictions`` rows, JSON columns decoded, sorted by actuator and cycle.
    limits : dict
        ``{fault: limit}`` (SI).
    faults : list of str
        The faults tracked (keys of the estimates).
    truth : dict or None
        ``{actuator: true end of life or None}`` when a truth file was found.
    truth_source : str or None
        Where the truth was read.
    reference : str
        The check the health history came from: ``fleet`` (every record identified) or
        ``baseline`` (``eha rul --check change``: each record's change since its baseline).
    changes : pandas.DataFrame or None
        With the change check: its ``change_checks`` rows (JSON decoded) by actuator and cycle.
    alarms : dict
        With the change check: ``{actuator: {fault: first-alarm row}}`` (``change_alarms``).
    """

    run_id: str
    predictions: Any
    limits: dict[str, float]
    faults: list[str]
    truth: dict[str, float | None] | None = None
    truth_source: str | None = None
    reference: str = "fleet"
    changes: Any = None
    alarms: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)


def read_fleets(con, truth: str | Path | None = None) -> list[Fleet]:
    """Every ``eha rul`` run in the database, newest first (empty list: none).

    The truth is ``truth`` when given, else a ``truth.json`` of ``eha fleet simulate`` found
    beside the run's records (the manifest's folder or its parents, two levels up) whose
    actuators include every actuator of the run.
    """
    if "rul_predictions" not in _tables(con) or not _count(con, "rul_predictions"):
        return []
    frame = con.execute("SELECT * FROM rul_predictions ORDER BY run_id, actuator, cycle").df()
    for col in ("estimates", "intervals", "crossings", "law_weights", "limits"):
        frame[col] = frame[col].map(_json)
    order = (frame.groupby("run_id")["created_at"].max().sort_values(ascending=False).index)
    fleets = []
    for run_id in order:
        rows = frame[frame["run_id"] == run_id].reset_index(drop=True)
        limits = {k: float(v) for k, v in (rows["limits"].iloc[0] or {}).items()}
        faults = list(dict.fromkeys(k for e in rows["estimates"] if e for k in e))
        fleet = Fleet(str(run_id), rows, limits, faults)
        _attach_truth(con, fleet, truth)
        _attach_changes(con, fleet)
        fleets.append(fleet)
    if truth is not None and fleets and not any(f.truth_source == str(truth) for f in fleets):
        from eha.prognostics.degradation import PrognosticsError

        have = sorted(set(fleets[0].predictions["actuator"]))
        raise PrognosticsError(f"`truth` {truth}: no end of life for every actuator of any "
                               f"eha rul run in the database (e.g. {', '.join(have[:5])} of "
                               f"{fleets[0].run_id})")
    return fleets


#: The JSON columns of a ``change_checks`` row.
CHANGE_JSON = ("changes", "intervals", "statistics", "thresholds", "degraded", "isolated",
               "screen")


def _attach_changes(con, fleet: Fleet) -> None:
    """The change check's rows of an ``eha rul --check change`` run (none for another)."""
    tables = _tables(con)
    ref = fleet.predictions["reference"].dropna() if "reference" in fleet.predictions else ()
    if len(ref):
        fleet.reference = str(ref.iloc[0])
    if "change_checks" in tables:
        frame = con.execute("SELECT * FROM change_checks WHERE campaign = ? "
                            "ORDER BY actuator, cycle", [fleet.run_id]).df()
        if len(frame):
            for col in CHANGE_JSON:
                frame[col] = frame[col].map(_json)
            fleet.changes, fleet.reference = frame, "baseline"
    if "change_alarms" in tables:
        for r in con.execute("SELECT * FROM change_alarms WHERE run_id = ?",
                             [fleet.run_id]).df().to_dict("records"):
            fleet.alarms.setdefault(str(r["actuator"]), {})[str(r["fault"])] = r


def _attach_truth(con, fleet: Fleet, truth: str | Path | None) -> None:
    from eha.prognostics.degradation import PrognosticsError
    from eha.prognostics.jobs import load_truth

    actuators = set(fleet.predictions["actuator"])
    candidates: list[Path] = []
    if truth is not None:  # given: read (an unusable file is refused, never ignored)
        eol = load_truth(truth)
        if actuators <= set(eol):
            fleet.truth, fleet.truth_source = eol, str(truth)
            return
    # not given, or not this run's actuators: the truth beside its records, if any
    rec = con.execute("SELECT record FROM health_checks WHERE campaign = ? LIMIT 1",
                      [fleet.run_id]).fetchone() if "health_checks" in _tables(con) \
        else None
    if rec and rec[0]:
        parents = Path(rec[0]).parents
        candidates += [parents[i] / "truth.json" for i in range(min(3, len(parents)))]
    for path in candidates:
        if not path.is_file():
            continue
        try:
            eol = load_truth(path)
        except PrognosticsError:
            continue
        if actuators <= set(eol):
            fleet.truth, fleet.truth_source = eol, str(path)
            return


def direction(first: float, limit: float) -> int:
    """+1 when the fault grows towards its limit (first estimate below it), -1 when it falls."""
    return 1 if first <= limit else -1


def fleet_table(fleet: Fleet, check_spacing: float | None = None) -> list[dict[str, Any]]:
    """One row per actuator at its last check.

    Columns: ``actuator, checks, last_cycle``; per fault ``<F>``, ``<F>_lo``, ``<F>_hi``
    (SI) and ``<F>_verdict`` (``beyond limit`` when the estimate has crossed the fault's
    limit, ``interval reaches limit`` when its interval has, ``below limit``, or ``tracked``
    for a fault without limit); ``rul, rul_lo, rul_hi, driver, predicted_eol, flagged`` and
    ``status``: ``end of life`` (a fault beyond its limit), ``attention`` (the 5 % RUL
    quantile within two check spacings), ``no trend`` (no RUL predicted), else ``ok``;
    ``true_eol`` with a truth.
    """
    rows = []
    preds = fleet.predictions
    for aid, grp in preds.groupby("actuator", sort=True):
        grp = grp.sort_values("cycle")
        last = grp.iloc[-1]
        cycles = grp["cycle"].to_numpy(float)
        spacing = check_spacing if check_spacing is not None else (
            float(np.median(np.diff(cycles))) if len(cycles) > 1 else None)
        row: dict[str, Any] = {"actuator": str(aid), "checks": int(len(grp)),
                               "last_cycle": float(last["cycle"])}
        crossed = False
        for name in fleet.faults:
            est = (last["estimates"] or {}).get(name)
            lo, hi = ((last["intervals"] or {}).get(name) or (None, None))
            row[name], row[f"{name}_lo"], row[f"{name}_hi"] = est, lo, hi
            lim = fleet.limits.get(name)
            if lim is None or est is None:
                row[f"{name}_verdict"] = "tracked"
                continue
            first = (grp["estimates"].iloc[0] or {}).get(name, est)
            sign = direction(first, lim)
            if sign * (est - lim) >= 0:
                row[f"{name}_verdict"] = "beyond limit"
                crossed = True
            elif (hi if sign > 0 else lo) is not None and sign * ((hi if sign > 0 else lo)
                                                                  - lim) >= 0:
                row[f"{name}_verdict"] = "interval reaches limit"
            else:
                row[f"{name}_verdict"] = "below limit"
        rul, rul_lo, rul_hi = (_num(last["rul"]), _num(last["rul_lo"]), _num(last["rul_hi"]))
        row.update({"rul": rul, "rul_lo": rul_lo, "rul_hi": rul_hi,
                    "driver": last["driver"] if isinstance(last["driver"], str) else None,
                    "predicted_eol": None if rul is None else row["last_cycle"] + rul,
                    "flagged": bool(last["flagged"]) if last["flagged"] is not None else False})
        if crossed or (rul is not None and rul <= 0):
            status = "end of life"
        elif rul is None:
            status = "no trend"
        elif rul_lo is not None and spacing and rul_lo <= 2 * spacing:
            status = "attention"
        else:
            status = "ok"
        row["status"] = status
        if fleet.truth is not None:
            row["true_eol"] = fleet.truth.get(str(aid))
        rows.append(row)
    return rows


def _num(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


# =========================================================================== health
@dataclass
class Health:
    """Health checks (``health_verdicts``) and detection campaigns (``health_assessments``).

    Attributes
    ----------
    verdicts : pandas.DataFrame or None
        One row per check and fault, newest check first.
    campaigns : dict
        ``{campaign: eha.health.detection.performance(...)}`` for every campaign with assessments.
    alpha : float
        False-alarm probability of the thresholds of ``campaigns``.
    thresholds : pandas.DataFrame or None
        The ``health_thresholds`` rows (``eha health calibrate``), newest calibration first.
    calibrations : dict
        ``{campaign: healthy actuators}`` of the campaigns with healthy actuators only (the
        fleets of ``eha health calibrate``: no fault to detect, shown as calibrations).
    skipped : dict
        ``{campaign: why}`` of the detection campaigns whose figures cannot be computed
        (too few healthy actuators), named on the page rather than failing it.
    """

    verdicts: Any = None
    campaigns: dict[str, Any] = field(default_factory=dict)
    alpha: float = 0.01
    thresholds: Any = None
    calibrations: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)


def read_health(con) -> Health | None:
    """The health section's data, or None when there are neither checks nor assessments."""
    from eha.health.detection import DEFAULT_ALPHA, DetectionError, performance

    tables = _tables(con)
    out = Health(alpha=DEFAULT_ALPHA)
    if "health_verdicts" in tables and _count(con, "health_verdicts"):
        out.verdicts = con.execute("SELECT * FROM health_verdicts ORDER BY created_at DESC, "
                                   "check_id, fault").df()
    if "health_thresholds" in tables and _count(con, "health_thresholds"):
        out.thresholds = con.execute("SELECT * FROM health_thresholds ORDER BY created_at "
                                     "DESC, calibration, fault").df()
    if "health_assessments" in tables and _count(con, "health_assessments"):
        frame = con.execute("""
            SELECT r.campaign, h.* FROM health_assessments h JOIN runs r USING (run_key)
            WHERE r.status = 'done' ORDER BY r.campaign, h.seed""").df()
        for campaign, grp in frame.groupby("campaign", sort=True):
            if set(grp["grp"]) == {"healthy"}:  # a calibration's fleet: nothing to detect
                out.calibrations[str(campaign)] = int(len(grp))
                continue
            rows = []
            for rec in grp.drop(columns=["campaign"]).to_dict("records"):
                for k in ("truth", "hf", "estimates", "means", "spread", "intervals", "weights"):
                    rec[k] = _json(rec.get(k))
                rows.append(rec)
            try:
                perf = performance(rows, DEFAULT_ALPHA)
            except DetectionError as exc:  # a small fleet: named on the page, not fatal
                out.skipped[str(campaign)] = str(exc)
                continue
            if perf:
                out.campaigns[str(campaign)] = perf
            else:
                out.skipped[str(campaign)] = (f"fewer than 5 healthy actuators per command "
                                              f"({int((grp['grp'] == 'healthy').sum())} in all)")
    if "health_changes" in tables and _count(con, "health_changes"):
        _change_campaigns(con, out)
    found = (out.verdicts is not None or out.campaigns or out.thresholds is not None
             or out.calibrations or out.skipped)
    return out if found else None


def _change_campaigns(con, out: Health) -> None:
    """The change check's campaigns (``[health] baseline = true``), judged against their own
    healthy pairs as ``eha report health`` does."""
    from eha.health.change_performance import performance_change

    frame = con.execute("""
        SELECT r.campaign, h.* FROM health_changes h JOIN runs r USING (run_key)
        WHERE r.status = 'done' ORDER BY r.campaign, h.seed""").df()
    for campaign, grp in frame.groupby("campaign", sort=True):
        rows = []
        for rec in grp.drop(columns=["campaign"]).to_dict("records"):
            for k in ("nuisances", "test_day", "hf", "estimates", "intervals", "info",
                      "noise_factor", "alike", "blind"):
                rec[k] = _json(rec.get(k))
            rec["fault"] = rec["fault"] if isinstance(rec.get("fault"), str) else None
            rows.append(rec)
        perf = performance_change(rows, out.alpha)
        if perf:
            out.campaigns[str(campaign)] = perf


# =========================================================================== identification
@dataclass
class Identification:
    """FDI campaigns: per campaign its table (:func:`eha.reports.thesis.fdi_table`), its rows
    and definition, and the interval of each case (median over the seeds of each bound)."""

    tables: dict[str, Any] = field(default_factory=dict)
    rows: dict[str, list] = field(default_factory=dict)
    campaigns: dict[str, Any] = field(default_factory=dict)


def read_identification(con) -> Identification | None:
    """Every FDI campaign with results (the augmented thesis campaign joins the thesis table
    as its ``aug_*`` columns, as in ``fdi_table.csv``); None when there is none."""
    from eha.identification.cases import parse_fdi_campaign, rows_from_results
    from eha.reports.fdi_table import AUGMENTED_CAMPAIGN, FDI_CAMPAIGN, fdi_table

    if "fdi_results" not in _tables(con) or not _count(con, "fdi_results"):
        return None
    frame = con.execute("""
        SELECT r.campaign, f.* FROM fdi_results f JOIN runs r USING (run_key)
        WHERE r.status = 'done' ORDER BY r.campaign, f.case_id, f.seed""").df()
    defs = dict(con.execute("SELECT name, definition FROM campaigns").fetchall())
    by_campaign = {str(c): rows_from_results(g.drop(columns=["campaign"]))
                   for c, g in frame.groupby("campaign", sort=True)}
    out = Identification()
    for name, rows in by_campaign.items():
        if name == AUGMENTED_CAMPAIGN and FDI_CAMPAIGN in by_campaign:
            continue
        if name not in defs:
            continue
        camp = parse_fdi_campaign(json.loads(defs[name]), name)
        aug = by_campaign.get(AUGMENTED_CAMPAIGN) if name == FDI_CAMPAIGN else None
        table = fdi_table(rows, camp, aug)
        if table.empty:
            continue
        for n in camp.fit:
            lo, hi = [], []
            for case in table["case"]:
                ivs = [r.intervals[n] for r in rows if int(r.case) == int(case)
                       and r.intervals and n in r.intervals]
                lo.append(float(np.median([v[0] for v in ivs])) if ivs else np.nan)
                hi.append(float(np.median([v[1] for v in ivs])) if ivs else np.nan)
            table[f"{n.lower()}_int_lo"], table[f"{n.lower()}_int_hi"] = lo, hi
        out.tables[name], out.rows[name], out.campaigns[name] = table, rows, camp
    return out if out.tables else None


# =========================================================================== residual loop
def read_explain(con) -> dict[str, Any] | None:
    """``explain_runs`` (newest first) and ``explain_steps``; None when there is no run."""
    if "explain_runs" not in _tables(con) or not _count(con, "explain_runs"):
        return None
    runs = con.execute("SELECT * FROM explain_runs ORDER BY created_at DESC, run_id").df()
    for col in ("fit", "settings", "faults_before", "faults_after", "effects", "leads"):
        if col in runs:
            runs[col] = runs[col].map(_json)
    steps = con.execute("SELECT * FROM explain_steps ORDER BY run_id, step").df()
    for col in ("params", "faults_before", "faults_after"):
        steps[col] = steps[col].map(_json)
    return {"runs": runs, "steps": steps}


# =========================================================================== eha fdi, eha design
def read_fdi_runs(con) -> Any:
    """The ``fdi_runs`` rows (``eha fdi --results``), newest first, JSON columns decoded;
    None when there is none."""
    if "fdi_runs" not in _tables(con) or not _count(con, "fdi_runs"):
        return None
    runs = con.execute("SELECT * FROM fdi_runs ORDER BY created_at DESC, run_id").df()
    for col in ("names", "bounds", "estimates", "intervals", "truth", "errors_pct"):
        runs[col] = runs[col].map(_json)
    return runs


def read_designs(con) -> Any:
    """The ``design_runs`` rows (``eha design --results``), newest first, JSON columns
    decoded; None when there is none."""
    if "design_runs" not in _tables(con) or not _count(con, "design_runs"):
        return None
    runs = con.execute("SELECT * FROM design_runs ORDER BY created_at DESC, run_id").df()
    for col in ("settings", "targets", "pairs"):
        runs[col] = runs[col].map(_json)
    return runs


# =========================================================================== campaigns
def read_campaigns(con) -> dict[str, Any] | None:
    """Runs by status per campaign, and the HF-vs-LF errors of every simulation campaign.

    Returns
    -------
    dict or None
        ``status`` (DataFrame campaign, kind, status, n, description) and ``hf_lf`` (DataFrame
        of HF runs with an HF-vs-LF error: campaign, command, faults, rmse_xu_hf_lf,
        rmse_p12_hf_lf); None when no campaign has runs.
    """
    import pandas as pd

    tables = _tables(con)
    if "runs" not in tables or not _count(con, "runs"):
        return None
    status = con.execute("""
        SELECT r.campaign, r.kind, r.status, count(*) AS n, any_value(c.description)
               AS description
        FROM runs r LEFT JOIN campaigns c ON c.name = r.campaign
        GROUP BY r.campaign, r.kind, r.status ORDER BY r.campaign, r.kind, r.status""").df()
    # metrics: created by the first simulation campaign (a folder of health or rul runs only
    # has none)
    hf_lf = con.execute("""
        SELECT r.campaign, r.command, r.faults, r.seed, m.rmse_xu_hf_lf, m.rmse_p12_hf_lf,
               m.max_err_xu_hf_lf
        FROM runs r JOIN metrics m USING (run_key)
        WHERE r.kind = 'simulate' AND r.model = 'hf' AND r.status = 'done'
          AND m.rmse_xu_hf_lf IS NOT NULL
        ORDER BY r.campaign, r.command, r.fault_label, r.seed""").df() if "metrics" in tables \
        else pd.DataFrame(columns=["campaign", "command", "faults", "seed", "rmse_xu_hf_lf",
                                   "rmse_p12_hf_lf", "max_err_xu_hf_lf"])
    hf_lf["faults"] = hf_lf["faults"].map(lambda s: _json(s) or {})
    return {"status": status, "hf_lf": hf_lf}


def fault_key(faults: Mapping[str, float]) -> str:
    """Canonical text of a fault set (the key of the heat maps)."""
    return json.dumps(dict(faults), sort_keys=True)
