"""The residual loop on records of an independent simulator (the foreign validation set).

The 34 records, their truth and their scorer (``score.py``) are not in this repository: they
come from another implementation of the thesis' HF model. This script runs the scorer (which
calls ``eha explain`` on each record whose JSON is not yet in ``--out``, ``--jobs`` at a time,
default 2), reads its table and writes ``validation/results/explain_foreign.json`` with its
provenance. The speed goal (per record on 2 cores) is timed with ``--jobs 1``.

    python validation/explain_foreign.py --scorer PATH/TO/foreign/score.py --out DIR
    python validation/explain_foreign.py --scorer ... --out DIR --jobs 1
    python validation/explain_foreign.py --scorer ... --out DIR --note "4 rerun at ..."

Records already scored in ``--out`` are kept (the scorer skips them): say in ``--note`` which
records come from which commit. ``--json`` prints the result file.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper
from _results import provenance, write_result  # noqa: E402

#: the result file (named for the data set, not the script: docs quote it as such)
RESULT = "explain_foreign"


def calibration_seconds(doc: dict, path: Path) -> float:
    """Seconds the record's run spent calibrating its command's healthy null: the null's own
    time when its cache file was written during this record's run (between the run's start and
    its JSON), else 0 (the null came from the cache)."""
    from eha.explain.null import cache_dir

    null = doc.get("null") or {}
    cached = cache_dir() / f"{null.get('key', '')}.json"
    seconds = doc.get("_seconds")
    if not null.get("key") or not cached.exists() or seconds is None:
        return 0.0
    end = path.stat().st_mtime
    return float(null.get("seconds") or 0.0) \
        if end - seconds - 1.0 <= cached.stat().st_mtime <= end else 0.0


def loop_time_summary(rows: list[dict]) -> list[str]:
    """Median and max of the loop's own time (without a new command's calibration) and of
    the calibrations made during the run."""
    loop = [r["seconds"] - r["calibration_seconds"] for r in rows if r["seconds"] is not None]
    cal = [r["calibration_seconds"] for r in rows if r["calibration_seconds"]]
    out = []
    if loop:
        out.append(f"loop time per record (without calibrating a new null): median "
                   f"{statistics.median(loop):.0f} s, max {max(loop):.0f} s")
    if cal:
        out.append(f"null calibrations during the run: {len(cal)}, median "
                   f"{statistics.median(cal):.0f} s, max {max(cal):.0f} s")
    return out


def collect(out: Path, scorer: Path, table: str) -> list[dict]:
    """One row per record: the scorer's line, the verdict fields of its JSON, and the time it
    spent calibrating a new command's null (:func:`calibration_seconds`)."""
    truth = json.loads((scorer.parent / "truth.json").read_text())
    lines = {ln.split()[0]: ln for ln in table.splitlines() if ln[:1] == "f" and ln.split()}
    rows = []
    for name in sorted(truth):
        path = out / f"{name}.json"
        if not path.exists():
            continue
        doc = json.loads(path.read_text())
        rows.append({"record": name, "kind": truth[name]["kind"],
                     "truth": truth[name]["effect"],
                     "steps": [s["effect"] for s in doc.get("steps", [])],
                     "unexplained": doc.get("unexplained"),
                     "beyond_healthy": doc.get("beyond_healthy"),
                     "verdict": doc.get("verdict"), "score": lines.get(name, ""),
                     "seconds": doc.get("_seconds"),
                     "calibration_seconds": calibration_seconds(doc, path),
                     "residual_limit": (doc.get("null") or {}).get("residual_limit")})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scorer", required=True, type=Path, help="the foreign set's score.py")
    ap.add_argument("--out", required=True, type=Path, help="folder of the records' JSON")
    ap.add_argument("--note", default="", help="what the provenance should say")
    ap.add_argument("--jobs", type=int, default=2,
                    help="records at a time (the scorer's --jobs; 1 times the loop alone)")
    ap.add_argument("--json", action="store_true", help="print the result file")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, str(a.scorer), "--out", str(a.out),
                           "--jobs", str(a.jobs)], capture_output=True, text=True)
    if proc.returncode != 0:
        # nothing is written: a failed scorer (e.g. no `eha` on PATH) is not a result
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        print(f"error: {a.scorer.name} exited {proc.returncode}: {last}", file=sys.stderr)
        return 1
    table = proc.stdout
    summary = [ln for ln in table.splitlines()
               if ln.split()[:1] and ln.split()[0] in ("single", "two", "none", "outside",
                                                         "time")]
    rows = collect(a.out, a.scorer, table)
    result = {"what": f"score.py --out DIR --jobs {a.jobs} (eha explain defaults, {a.jobs} "
                      f"record{'s' if a.jobs > 1 else ''} at a time)",
              "provenance": {**provenance(), "note": a.note},
              "summary": summary + loop_time_summary(rows), "records": rows}
    write_result(RESULT, result)
    print(table)
    print("\n".join(result["summary"][len(summary):]))
    if a.json:
        print(json.dumps(result, indent=1, ensure_ascii=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
