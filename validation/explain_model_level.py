"""How often does the found model's own level say "more than that" when nothing is missing?

A record left above the noise within the healthy band is told what the found model itself
leaves on the HF (:func:`eha.explain.replicates.model_level`): the residual-to-noise ratio of
``interval_replicates`` least-squares refits to HF re-simulations of the final model, and the
one-sided Student prediction bound at the loop's ``alpha`` (``mean + t s sqrt(1 + 1/n)``).
A record above the bound reads "more than that: an effect that small may be missing". That
bound is a prediction bound only if the record's own ratio is exchangeable with the
re-simulations' ratios when the found model is the truth: the record went through the loop's
search (rounds, prune, polish), the re-simulations through one least-squares refit from the
found values. This study measures it where the truth is known.

Records: those of :mod:`explain_multi` (two or three undeclared effects on mixed, test,
chirp_1cm and a random step sequence; BKL 0.1 mm and FDJ 800 N declared), drawn with another
seed block (``--seed``, default 1; the bench's own records are block 0), run through
:func:`eha.explain.explain` with its defaults. On every record the model level is computed
(the loop itself computes it only for a record above the noise within the healthy band,
``shown``), by wrapping :meth:`eha.explain.loop.ResidualLoop.result`; nothing else changes.

Score: a record whose final model is the truth (every injected effect found, nothing spurious:
:func:`explain_multi.score`'s ``success``) and reads "more than that" (record above the bound)
is a false "more than that". The record's level is the lowest of the loop's fit and the
restarts from the re-simulations' spread (``model_level``'s ``restarts``); the loop's fit
alone is scored beside (``more_than_that_loop_fit``). The rate is reported with its exact
(Clopper-Pearson) 95 % upper bound, over all such records and over the ``shown`` ones;
records with an effect missing or spurious are listed beside (what the clause says when the
model is wrong).

    python validation/explain_model_level.py --records 0,2,4 --json part0.json
    python validation/explain_model_level.py --merge part0.json part1.json --json

A record takes 1-8 min on one core (the steps records simulate their own null).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import result_path, write_result  # noqa: E402

from explain_fp import clean, provenance, result_json, run_explain, warm_up  # noqa: E402
from explain_multi import (COMMANDS, FAULTS, T_END, injected, make_command, score,  # noqa: E402
                           select)

CONFIDENCE = 0.95


def always_model_level() -> None:
    """Make the loop compute its model level on every record (the study's only change)."""
    from eha.explain import loop as loop_module

    original = loop_module.ResidualLoop.result
    if getattr(original, "_study", False):
        return

    def result(self, before, faults_before, stop):
        res = original(self, before, faults_before, stop)
        res.model_level_shown = bool(res.model_level)
        if not res.model_level and self.settings.interval_replicates:
            res.model_level = self.model_level()
        return res

    result._study = True
    loop_module.ResidualLoop.result = result


def upper(k: int, n: int) -> float | None:
    """Exact one-sided upper bound of a rate k/n at :data:`CONFIDENCE`."""
    from scipy.stats import beta

    if not n:
        return None
    return 1.0 if k == n else float(beta.ppf(CONFIDENCE, k + 1, n - k))


def run(args, save=None) -> list[dict]:
    """Run the selected records; ``save(rows)`` after each (a part survives a stop)."""
    from eha.identification.measured import synthetic_record

    always_model_level()
    warm_up()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n, (i, name, combo, command) in enumerate(select(args)):
            seed = 1000 * args.seed + i
            inj = injected(combo)
            overrides = {**FAULTS, **{p: v for ps in inj.values() for p, v in ps.items()}}
            cmd, steps = make_command(command, seed)
            df = synthetic_record(cmd, overrides, t_end=T_END.get(command, 1.0),
                                  noise=args.noise, seed=seed, command_hold="auto")
            data, result, seconds = run_explain(df, Path(tmp) / f"{n:03d}.csv", args.pop,
                                                args.explain_seed)
            res = result_json(data, result, seconds)
            sc = score(res, result, inj)
            level = dict(result.model_level)
            row = {"i": i, "name": name, "command": command, "seed": seed,
                   "injected": inj, "success": sc["success"], "found": sc["found"],
                   "spurious": sc["spurious"], "effects": res["effects"],
                   "beyond_healthy": bool(result.beyond_healthy),
                   "shown": bool(getattr(result, "model_level_shown", False)),
                   "model_level": level, "more": bool(level) and not level["within"],
                   # the loop's own fit alone, without the restarts (the earlier reading)
                   "more_loop_fit": bool(level) and level.get(
                       "record_loop", level["record"]) > level["bound"],
                   "verdict": result.verdict, "seconds": seconds}
            rows.append(row)
            fig = (f"record {level['record']:.2f}x (loop's fit "
                   f"{level.get('record_loop', level['record']):.2f}x), "
                   f"refits {level['mean']:.2f} ± "
                   f"{level['std']:.2f}x, bound {level['bound']:.2f}x" if level else "no level")
            print(f"{name:34} {seed:5d} {'right model' if sc['success'] else 'model wrong':11} "
                  f"{'shown' if row['shown'] else '     '} {fig}"
                  f"{'  MORE' if row['more'] else ''} ({seconds:.0f} s)", flush=True)
            if save is not None:
                save(rows)
    return rows


def summarise(rows: list[dict]) -> dict:
    def rate(rs: list[dict]) -> dict:
        k = sum(r["more"] for r in rs)
        k0 = sum(r.get("more_loop_fit", r["more"]) for r in rs)
        return {"records": len(rs), "more_than_that": k,
                "rate": k / len(rs) if rs else None, "upper_95": upper(k, len(rs)),
                "more_than_that_loop_fit": k0}

    with_level = [r for r in rows if r["model_level"]]
    right = [r for r in with_level if r["success"]]
    wrong = [r for r in with_level if not r["success"]]
    return {"records": len(rows), "with_level": len(with_level),
            "right_model": rate(right),
            "right_model_shown": rate([r for r in right if r["shown"]]),
            "wrong_model": rate(wrong),
            "wrong_model_shown": rate([r for r in wrong if r["shown"]]),
            "no_level": [r["name"] for r in rows if not r["model_level"]]}


def print_summary(s: dict) -> None:
    def line(label: str, f: dict) -> str:
        if not f["records"]:
            return f"{label}: no record"
        return (f"{label}: {f['more_than_that']} of {f['records']} read 'more than that' "
                f"(95 % upper bound {100 * f['upper_95']:.0f} %; the loop's fit alone: "
                f"{f['more_than_that_loop_fit']})")

    print(line("final model = truth", s["right_model"]))
    print(line("  of them above the noise within the band (clause shown)",
               s["right_model_shown"]))
    print(line("final model missing or adding an effect", s["wrong_model"]))
    print(line("  of them shown", s["wrong_model_shown"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=None,
                    help="subset: record names (combo@command), combinations or indices")
    ap.add_argument("--commands", default=None, help=f"only these, of: {', '.join(COMMANDS)}")
    ap.add_argument("--seed", type=int, default=1, help="seed block of the records")
    ap.add_argument("--explain-seed", type=int, default=0, help="GA seed of the loop")
    ap.add_argument("--pop", type=int, default=20)
    ap.add_argument("--noise", type=float, default=1e-6, help="noise std on xu [m]")
    ap.add_argument("--limit", type=int, default=0, help="only the first N records")
    ap.add_argument("--merge", nargs="+", default=None, metavar="PART",
                    help="merge these parts' records instead of running")
    ap.add_argument("--json", nargs="?", const=str(result_path("explain_model_level")),
                    default=None, metavar="PATH", help="write records + summary")
    args = ap.parse_args()
    started = time.perf_counter()

    def save(rows: list[dict], sources: list | None = None) -> None:
        summary = summarise(rows)
        summary["wall_s"] = time.perf_counter() - started
        out = {"benchmark": "explain_model_level",
               "what": "false 'more than that' rate of the found model's own level "
                       "(eha.explain.replicates.model_level) where the final model is the truth",
               "settings": {"seed": args.seed, "explain_seed": args.explain_seed,
                            "pop": args.pop, "noise": args.noise, "faults": FAULTS},
               "provenance": {**provenance(sys.argv), "parts": sources or []},
               "summary": summary, "records": rows}
        write_result(Path(args.json), clean(out))

    if args.merge:
        parts = [json.loads(Path(p).read_text()) for p in args.merge]
        rows = {(r["name"], r["seed"]): r for part in parts for r in part["records"]}
        rows = sorted(rows.values(), key=lambda r: (r["seed"], r["i"]))
        sources = [{"part": p, "provenance": part["provenance"]}
                   for p, part in zip(args.merge, parts)]
    else:
        rows, sources = run(args, save if args.json else None), []
    print_summary(summarise(rows))
    if args.json:
        save(rows, sources)


if __name__ == "__main__":
    main()
