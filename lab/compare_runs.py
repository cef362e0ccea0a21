"""Whether two regor-bench runs came to the same thing: every CSV of one output folder against the
same CSV of the other, row by row, every column but the timings and the peak memory (which a
machine's load moves). For a change that must not move a verdict, a pose or a figure.

Usage: python lab/compare_runs.py BEFORE_DIR AFTER_DIR   (exit 1 when any row differs)
"""
import csv
import sys
from pathlib import Path


def machine_dependent(column: str) -> bool:
    return "seconds" in column or column.endswith("_s") or "time" in column or "memory" in column


def differences(before: Path, after: Path) -> dict[str, int]:
    """Column -> rows that differ (a missing file or a row count that differs: one entry)."""
    if not after.exists():
        return {"(no such file)": 1}
    old, new = list(csv.DictReader(before.open())), list(csv.DictReader(after.open()))
    if len(old) != len(new):
        return {f"(rows: {len(old)} against {len(new)})": 1}
    counts: dict[str, int] = {}
    for a, b in zip(old, new, strict=True):
        for column, value in a.items():
            if not machine_dependent(column) and value != b.get(column):
                counts[column] = counts.get(column, 0) + 1
    return counts


def main() -> int:
    before, after = Path(sys.argv[1]), Path(sys.argv[2])
    same = True
    for path in sorted(before.rglob("*.csv")):
        rows = sum(1 for _ in path.open()) - 1
        diff = differences(path, after / path.relative_to(before))
        same &= not diff
        print(f"{path.relative_to(before)}: {rows} rows, " + ("identical (timings and memory aside)" if not diff
                                                                else f"differ: {diff}"))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
