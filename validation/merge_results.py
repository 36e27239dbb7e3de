"""Merge JSON results of explain_multi.py or explain_fp.py and recompute the summary.

Parts are read in order; a record of a later part replaces the record of an earlier part with
the same key (multi: record name and seed; fp: command and seed). That serves two uses:

* one seed block run as two processes (two parts with different records): their union;
* a rerun of only the records a change of the loop can touch (``--records`` / ``--seeds``):
  the rerun records replace the old ones, the others are kept as they were. A record is
  untouched when the new code takes exactly the old path on it: the loop is deterministic for
  one seed, so when the JSON shows that no refit the change acts on occurred in the record's
  run, the old record *is* the new code's result. The provenance of every part is kept.

    python validation/merge_results.py multi validation/results/explain_multi.json \
        part0.json part1.json part2.json
    python validation/merge_results.py fp validation/results/explain_fp.json \
        validation/results/explain_fp.json rerun.json

The merged file's provenance says where each part comes from (``parts``) and, on top, the
commit(s), the latest date, the machine(s), cores and load of the parts.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))   # _results: the shared helper

from _results import write_result  # noqa: E402


def merged_provenance(parts: list[dict]) -> dict:
    """The provenance of a merged file: what its parts share, and every part."""
    def one_or_all(key):
        values = sorted({str(p[key]) for p in parts if p.get(key) is not None})
        return values[0] if len(values) == 1 else (values or "not recorded")

    dates = sorted(p["date"] for p in parts if p.get("date"))
    return {"commit": one_or_all("commit"), "date": dates[-1] if dates else "not recorded",
            "machine": one_or_all("machine"), "cores": one_or_all("cores"),
            "load": one_or_all("load") if any(p.get("load") for p in parts) else "not recorded",
            "parts": parts}


def key(kind: str, row: dict) -> tuple:
    return (row["name"], row["seed"]) if kind == "multi" else (row["command"], row["seed"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("kind", choices=("multi", "fp"))
    ap.add_argument("out", help="merged JSON to write")
    ap.add_argument("parts", nargs="+", help="result JSONs, later ones replacing earlier rows")
    args = ap.parse_args()
    docs = [json.loads(Path(p).read_text()) for p in args.parts]
    rows: dict[tuple, dict] = {}
    replaced = []
    for part, doc in zip(args.parts, docs):
        for row in doc["records"]:
            k = key(args.kind, row)
            if k in rows:
                replaced.append({"record": list(k), "by": part})
            rows[k] = row
    merged = list(rows.values())
    if args.kind == "multi":
        import explain_multi as bench
        summary = bench.summarise(merged)
    else:
        import explain_fp as bench
        summary = bench.summarise(merged, list(dict.fromkeys(r["command"] for r in merged)))
    summary["wall_s"] = sum(d["summary"].get("wall_s", 0.0) for d in docs)
    parts = []
    for part, doc in zip(args.parts, docs):
        prov = doc["provenance"]
        if isinstance(prov, dict) and "parts" in prov:  # an earlier merge
            prov = prov["parts"]
        for p in prov if isinstance(prov, list) else [prov]:
            parts.append({"part": Path(part).name, **p})
    out = {"benchmark": f"explain_{args.kind}", "settings": docs[-1]["settings"],
           "provenance": merged_provenance(parts), "replaced": replaced, "summary": summary,
           "records": merged}
    write_result(Path(args.out), out)
    bench.print_summary(summary)
    print(f"wrote {args.out}: {len(merged)} records, {len(replaced)} replaced")


if __name__ == "__main__":
    main()
