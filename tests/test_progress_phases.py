"""No silent phase (issue 42, item 3): the healthy null says how far it is and how long is
left from its first second, and the exclusion check after the final estimates is named as what
it is, not "round 1" again. Each test failed before the change."""

from __future__ import annotations

import time

import pytest


def test_the_healthy_null_says_k_of_n_and_the_time_left():
    from eha.explain.null import _fleet_progress

    said: list[str] = []
    t0 = time.perf_counter() - 30.0            # 30 s spent when the 3rd actuator ends
    say = _fleet_progress(said.append, 12, t0)
    say(0)
    say(3)
    say(12)
    assert said[0].endswith("simulating and fitting 12 healthy actuators")
    assert "once, then cached" in said[0]
    assert said[1].endswith("actuator 3 of 12 done, about 1 min 30 s left"), said[1]
    assert said[2].endswith("actuator 12 of 12 done")


def test_the_exclusion_check_is_not_labelled_as_a_round():
    from eha.explain.fitting import Fitter
    from eha.explain.rounds import Rounds

    labels: list[str] = []

    class Probe(Rounds):
        phase = ""
        rounds = [object()]

    class Recording(Fitter):
        def __init__(self):         # no problem: the fits only record their labels
            pass

        def fit_with_cost(self, start, free, label, **kwargs):
            labels.append(label)
            raise StopIteration

    loop, fitter = Probe(), Recording()
    with pytest.raises(StopIteration):
        fitter.local_test(None, {}, [], loop.fit_phase())
    loop.phase = "exclusion check (does another effect fit as well?)"
    with pytest.raises(StopIteration):
        fitter.local_test(None, {}, [], loop.fit_phase())
    assert labels[0].startswith("round 1: local test")
    assert labels[1].startswith("exclusion check (does another effect fit as well?): local")
