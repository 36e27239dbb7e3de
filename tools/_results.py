"""One current result file per script, with provenance: the speed benchmarks write
``benchmarks/results/<name>.json``, the validation studies ``validation/results/<name>.json``.

Every script of ``benchmarks/`` and ``validation/`` writes its figures through
:func:`write_result`, which adds :func:`provenance` (commit, date, machine, cores, load) and
*replaces* the file: the history of a figure lives in git
(``git log -p --follow validation/results/<name>.json``), not in file names. A study run in parts
(seed blocks, ``--json PART``) writes its parts elsewhere and ``validation/merge_results.py``
merges them into the result file.

A script imports this module after putting ``tools/`` on its path::

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from _results import result_path, write_result
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
#: The folders of scripts that write result files, each into its own ``results/``.
FOLDERS = (ROOT / "benchmarks", ROOT / "validation")


def result_path(name: str) -> Path:
    """The current result file of script ``name`` (e.g. ``"explain_fp"``):
    ``results/<name>.json`` in the folder of ``<name>.py`` (:data:`FOLDERS`)."""
    for folder in FOLDERS:
        if (folder / f"{name}.py").is_file():
            return folder / "results" / f"{name}.json"
    raise ValueError(f"no script {name}.py in {', '.join(f.name + '/' for f in FOLDERS)}")


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
    of script ``name`` (or to a path: a part for ``merge_results.py``), replacing it
    atomically. ``benchmark`` names the script (the file's stem)."""
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
