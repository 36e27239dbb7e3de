"""The two things every figure module needs: matplotlib without a display, and saving a PNG
into a folder that may not exist yet. One definition for eha.reports.plots, eha.reports.thesis,
eha.explain.outputs, eha.health.plots and the prognostics plots."""

from __future__ import annotations

from pathlib import Path


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG at ``path`` (parents created), close it, return the path."""
    path = Path(path)
    from eha.outputs import atomic_path

    try:
        with atomic_path(path) as tmp:  # written whole: a temporary file, then renamed
            fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    finally:
        pyplot().close(fig)
    return path
