"""One current result file per benchmark: ``benchmarks/results/<name>.json``, with provenance.

Every benchmark script writes its figures through :func:`write_result`, which adds
:func:`provenance` (commit, date, machine, cores, load) and *replaces* the file: the history
of a figure lives in git (``git log -p benchmarks/results/<name>.json``), not in file names.
A benchmark run in parts (seed blocks, ``--json PART``) writes its parts elsewhere and
``merge_results.py`` merges them into the result file.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def result_path(name: str) -> Path:
    """The current result file of benchmark ``name`` (e.g. ``"bench_explain_fp"``)."""
    return RESULTS / f"{name}.json"


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def provenance(argv: list[str] | None = None, load_start: Any = None) -> dict[str, Any]:
    """Where a figure comes from: commit (and whether the tree was dirty), UTC date, machine,
    cores, Python, the command line and the load average (at the start when given, and now)."""
    load_end = [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None
    out = {"commit": _git("rev-parse", "HEAD"),
           "dirty": bool(_git("status", "--porcelain", "--untracked-files=no")),
           "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
           "machine": f"{platform.node()} {platform.machine()}".strip(),
           "cores": os.cpu_count(), "python": platform.python_version(),
           "argv": list(sys.argv if argv is None else argv)}
    if load_start is not None:
        out["load_start"] = [round(x, 2) for x in load_start]
    out["load"] = load_end
    return out


def write_result(name: str | Path, doc: dict[str, Any], argv: list[str] | None = None,
                 load_start: Any = None) -> Path:
    """Write ``doc`` (``benchmark`` and ``provenance`` added when missing) to the result file
    of ``name`` (or to a path: a part for ``merge_results.py``), replacing it atomically."""
    path = Path(name) if isinstance(name, Path) or str(name).endswith(".json") \
        else result_path(str(name))
    doc = {"benchmark": path.stem, **doc}
    doc.setdefault("provenance", provenance(argv, load_start))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1, default=_plain) + "\n", encoding="utf-8")
    os.replace(tmp, path)
    print(f"wrote {path}", flush=True)
    return path


def _plain(v: Any) -> Any:
    """numpy scalars and arrays, paths: as JSON values."""
    if hasattr(v, "tolist"):
        return v.tolist()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")
