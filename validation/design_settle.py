"""The first record as prior: does a designed follow-up settle each foreign ambiguity?

The foreign set's first records (``validation/priors/fNN.json``: their ``eha explain --json``)
end "cannot be told apart" between a found effect and a rival. Each pair has a 2-s separating
design (``validation/design.py``, ``OUT/ambiguities/A-B/design.csv``). On it, HF records are
made with either member as the truth at its fitted size (BKL 1e-4, FDJ 800 N, 1 µm noise,
seeds 5000+k: the records of ``validation/design.py --loop``, reused when there), and each is
settled against its first record (:mod:`eha.explain.settle`, the prior restricted to the pair's
rival: the design was made for that pair). Counted per truth: settled on the truth, settled on
the other (confidently wrong), not settled; and, as the control, on ``--healthy`` records
with neither effect, how many settle at all (each would be a confident wrong answer). With ``--loop K`` the whole ``eha explain
RECORD --prior FIRST`` runs on the first K records per truth too: the settlement, then the loop
from the explanation that stands (decisive and right: the truth settled, the loop's verdict
"explained", nothing further found and no rival left).

    python validation/design_settle.py --out results/bench-design --records 10 --json

A settlement takes 3-10 s on a record with the command's healthy null cached (the null itself
2-3 min per design, once); a whole explain 1-20 min.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper
from _results import ROOT, _git, result_path, write_result  # noqa: E402

from design import AMBIGUITIES  # noqa: E402

#: Each ambiguity's first record (validation/priors/) and the rival kept in its prior.
FIRST = {"load-offset (f01, f02)": ("f01", "offset"),
         "bias-offset (f09)": ("f09", "offset"),
         "motor gain-supply pressure (f13, f25)": ("f13", "supply_pressure"),
         "motor gain-viscous friction (f13, f25)": ("f13", "viscous_friction"),
         "sensor gain-hinge moment (f21)": ("f21", "hinge_moment")}
PRIORS = Path(__file__).resolve().parent / "priors"


def prior_of(label: str) -> dict:
    """The first record's JSON for ``label`` with its exclusions (:func:`with_exclusions`),
    its rivals restricted to the pair's."""
    name, rival = FIRST[label]
    prior = with_exclusions(json.loads((PRIORS / f"{name}.json").read_text()))
    prior["not_excluded"] = [r for r in prior["not_excluded"] if r["effect"] == rival]
    return prior


def with_exclusions(prior: dict) -> dict:
    """``prior`` with the ``excluded`` that ``eha explain --json`` now writes (these first
    records' JSON predate it), derived as the loop derives it: each first record reached the
    noise, so its exclusion check tested every effect of its null; each one neither found nor
    listed in its (whole) ``not_excluded`` is excluded beyond
    :func:`eha.explain.rival_check.excluded_beyond` of its null's threshold and detectable
    size (the supply pressure's on its PSR shift). These JSON predate the rival check: none
    was ruled out by it."""
    from eha.explain.effects import EFFECTS
    from eha.explain.rival_check import excluded_beyond

    if "excluded" in prior:
        return prior
    named = {s["effect"] for s in prior["steps"]} | {r["effect"] for r in prior["not_excluded"]}
    excluded = {}
    for name, entry in prior["null"]["effects"].items():
        effect = EFFECTS[name]
        bar = entry.get("shift") if effect.footprint else entry
        if name in named or not bar:
            continue
        excluded[name] = {"param": effect.tested, "unit": effect.units()[effect.tested],
                          "beyond": excluded_beyond(bar["threshold"], bar["detectable"])}
    return {**prior, "excluded": excluded}


def record(command: Path, name: str | None, dev: float, k: int, t_end: float = 2.0) -> Path:
    """HF record ``k`` of truth ``name`` (deviation ``dev`` from off; None: neither effect,
    the declared faults alone) on ``command``: the loop study's (same path, seed and truth),
    made when missing."""
    import eha
    from eha.explain.effects import EFFECTS

    path = command.parent / "loop" / f"{name or 'healthy'}-{k}.csv"
    if not path.exists():
        truth = {"BKL": 1e-4, "FDJ": 800.0}
        if name is not None:
            param = EFFECTS[name].tested
            truth[param] = EFFECTS[name].off[param] + dev
        df = eha.synthetic_record(str(command), truth, t_end=t_end, noise=1e-6, seed=5000 + k)
        path.parent.mkdir(parents=True, exist_ok=True)
        df.to_csv(path, index=False)
    return path


