"""Time one source tree of regor_ros on the map queries, as regor-bench --maps times a query.

regor-bench compares methods within one tree; this compares commits on a map's queries (see
time_across_commits.py for the lists' pairs). Each tree (a `git archive` of a commit) is run in
turn on the same quiet machine, alternating. Every query of each sequence folder, single and
fused along odometry, is registered against the map prepared once with its trajectory (the
outdoor preset, as regor-bench --maps), after one query to warm the caches; then every other
place's queries against it (`outside`: from outside the map, withheld unless the gate errs), so a
tree's time to withhold is read beside its time to find, on the same map.

Usage: python lab/time_map_queries.py TREE OUT.json SEQUENCE_FOLDER...
"""
import json
import sys
import time
from pathlib import Path

tree, out_path, folders = sys.argv[1], Path(sys.argv[2]), [Path(p) for p in sys.argv[3:]]
sys.path.insert(0, tree)

import numpy as np  # noqa: E402

import regor_ros  # noqa: E402
from regor_ros.bench.datasets import INPUTS, load_sequence, one_place  # noqa: E402
from regor_ros.core import RegorConfig, is_success, prepare_cloud, register, warm_up  # noqa: E402

assert regor_ros.__file__.startswith(tree), f"imported {regor_ros.__file__}, not the tree's"
warm_up()
config = RegorConfig.preset("outdoor")
rows = []
queries_of = {folder: load_sequence(folder)[2] for folder in folders}
for folder in folders:
    cloud, trajectory, _ = load_sequence(folder)
    prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
    register(queries_of[folder][0].scan, prepared, config)
    for origin, queries in queries_of.items():
        if origin != folder and one_place(origin.name, folder.name):
            continue   # another recording of the same place: not outside the map
        for query in queries:
            for which in INPUTS:
                source = query.cloud(which)
                if source is None:
                    continue
                start = time.perf_counter()
                result = register(source, prepared, config)
                rows.append({"map": folder.name, "query": query.id, "input": which,
                             "set": "own" if origin == folder else "outside", "t": time.perf_counter() - start,
                             "ok": origin == folder and bool(is_success(result.transform, query.truth, "outdoor")),
                             "acc": bool(result.accepted)})
out_path.write_text(json.dumps(rows))
for folder in folders:
    for which in INPUTS:
        own = [r for r in rows if r["map"] == folder.name and r["input"] == which and r["set"] == "own"]
        found = [r["t"] for r in own if r["ok"] and r["acc"]]
        withheld = [r["t"] for r in rows if r["map"] == folder.name and r["input"] == which
                    and r["set"] == "outside" and not r["acc"]]
        print(f"{tree} {folder.name} {which}: median {np.median([r['t'] for r in own]):.3f} s over {len(own)}, "
              f"correct {sum(r['ok'] for r in own)}, published correct {len(found)}; found in a median "
              f"{np.median(found):.3f} s, withheld from outside in {np.median(withheld):.3f} s over {len(withheld)}")
