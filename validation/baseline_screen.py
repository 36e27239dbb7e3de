"""The change calibration's screen of a baseline record measured (issue 60): how often it
finds a healthy actuator's baseline unlike the healthy fleet, and from which size it finds a
fault the actuator arrived with, and names it first.

``eha rul --check change`` takes a baseline the screen finds unlike the healthy fleet as the
first alarm of the fault it is farthest in (``at_baseline``): the actuator arrived with it.
That is an alarm, so its false-alarm rate and its power are measured here, per sensor noise
(``--noise``, default 1 µm, the issue's records, and 3 µm, the fleet-validation fleet's):

- a change calibration of ``--command`` (1 s, alpha 0.01, the default test-day differences,
  30 healthy pairs; the screen's bounds come from their earlier records);
- ``--held-out`` healthy actuators on fresh seeds: the share whose baseline is flagged in any
  fault, with its 95 % binomial upper bound;
- per fault, ``--per-level`` actuators at each size (multiples of the fault's signature step):
  flagged in that fault, and named first; the detectable size is the smallest from which
  every larger one is flagged in 95 % or more;
- with ``--foreign-pairs DIR`` (the independent simulator's pairs, 1 µm noise on
  ``chirp_1cm``; their earlier records are healthy acceptance tests, their later ones healthy
  on another test day or with one fault grown from healthy): how many healthy records are
  flagged, and how many faulty ones are flagged and named first (or a fault whose signature
  the check does not tell from it).

Usage::

    python validation/baseline_screen.py            # prints the table
    python validation/baseline_screen.py --json     # validation/results/baseline_screen.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from _results import write_result  # noqa: E402

#: Fault sizes, in multiples of its signature step (:data:`eha.health.change.PROBE`).
MULTIPLES = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def _upper(k: int, n: int) -> float:
    from scipy.stats import beta

    return 1.0 if k >= n else float(beta.ppf(0.95, k + 1, n - k))


def measure(command: str, noise: float, held_out: int, per_level: int, calibration: int,
            seed: int, foreign: Path | None) -> dict:
    """One noise level's figures (see the module docstring)."""
    from eha.health.change import probe
    from eha.health.change_calibration import _faulted, _record, calibrate_change
    from eha.health.change_check import screen_baseline, signatures_of
    from eha.identification.healthy import draw_actuator
    from eha.identification.measured import load
    from eha.models.commands import as_command

    cmd = as_command(command)
    cal, _ = calibrate_change(command, actuators=calibration, seed=seed, t_end=1.0,
                              noise=noise, alpha=0.01)
    sig = signatures_of(cal, _record(cmd, draw_actuator(seed), 1.0, noise, seed).command)
    flagged = 0
    for k in range(held_out):
        s = seed + 800_000 + k
        flagged += bool(screen_baseline(cal, sig, _record(cmd, draw_actuator(s), 1.0, noise,
                                                          s).xu))
    out = {"noise_m": noise, "held_out": held_out, "flagged": flagged,
           "rate": flagged / held_out, "upper_95": _upper(flagged, held_out), "faults": {}}
    for fi, name in enumerate(cal.faults):
        rows = []
        for li, mult in enumerate(MULTIPLES):
            seen = first = 0
            applied = []
            for k in range(per_level):
                s = seed + 900_000 + 10_000 * fi + 1_000 * li + k
                hf, change = _faulted(draw_actuator(s), name, mult * probe(name))
                applied.append(abs(change))
                sc = screen_baseline(cal, sig, _record(cmd, hf, 1.0, noise, s).xu)
                seen += name in sc
                first += bool(sc) and sc[0] == name
            rows.append({"size": sum(applied) / len(applied), "flagged": seen / per_level,
                         "named_first": first / per_level})
        ok = [r["size"] for k, r in enumerate(rows) if all(o["flagged"] >= 0.95 for o in rows[k:])]
        out["faults"][name] = {"levels": rows, "detectable": min(ok) if ok else None}
    if foreign is not None:
        out.update(_foreign(foreign, cal, sig))
    return out


