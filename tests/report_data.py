"""A results folder with something for every section of the HTML report, in milliseconds.

A real DuckDB file written through the store's writers (:func:`eha.campaigns.store.replace_rows`,
:func:`eha.explain.tables.save_explain`) with rows shaped as the commands write them: a 3-actuator
``eha rul`` run (with a ``truth.json`` beside its records), two health checks and a detection
campaign, the thesis' FDI campaign (its real definition, three seeds per case, and its
augmented twin), one residual-loop run and a simulation campaign with HF-vs-LF errors. The
values are drawn from seeded generators, not computed by the models: the report is checked
against the database, whatever the numbers.
"""

from __future__ import annotations

import json
import tomllib
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from eha.campaigns.files import campaigns_dir
from eha.health.assessment import FAULTS
from eha.campaigns.store import replace_rows
from eha.explain.tables import save_explain

NOW = datetime(2026, 11, 1, 12, 0, 0)
ACTUATORS = {"A1": 1300.0, "A2": 2100.0, "A3": None}        # true end of life (None: never)
FLEET_RUN = "rul-manifest-canned"
LIMITS = {"BKL": 5e-4, "FDJ": 2000.0}


def _runs(campaign: str, kind: str, keys, **cols) -> list[dict]:
    return [{"run_key": k, "campaign": campaign, "kind": kind, "status": "done", **cols}
            for k in keys]


def _campaign(results: Path, name: str, definition: dict, n: int, description: str = ""
              ) -> None:
    replace_rows(results, "campaigns", [{
        "name": name, "description": description or definition.get("description", ""),
        "source": f"{name}.toml", "spec_hash": "0" * 16, "model_version": "1", "n_runs": n,
        "definition": definition, "created_at": NOW, "updated_at": NOW}], {"name": name})


def build(results: Path) -> Path:
    """Write the canned results folder ``results``; returns it."""
    results.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    _fleet(results, rng)
    _health(results, rng)
    _fdi(results, rng)
    _explain(results)
    _simulations(results, rng)
    return results


def _fleet(results: Path, rng) -> None:
    records = results / "fleet" / "records"
    records.mkdir(parents=True, exist_ok=True)
    (results / "fleet" / "truth.json").write_text(json.dumps(
        {"actuators": {a: {"eol": e} for a, e in ACTUATORS.items()}}))
    checks, preds = [], []
    for a, eol in ACTUATORS.items():
        for i, cycle in enumerate(np.arange(0.0, 1300.0, 200.0)):
            rec = records / a / f"c{int(cycle)}.csv"
            fdj = 200 + (1800 / (eol or 6000)) * cycle + rng.normal(0, 20)
            bkl = 2e-5 + 1e-7 * cycle
            est = {"BKL": bkl, "FDJ": fdj, "GM": 0.01 + rng.normal(0, 1e-4)}
            iv = {k: [0.95 * v, 1.05 * v] for k, v in est.items()}
            key = f"{a}{i:014d}"
            checks.append({"run_key": key, "campaign": FLEET_RUN, "actuator": a,
                           "cycle": float(cycle), "record": str(rec.resolve()),
                           "record_sha": "0" * 16, "fit": {"FDJ": [200, 4000]},
                           "estimates": est, "intervals": iv, "level": 0.9, "flagged": i == 3,
                           "objective": 2e-6, "seed": 0, "method": "lm", "seconds": 1.0})
            rul = None if eol is None else max(eol - cycle + rng.normal(0, 40), 0.0)
            preds.append({"run_id": FLEET_RUN, "actuator": a, "cycle": float(cycle),
                          "rul": rul, "rul_lo": None if rul is None else 0.7 * rul,
                          "rul_hi": None if rul is None or i < 2 else 1.3 * rul,
                          "driver": None if rul is None else "FDJ", "estimates": est,
                          "intervals": iv, "flagged": i == 3,
                          "crossings": {} if rul is None else {"FDJ": {
                              "median": cycle + rul, "lo": cycle + 0.7 * rul,
                              "hi": cycle + 1.3 * rul}},
                          "law_weights": {"FDJ": {"linear": 1.0}}, "limits": LIMITS,
                          "n_used": i + 1, "seed": i, "created_at": NOW})
    replace_rows(results, "runs", _runs(FLEET_RUN, "health", [c["run_key"] for c in checks]),
                 {"campaign": FLEET_RUN})
    replace_rows(results, "health_checks", checks, {"campaign": FLEET_RUN})
    replace_rows(results, "rul_predictions", preds, {"run_id": FLEET_RUN})


