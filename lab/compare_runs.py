"""Whether two regor-bench runs came to the same thing: every CSV of one output folder against the
same CSV of the other, row by row, every column but the timings and the peak memory (which a
machine's load moves). For a change that must not move a verdict, a pose or a figure; with
``--tolerance REL``, for one that sums in another order: numbers within REL of each other (relative)
count as the same, and the largest relative difference is printed. With ``--verdicts``, for a
change that may move poses: each method's tally (runs, correct, published correct, published
wrong) before and after, and every run whose verdict moved, matched by its name, not its row.

Either side's CSVs may be compressed (.csv.gz, as results/ keeps them).

Usage: python lab/compare_runs.py [--tolerance REL | --verdicts] BEFORE_DIR AFTER_DIR
(exit 1 when any row differs; with --verdicts, when any verdict does)
"""
import argparse
import csv
import math
from pathlib import Path

from regor_ros.bench.results import open_run, run_files, same_run


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
    old, new = (list(csv.DictReader(open_run(p))) for p in (before, after))
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


RUN = ("bench", "seed", "pair", "map", "query", "input", "method")   # the columns that name a run


def verdict(row: dict) -> str:
    return ("correct" if row["success"] == "True" else "wrong") + (", published" if row["accepted"] == "True"
                                                                    else ", withheld")


def tally(rows: list[dict]) -> str:
    correct = sum(r["success"] == "True" for r in rows)
    published = sum(r["success"] == "True" and r["accepted"] == "True" for r in rows)
    wrong = sum(r["success"] != "True" and r["accepted"] == "True" for r in rows)
    return f"{len(rows)} runs, {correct} correct, {published} published correct, {wrong} published wrong"


def verdict_changes(before: Path, after: Path) -> tuple[list[str], int]:
    """(each method's tally before -> after, then every run in both whose verdict moved; how many
    moved)."""
    if not after.exists():
        return ["  (no such file)"], 1
    old, new = ({tuple(r.get(c, "") for c in RUN): r for r in csv.DictReader(open_run(p))} for p in (before, after))
    lines = [f"  {m}: {tally([r for k, r in old.items() if k[-1] == m])} -> "
             f"{tally([r for k, r in new.items() if k[-1] == m])}" for m in sorted({k[-1] for k in old})]
    moved = [key for key in sorted(old.keys() & new.keys()) if verdict(old[key]) != verdict(new[key])]
    for key in moved:
        a, b = old[key], new[key]
        why = f" ({b['failed_check']})" if b["accepted"] != "True" and b.get("failed_check") else ""
        lines.append(f"  {' '.join(part for part in key if part)}: {verdict(a)} -> {verdict(b)}{why}; "
                     f"{float(a['rotation_error_deg']):.1f} -> {float(b['rotation_error_deg']):.1f} deg")
    return lines, len(moved)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    compared = parser.add_mutually_exclusive_group()
    compared.add_argument("--tolerance", type=float, default=0.0, help="relative difference two numbers may have")
    compared.add_argument("--verdicts", action="store_true", help="compare verdicts, not figures")
    args = parser.parse_args()
    same = True
    for path in run_files(args.before):
        counterpart = same_run(path, args.after / path.parent.relative_to(args.before))
        if args.verdicts:
            lines, moved = verdict_changes(path, counterpart)
            same &= not moved
            print(f"{path.relative_to(args.before)}:", *lines, sep="\n")
            continue
        rows = sum(1 for _ in open_run(path)) - 1
        largest = [0.0]
        diff = differences(path, counterpart, args.tolerance, largest)
        same &= not diff
        within = f", numbers within {largest[0]:.1e} of each other" if largest[0] else ""
        print(f"{path.relative_to(args.before)}: {rows} rows, "
              + (f"identical (timings and memory aside{within})" if not diff else f"differ: {diff}"))
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
