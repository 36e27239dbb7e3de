"""What a job kind's expander returns (:class:`JobDraft`) and the hashing of run keys: shared by
the campaign files (:mod:`eha.campaigns.files`) and the kinds' expanders (e.g. the simulate
kind's, :mod:`eha.simulations.expand`)."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

#: Upper bound on the number of jobs of one campaign (a typo in a grid should not explode).
MAX_JOBS = 200_000


@dataclass(frozen=True)
class JobDraft:
    """A job before its run key: what an expander returns.

    Attributes
    ----------
    kind : str
        Job kind (``"simulate"``; others: :class:`eha.campaigns.jobs.JobKind`).
    spec : dict
        Compact, JSON-serialisable description the worker needs (stored in ``runs.spec``).
    identity : dict
        What the run key hashes besides ``spec`` (e.g. the fully resolved parameters).
    columns : dict
        Values of the descriptive ``runs`` columns (model, command, faults, seed, t_end, label,
        case_key).
    version : str
        Version of the code that computes the job (the models':
        :data:`eha.models.simulate.MODEL_VERSION`), hashed into its run key: a new version
        runs the job again. Recorded as the campaign's ``model_version``.
    """

    kind: str
    spec: dict
    identity: dict = field(default_factory=dict)
    columns: dict = field(default_factory=dict)
    version: str = ""


def _dumps(obj: Any) -> str:
    """The canonical JSON text that keys are hashed from."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=float)


def _hash(obj: Any, n: int = 16) -> str:
    return _hash_text(_dumps(obj), n)


def _hash_text(text: str, n: int = 16) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:n]


def _did_you_mean(key: str, allowed: tuple[str, ...] | list[str]) -> str:
    import difflib

    close = difflib.get_close_matches(key, list(allowed), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


__all__ = ["MAX_JOBS", "JobDraft"]