def _health(results: Path, rng) -> None:
    rows = []
    for check, (record, deg) in enumerate((("ok.csv", None), ("worn.csv", "FDJ"))):
        for name, spec in FAULTS.items():
            est = spec.healthy * (1.0 + (0.5 if name == deg else 0.0)) + 1e-9
            rows.append({"check_id": f"check{check}", "record": f"/data/{record}",
                         "created_at": NOW + timedelta(minutes=check), "calibration": "c.json",
                         "fault": name, "estimate": est, "lo": est * 0.9, "hi": est * 1.1,
                         "level": 0.9, "healthy": spec.healthy, "threshold": 1.0,
                         "statistic": 1.5 if name == deg else 0.2,
                         "degraded": name == deg, "weight": 0.9 if name == deg else 0.01,
                         "isolated": name == deg, "flagged": False})
    replace_rows(results, "health_verdicts", rows, {"calibration": "c.json"})
    camp, assess = "health-canned", []
    for k in range(30):
        grp, value = ("healthy", None) if k < 20 else ("FDJ=400", 400.0) if k < 25 else \
            ("FDJ=220", 220.0)
        means = {n: FAULTS[n].healthy for n in FAULTS}
        means["FDJ"] = (value or 200.0) + rng.normal(0, 5)
        assess.append({"run_key": f"h{k:015d}", "command": "chirp_1cm", "grp": grp, "seed": k,
                       "t_end": 1.0, "noise": 2e-6, "base_model": "calibrated", "level": 0.9,
                       "truth": means, "hf": {}, "estimates": means, "means": means,
                       "spread": {n: 0.0 for n in FAULTS}, "intervals": {},
                       "weights": {"none": 1.0} if grp == "healthy" else {"FDJ": 1.0},
                       "best": "none", "flagged": False, "residual_rmse": 2e-6,
                       "noise_rmse": 2e-6, "n_eff": 100.0, "seconds": 1.0})
    _campaign(results, camp, {"name": camp, "kind": "health"}, len(assess),
              "canned detection campaign")
    replace_rows(results, "runs", _runs(camp, "health", [a["run_key"] for a in assess],
                                        command="chirp_1cm"), {"campaign": camp})
    replace_rows(results, "health_assessments", assess, {"command": "chirp_1cm"})


def _fdi(results: Path, rng) -> None:
    every = []
    for name, shift in (("thesis-fdi", 0.0), ("thesis-fdi-augmented", -0.9)):
        definition = tomllib.loads((campaigns_dir() / f"{name}.toml").read_text())
        definition["fdi"]["t_end"] = 0.2         # the report re-simulates each case's fit
        rows = []
        for case in definition["fdi"]["cases"]:
            for seed in (0, 1, 2):
                truth = {"BKL": case["faults"].get("BKL", 0.0), "FDJ": case["faults"]["FDJ"]}
                err = {"BKL": float(rng.normal(3, 2) * (1 + shift)) if truth["BKL"]
                       else 0.0,
                       "FDJ": float(rng.normal(-2, 1) * (1 + shift))}
                est = {k: v * (1 - err[k] / 100) for k, v in truth.items()}
                if not truth["BKL"]:
                    est["BKL"] = 1e-6
                rows.append({
                    "run_key": f"{name[-4:]}{case['case']:02d}{seed:010d}",
                    "case_id": case["case"], "command": case["command"], "seed": seed,
                    "method": "ga+ps", "objective_name": "rmse", "fit": ["BKL", "FDJ"],
                    "truth": truth, "estimates": est, "errors_pct": err,
                    "bounds": case["bounds"], "bkl_true": truth["BKL"], "bkl_est": est["BKL"],
                    "err_bkl_pct": err["BKL"], "fdj_true": truth["FDJ"], "fdj_est": est["FDJ"],
                    "err_fdj_pct": err["FDJ"],
                    "mean_err_pct": (abs(err["BKL"]) + abs(err["FDJ"])) / 2,
                    "objective": 1e-6, "evaluations": 400 + seed, "seconds": 1.0 + seed,
                    "pop": case.get("pop", 20), "history": [1e-5, 1e-6], "level": 0.9,
                    "intervals": {k: [0.9 * v, 1.1 * v] for k, v in est.items()},
                    "flagged": False, "noise_rmse": 1e-7})
        _campaign(results, name, definition, len(rows))
        replace_rows(results, "runs", _runs(name, "fdi", [r["run_key"] for r in rows]),
                     {"campaign": name})
        every += rows
    replace_rows(results, "fdi_results", every, {"objective_name": "rmse"})


