"""How narrow is a separating design's optimum? The sensor gain / hinge moment pair (f21).

The separating design the residual loop's records were made on for this pair
(``validation/results/design.json``, ``ambiguities``: a 0.80 cm, 2.39 Hz sine) is not what
``eha design`` finds with the same settings today. This study scores, with the search's own
objective (:func:`eha.design.search.score` plus the not-followed rule) and the current
predictor: the recorded design rebuilt from its segments, the command ``eha design`` makes now
(seed 0, 32 candidates, 20 generations; or a design file given with ``--design``), the
recorded sine's neighbours, and a grid of full-length sines within the limits (a search that
knew the shape). Lower scores are better; each row has the separable sizes both ways and the
check's LF model-form residual (a command beyond ``FOLLOW_RATIO`` noise stds is not
followed).

    python validation/design_edge.py --json

About 1 s a candidate; with the design search 4-10 min on the 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper
from _results import write_result  # noqa: E402

from design import AMBIGUITIES  # noqa: E402

LABEL = "sensor gain-hinge moment (f21)"
AMPLITUDES = (0.1, 0.25, 0.5, 0.75, 1.0)       # of the stroke
FREQUENCIES = tuple(float(f) for f in np.geomspace(0.5, 6.0, 9))   # Hz


def recorded_segments() -> list[dict]:
    """The recorded design's segments (design.json's ambiguity entry)."""
    doc = json.loads((Path(__file__).resolve().parent / "results" / "design.json").read_text())
    return doc["ambiguities"][LABEL]["segments"]


def sine(amplitude: float, frequency: float, limits) -> tuple[np.ndarray, np.ndarray]:
    """A full-length sine of the family (``amplitude`` a fraction of the stroke)."""
    from eha.design.family import command_samples, genes

    return command_samples(genes([{"shape": "sine", "share": 1.0, "amplitude": amplitude,
                                   "frequency": frequency}], limits), limits)


class Scorer:
    """The search's objective for this pair on any command (``eha.design.design``'s setup)."""

    def __init__(self, limits):
        from eha.design.api import _check, _pairs
        from eha.design.search import best_library, library_predictions
        from eha.design.targets import resolve_targets, with_probes

        (a, va), (b, vb) = AMBIGUITIES[LABEL]
        self.limits, self.pairs = limits, _pairs([(a, b)])
        self.options = _check(("xu",), 1000.0, None, 0.01, 3, 32, 20, 0)
        self.targets = with_probes(resolve_targets([], (), self.pairs), {a: va, b: vb})
        library = library_predictions(self.targets, limits.duration, **self.options)
        self.reference = best_library(self.targets, library)
        self.ordered = [q for f, g in self.pairs for q in ((f, g), (g, f))]

    def __call__(self, t: np.ndarray, com: np.ndarray) -> dict:
        from eha.design.family import at_rest_at_the_end
        from eha.design.predict import predict
        from eha.design.search import score, unfollowed_penalty
        from eha.models.commands import array_command

        p = predict(array_command(t, com, "candidate"), self.targets, self.limits.duration,
                    pairs=self.ordered, **self.options)
        sizes = {f"{f} from {g}": _plain(p.separable_size(f, g)) for f, g in self.ordered}
        return {"score": score(p, self.targets, self.reference, self.pairs, True, set())
                + unfollowed_penalty(p), "followed": bool(p.followed),
                "model_form": float(p.model_form), "separable_from": sizes,
                "at_rest_at_the_end": at_rest_at_the_end(com, self.limits),
                "peak": float(np.max(np.abs(com)))}


def _plain(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def searched(limits, design_file: str | None) -> tuple[np.ndarray, np.ndarray, str]:
    """The command ``eha design`` makes for the pair now (or the one in ``design_file``)."""
    from eha.models.commands import load_command_file

    if design_file:
        t, com = load_command_file(design_file).samples
        return np.asarray(t), np.asarray(com), f"the design file {design_file}"
    from eha.design import design

    (a, va), (b, vb) = AMBIGUITIES[LABEL]
    start = time.perf_counter()
    r = design(faults=[], separate=[(a, b)], around={a: va, b: vb}, limits=limits, seed=0,
               generations=20)
    return r.t, r.com, (f"eha design (seed 0, 32 candidates, 20 generations, "
                        f"{time.perf_counter() - start:.0f} s): {json.dumps(r.segments)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", help="a design file instead of running eha design")
    ap.add_argument("--json", action="store_true", help="write the result file")
    args = ap.parse_args()
    from eha.design import Limits
    from eha.design.family import segment_samples

    load = os.getloadavg()
    limits = Limits(2.0, 0.01, 0.1).check()
    scorer = Scorer(limits)
    recorded = segment_samples(recorded_segments(), limits)
    rows = {"recorded design (design.json's segments)": scorer(*recorded)}
    t, com, what = searched(limits, args.design)
    rows["eha design now"] = {**scorer(t, com), "what": what}
    for amp, freq in ((0.80, 2.39), (0.75, 2.36), (1.0, 2.36), (0.80, 2.2), (0.80, 2.6)):
        rows[f"sine {amp:g} of the stroke at {freq:g} Hz"] = scorer(*sine(amp, freq, limits))
    grid = [{"amplitude": a, "frequency": f, **scorer(*sine(a, f, limits))}
            for a in AMPLITUDES for f in FREQUENCIES]
    best = min((g for g in grid if g["at_rest_at_the_end"]), key=lambda g: g["score"])
    for name, row in rows.items():
        print(f"{name}: score {row['score']:.3f}, model form {row['model_form']:.2f}, "
              f"{row['separable_from']}", flush=True)
    print(f"best of the {len(grid)} grid sines: {best['amplitude']} of the stroke at "
          f"{best['frequency']:.2f} Hz, score {best['score']:.3f}", flush=True)
    if args.json:
        write_result("design_edge", {
            "what": "the sensor gain / hinge moment separating design's optimum: scores "
                    "(lower is better) of the recorded design, eha design's, neighbours and "
                    "a grid of sines, by the search's own objective",
            "limits": limits.to_dict(), "rows": rows, "grid": grid, "best_grid_sine": best},
            load_start=load)


if __name__ == "__main__":
    main()
