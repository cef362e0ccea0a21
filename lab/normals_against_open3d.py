"""Are the normals a cloud is prepared with Open3D's, to the bit, on every shared cloud?

prepare_cloud computes them on both cores in Open3D's arithmetic (features.surface_normals). This
takes each cloud as the benchmarks prepare it (the 3DMatch fragments under the indoor preset seen
from their origins; each pair's clouds under their kind's preset, from their own viewpoints or
none; the maps with their trajectories, so their normals face the nearest position; the maps'
query scans from their origins), asks Open3D's ``estimate_normals`` for the normals of the same
keypoints, turns them the same way, and counts the keypoints whose normal differs in any bit.

Usage: python lab/normals_against_open3d.py DATA OUT.json   (DATA: ../shared/data)
"""
import json
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from regor_ros.bench.datasets import load_pairs, load_sequence
from regor_ros.core import RegorConfig, prepare_cloud

data, out_path = Path(sys.argv[1]), Path(sys.argv[2])
ORIGIN = np.zeros(3)


def clouds():
    """(set, name, points, preset, viewpoint, trajectory) of every cloud to check."""
    for path in sorted((data / "threedmatch").glob("*/*.npy")):
        yield "threedmatch", f"{path.parent.name}/{path.name}", np.load(path), "indoor", ORIGIN, None
    for folder in ("pairs", "pairs_scenes", "pairs_hard"):
        for pair in load_pairs(data / folder, None):
            yield folder, f"{pair.name}/src", pair.src, pair.kind, pair.src_viewpoint, None
            yield folder, f"{pair.name}/tgt", pair.tgt, pair.kind, pair.tgt_viewpoint, None
    for folder in ("maps", "revisit", "xseason"):
        for sequence in sorted(p for p in (data / folder).iterdir() if p.is_dir()):
            cloud, trajectory, queries = load_sequence(sequence)
            yield folder, f"{sequence.name}/map", cloud, "outdoor", None, trajectory
            for query in queries:
                yield folder, f"{sequence.name}/{query.id}", query.scan, "outdoor", ORIGIN, None


counts = {}
for subset, name, points, preset, viewpoint, trajectory in clouds():
    config = RegorConfig.preset(preset)
    prepared = prepare_cloud(points[:, :3].astype(np.float64), config, name, viewpoint=viewpoint,
                             trajectory=trajectory)
    keypoints = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(prepared.points))
    keypoints.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=config.features.normal_radius,
                                                                     max_nn=config.features.normal_max_nn))
    theirs = np.asarray(keypoints.normals)
    if prepared.normals_toward_sensors:
        sensors = viewpoint[None] if trajectory is None else np.asarray(trajectory)[:, :3, 3]
        toward = sensors[cKDTree(sensors).query(prepared.points)[1]] - prepared.points
        theirs = np.where(((toward * theirs).sum(axis=1) < 0)[:, None], -theirs, theirs)
    differ = int((~(prepared.normals == theirs).all(axis=1)).sum())
    tally = counts.setdefault(subset, {"clouds": 0, "keypoints": 0, "differ": 0, "clouds_differing": []})
    tally["clouds"] += 1
    tally["keypoints"] += len(prepared.points)
    tally["differ"] += differ
    if differ:
        tally["clouds_differing"].append(name)
    print(f"{subset} {name}: {len(prepared.points)} keypoints, {differ} differ", flush=True)
out_path.write_text(json.dumps(counts, indent=1) + "\n")
print(json.dumps({subset: {k: v for k, v in tally.items() if k != "clouds_differing"}
                  for subset, tally in counts.items()}))
