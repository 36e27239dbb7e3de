"""What a residual loop's result writes: its figures, its files and its database rows, all
made from the result's serialisation (:class:`eha.explain.results.ExplainResult`, whose
``.plot()``, ``.save()`` and ``.store()`` call these). Reading the measured files and running
the loop on them is :mod:`eha.explain.from_file`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eha.figures import pyplot as _pyplot
from eha.figures import save as _save


def plot_explain_residuals(result, path: str | Path | None = None):
    """Measured vs LF before/after, and the residual before/after the added effects: the
    figure (matplotlib), or, with ``path``, written as PNG (the path returned).

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
    n_fit = len(t) if result.facts.n_fit is None else result.facts.n_fit
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
    return fig if path is None else _save(fig, Path(path))


def plot_explain_trace(result, path: str | Path | None = None):
    """How the first residual traces to effects: signature correlation, the fraction each
    effect's linearised fit explains, held-out gain of the refits, and signal correlations
    (the figure, or, with ``path``, written as PNG)."""
    plt = _pyplot()
    if not result.rounds:
        fig, ax = plt.subplots(figsize=(7, 2))
        ax.axis("off")
        ax.text(0.5, 0.5, f"Residual not traced: {result.stop_reason}", ha="center",
                va="center", wrap=True, fontsize=9)
        return fig if path is None else _save(fig, Path(path))
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
    return fig if path is None else _save(fig, Path(path))


def save_result(result, folder: str | Path, json_path: str | Path | None = None
                ) -> dict[str, Path]:
    """Write a result's files under ``folder`` (created): ``steps.csv`` (the steps table),
    ``candidates.csv`` (every candidate of every round), ``residuals.png``, ``trace.png``,
    ``explain.json`` (everything); and, with ``json_path``, the contract of ``--json``
    (:meth:`~eha.explain.results.ExplainResult.to_json`, with the test that would decide
    between rivals the record could not rule out). Each file is written whole or not at all.

    Returns
    -------
    dict
        Name -> path of each file written.
    """
    import pandas as pd

    from eha.outputs import atomic_path, write_json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {"steps": folder / "steps.csv", "candidates": folder / "candidates.csv",
             "residuals": folder / "residuals.png", "trace": folder / "trace.png",
             "details": folder / "explain.json"}
    with atomic_path(paths["steps"]) as tmp:
        pd.DataFrame(result.steps_table()).to_csv(tmp, index=False)
    with atomic_path(paths["candidates"]) as tmp:
        pd.DataFrame(result.candidates_table()).to_csv(tmp, index=False)
    plot_explain_residuals(result, paths["residuals"])
    plot_explain_trace(result, paths["trace"])
    write_json(paths["details"], result.details(result.key), indent=2, default=float)
    if json_path is not None:
        doc = result.to_json()
        if result.not_excluded:  # the test that would decide it (docs/design.md)
            doc["separating_test"] = {
                "rivals": [{"effect": e["effect"], "param": e["param"], "value": e["value"]}
                           for e in result.not_excluded],
                "design": f"eha design --faults none --around {json_path}"}
        write_json(json_path, doc, indent=2)
        paths["json"] = Path(json_path)
    return paths


def store_result(result, results: str | Path = "results") -> Path:
    """Write a result's rows of ``explain_runs`` and ``explain_steps`` into the results
    folder's database (a run of the same ``run_id`` is replaced); returns the database's path.

    Raises
    ------
    eha.campaigns.store.StoreError
        The database cannot be written (locked by a running campaign, a full disk).
    """
    import datetime

    from eha.explain.tables import save_explain

    key = result.key
    return save_explain(results, result.run_row(key, str(result.source), datetime.datetime.now()),
                        result.step_rows(key))
