"""The outdoor preset with estimation.visible_candidates 0 and 8, alternating query by query in one
process: every query of maps/ and revisit/, single, thinned to every 4th point, and fused.

Run from the repository root with the package's environment:
    python results/visible_candidates_outdoor/alternate.py ../shared/data
"""
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig, prepare_cloud, register  # noqa: E402
from regor_ros.core.metrics import is_success  # noqa: E402
from regor_ros.tools.map_benchmark import load_sequence  # noqa: E402

INPUTS = ("single", "thinned", "sequence")


def main(data: Path):
    base = RegorConfig.preset("outdoor")
    configs = {count: base.replace({"estimation.visible_candidates": count}) for count in (0, 8)}
    rows = []
    folders = [p for p in sorted((data / "maps").iterdir()) if p.is_dir()] + [data / "revisit" / "avia_hku2_loop"]
    for folder in folders:
        points, trajectory, queries = load_sequence(folder)
        target = prepare_cloud(points, base, "map", trajectory=trajectory)
        for n, query in enumerate(queries):
            for which in INPUTS:
                source = query.cloud(which)
                if source is None:
                    continue
                for count in ((8, 0) if n % 2 else (0, 8)):
                    start = time.perf_counter()
                    result = register(source, target, configs[count])
                    seconds = time.perf_counter() - start
                    right = is_success(result.transform, query.truth, "outdoor")
                    rows.append((folder.name, query.id, which, count, right, result.accepted, seconds, result.selected))
    for which in INPUTS:
        for count in (0, 8):
            runs = [r for r in rows if r[2] == which and r[3] == count]
            print(f"{which} visible_candidates={count}: found {sum(r[4] for r in runs)}, published correct "
                  f"{sum(r[4] and r[5] for r in runs)}, WRONG {sum(r[5] and not r[4] for r in runs)} of {len(runs)}; "
                  f"median {np.median([r[6] for r in runs]):.2f} s")
    paired = {}
    for r in rows:
        paired.setdefault(r[:3], {})[r[3]] = r
    for key, by in paired.items():
        if by[0][4:6] != by[8][4:6]:
            print("changed:", *key, "found", by[0][4], "->", by[8][4], "published", by[0][5], "->", by[8][5],
                  "selected", by[8][7])


if __name__ == "__main__":
    main(Path(sys.argv[1]))
