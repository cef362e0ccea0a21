"""regor-bench: Regor against the methods users would otherwise pick, on the shared real data.

One command line for every benchmark: pairs (and ``--mismatched``, pairs_benchmark), the 3DMatch /
3DLoMatch test lists (``--threedmatch``, threedmatch_benchmark), scan-to-map
relocalization (``--maps``) and map scaling (``--map-scaling``, map_benchmark), and regor-batch's
throughput (``--batch``, batch_benchmark). Each writes a markdown report, a per-registration CSV
and a plot into ``--out``, and prints the report.
"""
from __future__ import annotations

import argparse
from pathlib import Path

EPILOG = """examples:
  regor-bench ../shared/data/pairs --methods regor,kiss-matcher --rotate 1 2 3
  regor-bench --threedmatch ../shared/data/threedmatch --sample 200
  regor-bench --verify ../shared/data/pairs --maps ../shared/data/xseason
  regor-bench --maps ../shared/data/maps ../shared/data/revisit ../shared/data/xseason --methods regor,kiss-matcher

data formats:
  pairs folder: pairs.json, a list of {"name", "kind": indoor|outdoor|object, optional
    "src_viewpoint"/"tgt_viewpoint": [x, y, z] or null}, and <name>/src.npy, tgt.npy ((N, 3)
    float, metres), gt.txt (4x4 T_target_source)
  --threedmatch folder: pairs.json, a list of {"bench": 3DMatch|3DLoMatch, "scene", "i", "j",
    "T": 4x4 mapping fragment j into fragment i}, and <scene>/<k>.npy (viewpoint at the origin)
  --maps folder: one folder per sequence with map.npy, queries.json and queries/<id>/"""


