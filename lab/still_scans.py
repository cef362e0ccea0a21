"""Does the scans' own check of rest (core.was_still, what the node fuses at rest without odometry)
say "still" for a robot that moved? And "moved" for one that did not?

Every pair of consecutive scans the shared sequences hold (each step a robot in motion, by their
SLAM poses): how many are said still (each would be fused at identity, smeared). Then every query
scan split into two random halves (the same place, two samplings, as a resting sensor's frames):
how many are said still. Prints the counts per sequence and the moving pairs' odometry steps.

    python lab/still_scans.py ../shared/data/maps ../shared/data/revisit ../shared/data/xseason
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from regor_ros.bench.datasets import consecutive_scans, load_sequence, sequence_folders
from regor_ros.core import RegorConfig, was_still


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folders", type=Path, nargs="+", help="folders of sequence folders (queries.json)")
    args = parser.parse_args()
    features = RegorConfig.preset("outdoor").features
    voxel, radius = features.voxel_size, features.normal_radius
    print("| sequence | consecutive pairs (moving) | said still | their odometry steps, m | halves of a scan "
          "| said still |")
    print("|---|---|---|---|---|---|")
    for folder in sequence_folders(args.folders):
        _, _, queries = load_sequence(folder)
        moving = consecutive_scans(queries)
        moving_still = sum(was_still(a, b, voxel, radius).still for a, b, _ in moving)
        steps = [step for *_, step in moving]
        halves = 0
        for query in queries:
            order = np.random.default_rng(0).permutation(len(query.scan))
            half = len(order) // 2
            halves += was_still(query.scan[order[:half]], query.scan[order[half:]], voxel, radius).still
        print(f"| {folder.name} | {len(moving)} | {moving_still} | {min(steps):.2f}-{max(steps):.2f} | "
              f"{len(queries)} | {halves} |", flush=True)


if __name__ == "__main__":
    main()
