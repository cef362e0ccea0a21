"""Whether two regor-bench runs came to the same thing: every CSV of one output folder against the
same CSV of the other, row by row, every column but the timings and the peak memory (which a
machine's load moves). For a change that must not move a verdict, a pose or a figure; with
``--tolerance REL``, for one that sums in another order: numbers within REL of each other (relative)
count as the same, and the largest relative difference is printed.

Usage: python lab/compare_runs.py [--tolerance REL] BEFORE_DIR AFTER_DIR   (exit 1 when any row differs)
"""
import argparse
import csv
import math
from pathlib import Path


def machine_dependent(column: str) -> bool:
    return "seconds" in column or column.endswith("_s") or "time" in column or "memory" in column


def relative_difference(a: str, b: str) -> float:
    """How far apart two cells are, relative to the larger; inf unless both are numbers."""
    try:
        x, y = float(a), float(b)
    except ValueError:
        return math.inf
    if x == y or (math.isnan(x) and math.isnan(y)):
        return 0.0
    return abs(x - y) / max(abs(x), abs(y))


def differences(before: Path, after: Path, tolerance: float, largest: list) -> dict[str, int]:
    """Column -> rows that differ (a missing file or a row count that differs: one entry);
    ``largest`` gets the largest relative difference within the tolerance."""
    if not after.exists():
        return {"(no such file)": 1}
    old, new = list(csv.DictReader(before.open())), list(csv.DictReader(after.open()))
    if len(old) != len(new):
        return {f"(rows: {len(old)} against {len(new)})": 1}
    counts: dict[str, int] = {}
    for a, b in zip(old, new, strict=True):
        for column, value in a.items():
            other = b.get(column)
            if machine_dependent(column) or value == other:
                continue
            apart = relative_difference(value, other or "")
            if apart > tolerance:
                counts[column] = counts.get(column, 0) + 1
            else:
                largest[0] = max(largest[0], apart)
    return counts


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--tolerance", type=float, default=0.0, help="relative difference two numbers may have")
    args = parser.parse_args()
    same = True
    for path in sorted(args.before.rglob("*.csv")):
        rows = sum(1 for _ in path.open()) - 1
        largest = [0.0]
        diff = differences(path, args.after / path.relative_to(args.before), args.tolerance, largest)
        same &= not diff
        within = f", numbers within {largest[0]:.1e} of each other" if largest[0] else ""
        print(f"{path.relative_to(args.before)}: {rows} rows, "
              + (f"identical (timings and memory aside{within})" if not diff else f"differ: {diff}"))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