def settle_one(path: Path, prior: dict, k: int) -> dict:
    """Record ``k`` settled against ``prior``; every record of a design against its one
    healthy null (seed 0: calibrated once, as a user would; the records' own noise and dither
    seeds differ)."""
    import eha
    from eha.explain.api import settle_prior

    start = time.perf_counter()
    s = settle_prior(eha.load(path), prior, fit="BKL,FDJ", seed=0)
    return {"record": k, "winner": s.winner, "text": s.text,
            "hypotheses": [{key: h[key] for key in ("name", "residual_ratio", "fits",
                                                    "stands", "readings")}
                           for h in s.hypotheses],
            "residual_limit": s.residual_limit, "seconds": time.perf_counter() - start}


def explain_one(path: Path, prior_path: Path, k: int, truth: str) -> dict:
    from eha.explain.from_file import explain_file

    start = time.perf_counter()
    res = explain_file(path, prior=prior_path, fit="BKL,FDJ", seed=0)
    found = [e for e in res.effects if e not in ("orifice_law", "flapper_dynamics")]
    rivals = [e["effect"] for e in res.not_excluded]
    winner = (res.settled or {}).get("winner")
    explained = res.verdict.startswith("explained")
    return {"record": k, "settled": winner, "found_after": found, "rivals": rivals,
            "verdict": res.verdict, "explained": explained,
            "decisive_and_right": winner == truth and explained and not found and not rivals,
            # each rival with its figures (and its rival check's: why it stayed)
            "not_excluded": [dict(e) for e in res.not_excluded],
            # rivals ruled out, by re-simulation or left to the first record's exclusion
            # (``first_record``: this record does not show them)
            "rivals_ruled_out": [dict(e) for e in res.rivals_ruled_out],
            # above the noise: what the found model itself leaves on the HF (model_level)
            "model_level": dict(res.model_level),
            "seconds": time.perf_counter() - start,
            "commit": _git("rev-parse", "HEAD")}   # a kept call outlives the code that made it


def _kept(path: Path, fresh: bool, run) -> dict:
    """A record's call kept beside it (``NAME-K.settle.json``, ``NAME-K.explain-prior.json``)
    and reused by a later run unless ``--fresh``: a run cut short loses one record."""
    if path.exists() and not fresh:
        return json.loads(path.read_text())
    row = run()
    path.write_text(json.dumps(row, indent=1))
    return row


