"""Would more of the narrow views be found and published with a hint at where the truth is, or
with features at another scale? (A hint keeps every map keypoint the view can reach from near the
truth, which on the shared maps is nearly all of them: it does not bound a search over the map's
own places; results/narrow_levers/README.md.)

Each query scan of one sequence folder, seen by a narrow sensor as ``regor-bench --narrow`` sees it
(map_benchmark.narrow_view), registered against the map prepared once, as the benchmark does;
with ``--region R`` the search is limited to the map keypoints the view can overlap from within
R metres of its true position (register's search_region: a hint, as an operator's), and with
``--set name=value`` the preset is changed (for both the map and the views). Prints a line per
view and the counts: found (right within the outdoor success tolerance), published, published
wrong.

    python lab/narrow_levers.py ../shared/data/xseason/eth_gazebo_summer_winter
    python lab/narrow_levers.py ../shared/data/xseason/eth_gazebo_summer_winter --region 10
    python lab/narrow_levers.py ../shared/data/xseason/eth_gazebo_summer_winter --set features.fpfh_radius=2.25
"""
from __future__ import annotations

import argparse
from pathlib import Path

from regor_ros.bench.datasets import NARROW_INPUTS, load_sequence
from regor_ros.core import RegistrationError, RegorConfig, SearchRegion, is_success, prepare_cloud, register, warm_up


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=Path, help="a sequence folder (map.npy, queries.json, ...)")
    parser.add_argument("--region", type=float, default=None, help="search within this many metres of the truth")
    parser.add_argument("--set", nargs="*", default=[], help="preset changes, name=value")
    args = parser.parse_args()
    warm_up()
    config = RegorConfig.preset("outdoor").replace(dict(item.split("=", 1) for item in args.set))
    cloud, trajectory, queries = load_sequence(args.sequence)
    prepared = prepare_cloud(cloud, config, "map", trajectory=trajectory)
    views = found = published = wrong = 0
    for query in queries:
        for which in NARROW_INPUTS:
            view = query.cloud(which)
            if view is None:
                continue
            views += 1
            region = None if args.region is None else SearchRegion.checked(query.truth[:3, 3], args.region)
            try:
                result = register(view, prepared, config, search_region=region)
            except RegistrationError as exc:
                print(f"{query.id} {which}: {exc}")
                continue
            right = is_success(result.transform, query.truth, "outdoor")
            found += right
            published += right and result.accepted
            wrong += result.accepted and not right
            print(f"{query.id} {which}: {'right' if right else 'wrong'}, "
                  f"{'published' if result.accepted else 'withheld: ' + result.reason[:70]}", flush=True)
    print(f"{views} views: found {found}, published {published}, published wrong {wrong}")


if __name__ == "__main__":
    main()
