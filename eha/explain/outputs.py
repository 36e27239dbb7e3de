"""``eha explain``'s input and output: read the measured files, run the residual loop
(:func:`eha.explain.explain`), write its tables, figures, JSON and database rows (all of them
made by the result's serialisation, :class:`eha.explain.results.ExplainResult`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np

from eha.figures import pyplot as _pyplot
from eha.figures import save as _save


def plot_explain_residuals(result, path: str | Path) -> Path:
    """Measured vs LF before/after, and the residual before/after the added effects (PNG).

    ``result`` is an :class:`eha.explain.results.ExplainResult`; the held-out part is shaded.
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


def read_prior(path: str | Path) -> list:
    """``--prior``: the ``--json`` of an earlier ``eha explain`` (an object whose ``steps`` is a
    list of ``{"effect": ..., "params": {...}}``, or that list itself); its steps.

    Raises
    ------
    ExplainError
        Not a readable JSON file, or not of that shape (one line naming ``--prior``).
    """
    from eha.explain.settings import ExplainError

    try:
        prior = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ExplainError(f"--prior {path}: not a readable JSON file "
                           f"({getattr(exc, 'strerror', None) or str(exc).splitlines()[0]})"
                           ) from None
    steps = prior.get("steps") if isinstance(prior, dict) else prior
    if not isinstance(steps, list) or not all(isinstance(s, dict) and "effect" in s
                                              for s in steps):
        keys = ", ".join(sorted(prior)) if isinstance(prior, dict) else type(prior).__name__
        raise ExplainError(f"--prior {path}: expected the --json of an earlier eha explain (key "
                           f"'steps', a list of {{effect, params}}); found "
                           f"{keys or 'an empty object'}")
    return steps


def explain_report(data: str | Path, fit: str | None = None, effects: str | None = None,
                   holdout: float | None = None, validate: str | Path | None = None,
                   prior: str | Path | None = None, json_path: str | Path | None = None,
                   out: str | Path | None = None, results: str | Path = "results",
                   on_progress=None, known=None, command_hold: str = "auto",
                   **options) -> dict:
    """``eha explain``: run the residual loop on a measured file and write its outputs.

    Everything is read and validated before anything is written. Writes, under ``out``
    (default ``results/explain/<file stem>``): ``steps.csv`` (the steps table),
    ``candidates.csv`` (every candidate of every round), ``residuals.png``, ``trace.png``,
    ``explain.json`` (everything); the rows of ``explain_runs``/``explain_steps`` in
    ``results/eha.duckdb``; and, when given, ``json_path`` with the contract of issue 5.
    ``known`` holds LF parameters fixed at known values (test conditions such as a test load
    ``{"FRC": 4000}``, or ``--set`` items ``["FRC=4000"]``), on top of the ``prior``'s effects;
    they are not candidates. ``command_hold`` says how the records' commands are rebuilt
    between their samples (:data:`eha.identification.measured.COMMAND_HOLDS`). ``data`` and ``validate`` may
    be :class:`eha.identification.measured.RecordFile` (a record's columns and units); ``options`` go to
    :func:`eha.explain.api.explain` (``settings``: a :class:`LoopSettings`).

    Returns
    -------
    dict
        ``result`` (:class:`eha.explain.results.ExplainResult`), ``paths`` (name -> Path),
        ``run_id``, ``db_error`` (None, or why the database could not be written).
    """
    import datetime
    import hashlib

    import pandas as pd

    from eha.explain.api import explain
    from eha.explain.record import augmented_base
    from eha.explain.settings import ExplainError
    from eha.identification.measured import load
    from eha.campaigns.store import StoreError
    from eha.explain.tables import save_explain

    from eha.models.params import ParameterError, parse_assignments, resolve

    if known is not None and not isinstance(known, Mapping):
        try:
            known = parse_assignments(known)
        except ParameterError as exc:
            raise ExplainError(f"--set {exc}") from None
    steps = read_prior(prior) if prior is not None else None
    record = load(data, command_hold=command_hold)
    check = load(validate, command_hold=command_hold) if validate is not None else None
    base = augmented_base(steps) if steps is not None else None
    if known:
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
    if getattr(data, "columns", None) or getattr(data, "units", None):   # a RecordFile's format
        digest.update(json.dumps([data.columns, data.units], sort_keys=True).encode())
    run_id = digest.hexdigest()[:16]
    paths = {"steps": out / "steps.csv", "candidates": out / "candidates.csv",
             "residuals": out / "residuals.png", "trace": out / "trace.png",
             "details": out / "explain.json"}
    from eha.outputs import atomic_path, write_json

    with atomic_path(paths["steps"]) as tmp:
        pd.DataFrame(result.steps_table()).to_csv(tmp, index=False)
    with atomic_path(paths["candidates"]) as tmp:
        pd.DataFrame(result.candidates_table()).to_csv(tmp, index=False)
    plot_explain_residuals(result, paths["residuals"])
    plot_explain_trace(result, paths["trace"])
    write_json(paths["details"], result.details(run_id), indent=2, default=float)
    if json_path is not None:
        doc = result.to_json()
        if result.not_excluded:  # the test that would decide it (docs/design.md)
            doc["separating_test"] = {
                "rivals": [{"effect": e["effect"], "param": e["param"], "value": e["value"]}
                           for e in result.not_excluded],
                "design": f"eha design --faults none --around {json_path}"}
        write_json(json_path, doc, indent=2)
        paths["json"] = Path(json_path)
    db_error = None
    try:
        paths["database"] = save_explain(
            results, result.run_row(run_id, str(data), datetime.datetime.now()),
            result.step_rows(run_id))
    except StoreError as exc:
        db_error = str(exc)
    return {"result": result, "paths": paths, "run_id": run_id, "db_error": db_error}
