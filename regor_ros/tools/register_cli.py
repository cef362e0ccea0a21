"""regor-register: register two point cloud files with Regor and print T_target_source.

Reads .ply, .pcd, .xyz/.txt, .npy (N x 3) and KITTI .bin. Exit status: 0 registered and
accepted, 1 registered but not accepted by the quality gate, 2 the input could not be read or
registered (one-line reason on stderr).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from ..core import (
    PRESETS,
    ConfigError,
    RegistrationError,
    RegorConfig,
    parse_viewpoint,
)
from ..io.cloud_io import FORMATS, read_cloud

DEFAULT_PRESET = "indoor"   # register_node's, and every tool's: one rule
PRESET_HELP = ("the sensor's parameter set: indoor (RGB-D cameras, rooms; 5 cm voxels), outdoor (LiDAR; 30 cm), "
               "object (scanned objects); default: indoor in every tool, as register_node's (a map at the wrong "
               "scale is refused with the preset that fits)")


def parse_overrides(items):
    overrides = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ConfigError(f"--set {item!r}: expected NAME=VALUE, e.g. voxel_size=0.04")
        overrides[name.strip()] = value.strip()
    return overrides


def report(result, ground_truth=None) -> dict:
    from ..core import rotation_error_deg, translation_error  # scipy's load: not for --help
    out = {"transform": result.transform.tolist(), **result.summary().as_json()}
    if ground_truth is not None:
        out["rotation_error_deg"] = rotation_error_deg(result.transform, ground_truth)
        out["translation_error_m"] = translation_error(result.transform, ground_truth)
    return out


def print_text(rep: dict) -> None:
    np.set_printoptions(precision=6, suppress=True)
    print("T_target_source (maps source points into the target frame):")
    print(np.array(rep["transform"]))
    figures = rep["figures"]
    print(f"inliers: {figures['num_inliers']:.0f} of {rep['source_keypoints']} source keypoints "
          f"(fitness {figures['fitness']:.3f}), RMSE {rep['inlier_rmse']:.4f} m, "
          f"{figures['feature_inliers']:.0f} feature matches agree")
    worst = figures["worst_free_space"]
    if worst is not None:
        print(f"free space: {100 * worst:.1f} % of a cloud inside space the other sensor saw through")
    print("stages: " + ", ".join(f"{k} {v}" for k, v in rep["stage_sizes"].items()))
    print("timings [s]: " + ", ".join(f"{k} {v:.3f}" for k, v in rep["timings"].items()))
    if "rotation_error_deg" in rep:
        print(f"error against ground truth: rotation {rep['rotation_error_deg']:.3f} deg, "
              f"translation {rep['translation_error_m']:.4f} m")
    print("accepted" if rep["accepted"] else f"NOT accepted: {rep['reason']}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="regor-register", description=__doc__.split("\n\n")[0],
                                     epilog="examples:\n  regor-register demo/src.npy demo/tgt.npy --ground-truth "
                                            "demo/gt.txt --picture out.png\n  regor-register scan.pcd map.pcd "
                                            "--preset outdoor --target-viewpoint none --json\n\n"
                                            f"formats: {', '.join(FORMATS)}",
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("source", help="cloud to move")
    parser.add_argument("target", help="cloud it is registered to")
    parser.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET, help=PRESET_HELP)
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="override a parameter, e.g. --set voxel_size=0.04 (repeatable)")
    for side in ("source", "target"):
        parser.add_argument(f"--{side}-viewpoint", default="auto", metavar="'X,Y,Z'|none",
                            help=f"where the {side} sensor sat in its cloud's frame, for the free-space "
                                 "check; 'none' for a cloud aggregated along a trajectory (default: the origin)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--output", metavar="T.txt", help="write the 4x4 matrix to this file")
    parser.add_argument("--picture", metavar="OUT.png", help="render the clouds before/after and the correspondences")
    parser.add_argument("--ground-truth", metavar="GT.txt", help="4x4 T_target_source to compare with")
    args = parser.parse_args(argv)
    from ..core import register  # after parsing: --help and argument errors answer without loading it

    try:
        config = RegorConfig.preset(args.preset).replace(parse_overrides(args.set))
        source, target = read_cloud(args.source), read_cloud(args.target)
        truth = None
        if args.ground_truth:
            try:
                truth = np.loadtxt(args.ground_truth).reshape(4, 4)
            except (OSError, ValueError) as exc:
                raise RegistrationError(f"{args.ground_truth}: not a 4x4 matrix ({exc})") from None
        result = register(source, target, config,
                          source_viewpoint=parse_viewpoint(args.source_viewpoint, "--source-viewpoint"),
                          target_viewpoint=parse_viewpoint(args.target_viewpoint, "--target-viewpoint"))
    except (ConfigError, RegistrationError) as exc:
        print(f"regor-register: {exc}", file=sys.stderr)
        return 2

    rep = report(result, truth)
    if args.output:
        np.savetxt(args.output, result.transform, fmt="%.9f")
    if args.picture:
        from .picture import render
        render(source, target, result, args.picture)
    if args.json:
        print(json.dumps(rep, indent=2))
    else:
        print_text(rep)
    return 0 if result.accepted else 1


if __name__ == "__main__":
    raise SystemExit(main())