def _explain(results: Path) -> None:
    run = {"run_id": "e" * 16, "source": "/data/bench.csv", "created_at": NOW,
           "fit": {"BKL": [0, 1e-3], "FDJ": [200, 4000]}, "holdout": "last 30 %",
           "settings": {"seed": 0}, "rmse_before": 1.2e-5, "rmse_after": 2.1e-6,
           "noise_rmse": 2.0e-6, "unexplained_rmse": 7e-7,
           "faults_before": {"FDJ": 800.0}, "faults_after": {"FDJ": 805.0},
           "effects": ["leakage", "orifice_law"], "stop_reason": "no candidate improves",
           "seconds": 30.0, "unexplained": False,
           "verdict": "explained: residual 2.1 µm (1.05× noise)", "command_hold": "linear",
           "leads": None}
    steps = [{"run_id": run["run_id"], "step": i + 1, "effect": e, "params": p,
              "rmse_before": b, "rmse_after": a, "rmse_fit_before": b, "rmse_fit_after": a,
              "rmse_hold_before": 1.1 * b, "rmse_hold_after": 1.1 * a,
              "faults_before": {"FDJ": 800.0}, "faults_after": {"FDJ": 805.0},
              "gain": 1 - a / b, "score": 0.5}
             for i, (e, p, b, a) in enumerate((("leakage", {"Clk": 2e-13}, 1.2e-5, 5e-6),
                                               ("orifice_law", {"orifice_law": 1.0}, 5e-6,
                                                2.1e-6)))]
    save_explain(results, run, steps)


def _simulations(results: Path, rng) -> None:
    camp = "grid-canned"
    runs, metrics = [], []
    for cmd in ("mixed", "chirp_1cm"):
        for bkl in (1e-4, 5e-4):
            for fdj in (400.0, 800.0, 1600.0):
                for model in ("hf", "lf"):
                    key = f"{cmd[:4]}{int(bkl * 1e6):04d}{int(fdj):05d}{model}"
                    runs.append({"run_key": key, "campaign": camp, "kind": "simulate",
                                 "status": "done", "model": model, "command": cmd,
                                 "faults": {"BKL": bkl, "FDJ": fdj},
                                 "fault_label": f"BKL={bkl:g},FDJ={fdj:g}", "seed": 0,
                                 "t_end": 1.0})
                    metrics.append({"run_key": key, "rmse_xu_hf_lf": float(
                        1e-6 * (1 + 10 * bkl / 1e-3) * np.exp(rng.normal(0, 0.1))),
                        "rmse_p12_hf_lf": 1e5, "max_err_xu_hf_lf": 5e-6})
    runs.append({"run_key": "failedrun0000000", "campaign": camp, "kind": "simulate",
                 "status": "failed", "model": "hf", "command": "mixed", "faults": {},
                 "fault_label": "nominal", "seed": 0, "t_end": 1.0, "error": "diverged"})
    _campaign(results, camp, {"name": camp, "models": ["hf", "lf"]}, len(runs), "canned 2x3 grid")
    replace_rows(results, "runs", runs, {"campaign": camp})
    replace_rows(results, "metrics", metrics, {"max_err_xu_hf_lf": 5e-6})
