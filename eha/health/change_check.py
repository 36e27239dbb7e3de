"""``eha health check LATER --baseline EARLIER``: a record judged against the same actuator's own
earlier record (the change check, :mod:`eha.health.change`), and what it shows and writes.

The baseline must be fit for its purpose: the same command, sampling and length as the later
record and as the calibration (else one line, exit 2, nothing written); a baseline that looks
unlike the calibration's healthy fleet (the fleet screen, :func:`screen_baseline`) is used, and
the console and the JSON say so.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from eha.health.change import Signatures
from eha.health.change_calibration import (ChangeCalibration, load_change_calibration,
                                           sign_of)
from eha.health.change_second import judge_change
from eha.identification.healthy import DetectionError, command_signature
from eha.models.faults import FAULTS

#: Records the change check accepts [s].
RECORD_SECONDS = (0.2, 10.0)


@dataclass
class ChangeCheckResult:
    """What ``eha health check --baseline`` shows and writes.

    ``judged[name]``: the fault's ``change`` (later minus earlier, fault unit), its
    ``interval`` at ``level``, ``statistic``, ``threshold`` (in the estimate's units),
    ``alarm_change`` (the change at which it alarms), ``degraded``; ``isolated``: the faults
    the change is isolated to (more than one: the records cannot tell them apart);
    ``screen``: the faults in which the baseline itself is unlike the healthy fleet.
    """

    record: str
    baseline: str
    calibration: str
    level: float
    judged: dict[str, dict[str, Any]]
    isolated: list[str]
    screen: list[str]
    noise_rmse: dict[str, float]
    check_id: str
    seconds: float
    alpha: float = 0.01
    notes: list[str] = field(default_factory=list)
    #: the other faults judged beside the first isolated one
    #: (:func:`eha.health.change_second.judge_second`) and those changed beside it
    second: dict[str, dict[str, Any]] = field(default_factory=dict)
    also: list[str] = field(default_factory=list)
    paths: dict[str, Path] = field(default_factory=dict)
    db_error: str | None = None

    @property
    def status(self) -> str:
        return "degraded" if any(v["degraded"] for v in self.judged.values()) else "healthy"

    def finding(self) -> str:
        """The finding in one sentence, with units."""
        if self.status == "healthy":
            return ("healthy: no fault changed beyond its threshold since the baseline "
                    f"record (false-alarm probability at most {self.alpha:g})")
        parts = []
        for name in self.isolated or [n for n, v in self.judged.items() if v["degraded"]]:
            v = self.judged[name]
            parts.append(f"{name} ({FAULTS[name].description}) changed by "
                         f"{_signed(name, v['change'])} "
                         f"{interval_text(name, *v['interval'])} since the baseline")
        which = " or ".join(parts)
        beside = "".join(f"; and {name} ({FAULTS[name].description}) changed beside it, by "
                         f"{_signed(name, self.second[name]['change'])} "
                         f"{interval_text(name, *self.second[name]['interval'])}"
                         for name in self.also)
        return f"degraded: {which}{beside}"

    def to_dict(self) -> dict[str, Any]:
        from eha.models.units import display_unit

        faults = {}
        for name, v in self.judged.items():
            unit, scale = display_unit(name)
            faults[name] = {
                "change": v["change"], "interval": [_json_number(x) for x in v["interval"]],
                "open_ended": bool(v.get("open_ended")), "level": self.level,
                "unit": FAULTS[name].unit, "display_unit": unit, "display_scale": scale,
                "alarm_change": v["alarm_change"], "statistic": v["statistic"],
                "threshold": v["threshold"], "z": v["z"], "degraded": v["degraded"],
                "isolated": name in self.isolated, "blind": v["blind"],
                "not_told_apart_from": list(v.get("alike", []))}
            if name in self.second:
                faults[name]["beside"] = beside_record(self.second[name])
        return {"check": "change", "status": self.status, "isolated": list(self.isolated),
                "also_changed": list(self.also),
                "finding": self.finding(), "record": self.record, "baseline": self.baseline,
                "calibration": self.calibration, "level": self.level,
                "changes": {n: f["change"] for n, f in faults.items()},
                "intervals": {n: f["interval"] for n, f in faults.items()},
                "faults": faults,
                "baseline_screen": {"status": "unlike the healthy fleet" if self.screen
                                    else "like the healthy fleet", "faults": self.screen},
                "noise_rmse": self.noise_rmse, "alpha": self.alpha, "seconds": self.seconds,
                "check_id": self.check_id, "notes": list(self.notes)}

    def to_pandas(self):
        """One row per fault: change, interval, threshold, verdict (fault units)."""
        import pandas as pd

        return pd.DataFrame([{"fault": n, "change": v["change"], "lo": v["interval"][0],
                              "hi": v["interval"][1], "alarm_change": v["alarm_change"],
                              "degraded": v["degraded"], "isolated": n in self.isolated}
                             for n, v in self.judged.items()])


def _signed(name: str, value: float) -> str:
    from eha.models.units import show

    return ("+" if value >= 0 else "-") + show(name, abs(value))


def interval_text(name: str, lo: float, hi: float) -> str:
    """An interval of a change with its unit; an open end (beyond the response's growing
    range) as a bound: ``>= 410 µm``."""
    from eha.models.units import show

    if math.isinf(hi):
        return f">= {show(name, lo)}"
    if math.isinf(lo):
        return f"<= {show(name, hi)}"
    return f"[{show(name, lo)}, {show(name, hi)}]"


def _json_number(x: float) -> float | None:
    """JSON has no infinity: an open end of an interval is null."""
    return None if math.isinf(x) else float(x)


def _load_pair(record, baseline, cal: ChangeCalibration, calibration):
    """Both records, checked against each other and against the calibration."""
    from eha.identification.measured import load

    later, earlier = load(record), load(baseline)
    lo, hi = RECORD_SECONDS
    for what, data in (("record", later), ("baseline", earlier)):
        if not lo <= data.t_end <= hi:
            raise DetectionError(f"{data.source}: {what} of {data.t_end:g} s; the change check "
                                 f"takes [{lo:g}, {hi:g}] s")
    pa, pb = later.info.get("period"), earlier.info.get("period")
    if pa and pb and abs(pa - pb) > 1e-3 * pa:
        raise DetectionError(f"`baseline` {baseline}: sampled every {1e3 * pb:g} ms, the record "
                             f"{record} every {1e3 * pa:g} ms; record both the same way")
    if abs(later.t_end - earlier.t_end) > 1.5e-3 or len(later) != len(earlier):
        raise DetectionError(f"`baseline` {baseline}: {earlier.t_end:g} s long, the record "
                             f"{record} {later.t_end:g} s; a baseline on the same command and "
                             "length is needed")
    if command_signature(earlier.com) != command_signature(later.com):
        diff = float(np.max(np.abs(earlier.com - later.com)))
        raise DetectionError(f"`baseline` {baseline}: another command than the record {record} "
                             f"(largest difference {1e3 * diff:.3g} mm); a baseline on the same "
                             "command is needed")
    if abs(later.t_end - cal.t_end) > 1.5e-3:
        raise DetectionError(f"{record}: {later.t_end:g} s long, the calibration {calibration} "
                             f"is for {cal.t_end:g} s records of {cal.command}")
    if command_signature(later.com) != cal.command_sig:
        raise DetectionError(f"{record}: its command is not {cal.command}, the command the "
                             f"calibration {calibration} was made for; calibrate for this "
                             "command (eha health calibrate --baseline --command ...)")
    return later, earlier


#: How many times the two records' noise the difference may stay after the isolated fault's
#: fit before the check says the change is beyond its linear reading.
UNEXPLAINED_RATIO = 3.0


def _unexplained(sig: Signatures, r: np.ndarray, isolated: list[str], noise2: float) -> float:
    """The RMS of the difference left by the best isolated fault's linear fit, in multiples
    of the two records' noise, when above :data:`UNEXPLAINED_RATIO` (else 0)."""
    if not isolated or noise2 <= 0:
        return 0.0
    i = sig.faults.index(isolated[0])
    a = float(sig.W[i] @ r)
    ratio = float(np.sqrt(np.mean((r - sig.S[i] * a) ** 2) / noise2))
    return ratio if ratio > UNEXPLAINED_RATIO else 0.0


def screen_baseline(cal: ChangeCalibration, sig: Signatures, xu: np.ndarray) -> list[str]:
    """The faults in which a baseline record is unlike the calibration's healthy fleet: its
    difference from the nominal model on the faults' signatures, beyond the prediction bound
    of the fleet's earlier records at the calibration's alpha (a linear screen of the fleet,
    not the hypothesis bank of ``eha health check``), the farthest beyond its bound first
    (the fault the screen is isolated to, where several move with one: a backlash of 20 µm
    also moves the friction's and the leakage's readings)."""
    est = sig.estimate(xu - sig.y0)
    beyond = []
    for i, name in enumerate(sig.faults):
        sc = cal.screen.get(name)
        if sc is None or not sc["threshold"] > 0:
            continue
        d = sign_of(name) * float(est[i]) - sc["mean"]
        ratio = (abs(d) if sc["two_sided"] else d) / sc["threshold"]
        if ratio > 1.0:
            beyond.append((ratio, name))
    return [name for _, name in sorted(beyond, reverse=True)]


def signatures_of(cal: ChangeCalibration, command) -> Signatures:
    """The calibration's estimator on a record's own command."""
    return Signatures(command, cal.t_end, cal.noise, cal.nuisances, faults=list(cal.faults),
                      model=cal.signatures, at=cal.operating_point)


def check_change(record, baseline, calibration, level: float | None = None,
                 json_path: str | Path | None = None,
                 results: str | Path | None = "results") -> ChangeCheckResult:
    """Judge ``record`` against the same actuator's earlier ``baseline`` record.

    Raises
    ------
    DetectionError
        A missing or wrong calibration (a fleet calibration), a baseline on another command,
        sampling or length, a record outside the calibration's command or length.
    eha.identification.measured.MeasuredDataError
        A record that cannot be read.
    """
    from eha.identification.intervals import check_level
    from eha.identification.measured import noise_level

    start = time.perf_counter()
    if level is not None:
        try:
            level = check_level(level)
        except ValueError:
            raise DetectionError(f"`level` {level!r}: allowed range (0, 1), e.g. 0.9") from None
    cal = load_change_calibration(calibration)
    later, earlier = _load_pair(record, baseline, cal, calibration)
    sig = signatures_of(cal, later.command)
    n_a, n_b = noise_level(earlier.xu), noise_level(later.xu)
    judged, isolated, second, also = judge_change(cal, sig, later.xu - earlier.xu,
                                                  n_a ** 2 + n_b ** 2, level)
    screen = screen_baseline(cal, sig, earlier.xu)
    notes = []
    if screen:
        notes.append(f"the baseline {baseline} itself looks unlike the healthy fleet in "
                     f"{', '.join(screen)} (fleet screen at alpha {cal.alpha:g}): it is used, "
                     "but the changes are from an actuator that may already be degraded"
                     + ("" if cal.operating_point else "; a fault's signature changes with the "
                        "faults already there: calibrate at the baseline's identified faults "
                        "(eha health calibrate --baseline --at NAME=VALUE)"))
    unexplained = _unexplained(sig, later.xu - earlier.xu, isolated, n_a ** 2 + n_b ** 2)
    if unexplained:
        notes.append(f"the difference is {unexplained:.1f}x the noise after the isolated "
                     f"fault's fit: a change beyond the check's linear range or of several "
                     "faults; the sizes are indicative (eha health check without --baseline, "
                     "or eha explain, fits the whole model)")
    if isolated and not cal.second:
        notes.append(f"the calibration {calibration} has no two-fault reading (made without "
                     "the gain curves, or by an older eha): no fault is judged beside "
                     f"{isolated[0]}; calibrate again to judge one (eha health calibrate "
                     "--baseline)")
    for name, v in judged.items():
        if v["blind"]:
            notes.append(f"{name}: this command does not move it; a change is not seen")
    ratio = max(n_a, n_b) / cal.noise if cal.noise > 0 else 1.0
    if ratio > 3:
        notes.append(f"sensor noise {1e6 * max(n_a, n_b):.3g} µm, {ratio:.1f}x the "
                     f"calibration's: thresholds widened for it")
    check_id = hashlib.sha256(json.dumps(
        [str(Path(str(record)).resolve()), str(Path(str(baseline)).resolve()),
         str(calibration), level]).encode()).hexdigest()[:16]
    out = ChangeCheckResult(str(record), str(baseline), str(calibration),
                            cal.level if level is None else level, judged, isolated, screen,
                            {"record": n_b, "baseline": n_a}, check_id,
                            time.perf_counter() - start, cal.alpha, notes, second=second,
                            also=also)
    if json_path is not None:
        from eha.outputs import write_json

        out.paths["json"] = write_json(Path(json_path), out.to_dict(), indent=2)
    if results is not None:
        _store(out, results)
    return out


def beside_record(b: Mapping[str, Any], named: bool | None = None) -> dict[str, Any]:
    """A fault's reading beside the first isolated one
    (:func:`eha.health.change_second.judge_second`) as JSON: the first fault, the change with
    its interval (an open end null), statistic, threshold, alarm and, where given, whether it
    is the one named beside (``also_changed``). The same record in the check's JSON,
    ``health_verdicts.beside`` and ``change_checks.beside``."""
    out = {"fault": b["beside"], "change": float(b["change"]),
           "interval": [_json_number(x) for x in b["interval"]],
           "open_ended": bool(b["open_ended"]), "statistic": float(b["statistic"]),
           "threshold": float(b["threshold"]), "degraded": bool(b["degraded"])}
    if named is not None:
        out["named"] = bool(named)
    return out


def _beside_cell(out: ChangeCheckResult, name: str) -> dict[str, Any] | None:
    """``health_verdicts.beside`` of fault ``name`` (None where it was not judged)."""
    b = out.second.get(name)
    return None if b is None else beside_record(b, name in out.also)


def _store(out: ChangeCheckResult, results) -> None:
    """The check's rows in ``health_verdicts`` (``reference`` 'baseline')."""
    from eha.campaigns.store import StoreError, replace_rows

    now = datetime.now(timezone.utc).replace(tzinfo=None)
    rows = [{"check_id": out.check_id, "record": out.record, "created_at": now,
             "calibration": out.calibration, "fault": n, "estimate": v["change"],
             "lo": _json_number(v["interval"][0]), "hi": _json_number(v["interval"][1]),
             "level": out.level,
             "healthy": None, "threshold": v["threshold"], "statistic": v["statistic"],
             "degraded": v["degraded"], "weight": None, "isolated": n in out.isolated,
             "flagged": bool(out.screen), "reference": "baseline", "baseline": out.baseline,
             "beside": _beside_cell(out, n)}
            for n, v in out.judged.items()]
    try:
        out.paths["database"] = replace_rows(results, "health_verdicts", rows,
                                             {"check_id": out.check_id})
    except StoreError as exc:
        out.db_error = str(exc)


def calibrate_baseline(command: str = "chirp_1cm", actuators: int = 30, seed: int = 0,
                       t_end: float = 1.0, noise: float = 1e-6, alpha: float = 0.01,
                       level: float = 0.9, nuisances: Mapping[str, float] | None = None,
                       out: str | Path | None = None, results: str | Path | None = "results",
                       on_progress=None, at: Mapping[str, float] | None = None
                       ) -> dict[str, Any]:
    """``eha health calibrate --baseline``: :func:`eha.health.change_calibration.calibrate_change`
    (at the operating point ``at``, default healthy), saved (default ``RESULTS/health/calibration-COMMAND-baseline.json``) and its thresholds in
    ``health_thresholds`` (``reference`` 'baseline').

    Returns ``{"calibration": ChangeCalibration, "path": file}``.
    """
    from eha.health.change_calibration import calibrate_change
    from eha.models.commands import CommandError, command_label, pin_command

    try:
        pinned, label = pin_command(command), command_label(command)
    except (CommandError, ValueError) as exc:
        raise DetectionError(f"`command`: {exc}") from None
    cal, _ = calibrate_change(pinned, actuators, seed, t_end, noise, alpha, level, nuisances,
                              on_progress=on_progress, at=at)
    base = Path(results) if results is not None else Path("results")
    path = Path(out) if out is not None else base / "health" / f"calibration-{label}-baseline.json"
    cal.save(path)
    if results is not None:
        from eha.campaigns.store import replace_rows

        now = datetime.now(timezone.utc).replace(tzinfo=None)
        replace_rows(results, "health_thresholds",
                     [{"calibration": str(path), "command": label, "t_end": float(t_end),
                       "fault": n, "threshold": f["threshold"], "mean": f["mean"],
                       "std": f["std"], "n": f["n"], "alpha": alpha, "created_at": now,
                       "reference": "baseline"} for n, f in cal.faults.items()],
                     {"calibration": str(path)})
    return {"calibration": cal, "path": path}


__all__ = ["ChangeCheckResult", "check_change", "calibrate_baseline", "screen_baseline",
           "beside_record", "signatures_of"]
