"""Old (Open3D's tensor FPFH) and new (compiled, kernels.fpfh_features) descriptors, alternating
in one process.

Run from the repository root with the package's environment:
    python results/profile/fpfh/alternate.py pairs 60
    python results/profile/fpfh/alternate.py maps ../shared/data/maps
Prints each version's median seconds per registration (features included for pairs; a map is
prepared once per version, its preparation timed) and every verdict that differs between them,
with the pose's distance between the versions.
"""
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d

sys.path.insert(0, ".")
from regor_ros.core import RegorConfig, prepare_cloud, register, rotation_error_deg, translation_error  # noqa: E402
from regor_ros.core import features as features_module  # noqa: E402
from regor_ros.core.metrics import is_success  # noqa: E402
from regor_ros.tools.map_benchmark import load_sequence  # noqa: E402
from regor_ros.tools.threedmatch_benchmark import Fragments, load_list  # noqa: E402

COMPILED = features_module.fpfh


def open3d_fpfh(points, normals, radius, max_nn):
    """The descriptors as they were: Open3D's tensor FPFH, in one call (the shared maps have fewer
    keypoints than a slab held, 100 k)."""
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
    cloud.point.normals = o3d.core.Tensor(normals)
    return o3d.t.pipelines.registration.compute_fpfh_feature(
        cloud, max_nn=max_nn, radius=radius).numpy().astype(np.float32)


VERSIONS = {"compiled": COMPILED, "open3d": open3d_fpfh}


def use(version):
    features_module.fpfh = VERSIONS[version]


def jobs(kind, where):
    """(name, source, {version: target}, preset, truth or None)."""
    if kind == "pairs":
        data = Path("../shared/data/threedmatch")
        fragments = Fragments(data)
        for e in load_list(data, int(where), None):
            target = fragments(e["scene"], e["i"])
            yield e["name"], fragments(e["scene"], e["j"]), {v: target for v in VERSIONS}, "indoor", np.asarray(e["T"])
        return
    config = RegorConfig.preset("outdoor")
    for folder in sorted(p for p in Path(where).iterdir() if p.is_dir()):
        points, trajectory, queries = load_sequence(folder)
        targets = {}
        for version in VERSIONS:
            use(version)
            start = time.perf_counter()
            targets[version] = prepare_cloud(points, config, "map", trajectory=trajectory)
            print(f"{folder.name}: map prepared with {version} in {time.perf_counter() - start:.2f} s")
        for q in queries:
            for which in ("single", "sequence"):
                if q.cloud(which) is not None:
                    yield f"{q.id} {which}", q.cloud(which), targets, "outdoor", q.truth


def main(kind, where):
    seconds = {v: [] for v in VERSIONS}
    correct = {v: 0 for v in VERSIONS}
    published = {v: 0 for v in VERSIONS}
    for n, (name, source, targets, preset, truth) in enumerate(jobs(kind, where)):
        runs = {}
        for version in (["compiled", "open3d"] if n % 2 else ["open3d", "compiled"]):
            use(version)
            start = time.perf_counter()
            result = register(source, targets[version], RegorConfig.preset(preset))
            seconds[version].append(time.perf_counter() - start)
            good = is_success(result.transform, truth, preset)
            correct[version] += good
            published[version] += good and result.accepted
            runs[version] = (good, result.accepted, result.transform)
        (g1, a1, T1), (g2, a2, T2) = runs["compiled"], runs["open3d"]
        if (g1, a1) != (g2, a2):
            print(f"differs: {name} compiled correct={g1} published={a1}, open3d correct={g2} published={a2}, "
                  f"poses {rotation_error_deg(T1, T2):.2f} deg / {translation_error(T1, T2):.3f} m apart")
    for version in VERSIONS:   # the first registration compiles and loads: left out
        print(f"{version}: median {np.median(seconds[version][1:]):.3f} s, correct {correct[version]}, "
              f"published correct {published[version]}, {len(seconds[version])} runs")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
