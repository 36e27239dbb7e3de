"""The search: the family member that shows the targets best against the library commands.

Each candidate's score is the mean, over the targets, of the log ratio of its predicted
minimum detectable size to the best library command's, with every ratio above 1 counted again
twice (better on average, worse on none); a requested pair adds the log of its separable size
in multiples of the detectable one. Sizes are capped at ten times a target's limit (a target
that no command shows does not steer the search). A candidate the check's LF model cannot
follow loses to every candidate it can follow (:func:`unfollowed_penalty`). A genetic algorithm
(pymoo's GA, the identification's optimizer) searches the family's unit cube from a seeded
population that includes slow chirps and triangles like the library's best; the same seed
gives the same command.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Collection, Mapping, Sequence

import numpy as np

from eha.design.family import Limits, at_rest_at_the_end, command_samples, genes, n_genes
from eha.design.predict import FOLLOW_RATIO, Prediction, predict
from eha.design.targets import Target
from eha.models.commands import array_command, make_command

#: The library commands a design is compared with.
LIBRARY = ("chirp_1cm", "mixed", "test", "sine")
#: Weight of a pair's log separable size (the pairs are what a separating test is for).
PAIR_WEIGHT = 2.0
#: Score added to a candidate the check's LF cannot follow: more than a followed candidate's
#: score can span (a pair's term spans 2 * log(1e5) = 23), so that one is never preferred.
UNFOLLOWED = 25.0
#: Weight of a target's log ratio where the candidate shows it worse than the library.
WORSE_WEIGHT = 2.0
#: Starting points of the search beside the random ones: slow chirps and triangles like the
#: library's best (so that the design is never worse than what the family can copy).
STARTS = (
    [{"shape": "chirp", "share": 1.0, "amplitude": 1.0, "frequency": 1.5}],
    [{"shape": "triangle", "share": 1.0, "amplitude": 1.0, "frequency": 1.0}],
    [{"shape": "chirp", "share": 0.7, "amplitude": 1.0, "frequency": 1.5},
     {"shape": "hold", "share": 0.3, "centre": 0.5}],
    [{"shape": "triangle", "share": 0.5, "amplitude": 1.0, "frequency": 1.0},
     {"shape": "sine", "share": 0.5, "amplitude": 0.3, "frequency": 5.0}],
)


def library_predictions(targets: Sequence[Target], t_end: float, **options) -> dict[str, Prediction]:
    """The prediction on every library command at the design's record length."""
    return {name: predict(make_command(name), targets, t_end, **options) for name in LIBRARY}


def best_library(targets: Sequence[Target], library: Mapping[str, Prediction]
                 ) -> dict[str, tuple[str, float]]:
    """Per target, the library command that shows it best and its detectable size (capped at
    the target's limit), among the commands the check's LF model can follow."""
    out = {}
    usable = {c: p for c, p in library.items() if p.followed} or dict(library)
    for t in targets:
        name = min(usable, key=lambda c: usable[c].mds[t.name])
        out[t.name] = (name, min(library[name].mds[t.name], t.limit))
    return out


def score(pred: Prediction, targets: Sequence[Target], reference: Mapping[str, tuple[str, float]],
          pairs: Sequence[tuple[str, str]] = (), at_size: bool = False,
          detect: Collection[str] | None = None) -> float:
    """The search's objective (lower is better): the mean log ratio of the predicted
    detectable sizes to the best library command's, each ratio above 1 counted again
    :data:`WORSE_WEIGHT` times; a requested pair adds the log of its separable size.

    ``detect`` names the targets whose detection counts (default all): a pair's members that
    were not asked for in their own right count only through the pair (a separating test is
    judged by how well it separates; a separable size already includes being seen)."""
    logs = []
    for t in targets:
        if detect is not None and t.name not in detect:
            continue
        size = min(pred.mds[t.name], 10.0 * t.limit)
        logs.append(math.log(size / reference[t.name][1]))
    # better than the library on average, and worse on none (each excess weighs double)
    value = (float(np.mean(logs)) + WORSE_WEIGHT * sum(max(0.0, v) for v in logs)
             if logs else 0.0)
    probe = {t.name: abs(t.probe) for t in targets}
    for f, g in pairs:
        if at_size:   # told apart at the record's own sizes: separable size over that size
            worst = max(pred.separable_size(f, g) / probe[f], pred.separable_size(g, f) / probe[g])
        else:
            worst = max(pred.separable[f][g], pred.separable[g][f])
        value += PAIR_WEIGHT * math.log(min(max(worst, 1e-3), 100.0))
    return value