def main(argv=None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    instead = next((flag for flag, given in (("--threedmatch", args.threedmatch), ("--maps", args.maps),
                                             ("--map-scaling", args.map_scaling), ("--batch", args.batch))
                    if given), None)
    if args.verify and instead not in (None, "--maps"):
        parser.error(f"--verify checks poses on folders of pairs and --maps, not with {instead}")
    if args.data and instead and not (args.profile or args.verify):
        # a folder it would not read, or an override that lost its --set: refused, not silently dropped
        parser.error(f"{instead} reads no folders of pairs, but {', '.join(map(str, args.data))} was given "
                     "(each override needs its own --set NAME=VALUE)")
    if any(item.split("=", 1)[0].strip() == "seed" for item in args.set) and instead is None \
            and not (args.profile or args.verify):
        # each pair's registration is seeded with its motion's seed (0 without --rotate): refused, not ignored
        parser.error("--set seed has no effect on pairs: a pair's registration takes its motion's seed "
                     "(--rotate SEED ...; 0 without); it applies with --threedmatch and --maps")
    if args.rotate and (instead or args.profile or args.verify):
        # only the pairs run moves its sources: a run meant under another motion would repeat this one
        parser.error(f"--rotate moves the sources of a run over folders of pairs; "
                     f"{instead or ('--profile' if args.profile else '--verify')} registers them as they are")
    if (args.stress or args.narrow) and (args.profile or args.verify or instead != "--maps"):
        parser.error("--stress and --narrow change the queries of a --maps run")
    if args.at_rest and not args.narrow:
        parser.error("--at-rest gives the views of --narrow at rest: give --narrow with it")
    if args.stress and args.narrow:
        parser.error("--stress and --narrow are two runs: give one")
    if args.no_viewpoints and (args.profile or instead not in (None, "--threedmatch")):
        parser.error("--no-viewpoints is for pairs and --threedmatch (a map's view comes from its trajectory)")
    # the benchmarks load open3d, the peers and the compiled kernels: only once the arguments are
    # known, so that --help and a mistyped option answer at once
    from ..core import warm_up
    from .pairs import run_pairs
    from .peers import METHODS
    from .profiling import run_profile
    from .threedmatch import run_threedmatch

    warm_up()  # numba's compile or cache load, before any clock starts (as the node does at configure)
    if args.profile:
        print(run_profile(args.data, args.maps, args.pairs, args.out, argv))
        return 0
    if args.verify:
        return _verify_main(args, argv, parser)
    if args.threedmatch:
        return run_threedmatch(args, argv, _methods(args.methods or "regor,kiss-matcher", METHODS, parser), parser)
    if args.maps or args.map_scaling or args.batch:
        return _map_main(args, argv, parser)
    if not args.data:
        parser.error("give one or more folders of pairs, or --maps / --map-scaling")

    return run_pairs(args, argv, _methods(args.methods, METHODS, parser), parser)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="regor-bench", description=__doc__.split("\n\n")[0], epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", type=Path, nargs="*",
                        help="folders with pairs.json and one folder per pair")
    parser.add_argument("--methods", help="comma-separated subset of regor (and its variants), o3d-ransac, "
                                          "o3d-fgr, kiss-matcher (default: all; with --threedmatch, --maps "
                                          "or --map-scaling: regor, kiss-matcher); a wrong name lists them all")
    parser.add_argument("--rotate", type=int, nargs="+", metavar="SEED",
                        help="move each source by a random rigid motion drawn from SEED; several "
                             "seeds give a mean and spread")
    parser.add_argument("--pairs", help="only pairs (with --maps: sequences) whose name contains one of "
                                        "these comma-separated strings")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a core parameter for every preset (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("bench-out"),
                        help="output folder (default: %(default)s; the committed figures are in results/)")
    parser.add_argument("--level", action="store_true",
                        help="the clouds come from level-mounted sensors in z-up frames (ground "
                             "vehicles): the gravity prior is on with each cloud's z axis up (a moved "
                             "source's up turns with it); regor-noprior runs without it")
    parser.add_argument("--imu-up", type=float, metavar="DEG",
                        help="with --maps: each query given its up as an IMU would give it, the truth's "
                             "tilted by DEG in a direction drawn per query, and the map's up (z); "
                             "regor-noprior runs without it")
    parser.add_argument("--no-viewpoints", action="store_true",
                        help="with pairs or --threedmatch: neither cloud's sensor position is given (a map "
                             "without its trajectory, clouds not in their sensors' frames): free space is not "
                             "checked, the normals keep the solver's signs and the partial feature count applies")
    parser.add_argument("--mismatched", action="store_true",
                        help="instead: register each source against targets of other places (one per "
                             "place and seed) and count the poses each method's gate accepts: all wrong")
    parser.add_argument("--maps", type=Path, nargs="+", metavar="DIR",
                        help="instead: scan-to-map relocalization on every sequence folder in each DIR "
                             "(map.npy, queries.json, queries/<id>/), Regor and KISS-Matcher; every query "
                             "is also registered against every other sequence's map (cross-map)")
    parser.add_argument("--stress", action="store_true",
                        help="with --maps: each map enlarged with the other places' maps (the true place "
                             "still inside), queries single, thinned to every 4th point and fused: chance "
                             "support is high")
    parser.add_argument("--narrow", action="store_true",
                        help="with --maps: each query scan as a narrow solid-state sensor at its origin would "
                             "see it (70 x 70 deg, a return per 0.7 deg), facing four ways: sparse scans, "
                             "and from xseason, sparse scans from another recording than their map's")
    parser.add_argument("--at-rest", action="store_true",
                        help="with --narrow: each view also as the frames of a narrow sensor at rest (its "
                             "pattern filling in), fused as the node fuses scans taken at rest without odometry")
    parser.add_argument("--map-scaling", type=Path, metavar="SEQUENCE",
                        help="instead: tile the map of one sequence folder --tiles times and measure "
                             "preparation, registration time and peak memory against map size")
    parser.add_argument("--tiles", type=int, nargs="+", default=[1, 2, 4, 7],
                        help="copies of the map for --map-scaling (default 1 2 4 7)")
    parser.add_argument("--batch", type=Path, metavar="DIR",
                        help="instead: regor-batch's throughput on every within-sequence pair of query "
                             "scans of the maps folder DIR, serially and on --workers local workers")
    parser.add_argument("--verify", action="store_true",
                        help="instead: verify given poses (the truth, nudged, made wrong ones, KISS-Matcher's) on "
                             "the pairs of the given folders and the queries of --maps, against ICP's fitness and "
                             "KISS-Matcher's inlier count")
    parser.add_argument("--profile", action="store_true",
                        help="instead: register the pairs of the given folders (and with --maps, every map "
                             "query) under cProfile and report the stage medians and the functions with the "
                             "most own time")
    parser.add_argument("--threedmatch", type=Path, metavar="DIR",
                        help="instead: the 3DMatch / 3DLoMatch test lists in DIR (pairs.json: a list of "
                             "{bench, scene, i, j, T}, T mapping fragment j into fragment i; <scene>/<k>.npy), "
                             "Regor and KISS-Matcher by default; RR per list, published correct / wrong / gross")
    parser.add_argument("--sample", type=int, metavar="N",
                        help="with --threedmatch: a fixed seeded sample of N pairs (the same N, the same pairs)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                        help="local worker processes for --batch (default 1 2)")
    return parser


def _methods(requested: str | None, available, parser) -> list[str]:
    """The methods named by --methods (all available ones when not given); an unknown or
    unsupported name is an error, not silently dropped."""
    if requested is None:
        return list(available)
    methods = [m.strip() for m in requested.split(",") if m.strip()]
    unknown = [m for m in methods if m not in available]
    if unknown or not methods:
        parser.error(f"unknown or unsupported method {(unknown or [requested])[0]!r} here; choose from "
                     f"{', '.join(available)}")
    return methods


def _verify_main(args, argv, parser) -> int:
    """--verify: given poses on the pair folders and the --maps queries, with --set overrides."""
    from ..core import ConfigError
    from ..tools.register_cli import parse_overrides
    from .results import header
    from .verify import run_verify

    if not args.data and not args.maps:
        parser.error("--verify needs folders of pairs, --maps folders, or both")
    try:
        overrides = parse_overrides(args.set)
    except ConfigError as exc:
        raise SystemExit(f"regor-bench: {exc}") from None
    print(run_verify(args.data, args.maps or [], overrides, args.pairs, args.out, header(
        "regor_ros verification benchmark", argv) + "Each pair or map query's poses, right and wrong, checked by "
        "verify() with the preset of its kind; success tolerances: RE < 15 deg and TE < 30 cm indoors, "
        "RE < 5 deg and TE < 60 cm outdoors (verification.max_correction)."))
    return 0


def _map_main(args, argv, parser) -> int:
    """--maps, --map-scaling and --batch: the outdoor preset (every map here is LiDAR) with --set overrides."""
    from ..core import ConfigError, RegorConfig
    from ..tools.register_cli import parse_overrides
    from .batch_scaling import run_batch_scaling
    from .datasets import TILE_SPACING
    from .maps import (
        AT_REST_NOTE,
        IMU_NOTE,
        LEVEL_MOUNTED,
        MAP_METHODS,
        NARROW_NOTE,
        STRESS_NOTE,
        run_maps,
        run_scaling,
    )
    from .results import LEVEL_NOTE, header

    try:
        if args.level and args.imu_up is not None:
            parser.error("--level and --imu-up both give the up: choose one")
        overrides = {**(LEVEL_MOUNTED if args.level else {}), **parse_overrides(args.set)}
        config = RegorConfig.preset("outdoor").replace(overrides)
    except ConfigError as exc:
        raise SystemExit(f"regor-bench: {exc}") from None
    about = ("Outdoor preset; success: RE < 5 deg and TE < 60 cm against "
             "the sequence's SLAM pose. Regor prepares the map once (its time is the preparation "
             "column) and registers each query against it; KISS-Matcher is given the scan and the map "
             "on every call. Peak memory is the resident peak of the process that ran the method.")
    if args.batch:
        report = run_batch_scaling(args.batch, args.workers, config, overrides, args.out, (
            header("regor_ros batch benchmark", argv) + "Every pair of query scans within each sequence of "
            f"`{args.batch}` (loop-closure candidates: each scan is in several pairs), outdoor preset; "
            "success: RE < 5 deg and TE < 60 cm against the sequences' SLAM poses. Serial: register() "
            "pair by pair in one process. regor-batch: a new local cluster per run (its start counted), "
            "worker processes started with this process's environment; identical: the same pose (every bit) and "
            "verdict "
            "as the serial run."))
    elif args.maps:
        report = run_maps(args.maps, _methods(args.methods, MAP_METHODS, parser), config, args.out,
                          header("regor_ros scan-to-map benchmark", argv) + about + LEVEL_NOTE * args.level
                          + STRESS_NOTE * args.stress + NARROW_NOTE * args.narrow + AT_REST_NOTE * args.at_rest
                          + (IMU_NOTE.format(args.imu_up) if args.imu_up is not None else ""), args.pairs,
                          args.stress, args.narrow, args.imu_up, args.at_rest)
    else:
        report = run_scaling(args.map_scaling, args.tiles, config, args.out, header(
            "regor_ros map scaling benchmark", argv) + about + " The map is tiled: identical copies "
            f"{TILE_SPACING:.0f} m apart, each turned about the vertical; a pose counts as correct against any copy. "
            "Every copy fits a query as well as the one the search found, so the gate withholds most poses as "
            "ambiguous (its rivals include the other places the search found), as it should in a map that repeats a "
            "place: the published count says so, the times and memory are what this benchmark measures. "
            "The cold start (the map prepared from its file, the cache written) and the warm start (the cache "
            "loaded, a robot's restart) with the queries run in processes of their own: each peak is that start's.")
    print(report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
