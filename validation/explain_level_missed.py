"""Does "explained at the found model's own level" hide an effect the loop missed?

A record above the noise within the healthy band is explained at the found model's own level
when its residual is within what that model leaves on HF re-simulations of itself (and the
bound is below the healthy band's limit: :func:`eha.explain.replicates.explains`); it then
gets the exclusion check. The danger is a record whose effect the loop missed: its rest is
the missing effect, and if the re-simulations of the model without it scatter as widely, the
record would be called explained without it.

The records here are exactly those: every record of the loop's own power study
(``validation/results/explain_loop_power.json``: one undeclared effect at the gate's 90 %
size, or twice it, on ``mixed`` and ``chirp_1cm``; seeds as there) on which the loop did not
find the effect and ended above the noise within the band ("not explained to the noise").
Each is rebuilt from its seed and explained again with the current code and its defaults.

Per record the verdict's kind, whether the model level explains it, and the rivals named.
Counted: *confidently wrong* (explained, the effect not found, no rival named), *ambiguous
with the truth* (the missing effect among the rivals), and the rest (partly explained: the
model level says more, or decides nothing).

    python validation/explain_level_missed.py --workers 2 --json

A record takes 1-4 min on one core (the exclusion check runs only where the level explains).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

#: the loop power study's verdict of a record left above the noise within the band
ABOVE_NOISE = "not explained to the noise"


def missed_records(power: dict) -> list[tuple[str, str, float, int]]:
    """(command, effect, injected value, seed) of every record of the loop power study on
    which the loop missed the effect and ended above the noise within the band."""
    return [(row["command"], row["effect"], level["injected"], rec["seed"])
            for row in power["rows"] for level in row["levels"] for rec in level["records"]
            if rec["verdict"] == ABOVE_NOISE and not rec["found"]]


def explain_one(job: tuple[str, str, float, int]) -> dict:
    """One record rebuilt from its seed through :func:`eha.explain.explain` (defaults)."""
    from eha.explain import DEFAULT_FAULT_BOUNDS, explain
    from eha.explain.effects import EFFECTS
    from eha.explain.simulated_record import healthy_record
    from explain_power import template

    command, effect, value, seed = job
    rec, _ = healthy_record(template(command), dict(DEFAULT_FAULT_BOUNDS), seed,
                            {EFFECTS[effect].tested: value})
    start = time.perf_counter()
    res = explain(rec)
    doc = res.to_json()
    rivals = [e["effect"] for e in res.not_excluded]
    found = effect in res.effects
    return {"command": command, "effect": effect, "injected": value, "seed": seed,
            "found": found, "effects": list(res.effects), "rivals": rivals,
            "verdict_kind": doc["verdict_kind"], "verdict": res.verdict,
            "explains": bool(res.model_level.get("explains")),
            "model_level": dict(res.model_level),
            "confidently_wrong": doc["verdict_kind"] == "explained" and not found,
            "truth_among_rivals": effect in rivals,
            "seconds": time.perf_counter() - start}


def summary(rows: list[dict]) -> dict:
    return {"records": len(rows),
            "explained_at_model_level": sum(r["explains"] for r in rows),
            "confidently_wrong": sum(r["confidently_wrong"] for r in rows),
            "ambiguous_with_the_truth": sum(r["verdict_kind"] == "explained, ambiguous"
                                            and r["truth_among_rivals"] for r in rows),
            "ambiguous_without_the_truth": sum(r["verdict_kind"] == "explained, ambiguous"
                                               and not r["truth_among_rivals"]
                                               for r in rows),
            "partly_explained": sum(r["verdict_kind"] == "partly explained" for r in rows),
            "found_now": sum(r["found"] for r in rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--power", default=str(result_path("explain_loop_power")),
                    help="the loop power study's result file")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--json", action="store_true", help="write the result file")
    args = ap.parse_args()
    load = os.getloadavg()
    power = json.loads(Path(args.power).read_text())
    jobs = missed_records(power)
    print(f"{len(jobs)} records the loop missed and left above the noise", flush=True)
    rows, start = [], time.perf_counter()
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        for row in pool.map(explain_one, jobs):
            rows.append(row)
            print(f"{row['command']} {row['effect']} seed {row['seed']}: {row['verdict'][:160]}"
                  f" ({row['seconds']:.0f} s)", flush=True)
    doc = {"what": "the loop power study's missed records left above the noise, explained "
                   "again: does the found model's own level call them explained?",
           "power_file": {"path": args.power,
                          "commit": power.get("provenance", {}).get("commit")},
           "summary": summary(rows), "rows": rows, "seconds": time.perf_counter() - start}
    print(json.dumps(doc["summary"], indent=1))
    if args.json:
        write_result("explain_level_missed", doc, load_start=load)


if __name__ == "__main__":
    main()