def _foreign(folder: Path, cal, sig) -> dict:
    """The screen on the independent simulator's records: the earlier ones (healthy), the
    later healthy ones (another test day) and the later faulty ones (flagged, and named first
    or a fault the signatures do not tell from it, as the change check's isolation counts)."""
    import json

    from eha.health.change_check import screen_baseline
    from eha.identification.measured import load

    cases = json.loads((folder / "truth.json").read_text())["cases"]
    names = list(sig.faults)

    def alike(name: str) -> set[str]:
        i = names.index(name)
        return {name} | {g for j, g in enumerate(names) if j != i and sig.separation[i, j]
                         <= max(sig.shape_doubt[i], sig.shape_doubt[j])}

    earlier = [bool(screen_baseline(cal, sig, load(folder / f"{p}-a.csv").xu)) for p in cases]
    healthy_later, faulty = [], {}
    for p, c in cases.items():
        sc = screen_baseline(cal, sig, load(folder / f"{p}-b.csv").xu)
        if c["fault"] is None:
            healthy_later.append(bool(sc))
        else:
            row = faulty.setdefault(c["fault"], {"records": 0, "flagged": 0, "named_first": 0})
            row["records"] += 1
            row["flagged"] += bool(sc)
            row["named_first"] += bool(sc) and sc[0] in alike(c["fault"])
    return {"foreign_earlier_records": len(earlier), "foreign_flagged": sum(earlier),
            "foreign_healthy_later": len(healthy_later),
            "foreign_healthy_later_flagged": sum(healthy_later), "foreign_faulty": faulty}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--command", default="chirp_1cm")
    ap.add_argument("--noise", type=float, nargs="+", default=[1e-6, 3e-6],
                    help="Sensor noise of the records [m], one study each.")
    ap.add_argument("--held-out", type=int, default=300)
    ap.add_argument("--per-level", type=int, default=20)
    ap.add_argument("--calibration", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--foreign-pairs", type=Path, default=None,
                    help="Folder of the independent simulator's pairs (pNNN-a.csv), 1 µm only.")
    ap.add_argument("--json", action="store_true",
                    help="write validation/results/baseline_screen.json")
    args = ap.parse_args(argv)
    from eha.models.units import show

    start = time.perf_counter()
    studies = []
    for noise in args.noise:
        m = measure(args.command, noise, args.held_out, args.per_level, args.calibration,
                    args.seed, args.foreign_pairs if noise == 1e-6 else None)
        studies.append(m)
        print(f"{args.command}, {1e6 * noise:g} µm noise: healthy baselines flagged "
              f"{m['flagged']}/{m['held_out']} (95 % upper bound {m['upper_95']:.3f})"
              + (f"; the independent simulator's {m['foreign_flagged']}/"
                 f"{m['foreign_earlier_records']} earlier and "
                 f"{m['foreign_healthy_later_flagged']}/{m['foreign_healthy_later']} later "
                 "healthy records" if "foreign_flagged" in m else ""),
              flush=True)
        for name, f in m.get("foreign_faulty", {}).items():
            print(f"  independent simulator, {name} grown: flagged {f['flagged']}/"
                  f"{f['records']}, named first (or a look-alike) {f['named_first']}",
                  flush=True)
        for name, f in m["faults"].items():
            named = next((r["named_first"] for r in f["levels"]
                          if f["detectable"] is not None and r["size"] >= f["detectable"]),
                         None)
            print(f"  {name}: flagged from {show(name, f['detectable']) if f['detectable'] else '-'}"
                  + ("" if named is None else f", named first there in {100 * named:.0f} %"),
                  flush=True)
    out = {"settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
           "command": args.command, "studies": studies,
           "seconds": time.perf_counter() - start}
    if args.json:
        write_result("baseline_screen", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
