"""What the map's approximate feature search trades: time a query against how many of its nearest
neighbours the inverted file finds, at several probe settings (features.search_probes and
search_probes_nearest), on a map tiled as regor-bench --map-scaling tiles it.

For each setting the map is prepared with it, every scan query of the sequence is registered (after
one to warm the caches), and the index's nearest neighbour of a query's first keypoints is compared
with an exact pass over every map keypoint. What registration needs of the search is its right
matches, not every exact nearest neighbour: so the script also counts, over every query, the
keypoints whose nearest map keypoint in feature space lies within the inlier threshold of where
the true pose puts them (on any copy of the map). Times are in-process, so compare settings within
one run on a quiet machine.

Usage: python lab/map_probes.py SEQUENCE_FOLDER TILES OUT.json [PROBES/NEAREST ...]
(default settings: 128/64 64/32 32/16)
"""
import json
import sys
from pathlib import Path

import numpy as np

from regor_ros.bench.datasets import load_sequence, tiled
from regor_ros.core import RegorConfig, is_success, prepare_cloud, register, transform_points, warm_up

RECALL_KEYPOINTS = 2000   # a query's first keypoints whose nearest neighbour is checked exactly
EXACT_BLOCK = 500         # query rows per exact product (the map's similarities, a block at a time)

folder, tiles, out_path = Path(sys.argv[1]), int(sys.argv[2]), Path(sys.argv[3])
settings = [tuple(int(v) for v in s.split("/")) for s in sys.argv[4:]] or [(128, 64), (64, 32), (32, 16)]
warm_up()
cloud, trajectory, queries = load_sequence(folder)
big, poses = tiled(cloud, tiles)
map_trajectory = None if trajectory is None else np.concatenate([P @ trajectory for P in poses])
scans = [q for q in queries if q.kind == "scan"]
rows = []
for probes, nearest in settings:
    config = RegorConfig.preset("outdoor").replace({"features.search_probes": probes,
                                                    "features.search_probes_nearest": nearest})
    prepared = prepare_cloud(big, config, "map", trajectory=map_trajectory)
    register(scans[0].scan, prepared, config)
    seconds, matching, correct, published, right = [], [], 0, 0, 0
    for i, query in enumerate(scans):
        source = prepare_cloud(query.scan, config, "source")
        if i == len(scans) // 2:   # the query whose first keypoints the exact pass checks (below)
            recall_features = source.features[:RECALL_KEYPOINTS]
        matched = prepared.points[np.maximum(prepared.index.search(source.features, 1)[0][:, 0], 0)]
        near = np.zeros(len(matched), dtype=bool)
        for P in poses:
            near |= np.linalg.norm(transform_points(P @ query.truth, source.points) - matched, axis=1) \
                < config.initial.inlier_threshold
        right += int(near.sum())
        result = register(query.scan, prepared, config)
        seconds.append(result.timings["total"])
        matching.append(result.timings["matching"])
        success = any(is_success(result.transform, P @ query.truth, "outdoor") for P in poses)
        correct += success
        published += success and result.accepted
    found = prepared.index.search(recall_features, 1)[0][:, 0]
    exact = np.concatenate([np.argmax(recall_features[i:i + EXACT_BLOCK] @ prepared.features.T, axis=1)
                            for i in range(0, len(recall_features), EXACT_BLOCK)])
    rows.append({"probes": probes, "nearest_probes": nearest, "median_seconds": float(np.median(seconds)),
                 "median_matching_seconds": float(np.median(matching)), "queries": len(scans), "correct": correct,
                 "published_correct": published, "right_matches": right,
                 "nearest_recall": float(np.mean(found == exact))})
    print(f"probes {probes}/{nearest}: median {rows[-1]['median_seconds']:.3f} s a query (matching "
          f"{rows[-1]['median_matching_seconds']:.3f} s), correct {correct} of {len(scans)}, published {published}, "
          f"right matches {right}, "
          f"the exact nearest neighbour found for {100 * rows[-1]['nearest_recall']:.1f} % of keypoints")
out_path.write_text(json.dumps({"sequence": folder.name, "tiles": tiles, "map_keypoints": len(prepared),
                                "rows": rows}, indent=1))
