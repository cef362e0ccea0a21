"""The cross-place runs whose verdict the fix can change, registered again with the fixed retries.

A retry now publishes only another place than the first attempt's. A run's attempts are
deterministic, so a run in which no retry was accepted before the fix (before_fix/mismatched.csv)
runs the same attempts to the same verdict after it; only a run in which a retry was accepted can
change (the fix may refuse that place and go on). This registers exactly those runs, built as
regor-bench --mismatched builds them (the same pairs, selection and motions). Run from the
repository: python results/retries/cross_place_rerun.py
"""
import csv
import sys
from pathlib import Path

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig  # noqa: E402
from regor_ros.tools.pairs_benchmark import cross_place_pairs, evaluate_pair, load_pairs  # noqa: E402

DATA = [Path("../shared/data") / name for name in ("pairs", "pairs_scenes", "pairs_hard")]
BEFORE = Path("results/retries/before_fix/mismatched.csv")

accepted = {(r["seed"], r["pair"]) for r in csv.DictReader(open(BEFORE)) if r["accepted"] == "True"}
pairs = [p for folder in DATA for p in load_pairs(folder, "3dmatch")]
config = RegorConfig.preset("indoor").replace({"acceptance.retries": 3})
for seed in sorted({int(s) for s, _ in accepted}):
    for pair in cross_place_pairs(pairs, seed):
        if (str(seed), pair.name) in accepted:
            moved = pair.moved(seed)
            row = evaluate_pair(moved, ["regor"], moved.configured(config), seed)[0]
            print(f"seed {seed} {pair.name}: accepted before the fix; now accepted={row['accepted']}, "
                  f"{row['attempts']} attempts, failed check {row['failed_check'] or '-'}")
