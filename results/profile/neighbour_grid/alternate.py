"""Old (scipy's kd-tree) and new (hashed grid) nearest-keypoint search, alternating in one process.

Run from the repository root with the package's environment:
    python results/profile/neighbour_grid/alternate.py pairs 60
    python results/profile/neighbour_grid/alternate.py maps ../shared/data/maps
Prints each version's median seconds (and the stages the search is in) and every verdict or pose
that differs between them.
"""
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig, prepare_cloud, register  # noqa: E402
from regor_ros.core import cloud as cloud_module  # noqa: E402
from regor_ros.core.neighbour_grid import NeighbourGrid  # noqa: E402
from regor_ros.tools.map_benchmark import load_sequence  # noqa: E402
from regor_ros.tools.threedmatch_benchmark import Fragments, load_list  # noqa: E402


class KdTree:
    """The search as it was: scipy's kd-tree, split over both cores for large queries."""

    def __init__(self, points):
        self.points, self.tree = points, cKDTree(points)

    def nearest_within(self, queries, threshold):
        return self.tree.query(queries, distance_upper_bound=threshold, workers=2 if len(queries) >= 8192 else 1)


VERSIONS = {"grid": NeighbourGrid, "kd-tree": KdTree}


def use(version):
    cloud_module.PreparedCloud.neighbours = property(
        lambda self: self.__dict__.setdefault("_search_" + version, VERSIONS[version](self.points)))


def jobs(kind, where):
    """(name, source, target, preset) to register, the target prepared once for maps."""
    if kind == "pairs":
        data = Path("../shared/data/threedmatch")
        fragments = Fragments(data)
        for e in load_list(data, int(where), None):
            yield e["name"], fragments(e["scene"], e["j"]), fragments(e["scene"], e["i"]), "indoor"
        return
    config = RegorConfig.preset("outdoor")
    for folder in sorted(p for p in Path(where).iterdir() if p.is_dir()):
        points, trajectory, queries = load_sequence(folder)
        target = prepare_cloud(points, config, "map", trajectory=trajectory)
        for q in queries:
            for which in ("single", "sequence"):
                if q.cloud(which) is not None:
                    yield f"{q.id} {which}", q.cloud(which), target, "outdoor"


def main(kind, where):
    seconds = {v: [] for v in VERSIONS}
    stages = {v: [] for v in VERSIONS}
    for n, (name, source, target, preset) in enumerate(jobs(kind, where)):
        poses = {}
        for version in (["grid", "kd-tree"] if n % 2 else ["kd-tree", "grid"]):
            use(version)
            start = time.perf_counter()
            result = register(source, target, RegorConfig.preset(preset))
            seconds[version].append(time.perf_counter() - start)
            stages[version].append(result.timings["estimation"] + result.timings["verification"])
            poses[version] = (result.accepted, result.transform)
        (a, A), (b, B) = poses["grid"], poses["kd-tree"]
        if a != b or np.abs(A - B).max() > 1e-9:
            print("differs:", name, a, b, np.abs(A - B).max())
    for version in VERSIONS:   # the first registration compiles and loads: left out
        print(f"{version}: median {np.median(seconds[version][1:]):.3f} s "
              f"(estimation + verification {np.median(stages[version][1:]):.3f} s), {len(seconds[version])} runs")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
