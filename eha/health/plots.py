"""Figures of the health assessment: ROC curves, isolation confusion matrices, a check's
estimates with their intervals and thresholds (PNG, matplotlib Agg)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.figures import pyplot as _pyplot
from eha.figures import save


def plot_roc(perf: Mapping[str, Any], command: str, path: str | Path) -> Path:
    """One panel per fault: ROC curve of every injected level (healthy vs that level), the
    operating threshold's false-alarm budget marked."""
    plt = _pyplot()
    faults = list(perf["faults"])
    ncol = min(4, max(1, len(faults)))
    nrow = int(np.ceil(len(faults) / ncol)) or 1
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.3 * nrow), squeeze=False)
    for ax, name in zip(axes.flat, faults):
        for lev in perf["faults"][name]["levels"]:
            roc = lev["roc"]
            ax.step(roc["pfa"], roc["pd"], where="post",
                    label=f"{lev['value']:.3g} (P_D {lev['p_detect']:.2f})")
        ax.axvline(0.01, color="0.5", ls=":", lw=1)
        ax.plot([0, 1], [0, 1], color="0.8", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("false-alarm probability")
        ax.set_ylabel("detection probability")
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=7, title="injected", title_fontsize=7, loc="lower right")
    for ax in list(axes.flat)[len(faults):]:
        ax.axis("off")
    fig.suptitle(f"ROC per fault on {command} (healthy fleet vs injected level; dotted: 1 %)")
    fig.tight_layout()
    return save(fig, path, dpi=110)


def plot_confusion(confusion: Mapping[str, Mapping[str, int]], command: str,
                   path: str | Path) -> Path:
    """Heat map: rows the injected fault, columns the declared one (row fractions)."""
    plt = _pyplot()
    rows = list(confusion)
    cols = list(dict.fromkeys([*rows, *[c for r in confusion.values() for c in r]]))
    m = np.array([[confusion[r].get(c, 0) for c in cols] for r in rows], dtype=float)
    frac = m / np.maximum(m.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(1.0 + 0.75 * len(cols), 1.0 + 0.6 * len(rows)))
    im = ax.imshow(frac, cmap="Blues", vmin=0, vmax=1)
    for i in range(len(rows)):
        for j in range(len(cols)):
            if m[i, j]:
                ax.text(j, i, f"{int(m[i, j])}", ha="center", va="center",
                        color="white" if frac[i, j] > 0.6 else "black", fontsize=8)
    ax.set_xticks(range(len(cols)), cols, rotation=45, ha="right")
    ax.set_yticks(range(len(rows)), rows)
    ax.set_xlabel("declared")
    ax.set_ylabel("injected")
    ax.set_title(f"Isolation on {command}")
    fig.colorbar(im, ax=ax, fraction=0.046, label="fraction of the row")
    fig.tight_layout()
    return save(fig, path, dpi=110)