def pair(label: str, args, folder: Path) -> dict:
    (a, va), (b, vb) = AMBIGUITIES[label]
    command = folder / f"{a}-{b}" / "design.csv"
    if not command.exists():
        return {"skipped": f"no design at {command} (run validation/design.py first)"}
    prior = prior_of(label)
    prior_path = folder / f"{a}-{b}" / "prior.json"
    prior_path.write_text(json.dumps(prior))
    out = {"command": str(command), "first_record": FIRST[label][0], "truths": {}}
    for name, dev in ((a, va), (b, vb)):
        rows = []
        for k in range(args.records):
            path = record(command, name, dev, k)
            row = _kept(path.with_suffix(".settle.json"), args.fresh,
                        lambda: settle_one(path, prior, k))
            rows.append(row)
            print(f"{label} truth {name} #{k}: {row['text'][:150]} ({row['seconds']:.0f} s)",
                  flush=True)
        loops = []
        for k in range(max(args.loop, args.records)):
            path = record(command, name, dev, k)
            kept = path.with_suffix(".explain-prior.json")
            skip = k >= args.loop or k < args.loop_from or (args.truths and name not in
                                                             args.truths.split(","))
            if skip and not kept.exists():
                continue        # beyond --loop: only the explain calls an earlier run kept
            loops.append(_kept(kept, args.fresh and k < args.loop,
                               lambda: explain_one(path, prior_path, k, name)))
            print(f"  explain --prior #{k}: {loops[-1]['verdict'][:150]}", flush=True)
        out["truths"][name] = {
            "at": dev, "records": len(rows),
            "settled_right": sum(r["winner"] == name for r in rows),
            "settled_wrong": sum(r["winner"] not in (None, name) for r in rows),
            "not_settled": sum(r["winner"] is None for r in rows),
            "rows": rows,
            **({"explain": {"records": len(loops),
                            "decisive_and_right": sum(r["decisive_and_right"] for r in loops),
                            # the truth alone named (settled, nothing further, no rival), the
                            # residual's verdict aside: "partly explained" counts here
                            "truth_alone": sum(r["settled"] == name and not r["found_after"]
                                               and not r["rivals"] for r in loops),
                            # of those, explained, or above the noise by no more than the
                            # found model itself leaves on the HF (its model_level)
                            "truth_alone_at_model_level": sum(
                                r["settled"] == name and not r["found_after"]
                                and not r["rivals"] and (r["explained"] or r.get(
                                    "model_level", {}).get("within", False)) for r in loops),
                            "rows": loops}} if loops else {})}
    if args.healthy:
        # the control: an actuator with neither explanation must settle nothing
        rows = []
        for k in range(args.healthy):
            path = record(command, None, 0.0, k)
            rows.append(_kept(path.with_suffix(".settle.json"), args.fresh,
                              lambda: settle_one(path, prior, k)))
            print(f"{label} healthy #{k}: {rows[-1]['text'][:150]}", flush=True)
        out["healthy"] = {"records": len(rows),
                          "settled": sum(r["winner"] is not None for r in rows),
                          "not_settled": sum(r["winner"] is None for r in rows), "rows": rows}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results" / "bench-design"),
                    help="validation/design.py's output folder (its ambiguities/ designs)")
    ap.add_argument("--records", type=int, default=10, help="HF records per truth and pair")
    ap.add_argument("--healthy", type=int, default=5,
                    help="records per pair with neither effect (the control: nothing may "
                         "settle)")
    ap.add_argument("--loop", type=int, default=0,
                    help="of those, how many also get the whole explain with the prior "
                         "(the calls kept beside further records are summarised too)")
    ap.add_argument("--pairs", default="",
                    help="only these ambiguities, by folder name (A-B, comma-separated)")
    ap.add_argument("--loop-from", type=int, default=0,
                    help="the first record the whole explain runs on (a second worker)")
    ap.add_argument("--truths", default="",
                    help="the whole explain only on records of these truths (comma-separated; "
                         "default both)")
    ap.add_argument("--fresh", action="store_true",
                    help="settle and explain every record again (default: reuse the calls "
                         "kept beside the records)")
    ap.add_argument("--json", action="store_true", help="write the result file")
    ap.add_argument("--keep-other-pairs", action="store_true",
                    help="with --pairs and --json: keep the pairs not run from the current "
                         "result file, each marked with the run it comes from")
    args = ap.parse_args()
    load = os.getloadavg()
    folder = Path(args.out).resolve() / "ambiguities"
    start = time.perf_counter()
    doc = {"what": "the foreign ambiguities settled by a record of their 2-s separating "
                   "design, the first record as prior (eha.explain.settle)",
           "records_per_truth": args.records, "pairs": {}}
    wanted = [p for p in args.pairs.split(",") if p]
    for label in AMBIGUITIES:
        (a, _), (b, _) = AMBIGUITIES[label]
        if wanted and f"{a}-{b}" not in wanted:
            continue
        doc["pairs"][label] = pair(label, args, folder)
    doc["seconds"] = time.perf_counter() - start     # this run's (kept calls are reused)
    doc["seconds_of_the_calls"] = {
        "settle": sum(r["seconds"] for p in doc["pairs"].values()
                      for v in [*p.get("truths", {}).values(), p.get("healthy", {})]
                      for r in v.get("rows", [])),
        "explain": sum(r["seconds"] for p in doc["pairs"].values()
                       for v in p.get("truths", {}).values()
                       for r in v.get("explain", {}).get("rows", []))}
    if args.keep_other_pairs and wanted:
        # the other pairs as their last run left them (their kept calls may be gone), named
        old = json.loads(result_path("design_settle").read_text())
        run = {k: old["provenance"].get(k) for k in ("commit", "date")}
        doc["pairs"] = {label: doc["pairs"].get(label) or {**entry, "run": entry.get("run", run)}
                        for label, entry in old["pairs"].items()} | doc["pairs"]
    summary = {label: {t: f"{v['settled_right']}/{v['records']} right, "
                          f"{v['settled_wrong']} wrong, {v['not_settled']} not settled"
                          + (f"; explain --prior decisive and right "
                             f"{v['explain']['decisive_and_right']}/{v['explain']['records']}"
                             f" (the truth alone {v['explain']['truth_alone']}, at the "
                             f"noise or the model's own level "
                             f"{v['explain']['truth_alone_at_model_level']})"
                             if "explain" in v else "")
                       for t, v in p.get("truths", {}).items()}
               | ({"healthy": f"{p['healthy']['settled']}/{p['healthy']['records']} settled"}
                  if "healthy" in p else {})
               for label, p in doc["pairs"].items()}
    print(json.dumps(summary, indent=1))
    if args.json:
        write_result("design_settle", doc, load_start=load)


if __name__ == "__main__":
    main()
