"""The residual loop's own detection power, end to end, at the gate's measured detectable size.

``explain_power.py`` measures the *gate* (the local test of one effect past its healthy
threshold): necessary for the loop to add an effect, not sufficient (the loop also ranks the
candidates, asks for a significant and specific gain, and its final check may set the effect
aside for a rival). This benchmark runs the whole of :func:`eha.explain.explain`, with its
defaults (alpha 0.05, fit BKL and FDJ), on the *same* records as the gate's result file
(``validation/results/explain_power.json``): per command and effect, ``--records``
records with the effect at the size where the gate reached 90 % (its ``measured_detectable``;
cells the gate never reached are skipped and listed), seeds ``100000 + 1000 * command index +
k`` (the gate bench's, so the comparison is paired).

Per record: ``found`` (the effect is among the steps the loop added), ``extra`` (another
non-structural effect added), the verdict and the wall time. Per cell: the loop's power at
the gate's size (the fraction found) and, where it falls short of 90 %, the same records at
``--escalate`` times that size.

    python validation/explain_loop_power.py --commands mixed           # 12 cells
    python validation/explain_loop_power.py --commands mixed --effects offset --records 2
    python validation/explain_loop_power.py --commands mixed --json    # the result file

``--json`` writes ``validation/results/explain_loop_power.json`` (one current file, with
provenance; each row names the commit it was measured at). ``--merge EARLIER.json`` keeps the
earlier file's cells that this run does not redo (a rerun of the cells a change can touch). A record takes 0.5-2 min on one core; a command's 12 cells of 5 records about
25 min on 2 cores.
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import provenance, result_path, write_result  # noqa: E402
from explain_power import COMMANDS, injected_value, template  # noqa: E402


#: the verdict's kind (the start of :attr:`eha.explain.results.ExplainResult.verdict`)
VERDICTS = ("explained", "not explained to the noise", "not uniquely explained",
            "unexplained", "")


def _one(args):
    """One record of a cell through the whole loop."""
    data, effect, value, seed = args
    from eha.explain import DEFAULT_FAULT_BOUNDS, explain
    from eha.explain.effects import EFFECTS
    from eha.explain.simulated_record import healthy_record
    from eha.explain.settings import STRUCTURAL

    rec, _ = healthy_record(data, dict(DEFAULT_FAULT_BOUNDS), seed,
                            {EFFECTS[effect].tested: value})
    t0 = time.perf_counter()
    result = explain(rec)
    added = list(result.effects)
    return {"seed": seed, "found": effect in added,
            "extra": [e for e in added if e != effect and e not in STRUCTURAL],
            "effects": added, "verdict": next(v for v in VERDICTS if result.verdict.startswith(v)),
            "ratio": float(result.rmse_after / result.noise_rmse)
            if result.noise_rmse else None,
            "seconds": time.perf_counter() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--commands", default=",".join(COMMANDS))
    ap.add_argument("--effects", default="")
    ap.add_argument("--records", type=int, default=5, help="records per effect and command")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--escalate", default="2",
                    help="multiples of the gate's size tried where the loop falls short of 90 %%")
    ap.add_argument("--gate", default=str(result_path("explain_power")),
                    help="the gate's result file (explain_power.py --json)")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_loop_power")))
    ap.add_argument("--merge", default=None,
                    help="an earlier result file whose cells not rerun here are kept "
                         "(each row says its commit)")
    a = ap.parse_args(argv)
    from eha.explain import DEFAULT_FAULT_BOUNDS, LoopSettings
    from eha.explain.api import healthy_null
    from eha.explain.problem import Problem
    from eha.explain.effects import EFFECTS

    gate = json.loads(Path(a.gate).read_text())
    wanted = set(a.effects.split(",")) if a.effects else None
    commands = [c for c in a.commands.split(",") if c]
    rows, skipped, t_start = [], [], time.perf_counter()
    load_start = os.getloadavg()
    for cname in commands:
        cells = [r for r in gate["rows"] if r["command"] == cname
                 and (wanted is None or r["effect"] in wanted)]
        skipped += [{"command": cname, "effect": r["effect"]} for r in cells
                    if r["measured_detectable"] is None]
        cells = [r for r in cells if r["measured_detectable"] is not None]
        if not cells:
            continue
        data = template(cname)
        # the record's null once, here: the workers then read it from the cache
        t0 = time.perf_counter()
        healthy_null(Problem.build(data), LoopSettings(), "simulate")
        null_s = time.perf_counter() - t0
        levels = {r["effect"]: [] for r in cells}   # (multiple, injected, records)
        todo = [r["effect"] for r in cells]
        for multiple in [1.0] + [float(m) for m in a.escalate.split(",") if m]:
            jobs = []
            for r in cells:
                effect = r["effect"]
                if effect not in todo:
                    continue
                value = injected_value(effect, multiple * r["measured_detectable"])
                if levels[effect] and value == levels[effect][-1][1]:
                    continue                      # clipped at a bound: no larger size exists
                jobs += [(data, effect, value, 100000 + 1000 * COMMANDS.index(cname) + k)
                         for k in range(a.records)]
            if not jobs:
                break
            with ProcessPoolExecutor(a.workers, mp_context=get_context("spawn")) as pool:
                results = list(pool.map(_one, jobs))
            for effect in dict.fromkeys(j[1] for j in jobs):
                got = [res for j, res in zip(jobs, results) if j[1] == effect]
                value = next(j[2] for j in jobs if j[1] == effect)
                levels[effect].append((multiple, value, got))
                power = np.mean([g["found"] for g in got])
                print(f"{cname:10s} {effect:17s} {multiple:g}x the gate's size "
                      f"({EFFECTS[effect].tested} {value:.3g}): loop found {power:.0%} of "
                      f"{len(got)}; extras {sum(bool(g['extra']) for g in got)}; "
                      f"median {np.median([g['seconds'] for g in got]):.0f} s", flush=True)
            todo = [e for e in todo if levels[e] and
                    np.mean([g["found"] for g in levels[e][-1][2]]) < 0.9]
        for r in cells:
            effect = r["effect"]
            first = levels[effect][0][2]
            reached = next((lv for lv in levels[effect]
                            if np.mean([g["found"] for g in lv[2]]) >= 0.9), None)
            rows.append({
                "command": cname, "effect": effect, "param": EFFECTS[effect].tested,
                "gate_detectable": r["measured_detectable"],
                "gate_multiple": r["measured_multiple"],
                "loop_power": float(np.mean([g["found"] for g in first])),
                "loop_detectable": (abs(reached[1] - EFFECTS[effect].off[
                    EFFECTS[effect].tested]) if reached else None),
                "loop_multiple": reached[0] if reached else None,
                "levels": [{"multiple": m, "injected": v,
                            "power": float(np.mean([g["found"] for g in got])),
                            "records": got} for m, v, got in levels[effect]],
                "null_seconds": null_s})
    commit = provenance()["commit"]
    for r in rows:
        r["commit"] = commit
    if a.merge:
        # the cells not rerun keep their rows (each with the commit it was measured at)
        kept = json.loads(Path(a.merge).read_text())
        for r in kept["rows"]:
            r.setdefault("commit", kept["provenance"]["commit"])
        done = {(r["command"], r["effect"]) for r in rows}
        rows = [r for r in kept["rows"] if (r["command"], r["effect"]) not in done] + rows
        rows.sort(key=lambda r: (COMMANDS.index(r["command"]), r["effect"]))
        skipped += [s for s in kept["summary"]["skipped_gate_not_reached"] if s not in skipped]
    seconds = [g["seconds"] for r in rows for lv in r["levels"] for g in lv["records"]]
    summary = {"cells": len(rows),
               "cells_at_90": int(sum(r["loop_power"] >= 0.9 for r in rows)),
               "cells_reached": int(sum(r["loop_detectable"] is not None for r in rows)),
               "records_with_extra": int(sum(bool(g["extra"]) for r in rows
                                             for lv in r["levels"] for g in lv["records"])),
               "records": len(seconds),
               "median_seconds": float(np.median(seconds)) if seconds else None,
               "max_seconds": float(np.max(seconds)) if seconds else None,
               "skipped_gate_not_reached": skipped,
               "seconds": time.perf_counter() - t_start}
    print(f"the loop finds the effect in >= 90 % of the records at the gate's size in "
          f"{summary['cells_at_90']} of {len(rows)} cells; within {a.escalate or '1'}x of it "
          f"in {summary['cells_reached']}; {summary['records_with_extra']} of "
          f"{summary['records']} records with an extra effect; skipped (the gate never "
          f"reached 90 %): {len(skipped)}; {summary['seconds']:.0f} s")
    if a.json:
        write_result(Path(a.json), {
            "settings": {"records": a.records, "escalate": a.escalate, "commands": commands,
                         "merged_from": a.merge,
                         "gate_file": str(a.gate), "gate_commit":
                         gate.get("provenance", {}).get("commit"),
                         "fit": sorted(DEFAULT_FAULT_BOUNDS)},
            "summary": summary, "rows": rows}, load_start=load_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
