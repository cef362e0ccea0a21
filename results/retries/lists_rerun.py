"""The 3DMatch / 3DLoMatch pairs whose verdict the fix can change, registered again with the
fixed retries (acceptance.retries=3), and the full lists' figures before and after the fix.

A retry now publishes only another place than the first attempt's. Attempts are deterministic, so
a pair no retry published before the fix (before_fix/rejected_pairs_retry3.csv: the pairs the
shipped preset withheld, with retries) runs the same attempts to the same verdict after it; only a
pair a retry published can change. This registers exactly those, writes them to
lists_rerun.csv, and prints each list's figures: the shipped preset's (results/singled_out), with
retries before the fix and after it. Run from the repository: python results/retries/lists_rerun.py
"""
import csv
import sys
from pathlib import Path

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig, is_gross  # noqa: E402
from regor_ros.tools.threedmatch_benchmark import THREEDMATCH_FIELDS, Fragments, entry_rows, load_list  # noqa: E402

DATA = Path("../shared/data/threedmatch")
SHIPPED = Path("results/singled_out/threedmatch/threedmatch.csv")
BEFORE = Path("results/retries/before_fix/rejected_pairs_retry3.csv")
AFTER = Path("results/retries/lists_rerun.csv")


def rows_by_pair(path: Path) -> dict:
    return {(r["bench"], r["pair"]): r for r in csv.DictReader(open(path)) if r["method"] == "regor"}


def figures(rows: list[dict]) -> str:
    correct = sum(r["success"] == "True" for r in rows)
    shown = [r for r in rows if r["accepted"] == "True"]
    wrong = [r for r in shown if r["success"] != "True"]
    right = len(shown) - len(wrong)
    gross = sum(is_gross(float(r["rotation_error_deg"]), float(r["translation_error_m"]), "indoor") for r in wrong)
    return (f"RR {100 * correct / len(rows):.1f} %, published correct {right} "
            f"({100 * right / correct:.1f} % of correct), WRONG {len(wrong)} (gross {gross})")


if __name__ == "__main__":
    shipped, before = rows_by_pair(SHIPPED), rows_by_pair(BEFORE)
    if not AFTER.is_file():
        entries = {(e["bench"], e["name"]): e for e in load_list(DATA, None, None)}
        config, fragments = RegorConfig.preset("indoor").replace({"acceptance.retries": 3}), Fragments(DATA)
        with open(AFTER, "w", newline="") as handle:
            writer = csv.DictWriter(handle, THREEDMATCH_FIELDS, extrasaction="ignore")
            writer.writeheader()
            for key, row in before.items():
                if row["accepted"] == "True":
                    writer.writerows(entry_rows(entries[key], fragments, ["regor"], config))
    after = {**before, **rows_by_pair(AFTER)}
    for bench in ("3DMatch", "3DLoMatch"):
        print(f"{bench}: shipped (retries 0): {figures([r for k, r in shipped.items() if k[0] == bench])}")
        for name, retried in (("before the fix", before), ("after the fix", after)):
            rows = [retried.get(k, r) for k, r in shipped.items() if k[0] == bench]
            print(f"{bench}: retries 3, {name}: {figures(rows)}")
