"""Fused queries of the shared maps with each older scan's odometry turned by a few degrees (a
hand-held sensor's deskew and odometry error), registered with their views read as wide as their
scans disagree (core/shake.py) and, in the same run, read as a steady sequence's.

    PYTHONPATH=. python results/shake/shaken.py ../shared/data [degrees ...]   (from the repository, set up)

Prints one line per query and a summary per shake; writes shaken.csv beside this file.
"""
import csv
import sys
from pathlib import Path

import numpy as np

from regor_ros.core import RegorConfig, prepare_cloud, register
from regor_ros.core.features import prepare
from regor_ros.core.metrics import is_success
from regor_ros.tools.map_benchmark import load_sequence, shaken

OUTDOOR = RegorConfig.preset("outdoor")


def main(data: Path, shakes: list[float]) -> None:
    rows = []
    for folder in sorted(p for p in (data / "maps").iterdir() if (p / "queries.json").exists()):
        cloud, trajectory, queries = load_sequence(folder)
        target = prepare_cloud(cloud, OUTDOOR, "map", trajectory=trajectory)
        for degrees in shakes:
            rng = np.random.default_rng(0)
            for query in queries:
                if query.history is None or len(query.history.scans) < 2:
                    continue
                sequence = shaken(query.history, degrees, rng)
                read_wide = prepare_cloud(sequence, OUTDOOR, "scans")
                as_steady = prepare(sequence.fused(), OUTDOOR.features, "scans")
                for name, source in (("as steady", as_steady), ("read wide", read_wide)):
                    result = register(source, target, OUTDOOR)
                    correct = is_success(result.transform, query.truth, "outdoor")
                    row = dict(map=folder.name, query=query.id, shake_deg=degrees, read=name,
                               shake_bins=source.shake_bins, correct=correct, published=result.accepted,
                               free_space=result.visibility.worst, reason=result.reason[:80])
                    rows.append(row)
                    print(" ".join(str(v) for v in row.values()), flush=True)
    with open(Path(__file__).with_name("shaken.csv"), "w", newline="") as out:
        writer = csv.DictWriter(out, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    for degrees in shakes:
        for name in ("as steady", "read wide"):
            group = [r for r in rows if r["shake_deg"] == degrees and r["read"] == name]
            print(f"shake {degrees:g} deg, {name}: {len(group)} queries, {sum(r['correct'] for r in group)} correct, "
                  f"{sum(r['correct'] and r['published'] for r in group)} published correct, "
                  f"{sum(r['published'] and not r['correct'] for r in group)} published WRONG")


if __name__ == "__main__":
    main(Path(sys.argv[1]), [float(v) for v in sys.argv[2:]] or [0.0, 2.0, 3.0])
