"""Resume with nothing to do (issue 43): what verifying every trace file costs.

Runs bench_scale's campaign (HF runs of ``mixed``, five fault sets, all nine signals; ``--runs``
runs of ``--t-end`` s) once into ``--results`` (kept: later calls reuse it), then times
``run_campaign`` on it ``--rounds`` times: every run is done, so the wall is the resume's own
cost (validation, database, verifying the trace files). Also the hashing alone
(:func:`eha.campaigns.integrity.check_files`, ``full``) and the query's check (not ``full``).

Run it with this checkout, and with an older one on the same folder to compare
(``PYTHONPATH=/path/to/old/checkout python benchmarks/bench_resume.py --results DIR``): an
older version ignores the checksum columns.

Usage::

    python benchmarks/bench_resume.py --runs 20000 --t-end 1.0 --results /tmp/resume-20000
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import campaign_table  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20000)
    ap.add_argument("--t-end", type=float, default=1.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--results", required=True)
    args = ap.parse_args(argv)
    os.environ["NUMBA_NUM_THREADS"] = "1"
    import eha
    from eha.campaigns.files import build_campaign
    from eha.campaigns.runner import run_campaign

    camp = build_campaign(campaign_table(args.runs, args.t_end))
    results = Path(args.results)
    out = {"eha": str(Path(eha.__file__).parent), "runs": args.runs, "t_end": args.t_end}
    if not (results / "eha.duckdb").exists():
        t0 = time.perf_counter()
        s = run_campaign(camp, results, workers=args.workers, progress=False)
        out["campaign_s"] = round(time.perf_counter() - t0, 2)
        assert s.failed == 0, s
    walls = []
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        s = run_campaign(camp, results, workers=args.workers, progress=False)
        walls.append(round(time.perf_counter() - t0, 3))
        assert s.done == 0 and s.skipped == s.total, s
    out["resume_s"] = walls
    try:
        from eha.campaigns.integrity import check_files, recorded_files
        from eha.campaigns.store import connect
    except ImportError:  # an older checkout
        pass
    else:
        con = connect(results, read_only=True)
        files = recorded_files(con)
        con.close()
        for full in (True, False):
            t0 = time.perf_counter()
            c = check_files(results, files, full=full)
            out[f"check_{'full' if full else 'query'}_s"] = round(time.perf_counter() - t0, 3)
            assert not c.damaged
        out["files"] = len(files)
        out["bytes"] = sum((results / f.path).stat().st_size for f in files)
    out["loadavg"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