def unfollowed_penalty(pred: Prediction) -> float:
    """0 for a command the check's LF model follows (:attr:`Prediction.followed`); otherwise
    :data:`UNFOLLOWED` plus the log of how far its model-form residual is beyond
    :data:`FOLLOW_RATIO` (the less unfollowed, the better). A hard rule, not a trade: on a
    command the LF cannot follow, what a signature promises is not what a fit finds (the
    5 Hz sine detects none of the seven faults; a 4 Hz sine separating a motor gain from a
    supply pressure, 22 noise stds of model-form residual, left the loop "partly explained"
    on its own truth, docs/design.md)."""
    if pred.followed:
        return 0.0
    return UNFOLLOWED + math.log(max(pred.model_form, FOLLOW_RATIO) / FOLLOW_RATIO)


def search(targets: Sequence[Target], limits: Limits, reference: Mapping[str, tuple[str, float]],
           pairs: Sequence[tuple[str, str]] = (), seed: int = 0, pop: int = 24,
           generations: int = 12, on_progress: Callable[[str], None] | None = None,
           at_size: bool = False, detect: Collection[str] | None = None,
           predictor: Callable[..., Prediction] | None = None,
           **options) -> tuple[np.ndarray, float, list[float]]:
    """The best gene vector found, its score and the best score of each generation
    (``detect``: :func:`score`'s; ``predictor``: the check's prediction, default the fleet
    check's :func:`eha.design.predict.predict`)."""
    from pymoo.algorithms.soo.nonconvex.ga import GA
    from pymoo.core.problem import Problem
    from pymoo.termination.max_gen import MaximumGenerationTermination

    say = on_progress or (lambda message: None)
    k = n_genes()
    all_pairs = [p for f, g in pairs for p in ((f, g), (g, f))]

    def evaluate(x: np.ndarray) -> float:
        t, com = command_samples(x, limits)
        if not at_rest_at_the_end(com, limits):
            return 50.0
        pred = (predictor or predict)(array_command(t, com, "candidate"), targets,
                                      limits.duration, pairs=all_pairs, **options)
        return score(pred, targets, reference, pairs, at_size, detect) + unfollowed_penalty(pred)

    class _Family(Problem):
        def __init__(self):
            super().__init__(n_var=k, n_obj=1, xl=np.zeros(k), xu=np.ones(k))

        def _evaluate(self, X, out, *args, **kwargs):
            out["F"] = np.array([[evaluate(x)] for x in X])

    first = np.random.default_rng([seed, 17]).random((pop, k))
    for i, start in enumerate(STARTS[:pop]):
        first[i] = genes(start, limits)
    algorithm = GA(pop_size=pop, sampling=first, eliminate_duplicates=True)
    algorithm.setup(_Family(), termination=MaximumGenerationTermination(generations),
                    seed=int(seed), verbose=False)
    history: list[float] = []
    start = time.perf_counter()
    while algorithm.has_next():
        algorithm.next()
        history.append(float(algorithm.opt[0].F[0]))
        done = len(history)
        eta = (time.perf_counter() - start) / done * (generations - done)
        say(f"searching: generation {done} of {generations}, best score {history[-1]:.3f}, "
            f"about {eta:.0f} s left")
    best = algorithm.opt[0]
    return np.array(best.X, dtype=np.float64), float(best.F[0]), history


__all__ = ["LIBRARY", "library_predictions", "best_library", "score", "search",
           "unfollowed_penalty"]
