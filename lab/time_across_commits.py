"""Time one source tree of regor_ros on the lists' 200-pair sample, as regor-bench times a pair.

regor-bench compares methods within one tree; this compares commits. Each tree is a `git archive`
of a commit, run in turn on the same quiet machine, twice each, alternating (README.md). The pairs
are regor-bench --threedmatch --sample 200's (sample200.json), FPFH included, seed 0, viewpoints at
the fragments' origins, as the benchmark runs them.

Usage: python lab/time_across_commits.py TREE DATA SAMPLE.json OUT.json
(TREE: the source tree; DATA: ../shared/data/threedmatch; SAMPLE: the pairs, as
results/singled_out/time/sample200.json)
"""
import json
import sys
import time
from pathlib import Path

tree, data, sample, out_path = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4])
sys.path.insert(0, tree)

import numpy as np  # noqa: E402

import regor_ros  # noqa: E402
from regor_ros.core import (  # noqa: E402
    RegorConfig,
    for_clouds_seen_from,
    prepare_cloud,
    register,
    rotation_error_deg,
    translation_error,
)

assert regor_ros.__file__.startswith(tree), f"imported {regor_ros.__file__}, not the tree's"
ORIGIN = np.zeros(3)
config = for_clouds_seen_from(RegorConfig.preset("indoor").replace({"seed": 0}), ORIGIN, ORIGIN)
rows = []
for entry in json.loads(sample.read_text()):
    folder = data / entry["scene"]
    source, target = np.load(folder / f"{entry['j']}.npy"), np.load(folder / f"{entry['i']}.npy")
    start = time.perf_counter()
    result = register(prepare_cloud(source, config, "source", viewpoint=ORIGIN),
                      prepare_cloud(target, config, "target", viewpoint=ORIGIN), config)
    seconds = time.perf_counter() - start
    truth = np.asarray(entry["T"])
    rotation, translation = rotation_error_deg(result.transform, truth), translation_error(result.transform, truth)
    rows.append({"name": entry["name"], "bench": entry["bench"], "ok": bool(rotation < 15 and translation < 0.3),
                 "acc": bool(result.accepted), "t": seconds, "re": float(rotation), "te": float(translation)})
out_path.write_text(json.dumps(rows))
for bench in ("3DMatch", "3DLoMatch"):
    group = [r for r in rows if r["bench"] == bench]
    print(f"  {bench}: RR {100 * np.mean([r['ok'] for r in group]):.1f} %, published correct "
          f"{sum(r['ok'] and r['acc'] for r in group)}, wrong {sum(r['acc'] and not r['ok'] for r in group)}")
print(f"{tree}: median {np.median([r['t'] for r in rows]):.3f} s over {len(rows)} pairs")
