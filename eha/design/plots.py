"""The design report's figure: the command, each target's detectable size against the library
commands', and how well each pair is told apart."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from eha.figures import pyplot, save
from eha.models.commands import make_command


def plot_design(result, path: str | Path) -> Path:
    """Three panels: (a) the designed command and the library's chirp_1cm [mm]; (b) per
    target the predicted minimum detectable size on each command, relative to the best
    library command's (log scale; below 1: the design shows it smaller); (c) the separable
    size of each pair in multiples of the row target's detectable size."""
    plt = pyplot()
    fig = plt.figure(figsize=(12, 9), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 1.3])
    ax = fig.add_subplot(grid[0, :])
    ax.plot(result.t, result.com * 1e3, lw=1.4, label="designed command")
    ref = make_command("chirp_1cm").sample(result.t)
    ax.plot(result.t, ref * 1e3, lw=0.8, alpha=0.6, label="chirp_1cm (library)")
    ax.set(xlabel="time [s]", ylabel="command [mm]",
           title="(a) designed command (starts and ends at rest)")
    ax.legend(loc="upper right")
    ax.grid(alpha=0.3)

    ax = fig.add_subplot(grid[1, 0])
    names = [t.name for t in result.targets]
    best = result.best_library()
    series = {"design": result.prediction} | result.library
    width = 0.8 / len(series)
    for k, (label, pred) in enumerate(series.items()):
        ratios = [min(pred.mds[n], 10 * t.limit) / best[n][1]
                  for n, t in zip(names, result.targets)]
        ax.bar(np.arange(len(names)) + k * width, ratios, width,
               label=label + ("" if label == "design" or pred.followed else " (LF cannot follow)"),
               edgecolor="black" if label == "design" else None)
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names)
    ax.set(ylabel="min. detectable size / best library command's",
           title=f"(b) detectable sizes (P_D 0.95, alpha {result.settings['alpha']:g})")
    ax.legend(fontsize=7)

    ax = fig.add_subplot(grid[1, 1])
    sep = result.prediction.separable
    m = np.full((len(names), len(names)), np.nan)
    for i, f in enumerate(names):
        for j, g in enumerate(names):
            v = sep.get(f, {}).get(g)
            if v is not None and math.isfinite(v):
                m[i, j] = min(v, 100.0)
    image = ax.imshow(np.log10(np.where(np.isnan(m), 100.0, m)), cmap="RdYlGn_r", vmin=0,
                      vmax=2)
    for i in range(len(names)):
        for j in range(len(names)):
            if i != j:
                text = "-" if np.isnan(m[i, j]) else f"{m[i, j]:.2g}"
                ax.text(j, i, text, ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(names)), names, rotation=45)
    ax.set_yticks(range(len(names)), names)
    ax.set(xlabel="rival hypothesis", ylabel="target",
           title="(c) told apart from the rival at x detectable size")
    fig.colorbar(image, ax=ax, label="log10 multiple")
    return save(fig, path)


__all__ = ["plot_design"]
