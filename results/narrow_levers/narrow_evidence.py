"""Could the gate's evidence against chance carry more of the narrow views it finds? Two tests of
the withheld views' evidence, neither built (results/narrow_levers/README.md):

- **the feature matches counted at a tighter tolerance** than initial.inlier_threshold: chance
  falls with the tolerance, and a right pose refined at the keypoint spacing should keep its
  matches; the a-contrario false alarms at each tolerance, as core/gate/evidence.py counts them;
- **the surfaces split by their direction**: the surfaces' test (core/gate/surface_evidence.py)
  pools every overlap cell against the best decoy's fraction; if the ground is on the surface
  under any pose that keeps it, the cells off the ground would tell a right pose from its decoys
  where the pooled count does not. Each stratum's cells on the surface under the pose, and the
  best decoy's fraction in it.

Each query scan of one sequence folder, seen by a narrow sensor as ``regor-bench --narrow`` sees it,
registered against the map prepared once. A line per view; then the counts over the views found
and withheld.

It reaches the gate's internals (the counts, the decoys), so it is kept here as the record of
this measurement at 362dad0, not in lab/ (which keeps to the package's public face):

    python results/narrow_levers/narrow_evidence.py ../shared/data/xseason/eth_gazebo_summer_winter
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from regor_ros.core import RegistrationError, RegorConfig, is_success, prepare_cloud, register, warm_up
from regor_ros.core.gate.evidence import (
    MINIMAL_SAMPLE,
    chance_of_agreement,
    independent,
    log10_binomial_tail,
    on_surface,
)
from regor_ros.core.gate.surface_evidence import DECOY_MIN_CELLS, decoys
from regor_ros.core.geometry import transform_points
from regor_ros.core.pipeline import prepare_pair
from regor_ros.tools.map_benchmark import NARROW_INPUTS, load_sequence

TOLERANCES = (0.6, 0.45, 0.3)   # metres: the outdoor preset's initial.inlier_threshold, then tighter
GROUND_DEG = 30.0               # a surface whose normal is within this of vertical is ground


def tail(agreeing: int, matches: int, chance: float) -> float:
    """log10 of the binomial tail beyond the minimal sample (0 when there is nothing beyond it)."""
    beyond = agreeing - MINIMAL_SAMPLE
    return 0.0 if beyond <= 0 else log10_binomial_tail(beyond, matches - MINIMAL_SAMPLE, chance)


def strata(T, source, target, config) -> list[tuple[int, int]]:
    """(cells, cells on the surface) of the overlap under ``T``: all, on the ground, off it."""
    placed = transform_points(T, source.points)
    distance, nearest = target.neighbours.nearest_within(placed, config.estimation.inlier_threshold)
    near = np.isfinite(distance)
    placed, normals = placed[near], target.normals[nearest[near]]
    on = on_surface(placed, target.points[nearest[near]], normals, config.features.voxel_size)
    ground = np.abs(normals[:, 2]) > np.cos(np.radians(GROUND_DEG))
    radius = config.features.fpfh_radius
    out = []
    for mask in (np.ones(len(placed), bool), ground, ~ground):
        cells = len(independent(placed[mask], radius))
        out.append((cells, min(len(independent(placed[mask & on], radius)), cells)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sequence", type=Path, help="a sequence folder (map.npy, queries.json, ...)")
    args = parser.parse_args()
    warm_up()
    config = RegorConfig.preset("outdoor")
    cloud, trajectory, queries = load_sequence(args.sequence)
    target = prepare_cloud(cloud, config, "map", trajectory=trajectory)
    chances = [chance_of_agreement(target.points, target.neighbours, tolerance) for tolerance in TOLERANCES]
    radius = config.features.fpfh_radius
    withheld = []
    for query in queries:
        for which in NARROW_INPUTS:
            view = query.cloud(which)
            if view is None:
                continue
            _, source, _, _ = prepare_pair(view, target, config)
            try:
                result = register(source, target, config)
            except RegistrationError:
                continue
            right = is_success(result.transform, query.truth, "outdoor")
            matches = result.initial.source
            residual = np.linalg.norm(transform_points(result.transform, matches) - result.initial.target, axis=1)
            n = len(independent(matches, radius))
            agreeing = [len(independent(matches[residual < tolerance], radius)) for tolerance in TOLERANCES]
            # the search's hypotheses, out of the recorded figure at the preset's tolerance
            tests = result.figures.log10_false_alarms - tail(agreeing[0], n, chances[0])
            alarms = [tests + tail(k, n, p) for k, p in zip(agreeing, chances, strict=True)]
            pose = strata(result.transform, source, target, config)
            decoy_strata = [strata(D, source, target, config) for D in decoys(result.transform, source, target, config)]
            best = [max((c[k][1] / c[k][0] for c in decoy_strata if c[k][0] >= DECOY_MIN_CELLS / 2), default=np.nan)
                    for k in range(3)]
            print(f"{query.id} {which}: {'right' if right else 'wrong'}, "
                  f"{'published' if result.accepted else 'withheld (' + result.verdict.failed + ')'}; "
                  + ", ".join(f"{k} of {n} agree within {t} m (10^{a:.1f})"
                              for k, t, a in zip(agreeing, TOLERANCES, alarms, strict=True))
                  + "; cells on the surface (best decoy): "
                  + ", ".join(f"{name} {on}/{cells} ({b:.2f})"
                              for name, (cells, on), b in zip(("all", "ground", "other"), pose, best, strict=True)),
                  flush=True)
            if right and not result.accepted and result.verdict.failed == "max_false_alarms":
                withheld.append((alarms, pose, best))
    print(f"{len(withheld)} views found and withheld by chance:")
    for at, tolerance in enumerate(TOLERANCES):
        passing = sum(alarms[at] <= 0 for alarms, _, _ in withheld)
        print(f"  within {tolerance} m: {passing} would pass (10^0 or fewer false alarms)")
    for at, name in enumerate(("all", "ground", "other")):
        fractions = [p[at][1] / p[at][0] for _, p, _ in withheld if p[at][0]]
        print(f"  {name} cells on the surface: pose median {np.median(fractions):.2f}, best decoy median "
              f"{np.nanmedian([b[at] for _, _, b in withheld]):.2f}")


if __name__ == "__main__":
    main()
