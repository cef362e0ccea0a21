"""The 3DMatch / 3DLoMatch pairs the shipped preset withheld, registered again with
acceptance.retries=N (a scratch run, 2026-11-29, on 2cd0ced: before a retry was held to another
place than the first attempt's). A retry runs only after a rejection, and a pair's first attempt
is deterministic, so these rows replace the withheld rows of results/singled_out's run and every
other row stands as it is. To reproduce these rows, copy it into a checkout of 2cd0ced and run it
there: python retry_rejected_pairs.py 3 OUT.csv (on later code it gives the fixed retries' rows).
"""
import csv
import sys
from multiprocessing import Pool
from pathlib import Path

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig  # noqa: E402
from regor_ros.tools.pairs_benchmark import evaluate_pair  # noqa: E402
from regor_ros.tools.threedmatch_benchmark import THREEDMATCH_FIELDS, Fragments, as_pair, load_list  # noqa: E402

DATA = Path("../shared/data/threedmatch")
BEFORE = Path("results/singled_out/threedmatch/threedmatch.csv")
fragments = None


def run(entry):
    global fragments
    fragments = fragments or Fragments(DATA)
    rows = evaluate_pair(as_pair(entry, fragments), ["regor"], CONFIG, None)
    return [{**row, "bench": entry["bench"]} for row in rows]


retries, out = int(sys.argv[1]), sys.argv[2]
CONFIG = RegorConfig.preset("indoor").replace({"acceptance.retries": retries})

if __name__ == "__main__":
    withheld = {(r["bench"], r["pair"]) for r in csv.DictReader(open(BEFORE))
                if r["method"] == "regor" and r["accepted"] != "True"}
    entries = [e for e in load_list(DATA, None, None) if (e["bench"], e["name"]) in withheld]
    with Pool(2) as pool, open(out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, THREEDMATCH_FIELDS, extrasaction="ignore")
        writer.writeheader()
        for rows in pool.imap(run, entries, chunksize=4):
            writer.writerows(rows)
