"""The residual loop on measured files (``eha explain``): read the record, its validation
record and an earlier run's effects (``prior``), hold known test conditions, run
:func:`eha.explain.explain` and name the run by what went in (:func:`explain_file`). What the
result writes is its own (``.save()``, ``.store()``, ``.plot()``:
:mod:`eha.explain.outputs`)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Mapping

from eha.explain.api import INPUTS, arguments, explain, settle_prior
from eha.explain.record import augmented_base
from eha.explain.results import ExplainResult
from eha.explain.settings import ExplainError, LoopSettings
from eha.explain.settle import excluded_of, rivals_of
from eha.identification.measured import load
from eha.models.params import ParameterError, parse_assignments, resolve


def read_prior(path: str | Path) -> list:
    """``--prior``: the ``--json`` of an earlier ``eha explain`` (an object whose ``steps`` is a
    list of ``{"effect": ..., "params": {...}}``, or that list itself); its steps.
    :func:`read_prior_json` returns the whole object.

    Raises
    ------
    ExplainError
        Not a readable JSON file, or not of that shape (one line naming ``--prior``).
    """
    return read_prior_json(path)["steps"]


def read_prior_json(path: str | Path) -> dict:
    """The whole ``--prior`` object, checked as :func:`read_prior` says (a bare list of steps
    becomes ``{"steps": [...]}``)."""
    try:
        prior = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ExplainError(f"`prior` {path}: not a readable JSON file "
                           f"({getattr(exc, 'strerror', None) or str(exc).splitlines()[0]})"
                           ) from None
    steps = prior.get("steps") if isinstance(prior, dict) else prior
    if not isinstance(steps, list) or not all(isinstance(s, dict) and "effect" in s
                                              for s in steps):
        keys = ", ".join(sorted(prior)) if isinstance(prior, dict) else type(prior).__name__
        raise ExplainError(f"`prior` {path}: expected the `json_out` of an earlier eha explain (key "
                           f"'steps', a list of {{effect, params}}); found "
                           f"{keys or 'an empty object'}")
    return prior if isinstance(prior, dict) else {"steps": steps}


def explain_file(data: str | Path, settings: LoopSettings | None = None, *,
                 validate: str | Path | None = None, prior: str | Path | None = None,
                 known: Mapping[str, float] | list[str] | None = None,
                 command_hold: str = "auto", **keywords: Any) -> ExplainResult:
    """Run the residual loop on a measured file; nothing is written (the result's
    ``.save(folder)`` and ``.store(results)`` do that).

    Parameters
    ----------
    data : path or RecordFile
        The record (:func:`eha.identification.measured.load`; a
        :class:`eha.identification.measured.RecordFile` carries its columns and units).
    settings : LoopSettings, optional
        The loop's settings (``eha explain`` builds them from its options), overridden by
        ``keywords`` as :func:`eha.explain.api.explain` does.
    validate : path or RecordFile, optional
        A second record scored as held-out data.
    prior : path, optional
        The JSON output of an earlier run: its effects start in the model
        (:func:`read_prior`). When it lists rivals it could not rule out, this record first
        settles between them (:mod:`eha.explain.settle`; the result's ``settled``) and the
        explanation that stands starts the model; an effect the first record excluded
        (its ``excluded``) that this record does not show beside the found model stays
        excluded (:func:`eha.explain.rival_check.deferred_to_first`).
    known : mapping or list of ``"NAME=VALUE"``, optional
        LF parameters held at known values (test conditions such as a test load
        ``{"FRC": 4000}``), on top of the prior's effects; they are not candidates.
    command_hold : str
        How the records' commands are rebuilt between their samples
        (:data:`eha.identification.measured.COMMAND_HOLDS`).
    **keywords
        :func:`eha.explain.api.explain`'s inputs and settings (``fit``, ``effects``,
        ``holdout``, ``null``, ``alpha``, ...); an unknown name is refused.

    Returns
    -------
    ExplainResult
        With ``run_id`` naming the run by the file's bytes and everything else that went in.
    """
    # the settings are checked (and an unknown keyword refused) before any file is read
    settings = arguments(settings, keywords)[1]
    keywords = {k: v for k, v in keywords.items() if k in INPUTS}
    if known is not None and not isinstance(known, Mapping):
        try:
            known = parse_assignments(known, "`known`")
        except ParameterError as exc:
            raise ExplainError(str(exc)) from None
    first = read_prior_json(prior) if prior is not None else None
    steps = first["steps"] if first is not None else None
    record = load(data, command_hold=command_hold)
    check = load(validate, command_hold=command_hold) if validate is not None else None
    settled = None
    if first is not None and rivals_of(first):
        # the first record could not tell its finding from a rival: this record decides
        # between them, and the one that stands starts the loop (eha.explain.settle)
        settled = settle_prior(record, first, settings, base=_known_base(known, None),
                               fixed=tuple(known or ()), **keywords)
        if settled is not None and settled.winner is not None:
            steps = settled.steps
    base = _known_base(known, augmented_base(steps) if steps is not None else None)
    # the follow-up of a first record: what it excluded stays excluded where this record,
    # designed for the pair, does not show it (eha.explain.rival_check.deferred_to_first)
    first_excluded = excluded_of(first) if settled is not None else None
    result = explain(record, settings, validate=check, base=base, fixed=tuple(known or ()),
                     first_excluded=first_excluded, **keywords)
    result.settled = settled.to_json() if settled is not None else None
    digest = hashlib.sha1(Path(data).read_bytes())
    digest.update(json.dumps([str(validate), str(prior), dict(known or {}), result.settings,
                              {k: list(v) for k, v in result.fit_bounds.items()}],
                             sort_keys=True, default=str).encode())
    if getattr(data, "columns", None) or getattr(data, "units", None):   # a RecordFile's format
        digest.update(json.dumps([data.columns, data.units], sort_keys=True).encode())
    result.run_id = digest.hexdigest()[:16]
    return result


def _known_base(known, base):
    """``base`` (nominal when None) with the known test conditions set; None when neither."""
    if not known:
        return base
    try:
        return resolve("lf", dict(known), base=base)
    except ParameterError as exc:
        raise ExplainError(f"`known` {exc}") from None
