"""Compare repeated runs of a benchmark suite between two versions of the code: the median
over the repeats of each row's time for each version and their ratio (new / old; > 1 is
slower), the same with the fastest repeat (less sensitive to other processes on a shared
machine), the median of the ratios of the repeats run back to back (repeat k of each
version), and the geometric mean of each ratio over the rows.

    python benchmarks/compare_results.py SUITE DIR
    # DIR holds res_<suite>.old.<k>.json and res_<suite>.new.<k>.json (harness.record
    # outputs of alternated runs: old = PYTHONPATH of the previous code)
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

#: Row fields that identify a row (its key) and the timed value of each suite: a time in s
#: or ms, or a throughput (inverted so that every ratio is a time ratio).
KEYS = ("case", "events", "size", "warp", "objective", "regularizer", "motion")
TIME_FIELDS = ("ms_per_eval", "median_s", "ms_total")
RATE_FIELDS = ("Mev_per_s",)


def _value(row: dict):
    for f in TIME_FIELDS:
        if row.get(f) is not None:
            return f, float(row[f])
    for f in RATE_FIELDS:
        if row.get(f) is not None:
            return f, 1.0 / float(row[f])
    return None, None


def load(folder: Path, suite: str, version: str) -> dict[tuple, tuple[str, list[float]]]:
    """Row key -> (timed field, its value in each repeat, in the order of the repeats)."""
    out: dict[tuple, tuple[str, list[float]]] = {}
    paths = folder.glob(f"res_{suite}.{version}.*.json")
    for path in sorted(paths, key=lambda q: int(q.stem.rsplit(".", 1)[1])):
        for row in json.loads(path.read_text())["rows"]:
            field, v = _value(row)
            if field is None:
                continue
            key = tuple(row.get(k) for k in KEYS)
            out.setdefault(key, (field, []))[1].append(v)
    return out


def compare(folder: Path, suite: str) -> list[dict]:
    old, new = load(folder, suite, "old"), load(folder, suite, "new")
    rows = []
    for key, (field, vals) in new.items():
        if key not in old:
            continue
        o, n = statistics.median(old[key][1]), statistics.median(vals)
        rows.append({"key": " / ".join(str(k) for k in key if k is not None), "field": field,
                     "old": o, "new": n, "ratio": n / o,
                     "ratio_min": min(vals) / min(old[key][1]),
                     # repeat k of each version ran back to back: the median of those
                     # pairs' ratios cancels the load that changes between repeats
                     "ratio_paired": statistics.median(
                         n_k / o_k for n_k, o_k in zip(vals, old[key][1], strict=False)),
                     "repeats": (len(old[key][1]), len(vals))})
    return rows


def geomean(xs: list[float]) -> float:
    return float(statistics.geometric_mean(xs)) if xs else float("nan")


if __name__ == "__main__":
    suite, folder = sys.argv[1], Path(sys.argv[2])
    rows = compare(folder, suite)
    print(f"{suite}: {len(rows)} rows, geometric mean of new/old time ratios: medians "
          f"{geomean([r['ratio'] for r in rows]):.3f}, fastest repeats "
          f"{geomean([r['ratio_min'] for r in rows]):.3f}, paired repeats "
          f"{geomean([r['ratio_paired'] for r in rows]):.3f}")
    for r in rows:
        unit = "1/(Mev/s)" if r["field"] in RATE_FIELDS else r["field"]
        print(f"| {r['key']} | {unit} | {r['old']:.4g} | {r['new']:.4g} | {r['ratio']:.3f} "
              f"| {r['ratio_min']:.3f} | {r['ratio_paired']:.3f} "
              f"| {r['repeats'][0]}/{r['repeats'][1]} |")
